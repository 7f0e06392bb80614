"""Cable tracking and stereo reconstruction (seed 05) on simulated pairs with ground truth:
accuracy in order against the per-row baseline, and the issue's hard cases."""
from __future__ import annotations


import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from nodes.vision.cable import Rectified, colour_distance, reconstruct, track_cable, triangulate
from sim.cable import Look, StereoRig, render_pair, scene_pair

RIG = StereoRig()
RECT = Rectified(RIG.f_px, RIG.K[0, 2], RIG.K[1, 2], RIG.baseline_m)


def _reference(depth_m: float, colour=Look().colour_bgr) -> tuple[float, float, float]:
    """The cable's colour as the camera sees it at this depth (what a user would pick)."""
    look = Look()
    att = np.exp(-np.array(look.attenuation_per_m) * depth_m)
    return tuple(float(v) for v in np.array(colour) * att + np.array(look.water_bgr) * (1 - att))


def _rms_mm(points_m: np.ndarray, *curves: np.ndarray) -> float:
    d, _ = cKDTree(np.vstack(curves)).query(points_m)
    return float(1000 * np.sqrt(np.mean(d ** 2)))


def test_colour_distance_wraps_the_hue_and_ignores_brightness():
    # hue 179 and hue 1 are both red; the seed's linear (H, S) distance puts them 178 apart
    hsv = np.uint8([[[179, 230, 200], [1, 230, 60], [60, 230, 200]]])
    bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    ref = tuple(int(v) for v in cv2.cvtColor(np.uint8([[[1, 230, 200]]]), cv2.COLOR_HSV2BGR)[0, 0])
    d = colour_distance(bgr, ref, blur_px=0)[0]
    assert d[0] < 0.1 and d[1] < 0.1          # wrapped hue, and a darker pixel of the same colour
    assert d[2] > 1.0                          # green is far
    dark = colour_distance(np.zeros((4, 4, 3), np.uint8), ref)
    assert np.all(dark == 2.0)                 # no colour in the dark: never cable


@pytest.mark.parametrize("image", [np.zeros((480, 640, 3), np.uint8), np.full((480, 640, 3), 255, np.uint8)],
                         ids=["black", "saturated"])
def test_black_or_saturated_images_are_lost_not_invented(image):
    r = reconstruct(image, image, RECT, reference_bgr=_reference(2.0))
    assert r.status == "lost" and len(r.points_m) == 0 and "no cable" in r.reason


def test_self_crossing_cable_in_order_beats_rows_by_far():
    p = scene_pair("crossing", depth_m=2.0, seed=3)
    ref = _reference(2.0)
    order = reconstruct(p.left, p.right, RECT, reference_bgr=ref)
    rows = reconstruct(p.left, p.right, RECT, reference_bgr=ref, matching="row")
    assert order.status == "tracked"
    assert len(order.points_m) > 150
    e_order, e_rows = _rms_mm(order.points_m, p.cable_m), _rms_mm(rows.points_m, p.cable_m)
    assert e_order < 25.0
    assert e_rows > 5 * e_order
    # the tracked order follows the cable: consecutive 3-D points are close along each segment
    for s in np.unique(order.segment):
        q = order.points_m[order.segment == s]
        assert np.percentile(np.linalg.norm(np.diff(q, axis=0), axis=1), 95) < 0.08


def test_tracker_keeps_its_branch_through_a_self_crossing():
    p = scene_pair("crossing", depth_m=2.0, seed=3)
    tracks = track_cable(colour_distance(p.left, _reference(2.0)))
    longest = max(tracks, key=lambda t: len(t.points_px))
    # one track covers most of the visible curve: it went through the crossing, not round the loop twice
    d, idx = cKDTree(p.truth_left_px[p.visible]).query(longest.points_px)
    assert np.median(d) < 1.0
    assert np.ptp(idx) > 0.8 * p.visible.sum()


