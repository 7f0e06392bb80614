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
        h.feed([(0.0, "pose", _pose(origin, rot, 0)), (0.01, "ping", _ping(10**7, altitude, tilt, fronts)),
                (0.02, "pose", _pose(origin, rot, 2 * 10**7))])          # the ping is placed between the two
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
    ping = SonarPing(stamp_ns=0, intensities=img, bearings_rad=BEARINGS.astype(np.float32), range_resolution_m=DR,
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
    events.append((0.3, "pose", _pose([3, 0, altitude], _rot(0, tilt), int(0.3 * 1e9))))
    with Harness(HighlightCloud, params={"max_points": 200, "publish_scan": True}) as h:
        h.feed(events)
    clouds = h.of("points")
    assert [len(c.points_m) for c in clouds] == [96, 192, 200]
    # the newest ping was taken 2 m further along x than the first: the last points are the newest
    # (interpolated: 2.1 m, each ping 10 ms after its pose at 10 m/s)
    assert np.asarray(clouds[-1].points_m)[-96:, 0].mean() == pytest.approx(
        np.asarray(clouds[0].points_m)[:, 0].mean() + 2.0, abs=0.02)
    assert len(h.of("scan")) == 3 and h.of("scan")[0].frame_id == "sonar"


def test_missing_stale_and_bad_inputs_are_dropped_and_counted() -> None:
    tilt = math.radians(15)
    bad = _ping(3 * 10**9, 5.0, tilt, {}, bearings=BEARINGS)
    bad = SonarPing(stamp_ns=bad.stamp_ns, intensities=bad.intensities, bearings_rad=bad.bearings_rad[:-3],
                    range_resolution_m=DR)
    nan_pose = Pose3D(x_m=float("nan"), stamp_ns=1)
    zero_q = Pose3D(qw=0.0, stamp_ns=2)
    with Harness(HighlightCloud) as h:
        h.feed([(0.0, "ping", _ping(0, 5.0, tilt, {})),                           # no pose yet: waits, then ...
                (0.1, "pose", nan_pose),
                (0.15, "pose", zero_q),
                (0.7, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 10**9)),          # ... is older than any pose
                (2.0, "ping", _ping(2 * 10**9, 5.0, tilt, {})),                   # waits for the pose at 3 s
                (2.5, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 3 * 10**9)),      # 2 s gap around it: dropped
                (3.0, "ping", bad),
                (3.1, "pose", _pose([0, 0, -1.0], _rot(0, tilt), 3 * 10**9)),    # below the seafloor
                (3.2, "ping", _ping(3 * 10**9, 5.0, tilt, {})),
                (3.3, "pose", _pose([0, 0, 5.0], _rot(0, tilt), 3 * 10**9)),
                (3.4, "ping", _ping(3 * 10**9, 5.0, tilt, {}))])
    assert len(h.of("points")) == 1
    assert h.node.dropped.pop("bad pose (non-finite or zero quaternion)") == 2
    assert sum(h.node.dropped.values()) == 4 and len(h.node.dropped) == 4, h.node.dropped
    assert h.node.waited == 2 and h.node.placed == {"exact": 3, "interpolated": 0}     # posed, 2 then failed


def test_a_stopped_pose_stream_makes_pings_wait_then_drop_counted() -> None:
    tilt = math.radians(15)
    pose = _pose([0, 0, 5.0], _rot(0, tilt), 0)
    events = [(0.0, "pose", pose)] + [(0.1 * k, "ping", _ping(int(0.1 * k * 1e9), 5.0, tilt, {}, ping_id=k))
                                      for k in range(1, 10)]
    with Harness(HighlightCloud, params={"max_wait_s": 0.25, "max_pending": 4}) as h:
        h.feed(events)
    assert not h.of("points")                          # never placed with the old pose
    assert h.node.dropped == {"no pose after the ping's stamp in time (pose stream late or stopped)": 6}
    assert len(h.node._pending) == 3 and h.node.waited == 9


