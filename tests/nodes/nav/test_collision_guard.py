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


def post(depth_m: float, hole: bool = False, t: float = 0.0) -> RgbdFrame:
    """A far wall (5 m) with a post in the middle columns at ``depth_m`` (``hole``: the post reads 0)."""
    depth = np.full((48, 64), 5.0, np.float32)
    depth[:, 28:36] = 0.0 if hole else depth_m
    return RgbdFrame(stamp_ns=int(round(t * 1e9)), depth_m=depth, info=INFO, rgb=np.zeros((48, 64, 3), np.uint8))


def odom_at(x: float, t: float):
    from msgs.geometry import Odometry2D, Pose2D
    return Odometry2D(stamp_ns=int(round(t * 1e9)), frame_id="world", pose=Pose2D(x_m=x), twist=Twist2D(vx_mps=0.5))


def test_speed_is_capped_so_the_robot_can_brake_before_an_obstacle_beyond_the_stop_distance():
    with Harness(CollisionGuard, params={"stride_px": 2}) as h:
        outs = h.feed([(0.0, "rgbd", post(0.9)), (0.01, "cmd", Twist2D(vx_mps=1.0))])     # post 1.2 m ahead
    v = cmds(outs)[-1][0]
    free = 1.2 - 0.45
    assert 0.8 < v < 1.0 and v * 0.15 + v * v / 1.6 <= free           # stops short of the post's disc
    assert any(o.output == "status" and o.msg.reason.startswith("slowed") for o in outs)


def test_a_post_that_drops_into_the_cameras_near_blind_zone_is_remembered_with_odometry():
    events = [(0.0, "odom", odom_at(0.0, 0.0)), (0.0, "rgbd", post(0.9))]
    for k in range(1, 17):                                   # the robot creeps up to the post: nearer than
        t = 0.1 * k                                          # 0.4 m to the camera it is a depth hole
        d = 0.9 - 0.06 * min(k, 9)
        events += [(t, "odom", odom_at(0.9 - d, t)), (t, "rgbd", post(d, hole=d < 0.4, t=t)), (t + 0.01, "cmd", GO)]
    with Harness(CollisionGuard, params={"stride_px": 2, "release_s": 0.3}) as h:
        remembered = cmds(h.feed(events))
    blind = [(t, n, m) for t, n, m in events if n != "odom"]            # the same frames without odometry
    with Harness(CollisionGuard, params={"stride_px": 2, "release_s": 0.3}) as h:
        forgotten = cmds(h.feed(blind))
    assert remembered[-1] == (0.0, 0.3)                      # still there, though unseen
    assert forgotten[-1] == (0.8, 0.3)                       # without odometry the hole looks clear


def test_a_person_walking_into_the_path_stops_the_robot_before_they_arrive():
    clear = post(5.0)
    walker = np.array([[0.9, -0.7, 1.0]], np.float32)
    straight = Twist2D(vx_mps=0.8)
    for vy, expected in ((1.0, 0.0), (0.0, 0.8)):
        flow = FlowPoints(points_m=walker, velocity_mps=np.array([[0.0, vy, 0.0]], np.float32))
        with Harness(CollisionGuard, params={"stride_px": 2}) as h:
            outs = h.feed([(0.0, "rgbd", clear), (0.0, "points", flow), (0.01, "cmd", straight)])
        assert cmds(outs)[-1][0] == expected


def test_one_wrong_flow_vector_on_a_passing_walker_does_not_brake_the_robot_with_cell_medians():
    """With ``cell_m`` 0.25: a walker 0.85 m to the side, coming along the corridor: 12 points in one 0.25 m cell. One of
    them has a wrong vector (1.5 m/s across, toward the path): alone it would be predicted onto the
    path; with its cell's median velocity it walks on past the robot, which keeps its speed."""
    rng = np.random.default_rng(0)
    body = np.column_stack([rng.uniform(0.77, 0.98, 12), rng.uniform(-0.98, -0.78, 12), rng.uniform(0.8, 1.6, 12)])
    vel = np.tile([-0.5, 0.0, 0.0], (12, 1))
    straight = Twist2D(vx_mps=0.8)

    def speed(velocity: np.ndarray, cell_m: float = 0.25) -> float:
        flow = FlowPoints(points_m=body.astype(np.float32), velocity_mps=velocity.astype(np.float32))
        with Harness(CollisionGuard, params={"stride_px": 2, "cell_m": cell_m}) as h:
            return cmds(h.feed([(0.0, "rgbd", post(5.0)), (0.0, "points", flow), (0.01, "cmd", straight)]))[-1][0]

    wrong = vel.copy()
    wrong[0] = [0.0, 1.5, 0.0]
    assert speed(vel) == 0.8
    assert speed(wrong) == 0.8
    assert speed(wrong, cell_m=0.0) == 0.0                 # the default: every vector counts, the robot stops
    crossing = np.tile([0.0, 1.5, 0.0], (12, 1))          # the whole walker turns into the path: a threat
    assert speed(crossing) < 0.8


