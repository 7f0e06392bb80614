"""RgbdFlow node through the harness: frames + odometry in, robot-frame FlowPoints out; bad input survives."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.sensor import CameraInfo, RgbdFrame
from nodes.nav.rgbd_flow import RgbdFlow
from sim.crowd import CrowdWorld
from sim.crowd_render import CameraModel
from tether.testing import Harness

CAM = CameraModel(width_px=320, height_px=240, fx_px=262.5, fy_px=262.5, cx_px=159.5, cy_px=119.5)
INFO = CameraInfo(width_px=320, height_px=240, fx_px=262.5, fy_px=262.5, cx_px=159.5, cy_px=119.5)
ROOM = {"name": "r", "walls": [{"points": [[-6, -6], [6, -6], [6, 6], [-6, 6], [-6, -6]], "height_m": 2.5}],
        "pedestrian_model": "linear",
        "pedestrians": [{"id": 1, "waypoints": [[3.0, 0.3]], "speed_mps": 0}]}


def recorded(cmd, n=4, dt=1 / 15, odom=True, scene=ROOM, warmup_s=0.0):
    """Events (t, input, msg) of n frames from the crowd world, with odometry at every frame."""
    world = CrowdWorld(scene, camera=CAM)
    world.step(*cmd, warmup_s)
    events = []
    for k in range(n):
        rgb, depth = world.render()
        t = k * dt
        stamp = int(round(t * 1e9))
        x, y, yaw = world.pose
        if odom:
            events.append((t, "odom", Odometry2D(stamp_ns=stamp, frame_id="world", pose=Pose2D(x_m=x, y_m=y, yaw_rad=yaw),
                                                 twist=Twist2D(vx_mps=world.twist[0], wz_radps=world.twist[1]))))
        events.append((t, "rgbd", RgbdFrame(stamp_ns=stamp, frame_id="camera", rgb=rgb, depth_m=depth, info=INFO)))
        world.step(*cmd, dt)
    return events


def test_first_frame_gives_nothing_then_every_frame_gives_robot_frame_points():
    with Harness(RgbdFlow) as h:
        outs = h.feed(recorded((0.5, 0.0), n=4))
    flows = [o.msg for o in outs]
    assert len(flows) == 3 and all(f.frame_id == "base_link" for f in flows)
    f = flows[-1]
    assert len(f.points_m) > 500 and f.points_m.dtype == np.float32
    assert f.points_m[:, 2].min() >= 0.15 and f.points_m[:, 2].max() <= 2.2       # floor and ceiling cut
    assert np.median(f.points_m[:, 0]) > 0                                         # ahead of the robot


def test_pure_rotation_through_the_node_leaves_a_static_world_still():
    with Harness(RgbdFlow) as h:
        h.feed(recorded((0.0, 1.0), n=6))
    speeds = np.concatenate([np.linalg.norm(f.velocity_mps, axis=1) for f in h.of("flow")[1:]])
    assert np.median(speeds) < 0.1


def test_without_odometry_it_warns_once_and_reports_motion_relative_to_the_camera(caplog):
    with Harness(RgbdFlow) as h:
        h.feed(recorded((0.6, 0.0), n=3, odom=False, warmup_s=1.0))
    assert sum("NOT removed" in r.message for r in caplog.records) == 1
    f = h.of("flow")[-1]
    # a driving robot sees the static world coming at it: about -0.6 m/s along x
    assert np.median(f.velocity_mps[:, 0]) == pytest.approx(-0.6, abs=0.15)


def test_bad_frames_are_dropped_and_counted_and_depth_holes_are_survived():
    events = recorded((0.3, 0.0), n=3)
    t, _, good = events[-1]
    broken = RgbdFrame(stamp_ns=good.stamp_ns + 1, rgb=good.rgb, depth_m=np.zeros((10, 10), np.float32), info=INFO)
    depth = good.depth_m.copy()
    depth[::3] = np.nan
    depth[1::3] = 0.0
    holey = RgbdFrame(stamp_ns=good.stamp_ns + 2 * 66_666_667, rgb=good.rgb, depth_m=depth, info=INFO)
    with Harness(RgbdFlow) as h:
        h.feed(events)
        h.feed([(t + 0.001, "rgbd", broken), (t + 0.13, "rgbd", holey)])
        assert h.node.bad_frames == 1
        last = h.of("flow")[-1]
        assert last.stamp_ns == holey.stamp_ns
        assert np.all(np.isfinite(last.points_m)) and np.all(np.isfinite(last.velocity_mps))


def test_a_gap_in_the_frames_restarts_the_flow():
    events = recorded((0.3, 0.0), n=2)
    t, _, frame = events[-1]
    late = RgbdFrame(stamp_ns=frame.stamp_ns + 2_000_000_000, rgb=frame.rgb, depth_m=frame.depth_m, info=INFO)
    with Harness(RgbdFlow) as h:
        h.feed(events + [(t + 2.0, "rgbd", late)])
        assert len(h.of("flow")) == 1


def test_unknown_method_is_a_clear_error():
    with pytest.raises(ValueError, match="choose one of"):
        Harness(RgbdFlow, params={"method": "magic"})