def _turning_run(pose_rate_hz: float, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """A sonar turning at 30 deg/s (1 m/s on a 1.9 m circle) past a pile 8-10 m ahead, 15 pings/s.

    ``mode``: "truth" (a pose at every ping's stamp), "interpolate" (poses at ``pose_rate_hz``, each
    arriving 30 ms after its stamp, so pings wait) or "nearest" (the old behaviour: each ping given
    the nearest pose of that stream as its own). Returns the world cloud and which points are on the pile.
    """
    from sim.fls import PingSettings, load_scene, render_ping
    from sim.fls_scene import sonar_frame

    scene = load_scene("cylinder")                     # pile axis at (2, 0), radius 0.5 m
    rate, radius = math.radians(30.0), 1.0 / math.radians(30.0)
    yaw0 = math.radians(-15.0)
    centre = np.array([-8.0, 0.0]) - radius * np.array([math.sin(yaw0), -math.cos(yaw0)])

    def truth(t: float) -> np.ndarray:
        yaw = yaw0 + rate * t
        xy = centre + radius * np.array([math.sin(yaw), -math.cos(yaw)])
        return sonar_frame(np.array([xy[0], xy[1], -1.0]), yaw, scene.sonar.tilt_rad)

    rng = np.random.default_rng(0)
    settings = PingSettings(n_beams=256, range_m=20.0, elevation_rays=24)
    ping_t = [0.013 + k / 15 for k in range(15)]
    pose_t = [k / pose_rate_hz for k in range(int(1.2 * pose_rate_hz) + 1)]
    events: list = []
    for t in ping_t:
        r = render_ping(scene, truth(t), settings, rng=rng)
        ping = SonarPing(stamp_ns=int(t * 1e9), intensities=r.intensities, bearings_rad=r.bearings_rad.astype(np.float32),
                         range_resolution_m=r.range_resolution_m, range_m=r.range_m,
                         vertical_aperture_rad=r.vertical_aperture_rad)
        events.append((t + 0.005, "ping", ping))
        if mode == "truth":
            events.append((t, "pose", Pose3D.from_matrix(truth(t), stamp_ns=ping.stamp_ns)))
        elif mode == "nearest":
            near = min(pose_t, key=lambda s: abs(s - t))
            events.append((t, "pose", Pose3D.from_matrix(truth(near), stamp_ns=ping.stamp_ns)))
    if mode == "interpolate":
        events += [(t + 0.03, "pose", Pose3D.from_matrix(truth(t), stamp_ns=int(round(t * 1e9)))) for t in pose_t]
    with Harness(HighlightCloud, params={"seafloor_z_m": -6.0, "include_seafloor": True}) as h:
        h.feed(events)
    cloud = h.of("points")[-1]
    pts = np.asarray(cloud.points_m, float)
    on_pile = (np.asarray(cloud.intensity) > 0) & (np.hypot(pts[:, 0] - 2.0, pts[:, 1]) < 1.5)
    assert len(h.of("points")) == 15 and h.node.placed["interpolated"] == (15 if mode == "interpolate" else 0)
    return pts, on_pile


def test_a_turning_vehicle_keeps_the_pile_sharp_when_each_ping_gets_the_pose_at_its_stamp() -> None:
    truth, on_pile = _turning_run(10.0, "truth")
    assert on_pile.sum() > 100
    cell = 20.0 / 1024                                  # the sonar's range resolution here (~2 cm)
    smear = {}
    for mode in ("interpolate", "nearest"):
        pts, _ = _turning_run(10.0, mode)
        assert pts.shape == truth.shape                 # one point per beam per ping: comparable point by point
        smear[mode] = float(np.sqrt(np.mean(np.sum((pts[on_pile] - truth[on_pile]) ** 2, axis=1))))
    # The pose stream's own points between 10 Hz poses on a 30 deg/s turn: within a range cell of the
    # cloud built with the true pose of every ping; the nearest pose (up to 50 ms off, 1.5 deg) smears it.
    assert smear["interpolate"] < cell, smear
    assert smear["nearest"] > 5 * cell, smear

    def spread(pts: np.ndarray) -> float:            # the pile's horizontal radius as the cloud shows it
        d = np.hypot(pts[on_pile, 0] - 2.0, pts[on_pile, 1])
        return float(np.percentile(d, 90) - np.percentile(d, 10))

    assert spread(_turning_run(10.0, "interpolate")[0]) < spread(truth) + cell


def test_detection_sees_gain_compensated_samples() -> None:
    tilt, altitude = math.radians(15), 5.0
    fronts = {j: 6.0 + 0.05 * j for j in range(20, 80)}
    clean = _ping(0, altitude, tilt, fronts)
    gains = np.linspace(1.0, 0.3, M)                    # the device attenuated far rows (-5 dB at the end)
    sent = np.rint(np.asarray(clean.intensities, float) * np.sqrt(gains)[:, None]).astype(np.uint8)
    with_gains = SonarPing(stamp_ns=0, intensities=sent, bearings_rad=clean.bearings_rad, range_resolution_m=DR,
                           range_m=M * DR, vertical_aperture_rad=SPREAD, gamma=0.5, row_gains=gains.astype(np.float32))
    clouds = {}
    for name, ping, mode in (("clean", clean, "apply"), ("gains", with_gains, "apply"), ("raw", with_gains, "ignore")):
        with Harness(HighlightCloud, params={"row_gains": mode}) as h:
            h.feed([(0.0, "pose", _pose([0, 0, altitude], _rot(0, tilt), 0)), (0.0, "ping", ping)])
        c = h.of("points")[-1]
        clouds[name] = (np.asarray(c.points_m), np.asarray(c.intensity) > 0)
    assert clouds["clean"][1].sum() >= len(fronts)          # (blur across beams adds a neighbour each side)
    np.testing.assert_array_equal(clouds["gains"][1], clouds["clean"][1])
    np.testing.assert_allclose(clouds["gains"][0], clouds["clean"][0], atol=2 * DR)
    assert not np.array_equal(clouds["raw"][1], clouds["clean"][1])     # uncompensated, the far fronts are lost
