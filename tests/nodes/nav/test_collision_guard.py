"""Collision guard: passes commands when clear, stops within 1 m whatever the planner says, fails safe."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.geometry import Twist2D
from msgs.nav import FlowPoints
from msgs.sensor import CameraInfo, RgbdFrame
from nodes.nav.collision_guard import CollisionGuard, nearest_obstacle_m
from tether.testing import Harness

INFO = CameraInfo(width_px=64, height_px=48, fx_px=52.5, fy_px=52.5, cx_px=31.5, cy_px=23.5)
GO = Twist2D(vx_mps=0.8, wz_radps=0.3)


def frame(wall_depth_m: float | None) -> RgbdFrame:
    """A floor-less view: a wall at ``wall_depth_m`` ahead of the camera (None = no returns at all)."""
    depth = np.zeros((48, 64), np.float32) if wall_depth_m is None else np.full((48, 64), wall_depth_m, np.float32)
    return RgbdFrame(depth_m=depth, info=INFO, rgb=np.zeros((48, 64, 3), np.uint8))


def cmds(outs):
    return [(o.msg.vx_mps, o.msg.wz_radps) for o in outs if o.output == "cmd"]


def test_passes_commands_when_clear_and_stops_near_an_obstacle():
    with Harness(CollisionGuard, params={"stride_px": 2}) as h:
        clear = h.feed([(0.0, "rgbd", frame(3.0)), (0.05, "cmd", GO)])
        assert cmds(clear) == [(0.8, 0.3)]
        near = h.feed([(0.1, "rgbd", frame(0.5)), (0.15, "cmd", GO)])    # 0.3 m mount + 0.5 m = 0.8 m
    assert cmds(near) == [(0.0, 0.3), (0.0, 0.3)]      # immediate stop on the frame, then on the next command
    assert any(o.output == "status" and o.msg.state == "stopped" and "0.80" in o.msg.reason for o in near)
    assert h.node.stops == 1


def test_full_stop_when_turning_is_not_allowed_and_release_needs_continuous_clearance():
    with Harness(CollisionGuard, params={"allow_turn_in_place": False, "release_s": 0.3}) as h:
        h.feed([(0.0, "rgbd", frame(0.4)), (0.01, "cmd", GO)])
        assert cmds(h.outputs)[-1] == (0.0, 0.0)
        assert cmds(h.feed([(0.1, "rgbd", frame(3.0)), (0.2, "cmd", GO)])) == [(0.0, 0.0)]   # clear for 0.1 s only
        assert cmds(h.feed([(0.45, "rgbd", frame(3.0)), (0.5, "cmd", GO)])) == [(0.8, 0.3)] * 2   # the frame releases


def test_no_depth_at_all_is_blind_and_stops():
    with Harness(CollisionGuard) as h:
        outs = h.feed([(0.0, "rgbd", frame(None)), (0.05, "cmd", GO)])
    assert cmds(outs)[-1] == (0.0, 0.0)
    assert any(o.output == "status" and o.msg.reason == "depth blind" for o in outs)


def test_empty_point_set_is_clear_but_silent_sensors_and_planners_stop_the_robot():
    with Harness(CollisionGuard, params={"sensor_timeout_s": 0.3, "cmd_timeout_s": 0.6}) as h:
        assert cmds(h.feed([(0.0, "points", FlowPoints()), (0.05, "cmd", GO)])) == [(0.8, 0.3)]
        assert cmds(h.feed([(0.5, "cmd", GO)])) == [(0.0, 0.0)]                     # sensor silent for 0.5 s
        assert cmds(h.feed([(0.55, "points", FlowPoints()), (0.6, "cmd", GO)])) == [(0.8, 0.3)] * 2
        late = h.advance_to(1.4)                                                   # planner silent
    assert cmds(late) == [(0.0, 0.0)]
    assert any(o.output == "status" and o.msg.reason == "planner silent" for o in late)


def test_points_in_robot_frame_floor_and_ceiling_ignored():
    pts = np.array([[0.5, 0.0, 0.0], [0.6, 0.0, 2.5], [0.7, 0.5, 1.0], [np.nan, 0, 1]])
    assert nearest_obstacle_m(pts) == pytest.approx(np.hypot(0.7, 0.5))
    assert nearest_obstacle_m(np.zeros((0, 3))) == float("inf")
    with Harness(CollisionGuard) as h:
        outs = h.feed([(0.0, "points", FlowPoints(points_m=pts.astype(np.float32))), (0.01, "cmd", GO)])
    assert cmds(outs)[-1] == (0.0, 0.3)
