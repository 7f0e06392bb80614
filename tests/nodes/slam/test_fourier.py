"""Fourier registration: exact sub-pixel shifts, the sign conventions against OpenCV and
scikit-image, rotation with its 180-degree ambiguity, and the cases that must yield no
constraint (blank, periodic, disjoint, masks that do not overlap)."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from nodes.slam import fourier
from nodes.slam.fourier import is_reliable, phase_correlate, register, warp

N, PAD = 256, 48


def texture(seed: int, n: int = N + 2 * PAD) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((n, n), np.float32)
    for sigma, amp in ((2, 0.5), (6, 1.0), (16, 1.5)):
        layer = cv2.GaussianBlur(rng.random((n, n)).astype(np.float32), (0, 0), sigma)
        img += amp * (layer - layer.mean()) / layer.std()
    return (1 / (1 + np.exp(-img))).astype(np.float32)


def shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Exact band-limited shift of the content by (+dx, +dy)."""
    fy, fx = np.fft.fftfreq(img.shape[0])[:, None], np.fft.fftfreq(img.shape[1])[None, :]
    return np.fft.ifft2(np.fft.fft2(img) * np.exp(-2j * np.pi * (fx * dx + fy * dy))).real.astype(np.float32)


def crop(img: np.ndarray) -> np.ndarray:
    return img[PAD:PAD + N, PAD:PAD + N]


@pytest.mark.parametrize("dx, dy", [(0.0, 0.0), (3.25, -7.6), (-15.5, 11.125), (0.4, 0.0), (20.0, 19.9)])
def test_exact_subpixel_shifts_are_recovered(dx, dy):
    base = texture(1)
    s = phase_correlate(crop(base), crop(shifted(base, dx, dy)))
    # Below FOLLOW_FRACTION of the size one pass runs, and the fixed window's pull is <= 0.05 px there.
    tol = 0.03 if max(abs(dx), abs(dy)) > fourier.FOLLOW_FRACTION * N else 0.05
    assert s.dx == pytest.approx(dx, abs=tol) and s.dy == pytest.approx(dy, abs=tol)
    assert s.pnr > 20 and is_reliable(s)
    sd = np.sqrt(np.diag(s.covariance))
    assert np.all(sd > 0) and np.all(sd < 0.5)


def test_sign_conventions_match_opencv_and_are_opposite_to_skimage():
    phase_cross_correlation = pytest.importorskip("skimage.registration").phase_cross_correlation   # bench extra

    base = texture(2)
    a, b = crop(base), crop(shifted(base, 6.0, -4.0))
    ours = phase_correlate(a, b)
    (cx, cy), _ = cv2.phaseCorrelate(a, b, cv2.createHanningWindow((N, N), cv2.CV_32F))
    rows_cols = phase_cross_correlation(a, b, upsample_factor=10)[0]
    assert np.sign(ours.dx) == np.sign(cx) == -np.sign(rows_cols[1]) == 1
    assert np.sign(ours.dy) == np.sign(cy) == -np.sign(rows_cols[0]) == -1


def test_speckle_does_not_break_it():
    rng = np.random.default_rng(3)
    base = texture(3)
    a = crop(base) * rng.gamma(1.0, 1.0, (N, N)).astype(np.float32)       # 1-look speckle, independent
    b = crop(shifted(base, -8.3, 5.7)) * rng.gamma(1.0, 1.0, (N, N)).astype(np.float32)
    s = phase_correlate(a, b)
    assert math.hypot(s.dx + 8.3, s.dy - 5.7) < 0.6 and is_reliable(s)


@pytest.mark.parametrize("angle_deg", [0.0, 12.0, -35.0, 90.0, 170.0, -170.0, 180.0])
def test_rotation_and_the_180_degree_ambiguity(angle_deg):
    big = texture(4)
    angle = math.radians(angle_deg)
    moved = warp(big, angle, 4.0, -3.0, interpolation=cv2.INTER_CUBIC)
    reg = register(crop(big), crop(moved))
    err = math.degrees((reg.angle - angle + math.pi) % (2 * math.pi) - math.pi)
    assert abs(err) < 0.5, f"170 deg read as {math.degrees(reg.angle):.2f}"   # not -10 (mod 180)
    assert reg.dx == pytest.approx(4.0, abs=0.3) and reg.dy == pytest.approx(-3.0, abs=0.3)
    assert is_reliable(reg)


