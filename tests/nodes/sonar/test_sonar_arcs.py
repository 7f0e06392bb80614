"""Elevation arcs on simulated pings: the tripod pass with a drifting navigation pose, ground truth from sim.fls.

Lower-edge points (eq. 13) are biased towards the sonar (a pylon's first return comes from the
upper edge); arcs are not, so arc ICP recovers the navigation drift and point ICP does not.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from nodes.sonar.arcs import arc_samples, arcs_from_scan
from nodes.sonar.highlight import edge_rays, extract_line_scan
from nodes.sonar.icp import IcpModel, IcpSettings, align
from nodes.sonar.icp_localizer import IcpLocalizer
from nodes.sonar.model import tripod_model
from sim.fls import PingSettings, load_scene, render_ping
from tether.testing import Harness

SPREAD = math.radians(20.0)


def _drift(x: float, y: float, yaw_deg: float) -> np.ndarray:
    a = math.radians(yaw_deg)
    d = np.eye(4)
    d[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    d[:2, 3] = (x, y)
    return d


DRIFT = _drift(0.4, -0.3, 3.0)          # navigation = DRIFT @ truth, as sim.nav_drift applies it


@pytest.fixture(scope="module")
def tripod_pass() -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """(stamp_ns, true pose, navigation pose, line scan FRD) for 8 s of the approach, 4 pings/s, seeded speckle."""
    scene = load_scene("tripod")
    rng = np.random.default_rng(0)
    out = []
    for t in np.arange(10.5, 18.5, 0.25):
        truth = scene.sonar_pose(float(t))
        ping = render_ping(scene, truth, PingSettings(n_beams=256, range_m=20.0), rng=rng)
        nav = DRIFT @ truth
        down = nav[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        scan = extract_line_scan(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                 altitude_m=float(nav[2, 3] + 6.0), tilt_rad=math.asin(down[0]), spread_rad=SPREAD,
                                 down_frd=down, include_seafloor=False)
        out.append((int(t * 1e9), truth, nav, scan.points_m))
    return out


@pytest.fixture(scope="module")
def model() -> IcpModel:
    return IcpModel.build(*tripod_model(spacing_m=0.1), grid_m=0.1)


def _error_at(correction: np.ndarray, nav: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    est = correction @ nav
    heading = math.atan2(est[1, 0], est[0, 0]) - math.atan2(truth[1, 0], truth[0, 0])
    return float(np.linalg.norm(est[:3, 3] - truth[:3, 3])), abs(math.degrees(math.remainder(heading, 2 * math.pi)))


def test_arc_samples_span_the_aperture_at_the_measured_range() -> None:
    arcs = arc_samples(np.array([5.0, 12.0]), np.radians([-40.0, 10.0]), SPREAD / 2, 9)
    assert arcs.shape == (2, 9, 3)
    np.testing.assert_allclose(np.linalg.norm(arcs, axis=2), [[5.0] * 9, [12.0] * 9])
    np.testing.assert_allclose(np.degrees(np.arcsin(arcs[:, :, 2] / np.linalg.norm(arcs, axis=2)))[:, [0, -1]],
                               [[-10.0, 10.0]] * 2, atol=1e-9)                     # upper to lower edge
    np.testing.assert_allclose(np.degrees(np.arctan2(arcs[..., 1], arcs[..., 0])), [[-40.0] * 9, [10.0] * 9])
    # a lower-edge scan point gives its own arc back, in the world frame
    pose = _drift(2.0, 1.0, 30.0)
    lower = 7.0 * edge_rays(np.radians([25.0]), SPREAD)
    world = arcs_from_scan(lower, pose, 5)
    np.testing.assert_allclose(world[0, -1], pose[:3, :3] @ lower[0] + pose[:3, 3], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(world[0] - pose[:3, 3], axis=1), 7.0)
    with pytest.raises(ValueError):
        arcs_from_scan(lower, np.full((4, 4), np.nan), 5)


def test_arcs_recover_the_drift_where_lower_edge_points_are_biased(tripod_pass, model) -> None:
    scans = [s for s in tripod_pass if len(s[3])]
    assert len(scans) > 20
    arcs = np.concatenate([arcs_from_scan(p, nav, 9) for _, _, nav, p in scans])
    points = np.concatenate([p @ nav[:3, :3].T + nav[:3, 3] for _, _, nav, p in scans])
    _, truth, nav, _ = scans[-1]
    arc_fix = align(arcs, model, settings=IcpSettings(dof="xy_yaw"))
    point_fix = align(points, model, settings=IcpSettings(dof="xy_yaw"))
    assert arc_fix.converged and not arc_fix.degenerate and not arc_fix.ambiguous
    e_arc, h_arc = _error_at(arc_fix.transform, nav, truth)
    e_pt, _ = _error_at(point_fix.transform, nav, truth)
    e_nav, h_nav = _error_at(np.eye(4), nav, truth)
    assert e_nav > 0.5 and h_nav > 2.9
    assert e_arc < 0.1 and h_arc < 0.3, (e_arc, h_arc)
    assert e_pt > 2 * e_arc and e_pt > 0.15, (e_pt, e_arc)        # lower-edge points are pulled towards the sonar


def test_localizer_on_arcs_waits_for_poses_and_corrects_the_drift(tripod_pass) -> None:
    params = {"source": "arcs", "spacing_m": 0.1, "grid_m": 0.1, "align_every": 4, "window_s": 6.0,
              "arc_samples": 9, "recheck_every": 3}
    events, t = [], 0.0
    for k, (stamp, truth, nav, pts) in enumerate(tripod_pass):
        pose = Pose3D.from_matrix(nav, stamp_ns=stamp, frame_id="world")
        scan = PointCloud(stamp_ns=stamp, frame_id="sonar", points_m=pts.astype(np.float32))
        pair = [("scan", scan), ("pose", pose)] if k % 3 == 0 else [("pose", pose), ("scan", scan)]
        events += [(t, name, msg) for name, msg in pair]        # every third scan arrives before its pose
        t += 0.25
    events.append((t, "scan", PointCloud(stamp_ns=int(60e9), frame_id="sonar",
                                         points_m=np.zeros((3, 3), np.float32))))   # no pose ever: dropped
    events.append((t + 1.0, "pose", Pose3D.from_matrix(np.eye(4), stamp_ns=int(61e9), frame_id="world")))
    with Harness(IcpLocalizer, params=params) as h:
        h.feed(events)
    results = h.of("correction")
    assert len(results) == len(tripod_pass) // 4 and h.node.scans == len(tripod_pass)
    assert h.node.flags["no_pose"] == 1
    last = results[-1]
    assert last.converged and not last.degenerate and not last.ambiguous
    _, truth, nav, _ = tripod_pass[-1]
    e, heading = _error_at(last.correction.matrix(), nav, truth)
    assert e < 0.1 and heading < 0.3, (e, heading)
    cov = last.covariance
    assert np.all(cov[2:5] == 0) and np.all(np.diag(cov)[[0, 1, 5]] > 0)   # x, y, yaw estimated; the rest held
