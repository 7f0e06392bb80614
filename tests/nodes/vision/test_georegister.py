"""Geo-registration of nadir frames (seed 11) on the procedural map, the real ortho when present,
and the issue's hard cases: outside the map, uniform, upside down, mirrored, 8x, 3 features."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from nodes.vision.geolocate import GeoLocator
from nodes.vision.geomap import DATA, procedural_map
from nodes.vision.georegister import MapFeatures, decompose, register
from sim.aerial import UavState, render_nadir


@pytest.fixture(scope="module")
def world():
    gm = procedural_map(rng=np.random.default_rng(0))
    return gm, MapFeatures.of(gm.image, method="sift")


def _yaw_err(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


@pytest.mark.parametrize("yaw", [0.0, 1.0, math.pi / 2, 2.5, math.pi, -2.0])
def test_any_rotation_gives_position_and_yaw(world, yaw):
    gm, mf = world
    st = UavState(15.0, -10.0, yaw, 40.0)
    loc = GeoLocator(gm, mf)
    f = loc.locate(render_nadir(gm, st, rng=np.random.default_rng(1)), alt_m=40.0)
    assert f.ok, f.reason
    assert math.hypot(f.e_m - st.e, f.n_m - st.n) < 0.12          # one map pixel is 0.12 m
    assert _yaw_err(f.yaw_rad, yaw) < math.radians(0.5)
    assert abs(f.alt_m - 40.0) < 0.5
    assert np.all(np.linalg.eigvalsh(f.cov_m2) > 0)


def test_decompose_keeps_the_quadrant_the_seeds_arctan_loses():
    for theta in np.radians([10, 100, 170, -170, -60, 180]):
        a, c, s = 1.3, math.cos(theta), math.sin(theta)
        T = np.array([[a * c, -a * s, 5.0], [a * s, a * c, -2.0]])
        alpha, th, b = decompose(T)
        assert alpha == pytest.approx(1.3) and abs(math.remainder(th - theta, 2 * math.pi)) < 1e-9
        assert np.allclose(b, [5.0, -2.0])
        seed = math.atan(T[0, 1] / (0.5 * (T[0, 0] + T[1, 1])))     # eq. (2.3) as printed
        if abs(theta) > math.pi / 2 or abs(theta) < 1e-9:
            continue
        assert seed == pytest.approx(-theta)                          # the sign the seed loses


def test_frame_outside_the_map_gives_no_fix(world):
    gm, mf = world
    f = GeoLocator(gm, mf).locate(render_nadir(gm, UavState(300.0, 300.0, 0.0, 40.0)), alt_m=40.0)
    assert not f.ok and f.reason


def test_uniform_and_three_feature_frames_give_no_fix(world):
    gm, mf = world
    flat = np.full((480, 640, 3), 128, np.uint8)
    assert not register(flat, mf).ok
    few = flat.copy()
    for c in ((100, 100), (300, 200), (500, 400)):
        cv2.circle(few, c, 6, (0, 0, 0), -1)
    f = register(few, mf)
    assert not f.ok and f.reason


def test_mirror_image_is_never_a_fix(world):
    gm, mf = world
    img = render_nadir(gm, UavState(5.0, 5.0, 0.7, 40.0), rng=np.random.default_rng(2))
    f = GeoLocator(gm, mf).locate(img[:, ::-1].copy(), alt_m=40.0)
    assert not f.ok


def test_a_frame_eight_times_finer_than_the_map_is_no_fix_and_two_and_a_half_is_a_good_one(world):
    gm, mf = world
    fine = UavState(-20.0, 10.0, 0.4, 5.0)       # 0.013 m/px against the map's 0.12: 70 map px across
    f = GeoLocator(gm, mf).locate(render_nadir(gm, fine, rng=np.random.default_rng(3)), alt_m=5.0)
    assert not f.ok and f.reason
    st = UavState(-20.0, 10.0, 0.4, 15.0)
    f = GeoLocator(gm, mf).locate(render_nadir(gm, st, rng=np.random.default_rng(3)), alt_m=15.0)
    assert f.ok and math.hypot(f.e_m - st.e, f.n_m - st.n) < 0.12


def test_localisation_mode_falls_back_to_search_after_failures(world):
    gm, mf = world
    loc = GeoLocator(gm, mf, fail_limit=2)
    st = UavState(0.0, 0.0, 0.0, 40.0)
    assert loc.locate(render_nadir(gm, st), alt_m=40.0).ok and loc.mode == "localise"
    flat = np.full((480, 640, 3), 90, np.uint8)
    for _ in range(2):
        assert not loc.locate(flat, alt_m=40.0, predicted_en=(0.0, 0.0)).ok
    assert loc.mode == "search"
    f = loc.locate(render_nadir(gm, st), alt_m=40.0, predicted_en=(25.0, 0.0))   # a wrong prediction
    assert f.ok and f.mode == "search" and abs(f.e_m) < 0.12


@pytest.mark.skipif(not DATA.exists(), reason="../shared/data/uav is absent")
def test_real_frames_georeference_the_ortho_to_gps_accuracy():
    from nodes.vision.geomap import georeference, register_brighton

    ortho, fixes, rows, enu = register_brighton(every=2)         # 9 of the 18 frames (the bench takes all)
    ok = [k for k, f in enumerate(fixes) if f.ok]
    assert len(ok) >= 8
    C = np.array([fixes[k].centre_px for k in ok])
    errs, heading = [], []
    for i in range(len(ok)):                                     # leave one frame out
        keep = [j for j in range(len(ok)) if j != i]
        G = georeference(C[keep], enu[ok][keep])
        errs.append(np.linalg.norm(C[i] @ G[:, :2].T + G[:, 2] - enu[ok][i]))
        up = G[:, :2] @ (fixes[ok[i]].T[:, :2] @ np.array([0.0, -1.0]))
        heading.append(abs(math.remainder(math.atan2(up[0], up[1]) - math.radians(float(rows[ok[i]]["xmp_gimbal_yaw"])),
                                          2 * math.pi)))
    assert np.median(errs) < 3.0                                 # consumer GPS: metres
    assert np.degrees(np.median(heading)) < 5.0                  # independent of the fit: the gimbal's yaw
