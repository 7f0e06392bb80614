"""HighlightCloud node: frames end to end (seafloor lands on z = 0), accumulation, bad and missing inputs."""
from __future__ import annotations

import math

import numpy as np
import pytest

from msgs.geometry import Pose3D
from msgs.sonar import SonarPing
from nodes.sonar.highlight import edge_rays, effective_region
from nodes.sonar.highlight_cloud import HighlightCloud
from tether.testing import Harness

DR, M = 0.02, 1000
BEARINGS = np.deg2rad(np.linspace(-60, 60, 96))
SPREAD = math.radians(20)


def _rot(yaw: float, pitch_down: float, roll: float = 0.0) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch_down), math.sin(pitch_down),
                              math.cos(roll), math.sin(roll))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])       # +angle about +y (left): nose down in FLU
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def _pose(origin, rot, stamp_ns: int) -> Pose3D:
    """FLU rotation in, FRD sonar pose out (the node's default body frame)."""
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot @ np.diag([1.0, -1.0, -1.0]), origin
    return Pose3D.from_matrix(t, stamp_ns=stamp_ns, frame_id="world")


def _ping(stamp_ns: int, altitude: float, tilt: float, fronts: dict[int, float], *, ping_id: int = 1,
          bearings=BEARINGS) -> SonarPing:
    reg = effective_region(bearings, altitude, SPREAD, tilt_rad=tilt, n_ranges=M, range_resolution_m=DR)
    r = (np.arange(M) + 0.5) * DR
    img = np.full((M, bearings.size), 8, np.uint8)
    img[r[:, None] >= np.minimum(reg.r_emin_m, 1e9)[None, :]] = 110
    for j, rf in fronts.items():
        img[(r >= rf) & (r < rf + 0.5), j] = 240
    return SonarPing(stamp_ns=stamp_ns, frame_id="sonar", intensities=img,
                     bearings_rad=bearings.astype(np.float32), range_resolution_m=DR, range_m=M * DR,
                     ping_id=ping_id, vertical_aperture_rad=SPREAD)


@pytest.mark.parametrize("attitude", ["pose", "param"])
def test_points_land_in_the_world_where_geometry_says(attitude: str) -> None:
    tilt, yaw, altitude = math.radians(15), math.radians(30), 5.0
    origin = np.array([10.0, 5.0, 3.0 + altitude])                 # seafloor at z = 3
    rot = _rot(yaw, tilt) if attitude == "pose" else _rot(yaw, 0.0)
    fronts = {j: 8.0 for j in range(40, 56)}
    params = {"seafloor_z_m": 3.0, "sigma_beam_px": 0.0, "attitude": attitude, "tilt_rad": tilt}
    with Harness(HighlightCloud, params=params) as h:
        h.feed([(0.0, "pose", _pose(origin, rot, 0)), (0.01, "ping", _ping(10**7, altitude, tilt, fronts))])
    cloud = h.of("points")[-1]
    pts = np.asarray(cloud.points_m, float)
    detected = np.asarray(cloud.intensity) > 0
    assert cloud.frame_id == "world" and len(pts) == BEARINGS.size and detected.sum() == len(fronts)
    np.testing.assert_allclose(pts[~detected, 2], 3.0, atol=0.02)             # seafloor fill on the seafloor
    rot_frd = _rot(yaw, tilt) @ np.diag([1.0, -1.0, -1.0])
    want = origin + (8.0 * edge_rays(BEARINGS[40:56], SPREAD)) @ rot_frd.T
    np.testing.assert_allclose(pts[detected], want, atol=2.5 * DR)
    assert np.all(pts[detected, 2] > 3.5)                                      # the object stands up