def test_a_person_who_left_the_near_blind_zone_is_forgotten_once_the_floor_shows_through():
    from test_clearance import _floor_view
    wide = CameraInfo(width_px=64, height_px=48, fx_px=20.0, fy_px=20.0, cx_px=31.5, cy_px=23.5)   # 116 degrees across
    near = _floor_view(slice(24, 40), f=20.0)                    # someone nearer than the camera's minimum range
    seen = _floor_view(f=20.0)
    seen[:, 28:36] = 0.5                                         # ... who was seen 0.5 m ahead of the camera
    frames = [seen, near, near, _floor_view(f=20.0), _floor_view(f=20.0)]    # then walked away: the floor shows through
    per_frame = []
    with Harness(CollisionGuard, params={"stride_px": 2, "release_s": 0.0}) as h:
        for k, depth in enumerate(frames):
            t = 0.1 * k
            rgbd = RgbdFrame(stamp_ns=int(round(t * 1e9)), depth_m=depth, info=wide, rgb=np.zeros((48, 64, 3), np.uint8))
            x = 0.0 if k == 0 else 0.2                           # crept 0.2 m closer: 0.3 m from the camera
            out = h.feed([(t, "odom", odom_at(x, t)), (t, "rgbd", rgbd), (t + 0.01, "cmd", Twist2D(vx_mps=0.8))])
            per_frame.append(cmds(out)[-1][0])
    assert per_frame[:3] == [0.0, 0.0, 0.0]                      # seen, then remembered while its column reads holes
    assert per_frame[-1] > 0.0                                   # gone once rays through the spot reach the floor


def test_a_stop_for_one_wrong_vector_lasts_as_long_as_its_prediction_a_walker_or_a_seen_obstacle_holds():
    """One wrong flow vector predicts a point onto the path for one frame: the robot stops on that frame and
    goes on the next one that predicts nothing (hold_min_points 3). A walker's body (12 points) predicted
    onto the path, or a seen obstacle, holds the stop release_s (hallway: 1-3 ticks of a phantom, then 8
    of waiting; group, DWA: a walker's prediction flickering at the path's edge needs the hold)."""
    clear = post(5.0)
    straight = Twist2D(vx_mps=0.8)
    rng = np.random.default_rng(1)
    one = np.array([[0.9, -0.7, 1.0]], np.float32)
    body = np.column_stack([rng.uniform(0.8, 1.0, 12), rng.uniform(-0.8, -0.6, 12), rng.uniform(0.8, 1.6, 12)])
    for points, hold_min, expected in ((one, 3, 0.8), (one, 0, 0.0), (body.astype(np.float32), 3, 0.0)):
        toward = FlowPoints(points_m=points, velocity_mps=np.tile(np.float32([0.0, 1.0, 0.0]), (len(points), 1)))
        still = FlowPoints(points_m=points, velocity_mps=np.zeros((len(points), 3), np.float32))
        with Harness(CollisionGuard, params={"stride_px": 2, "hold_min_points": hold_min}) as h:
            first = cmds(h.feed([(0.0, "rgbd", clear), (0.0, "points", toward), (0.01, "cmd", straight)]))
            assert first[-1][0] == 0.0                                  # the prediction stops it at once
            later = cmds(h.feed([(0.07, "rgbd", clear), (0.07, "points", still), (0.08, "cmd", straight)]))
        assert later[-1][0] == expected, (len(points), hold_min)
    with Harness(CollisionGuard, params={"stride_px": 2}) as h:                 # a seen obstacle holds
        h.feed([(0.0, "rgbd", frame(0.5)), (0.01, "cmd", straight)])
        assert cmds(h.feed([(0.07, "rgbd", frame(3.0)), (0.08, "cmd", straight)]))[-1][0] == 0.0


def test_a_person_who_steps_up_into_the_near_blind_zone_stays_an_obstacle():
    """Seen 0.5 m ahead of the camera, then nearer than it can measure: their pixels turn to holes while the
    points last seen on them are still in view by geometry (0.5 m > min_range_m). Holes clear nothing: the
    robot stays stopped (it drove into a walker who stepped up so, hallway t = 16.4 s)."""
    straight = Twist2D(vx_mps=0.8)
    per_frame = []
    with Harness(CollisionGuard, params={"stride_px": 2, "release_s": 0.0}) as h:
        for k, rgbd in enumerate([post(0.5, t=0.0), post(0.5, hole=True, t=0.1), post(0.5, hole=True, t=0.2)]):
            t = 0.1 * k
            out = h.feed([(t, "odom", odom_at(0.0, t)), (t, "rgbd", rgbd), (t + 0.01, "cmd", straight)])
            per_frame.append(cmds(out)[-1][0])
    assert per_frame == [0.0, 0.0, 0.0]


def _stop_with(points_xy, cmd: Twist2D, **params) -> tuple[float, float]:
    pts = np.column_stack([np.asarray(points_xy, float), np.full(len(points_xy), 1.0)]).astype(np.float32)
    with Harness(CollisionGuard, params=params) as h:
        return cmds(h.feed([(0.0, "points", FlowPoints(points_m=pts)), (0.01, "cmd", cmd)]))[-1]


def test_along_the_path_a_tight_turn_does_not_stop_for_someone_its_full_circle_would_reach_only_later():
    """A 0.6 m/s, -1.2 rad/s command's arc is a 0.5 m circle; a walker 0.9 m to the right lies on its far side,
    ~1.3 m of turning away. The shipped rule (straight distance now, 0.92 m < 1 m) stops; the along-path rule
    (``stop_along_path``, off: not safe for DWA, see Config) turns on, no faster than it can still stop."""
    side = [[0.2, -0.9], [0.25, -0.9], [0.2, -0.95]]
    turn = Twist2D(vx_mps=0.6, wz_radps=-1.2)
    assert _stop_with(side, turn)[0] == 0.0
    v, w = _stop_with(side, turn, stop_along_path=True)
    assert 0.0 < v <= 0.6 and w == -1.2


def test_an_obstacle_straight_ahead_stops_the_robot_under_either_rule():
    ahead = [[0.8, 0.0], [0.8, 0.05], [0.85, -0.05]]
    for old in (False, True):
        assert _stop_with(ahead, Twist2D(vx_mps=0.8, wz_radps=0.0), stop_along_path=not old)[0] == 0.0
