"""Row-gain compensation: inverse of the device's encoding, bad gains, and one target's echo across ranges."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.oculus import sonar_ping_from
from drivers.oculus_protocol import FireSettings, decode_ping, encode_ping
from msgs.sonar import SonarPing
from nodes.sonar.gain import compensate_row_gains
from nodes.sonar.polar_imager import PolarImager
from tether.testing import Harness


@pytest.mark.parametrize("bits", [8, 16])
def test_undoes_what_the_device_applied(bits: int) -> None:
    rng = np.random.default_rng(0)
    full = 255 if bits == 8 else 65535
    level = rng.uniform(0.0, 0.2, (300, 64))
    gains = 10 ** np.linspace(-0.5, 0.6, 300)                      # -5 .. +6 dB over the rows
    sample = lambda g: np.rint(full * np.clip(level * g[:, None], 0, 1) ** 0.5).astype(f"uint{bits}")
    out = compensate_row_gains(sample(gains), gains.astype(np.float32), 0.5)
    assert out.status == "applied" and out.image.dtype == np.dtype(f"uint{bits}")
    np.testing.assert_allclose(out.image.astype(float), sample(np.ones(300)).astype(float), atol=2.0)


def test_no_gains_and_unit_gains_change_nothing() -> None:
    img = np.arange(12, dtype=np.uint8).reshape(4, 3)
    assert compensate_row_gains(img, np.zeros(0), 0.5).status == "absent"
    np.testing.assert_array_equal(compensate_row_gains(img, np.ones(4), 0.5).image, img)


@pytest.mark.parametrize("gains", [np.zeros(4), -np.ones(4), np.full(4, np.nan)])
def test_all_bad_gains_pass_through_unscaled(gains: np.ndarray) -> None:
    img = np.full((4, 3), 100, np.uint8)
    out = compensate_row_gains(img, gains, 0.5)
    assert out.status == "invalid" and out.bad_rows == 4
    np.testing.assert_array_equal(out.image, img)


def test_a_bad_row_takes_its_neighbours_gain_and_nan_samples_do_not_survive() -> None:
    img = np.full((5, 3), 100.0, np.float32)
    img[2, 1] = np.nan
    out = compensate_row_gains(img, np.array([4.0, 4.0, np.nan, 4.0, 0.0]), 0.5)
    assert out.status == "repaired" and out.bad_rows == 2 and np.all(np.isfinite(out.image))
    np.testing.assert_allclose(out.image[[0, 1, 3, 4]], 50.0)
    assert out.image[2, 1] == 0 and out.image[2, 0] == 50.0
    assert compensate_row_gains(img, np.ones(3), 0.5).status == "mismatch"


def _ping(intensities: np.ndarray, gains: np.ndarray) -> SonarPing:
    return SonarPing(stamp_ns=1, intensities=intensities, bearings_rad=np.radians(np.linspace(-30, 30, 64)).astype(np.float32),
                     range_resolution_m=0.05, range_m=10.0, gamma=0.5, row_gains=gains.astype(np.float32))


def test_imager_counts_bad_gains_and_nan_does_not_spread() -> None:
    img = np.full((200, 64), 80.0, np.float32)
    img[100, 32] = np.nan
    gains = np.ones(200)
    gains[50] = np.nan
    with Harness(PolarImager, params={"width_px": 256, "backend": "numpy"}) as h:
        h.feed([(0.0, "ping", _ping(img, gains)), (0.1, "ping", _ping(img, np.zeros(200)))])
    images = [np.asarray(m.image) for m in h.of("image")]
    masks = [np.asarray(m.mask).astype(bool) for m in h.of("image")]
    assert h.node.gain_problems == {"invalid": 1, "mismatch": 0, "repaired": 1}
    for im, mask in zip(images, masks):
        assert np.all(np.isfinite(im)) and np.median(im[mask]) == pytest.approx(80.0)


def _echo_db(d: float, slope_db_per_m: float, apply: bool, bits: int = 8) -> float:
    """Peak echo (intensity dB of full scale, top 5 px) of a pile d m ahead, through the Oculus wire format."""
    from sim.fls import load_scene, render_ping, settings_from_fire
    from sim.fls_scene import sonar_frame

    scene = load_scene("cylinder")                          # pile axis at (2, 0)
    fire = FireSettings.make(range_m=20, gain_percent=0, gamma=127, frequency="low", bits=bits, beams=256,
                             row_gain=True)
    r = render_ping(scene, sonar_frame(np.array([2.0 - d, 0.0, -1.0]), 0.0, scene.sonar.tilt_rad),
                    settings_from_fire(fire, scene, 16, slope_db_per_m), rng=None)
    data = encode_ping(r.intensities, r.bearings_cdeg, fire=fire, version=2, ping_id=1, ping_start_time=1.0,
                       range_resolution_m=r.range_resolution_m, row_gains=r.row_gains)
    ping = sonar_ping_from(decode_ping(data), stamp_ns=1)
    with Harness(PolarImager, params={"width_px": 512, "row_gains": "apply" if apply else "ignore"}) as h:
        h.feed([(0.0, "ping", ping)])
    im = h.of("image")[0]
    img = np.asarray(im.image, float) / (255 if bits == 8 else 65535)
    rows, cols = np.indices(img.shape)
    near = np.hypot((cols - im.origin_col_px) * im.m_per_px, (im.origin_row_px - rows) * im.m_per_px - d) < 1.0
    return 10 / ping.gamma * math.log10(np.sort(img[near])[-5:].mean())


@pytest.mark.parametrize("bits", [8, 16])
def test_one_target_keeps_its_echo_as_range_and_row_gain_change(bits: int) -> None:
    # The sonar amplifies far rows (+1 dB/m, -10..+10 dB over 20 m) and says so in every row's gain.
    # Compensated, the pile's echo at 5-14 m is what it is with a gain of 1 on every row (the scene's
    # own fall with range: absorption and footprint); uncompensated it is off by the row gain.
    ranges = (5.0, 8.0, 11.0, 14.0)
    flat = np.array([_echo_db(d, 0.0, True, bits) for d in ranges])
    fixed = np.array([_echo_db(d, 1.0, True, bits) for d in ranges])
    raw = np.array([_echo_db(d, 1.0, False, bits) for d in ranges])
    assert np.all(flat < -1.0)                               # not saturated: the comparison means something
    assert np.abs(fixed - flat).max() < 0.5, (fixed, flat)   # well within the 3 dB goal
    assert np.abs(raw - flat).max() > 3.0, (raw, flat)
