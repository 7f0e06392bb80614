"""Dwa node through the harness: silent until it has a goal and a view, steers around what the depth camera sees,
uses the map near the robot, stops on the goal, and never crashes on bad frames."""
from __future__ import annotations

import numpy as np

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.nav import FlowPoints, Goal2D
from msgs.sensor import CameraInfo, Grid, RgbdFrame
from nodes.nav.dwa import Dwa
from tether.testing import Harness

W, H, F = 64, 48, 30.0          # a wide small camera (~94 deg)
INFO = CameraInfo(width_px=W, height_px=H, fx_px=F, fy_px=F, cx_px=(W - 1) / 2, cy_px=(H - 1) / 2)


def odom(x=0.0, y=0.0, yaw=0.0, v=0.0, w=0.0, t=0.0):
    return Odometry2D(stamp_ns=int(t * 1e9), frame_id="world", pose=Pose2D(x_m=x, y_m=y, yaw_rad=yaw),
                      twist=Twist2D(vx_mps=v, wz_radps=w))


def post_frame(depth_m: float, t: float = 0.0) -> RgbdFrame:
    """A narrow post straight ahead ``depth_m`` from the camera (columns around the centre), nothing else."""
    depth = np.zeros((H, W), np.float32)
    depth[:, W // 2 - 4:W // 2 + 4] = depth_m
    return RgbdFrame(stamp_ns=int(t * 1e9), depth_m=depth, info=INFO, rgb=np.zeros((H, W, 3), np.uint8))


def cmds(outs):
    return [o.msg for o in outs if o.output == "cmd"]


def test_silent_until_goal_and_a_view_then_heads_for_the_goal_in_free_space():
    with Harness(Dwa) as h:
        assert cmds(h.feed([(0.0, "odom", odom())])) == []                                  # no goal yet
        h.feed([(0.05, "goal", Goal2D(x_m=5.0, y_m=0.0, frame_id="world"))])
        assert cmds(h.feed([(0.1, "odom", odom(t=0.1))])) == []                               # nothing seen yet
        h.feed([(0.15, "rgbd", RgbdFrame(stamp_ns=int(0.15e9), depth_m=np.zeros((H, W), np.float32), info=INFO,
                                          rgb=np.zeros((H, W, 3), np.uint8)))])
        out = cmds(h.feed([(0.2, "odom", odom(t=0.2, v=0.5))]))
    assert len(out) == 1 and out[0].vx_mps > 0.5 and abs(out[0].wz_radps) < 1e-6


def test_turns_away_from_a_post_straight_ahead_and_keeps_going():
    with Harness(Dwa) as h:
        h.feed([(0.0, "goal", Goal2D(x_m=6.0, y_m=0.0, frame_id="world")), (0.0, "odom", odom(v=0.8)),
                (0.01, "rgbd", post_frame(0.9, 0.0))])
        out = cmds(h.feed([(0.05, "odom", odom(v=0.8, t=0.05))]))[-1]
        path = h.of("path")[-1].poses
    assert abs(out.wz_radps) > 0.2 and out.vx_mps > 0.3         # the straight arc runs into the post: swerve
    post = np.array([0.3 + 0.9, 0.0])                           # its face, seen by the camera 0.3 m ahead of the centre
    assert np.hypot(*(path[:, :2] - post).T).min() > 0.3        # the predicted arc passes beside it, not through


def test_map_cells_near_the_robot_count_as_obstacles():
    grid = np.zeros((40, 60), np.float32)
    grid[:, 10:12] = 1.0                                         # a wall across the way, 0.5-0.6 m ahead
    m = Grid(data=grid, resolution_m=0.1, origin_x_m=-0.5, origin_y_m=-2.0, frame_id="world")
    with Harness(Dwa) as h:
        h.feed([(0.0, "goal", Goal2D(x_m=3.0, y_m=0.0, frame_id="world")), (0.0, "map", m),
                (0.0, "odom", odom(v=1.0)), (0.01, "points", FlowPoints())])
        out = cmds(h.feed([(0.05, "odom", odom(v=1.0, t=0.05))]))[-1]
    assert out.vx_mps < 0.5                                      # it must brake for the wall it cannot see


def test_stops_on_the_goal_and_survives_frames_without_intrinsics():
    bad = RgbdFrame(depth_m=np.zeros((H, W), np.float32), info=CameraInfo(), rgb=np.zeros((H, W, 3), np.uint8))
    with Harness(Dwa, catch_errors=True) as h:
        h.feed([(0.0, "goal", Goal2D(x_m=1.0, y_m=0.0, tolerance_m=0.3, frame_id="world")), (0.0, "rgbd", bad),
                (0.01, "points", FlowPoints())])
        at_goal = h.feed([(0.05, "odom", odom(x=0.9, t=0.05))])
    assert not h.errors
    assert [(c.vx_mps, c.wz_radps) for c in cmds(at_goal)] == [(0.0, 0.0)]
    assert any(o.output == "status" and o.msg.state == "reached" for o in at_goal)


def test_with_predict_s_a_person_walking_into_the_path_is_an_obstacle_where_they_will_be():
    """dwa_predicts: the same constant-velocity prediction of people as the IRL stack's guard."""
    empty = RgbdFrame(stamp_ns=int(0.1e9), depth_m=np.zeros((H, W), np.float32), info=INFO, rgb=np.zeros((H, W, 3), np.uint8))
    # a person 0.9 m ahead, 0.6 m to the right, walking left at 1.2 m/s: in 0.5 s on the robot's line
    person = FlowPoints(stamp_ns=int(0.1e9), frame_id="base", points_m=np.tile([0.9, -0.6, 1.0], (10, 1)).astype(np.float32),
                        velocity_mps=np.tile([0.0, 1.2, 0.0], (10, 1)).astype(np.float32))
    speeds = {}
    for predict in (0.0, 1.0):
        with Harness(Dwa, params={"predict_s": predict}) as h:
            h.feed([(0.0, "goal", Goal2D(x_m=6.0, y_m=0.0, frame_id="world")), (0.05, "odom", odom(t=0.05, v=0.8)),
                    (0.1, "rgbd", empty), (0.1, "points", person)])
            moved = cmds(h.feed([(0.15, "odom", odom(t=0.15, v=0.8))]))[-1]
            speeds[predict] = (moved.vx_mps, moved.wz_radps, len(h.node._movers))
    assert speeds[0.0][2] == 0 and speeds[1.0][2] > 0
    # without prediction the person 0.6 m aside is no obstacle; with it DWA slows or turns away from their line
    assert speeds[1.0][0] < speeds[0.0][0] - 0.05 or abs(speeds[1.0][1] - speeds[0.0][1]) > 0.1