def test_an_angle_hint_skips_the_rotation_search():
    big = texture(5)
    moved = warp(big, math.radians(30), 2.0, 1.0, interpolation=cv2.INTER_CUBIC)
    reg = register(crop(big), crop(moved), angle_hint=math.radians(30))
    assert reg.angle == pytest.approx(math.radians(30)) and reg.dx == pytest.approx(2.0, abs=0.3)


def test_blank_periodic_and_disjoint_images_give_no_constraint():
    a = crop(texture(6))
    blank = phase_correlate(a, np.full_like(a, 0.5))
    assert not is_reliable(blank)
    other = phase_correlate(a, crop(texture(7)))                          # shares nothing
    assert not is_reliable(other) and other.pnr < 8
    y, x = np.mgrid[:N, :N]
    stripes = np.sin(2 * np.pi * x / 16.0).astype(np.float32)             # a period of 16 px: which peak?
    periodic = phase_correlate(stripes, np.roll(stripes, 5, axis=1))
    assert not is_reliable(periodic) and periodic.ambiguity == 1.0
    grating = (np.sin(2 * np.pi * x / 16.0) + np.sin(2 * np.pi * y / 11.0)).astype(np.float32)
    assert not is_reliable(phase_correlate(grating, np.roll(grating, (3, 4), axis=(0, 1))))
    lines = crop(texture(10)).mean(axis=0, keepdims=True).repeat(N, axis=0)     # texture along x only
    assert not is_reliable(phase_correlate(lines, np.roll(lines, (7, 2), axis=(0, 1))))
    assert phase_correlate(np.zeros((N, N)), np.zeros((N, N))).pnr == 0.0
    nan = crop(texture(8)).copy()
    nan[:10] = np.nan
    assert np.isfinite(phase_correlate(nan, nan).dx)


def test_fan_masks_the_overlap_and_zero_overlap():
    base = texture(9)
    a, b = crop(base), crop(shifted(base, 10.0, 6.0))
    y, x = np.mgrid[:N, :N]
    fan = np.hypot(x - N / 2, y - N) < N * 0.9                            # a fan-like region from the bottom
    fan &= np.abs(np.arctan2(x - N / 2, N - y)) < math.radians(60)
    s = phase_correlate(a, b, fixed_mask=fan, moving_mask=fan)
    assert s.dx == pytest.approx(10.0, abs=0.3) and s.dy == pytest.approx(6.0, abs=0.3) and s.overlap > 0.8
    left, right = x < N * 0.3, x > N * 0.7
    none = phase_correlate(a, b, fixed_mask=left, moving_mask=right)
    assert not is_reliable(none)


def test_shape_and_argument_errors_say_what_is_wrong():
    with pytest.raises(ValueError, match="images differ in shape"):
        phase_correlate(np.zeros((32, 32)), np.zeros((32, 16)))
    with pytest.raises(ValueError, match="band"):
        phase_correlate(np.zeros((32, 32)), np.zeros((32, 32)), band=0.0)
    with pytest.raises(ValueError, match="2-D array of at least 8"):
        phase_correlate(np.zeros(32), np.zeros(32))


def test_covariance_is_calibrated_under_speckle():
    """Predicted standard deviations match the spread of the errors within a factor of 3."""
    errors, predicted = [], []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        base = texture(100 + seed)
        dx, dy = rng.uniform(-10, 10, 2)
        a = crop(base) * rng.gamma(4.0, 0.25, (N, N)).astype(np.float32)
        b = crop(shifted(base, dx, dy)) * rng.gamma(4.0, 0.25, (N, N)).astype(np.float32)
        s = phase_correlate(a, b)
        errors += [s.dx - dx, s.dy - dy]
        predicted += list(np.sqrt(np.diag(s.covariance)))
    ratio = np.sqrt(np.mean(np.square(errors))) / np.sqrt(np.mean(np.square(predicted)))
    assert 1 / 3 < ratio < 3, ratio