def test_roll_from_the_pose_keeps_the_seafloor_flat() -> None:
    tilt, altitude = math.radians(20), 6.0
    rot = _rot(0.3, tilt, roll=math.radians(8))
    down = (rot @ np.diag([1.0, -1.0, -1.0])).T @ np.array([0, 0, -1.0])
    reg = effective_region(BEARINGS, altitude, SPREAD, tilt_rad=tilt, n_ranges=M, range_resolution_m=DR,
                           down_frd=down)
    r = (np.arange(M) + 0.5) * DR
    img = np.where(r[:, None] >= reg.r_emin_m[None, :], 110, 8).astype(np.uint8)
    ping = SonarPing(stamp_ns=1, intensities=img, bearings_rad=BEARINGS.astype(np.float32), range_resolution_m=DR,
                     vertical_aperture_rad=SPREAD)
    with Harness(HighlightCloud) as h:
        h.feed([(0.0, "pose", _pose([0, 0, altitude], rot, 0)), (0.0, "ping", ping)])
    z = np.asarray(h.of("points")[-1].points_m)[:, 2]
    assert z.size > 80 and np.abs(z).max() < 0.03


def test_upper_edge_above_the_horizon_is_fine() -> None:
    tilt = math.radians(6)                                     # t - s/2 < 0: r_emax infinite
    with Harness(HighlightCloud) as h:
        h.feed([(0.0, "pose", _pose([0, 0, 4.0], _rot(0, tilt), 0)),
                (0.0, "ping", _ping(0, 4.0, tilt, {50: 5.0}))])
    pts = np.asarray(h.of("points")[-1].points_m)
    assert len(pts) > 0 and np.all(np.isfinite(pts))


def test_accumulates_and_keeps_the_newest_points() -> None:
    tilt, altitude = math.radians(15), 5.0
    events = [(0.0, "pose", _pose([0, 0, altitude], _rot(0, tilt), 0))]
    for k in range(3):
        events += [(0.1 * k, "pose", _pose([k, 0, altitude], _rot(0, tilt), int(0.1 * k * 1e9))),
                   (0.1 * k + 0.01, "ping", _ping(int((0.1 * k + 0.01) * 1e9), altitude, tilt, {}, ping_id=k))]
    with Harness(HighlightCloud, params={"max_points": 200, "publish_scan": True}) as h:
        h.feed(events)
    clouds = h.of("points")
    assert [len(c.points_m) for c in clouds] == [96, 192, 200]
    # the newest ping was taken 2 m further along x than the first: the last points are the newest
    assert np.asarray(clouds[-1].points_m)[-96:, 0].mean() > np.asarray(clouds[0].points_m)[:, 0].mean() + 1.9
    assert len(h.of("scan")) == 3 and h.of("scan")[0].frame_id == "sonar"


def test_missing_stale_and_bad_inputs_are_dropped_and_counted() -> None:
    tilt = math.radians(15)
    bad = _ping(3 * 10**9, 5.0, tilt, {}, bearings=BEARINGS)
    bad = SonarPing(stamp_ns=bad.stamp_ns, intensities=bad.intensities, bearings_rad=bad.bearings_rad[:-3],
                    range_resolution_m=DR)
    nan_pose = Pose3D(x_m=float("nan"), stamp_ns=1)
    with Harness(HighlightCloud) as h:
        h.feed([(0.0, "ping", _ping(0, 5.0, tilt, {})),                           # no pose yet
                (0.1, "pose", nan_pose),
                (0.2, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 0)),
                (2.0, "ping", _ping(2 * 10**9, 5.0, tilt, {})),                   # pose is 2 s old
                (2.5, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 3 * 10**9)),
                (3.0, "ping", bad),
                (3.1, "pose", _pose([0, 0, -1.0], _rot(0, tilt), 3 * 10**9)),    # below the seafloor
                (3.2, "ping", _ping(3 * 10**9, 5.0, tilt, {})),
                (3.3, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 3 * 10**9)),
                (3.4, "ping", _ping(3 * 10**9, 5.0, tilt, {}))])
    assert len(h.of("points")) == 1
    assert sum(h.node.dropped.values()) == 5 and len(h.node.dropped) == 5