def test_cable_along_the_epipolar_lines_gets_no_invented_depth():
    # a straight cable along the image rows: the row crossing that fixes disparity does not exist
    x = np.linspace(-1.2, 1.2, 800)
    cable = np.stack([x, np.full_like(x, 0.1), np.full_like(x, 2.0)], axis=1)
    p = render_pair(RIG, cable, rng=np.random.default_rng(1))
    r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0))
    assert r.status in ("ambiguous", "lost")
    assert len(r.points_m) == 0 and "epipolar" in r.reason


def test_cable_leaving_the_image_and_coming_back_gives_two_stretches():
    p = scene_pair("exit", depth_m=2.0, seed=1)
    r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0))
    assert r.status == "tracked" and len(np.unique(r.segment)) >= 2
    assert _rms_mm(r.points_m, p.cable_m) < 30.0


def test_occluded_cable_has_no_points_behind_the_occluder():
    p = scene_pair("occluded", depth_m=2.0, seed=1)
    r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0))
    assert r.status == "tracked" and _rms_mm(r.points_m, p.cable_m) < 30.0
    poly = RIG.project(p.occluders[0][0]).astype(np.float32)
    inside = [cv2.pointPolygonTest(poly, (float(x), float(y)), True) > 2 for x, y in r.left_px]
    assert not any(inside)


def test_two_cables_of_the_same_colour_are_both_right_or_flagged():
    p = scene_pair("two", depth_m=2.0, seed=1)
    r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0))
    if r.status == "tracked":
        assert _rms_mm(r.points_m, p.cable_m, *p.others_m) < 30.0
        # and both cables were found
        for curve in (p.cable_m, *p.others_m):
            d, _ = cKDTree(r.points_m).query(curve[(curve[:, 2] > 0)])
            assert np.mean(d < 0.03) > 0.3
    else:
        assert r.status == "ambiguous"


def test_red_cable_near_the_hue_wrap():
    p = scene_pair("red", depth_m=2.0, seed=2)
    r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0, (40, 20, 210)))
    assert r.status == "tracked" and _rms_mm(r.points_m, p.cable_m) < 25.0


def test_triangulation_and_its_sigma():
    left = np.array([[RECT.cx_px + 40, RECT.cy_px - 20], [RECT.cx_px, RECT.cy_px], [RECT.cx_px, RECT.cy_px]])
    disp = np.array([RECT.baseline_m * RECT.f_px / 2.0, RECT.baseline_m * RECT.f_px / 4.0, -1.0])
    pts, sig = triangulate(left, disp, np.full(3, 0.5), RECT)
    assert pts[0, 2] == pytest.approx(2.0) and pts[1, 2] == pytest.approx(4.0)
    assert pts[0, 0] == pytest.approx(40 * 2.0 / RECT.f_px) and pts[0, 1] == pytest.approx(-20 * 2.0 / RECT.f_px)
    # sigma_z = z^2 sigma_d / (b f): four times larger at twice the depth
    assert sig[1, 2] == pytest.approx(4 * sig[0, 2]) and sig[0, 2] == pytest.approx(4 * 0.5 / (RECT.baseline_m * RECT.f_px))
    assert np.all(np.isnan(pts[2]))             # a negative disparity is refused, not a negative depth


def test_reported_sigma_is_the_right_size():
    # depth errors over a few frames against the reported sigma: neither hidden nor inflated 10x
    z_err, z_sig = [], []
    for seed in range(3):
        p = scene_pair("catenary", depth_m=2.0, seed=seed)
        r = reconstruct(p.left, p.right, RECT, reference_bgr=_reference(2.0))
        tree = cKDTree(p.truth_left_px)
        _, k = tree.query(r.left_px)
        z_err.append(r.points_m[:, 2] - p.cable_m[k, 2])
        z_sig.append(r.sigma_m[:, 2])
    ratio = np.sqrt(np.mean(np.concatenate(z_err) ** 2)) / np.sqrt(np.mean(np.concatenate(z_sig) ** 2))
    assert 0.3 < ratio < 3.0, ratio
