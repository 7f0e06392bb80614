"""Self-calibration (seed 12) on synthetic correspondences with a known camera: accuracy on
general motion and a rotating camera, and the critical motions flagged, never a NaN."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nodes.vision.planar_selfcal import estimate_division, homographies, planar_selfcal, undistort_division
from nodes.vision.selfcal import (PairGeometry, _normaliser, _normalise_F, bougnoux_focal, fixation_px,
                                  kruppa_residuals, pair_geometry, self_calibrate)
from sim.camera_motion import K_CHESSBOARD, camera_views, correspondences, look_at, project

SIZE = (640, 480)
K = K_CHESSBOARD


def _calibrate(motion: str, noise: float, seed: int = 0, n_views: int = 8, n_points: int = 300):
    rng = np.random.default_rng(seed)
    pairs = correspondences(camera_views(motion, n_views=n_views, rng=rng), K, noise_px=noise, rng=rng,
                            n_points=n_points)
    geo = [pair_geometry(a, b, sigma_px=max(noise, 0.3)) for a, b in pairs]
    return self_calibrate(geo, SIZE), geo


def _f_err(cal) -> float:
    return max(abs(cal.K[0, 0] - K[0, 0]) / K[0, 0], abs(cal.K[1, 1] - K[1, 1]) / K[1, 1])


def _finite(cal) -> None:
    assert np.all(np.isfinite(cal.K)) and cal.K[0, 0] > 0 and cal.K[1, 1] > 0


def test_kruppa_equations_hold_at_the_true_camera_only():
    rng = np.random.default_rng(1)
    geo = [pair_geometry(a, b) for a, b in correspondences(camera_views("general", n_views=4, rng=rng), K,
                                                            noise_px=0.0, rng=rng)]
    T = _normaliser(SIZE)
    Fn = [_normalise_F(g.F, T) for g in geo]
    Kn = T @ K
    true = np.array([Kn[0, 0], Kn[1, 1], Kn[0, 2], Kn[1, 2]])
    assert np.abs(kruppa_residuals(true, Fn)).max() < 1e-6
    assert np.abs(kruppa_residuals(true * [1.2, 1.2, 1, 1], Fn)).max() > 1e-3


def test_bougnoux_closed_form_on_an_exact_pair():
    rng = np.random.default_rng(2)
    Ks = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    a, b = correspondences(camera_views("general", n_views=2, rng=rng), Ks, noise_px=0.0, rng=rng)[0]
    g = pair_geometry(a, b)
    assert np.sqrt(bougnoux_focal(g.F, (320, 240))) == pytest.approx(700, rel=1e-3)


def test_general_motion_at_half_a_pixel_is_within_two_percent():
    for seed in range(3):
        cal, _ = _calibrate("general", 0.5, seed)
        assert not cal.degenerate, cal.reasons
        assert _f_err(cal) < 0.02
        assert abs(cal.K[0, 2] - K[0, 2]) < 15 and abs(cal.K[1, 2] - K[1, 2]) < 15
        assert np.all(np.isfinite(cal.sigma_px)) and cal.sigma_px[0] > 0
        assert _f_err(cal) * K[0, 0] < 6 * max(cal.sigma_px[0], cal.sigma_px[1]) + 1.0   # sigma is not fiction


def test_purely_rotating_camera_uses_the_infinite_homography():
    cal, geo = _calibrate("rotation", 0.5)
    assert all(g.model == "H" for g in geo)
    assert cal.method == "rotation" and not cal.degenerate
    assert _f_err(cal) < 0.01


@pytest.mark.parametrize("motion,words", [("translation", "translated"), ("fixating", "optical axes meet"),
                                          ("single_axis", "unconstrained")])
def test_critical_motions_are_flagged_with_a_reason_and_finite_numbers(motion, words):
    for noise in (0.0, 0.5):
        cal, _ = _calibrate(motion, noise)
        assert cal.degenerate, (motion, noise)
        assert any(words in r for r in cal.reasons), cal.reasons
        _finite(cal)


def test_a_single_motion_is_not_enough():
    rng = np.random.default_rng(3)
    a, b = correspondences(camera_views("general", n_views=2, rng=rng), K, noise_px=0.5, rng=rng)[0]
    cal = self_calibrate([pair_geometry(a, b)], SIZE)
    assert cal.degenerate and any("at least two" in r for r in cal.reasons)
    _finite(cal)


def test_rotations_below_five_degrees_are_flagged_or_honest():
    for seed in range(3):
        cal, _ = _calibrate("small_rotation", 1.0, seed)
        _finite(cal)
        if not cal.degenerate:
            assert _f_err(cal) * K[0, 0] < 4 * max(cal.sigma_px[:2]) + 1.0


def test_too_few_matches_are_dropped_and_said():
    cal, geo = _calibrate("general", 0.5, n_points=12)
    assert any("fewer than 20 inlier matches" in r for r in cal.reasons)
    assert cal.degenerate
    _finite(cal)
    assert pair_geometry(np.zeros((5, 2)), np.zeros((5, 2))).model == "none"


def test_rank_three_F_from_noise_is_projected_and_rank_one_is_dropped():
    rng = np.random.default_rng(4)
    geo = [pair_geometry(a, b) for a, b in correspondences(camera_views("general", n_views=6, rng=rng), K,
                                                            noise_px=0.0, rng=rng)]
    T = _normaliser(SIZE)
    Ti = np.linalg.inv(T)

    def rank3(F):             # a small full-rank perturbation in normalised coordinates, where F is well scaled
        Fn = Ti.T @ F @ Ti
        Fn = Fn / np.linalg.norm(Fn) + 1e-4 * rng.normal(size=(3, 3))
        return T.T @ Fn @ T
    noisy = [PairGeometry(g.n_matches, "F", rank3(g.F), None, g.inliers_F, 0) for g in geo]
    assert min(np.linalg.svd(p.F, compute_uv=False)[2] for p in noisy) > 0          # rank 3 as given
    cal = self_calibrate(noisy, SIZE)
    assert not cal.degenerate and _f_err(cal) < 0.02
    u = np.array([[1.0], [2.0], [3.0]])
    rank1 = [PairGeometry(100, "F", u @ u.T, None, 100, 0)] * 3
    cal = self_calibrate(rank1 + noisy[:1], SIZE)
    assert cal.degenerate and any("rank 1" in r for r in cal.reasons)
    _finite(cal)


def test_fixating_pairs_put_the_principal_points_on_each_others_epipolar_lines():
    rng = np.random.default_rng(5)
    a, b = correspondences(camera_views("fixating", n_views=2, rng=rng), K, noise_px=0.0, rng=rng)[0]
    g = pair_geometry(a, b)
    assert fixation_px(g.F / np.linalg.norm(g.F), (K[0, 2], K[1, 2])) < 0.5
    f2 = bougnoux_focal(g.F / np.linalg.norm(g.F), (K[0, 2], K[1, 2]))
    assert not (0.8 * K[0, 0] ** 2 < f2 < 1.2 * K[0, 0] ** 2)     # Bougnoux has no answer there


def _plane_views(n: int, rng, lam: float = 0.0):
    """A 9x6 grid on a plane seen from n cameras, optionally with division-model distortion."""
    gx, gy = np.meshgrid(np.arange(9) * 0.1 - 0.4, np.arange(6) * 0.1 - 0.25)
    X = np.stack([gx.ravel(), gy.ravel(), np.zeros(54)], axis=1)
    views = []
    for _ in range(n):
        C = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), -rng.uniform(0.8, 1.2)])
        R = look_at(C, rng.uniform(-0.1, 0.1, 3) * [1, 1, 0], rng.uniform(-0.3, 0.3))
        x, _ = project(K, type("V", (), {"R": R, "C": C})(), X)
        x = x + rng.normal(0, 0.2, x.shape)
        if lam:
            # inverse of the division model about the image centre, by fixed-point iteration
            c, s = np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2]), sum(SIZE) / 2
            u = (x - c) / s
            d = u.copy()
            for _ in range(50):
                d = u * (1 + lam * (d ** 2).sum(axis=1, keepdims=True))
            x = c + s * d
        views.append(x)
    return views


def test_planar_selfcal_from_an_unknown_plane():
    rng = np.random.default_rng(6)
    views = _plane_views(10, rng)
    cal = planar_selfcal(homographies(views), SIZE)
    assert not cal.degenerate, cal.reasons
    assert _f_err(cal) < 0.02


def test_planar_selfcal_estimates_the_distortion_it_needs():
    rng = np.random.default_rng(7)
    views = _plane_views(10, rng, lam=-0.15)
    plain = planar_selfcal(homographies(views), SIZE)
    lam, centre, scale = estimate_division(views, SIZE)
    assert lam == pytest.approx(-0.15, abs=0.03)
    cal = planar_selfcal(homographies([undistort_division(v, lam, centre, scale) for v in views]), SIZE)
    assert _f_err(cal) < 0.03 and _f_err(cal) < _f_err(plain)


def test_planar_selfcal_needs_four_views():
    rng = np.random.default_rng(8)
    cal = planar_selfcal(homographies(_plane_views(3, rng)), SIZE)
    assert cal.degenerate and np.all(np.isfinite(cal.K))


CHESS = Path(__file__).resolve().parents[4] / "shared" / "data" / "camera" / "opencv-chessboard-stereo"


@pytest.mark.skipif(not CHESS.exists(), reason="../shared/data/camera is absent")
def test_real_chessboard_views_self_calibrate_near_calibrate_camera():
    from nodes.vision.selfcal_images import calibrate_chessboard, read_images

    ref = 536.07                   # SOURCES.md: cv2.calibrateCamera on all 13 views (the ground truth)
    cal, extra = calibrate_chessboard(read_images(sorted(CHESS.glob("left*.jpg"))), (9, 6))
    assert len(extra["views_used"]) >= 10
    assert abs(cal.K[0, 0] - ref) / ref < 0.05
