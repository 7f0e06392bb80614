"""Highlight extension (eq. 7-17): effective region, front-end detection and 3D points on analytic pings."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.sonar.highlight import (detect_front_ends, down_from_tilt, edge_rays, effective_region,
                                   extract_line_scan, frd_to_flu, split_regions)

H, TILT, SPREAD = 5.0, np.deg2rad(15), np.deg2rad(20)
DR, M = 0.02, 1200                                   # 24 m of range
BEARINGS = np.deg2rad(np.linspace(-60, 60, 128))


def _ping(front_ranges: dict[int, float], region, *, rng=None, speckle: float = 0.0) -> np.ndarray:
    """Dark water column, bright seafloor from r_emin, and a 0.6 m highlight from each front range."""
    r = (np.arange(M) + 0.5) * DR
    img = np.full((M, BEARINGS.size), 10.0)
    img[r[:, None] >= region.r_emin_m[None, :]] = 120.0
    for j, rf in front_ranges.items():
        img[(r >= rf) & (r < rf + 0.6), j] = 230.0
    if rng is not None:
        img *= rng.exponential(1.0, img.shape) ** speckle
    return np.clip(img, 0, 255).astype(np.uint8)


def test_effective_region_matches_eq_7_8() -> None:
    reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR, model="paper")
    np.testing.assert_allclose(reg.r_emin_m, H / np.sin(TILT + SPREAD / 2))
    np.testing.assert_allclose(reg.r_emax_m, H / np.sin(TILT - SPREAD / 2))
    np.testing.assert_allclose(reg.m_emin, M * reg.r_emin_m / (M * DR))          # eq. (9), r_min = 0
    assert np.all(reg.m_emax == M)                                                # r_emax = 57 m > r_max


def test_upper_edge_at_or_above_horizon_makes_r_emax_infinite() -> None:
    for tilt in (SPREAD / 2, SPREAD / 4):                                         # t - s/2 = 0 and < 0
        for model in ("paper", "beam"):
            reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=tilt, n_ranges=M, range_resolution_m=DR,
                                   model=model)
            assert np.all(np.isinf(reg.r_emax_m)) and np.all(reg.m_emax == M)
            assert np.all(np.isfinite(reg.r_emin_m))
            s1, s2, s3 = split_regions(np.zeros((M, BEARINGS.size)), reg)
            assert not s3.any() and np.all(s1 ^ s2)


def test_sonar_looking_up_sees_no_seafloor() -> None:
    reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=-SPREAD, n_ranges=M, range_resolution_m=DR)
    assert np.all(np.isinf(reg.r_emin_m)) and np.all(reg.m_emin == M)
    scan = extract_line_scan(np.full((M, BEARINGS.size), 40, np.uint8), BEARINGS, DR, altitude_m=H,
                             tilt_rad=-SPREAD, spread_rad=SPREAD)
    assert scan.points_m.shape == (0, 3)                  # no seafloor to fill in, nothing detected


def test_beam_model_equals_paper_on_the_centre_beam_and_is_shallower_at_the_edges() -> None:
    paper = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR, model="paper")
    beam = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR, model="beam")
    b0 = effective_region(np.array([0.0, 0.01]), H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR)
    assert b0.r_emin_m[0] == pytest.approx(paper.r_emin_m[0])
    assert beam.r_emin_m[0] > 1.3 * paper.r_emin_m[0]      # the 60 deg beam's lower edge is much shallower


@pytest.mark.parametrize("model", ["beam", "paper"])
def test_front_ends_become_points_on_the_lower_edge(model: str) -> None:
    reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR, model=model)
    fronts = {j: 0.6 * reg.r_emin_m[j] + 0.0037 * j for j in range(40, 90)}
    scan = extract_line_scan(_ping(fronts, reg), BEARINGS, DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD,
                             model=model, sigma_px=1.0, sigma_beam_px=0.0)
    det = dict(zip(scan.beams[scan.detected], scan.points_m[scan.detected]))
    assert set(det) == set(fronts)
    iso = extract_line_scan(_ping(fronts, reg), BEARINGS, DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD,
                            model=model, sigma_px=1.0)
    assert set(fronts) <= set(iso.beams[iso.detected]) <= set(range(39, 91))   # across-beam blur: +-1 beam
    for j, rf in fronts.items():
        assert np.linalg.norm(det[j]) == pytest.approx(rf, abs=1.5 * DR)
        if model == "beam":
            np.testing.assert_allclose(det[j] / np.linalg.norm(det[j]), edge_rays(BEARINGS[j:j + 1], SPREAD)[0])
        else:   # eq. (17) in the level frame: depth below the sonar = r sin(t + s/2)
            depth = det[j] @ down_from_tilt(TILT)
            assert depth == pytest.approx(np.linalg.norm(det[j]) * np.sin(TILT + SPREAD / 2), rel=1e-9)
    # seafloor fill (m(j) = M_emin) lies on the seafloor: depth below the sonar = altitude
    floor = scan.points_m[~scan.detected] @ down_from_tilt(TILT)
    assert floor.size == BEARINGS.size - len(fronts)
    np.testing.assert_allclose(floor, H, atol=DR * np.sin(TILT + SPREAD / 2) + 1e-9)


def test_several_peaks_in_a_column_pick_the_front_end() -> None:
    reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR)
    r = (np.arange(M) + 0.5) * DR
    img = _ping({}, reg).astype(float)
    j = 64
    for start, level in [(6.0, 200.0), (8.0, 250.0), (10.0, 180.0)]:        # the strongest is not the first
        img[(r >= start) & (r < start + 0.5), j] = level
    rows, strength = detect_front_ends(img.astype(np.uint8), reg.m_emin, sigma_px=1.0, sigma_beam_px=0.0)
    assert (rows[j] + 0.5) * DR == pytest.approx(6.0, abs=1.5 * DR)
    assert np.isnan(rows[j + 5]) and strength[j] > 0.4


@pytest.mark.parametrize("kind", ["zero", "saturated", "garbage", "nan", "uint16"])
def test_hard_pings_stay_finite(kind: str) -> None:
    rng = np.random.default_rng(3)
    ping = {"zero": np.zeros((M, 128), np.uint8), "saturated": np.full((M, 128), 255, np.uint8),
            "garbage": rng.integers(0, 256, (M, 128), dtype=np.uint8),
            "nan": np.where(rng.random((M, 128)) < 0.1, np.nan, 0.2).astype(np.float32),
            "uint16": (rng.random((M, 128)) * 2000).astype(np.uint16)}[kind]
    scan = extract_line_scan(ping, BEARINGS, DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD)
    assert np.all(np.isfinite(scan.points_m)) and np.all(np.isfinite(scan.strength))
    assert np.all(np.linalg.norm(scan.points_m, axis=1) <= M * DR + 1e-9)
    if kind in ("zero", "saturated", "nan", "uint16"):
        assert not scan.detected.any() and len(scan.beams) == 128     # seafloor fill only


def test_speckle_with_blur_still_finds_the_front() -> None:
    rng = np.random.default_rng(4)
    reg = effective_region(BEARINGS, H, SPREAD, tilt_rad=TILT, n_ranges=M, range_resolution_m=DR)
    fronts = {j: 7.0 for j in range(50, 80)}
    ping = _ping(fronts, reg, rng=rng, speckle=0.5)
    scan = extract_line_scan(ping, BEARINGS, DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD, sigma_px=2.5,
                             threshold=0.15)
    ranges = np.linalg.norm(scan.points_m[scan.detected], axis=1)
    hits = np.isin(scan.beams[scan.detected], list(fronts))
    assert hits.sum() >= 27 and (~hits).sum() <= 3
    assert np.median(np.abs(ranges[hits] - 7.0)) < 3 * DR


def test_bad_arguments_raise() -> None:
    ping = np.zeros((M, 128), np.uint8)
    with pytest.raises(ValueError, match="altitude"):
        extract_line_scan(ping, BEARINGS, DR, altitude_m=0.0, tilt_rad=TILT, spread_rad=SPREAD)
    with pytest.raises(ValueError, match="one bearing per beam"):
        extract_line_scan(ping, BEARINGS[:-1], DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD)
    with pytest.raises(ValueError, match="model"):
        extract_line_scan(ping, BEARINGS, DR, altitude_m=H, tilt_rad=TILT, spread_rad=SPREAD, model="cone")


def test_frd_to_flu() -> None:
    np.testing.assert_array_equal(frd_to_flu(np.array([[1.0, 2.0, 3.0]])), [[1.0, -2.0, -3.0]])
