"""Three-layer planner (Algorithm 2) through the harness: global following, local detours, re-plan events."""
from __future__ import annotations

import numpy as np

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.nav import CostGrid, FeatureGrid, Goal2D
from msgs.sensor import Grid
from nodes.nav.dijkstra_planner import DijkstraPlanner
from nodes.nav.social_planner import PlannerParams, SocialPlanner
from nodes.nav.grid_frame import GridFrame
from tether.testing import Harness

RES, ROWS, COLS = 0.25, 21, 21
ORIGIN_X, ORIGIN_Y = 0.25, -2.5
NAMES = ["density_high", "density_medium", "density_low"]


def odom(x=0.0, y=0.0, yaw=0.0, stamp_ns=0) -> Odometry2D:
    return Odometry2D(stamp_ns=stamp_ns, pose=Pose2D(x_m=x, y_m=y, yaw_rad=yaw), twist=Twist2D())


def crowd(blob_xy=None, radius_m=0.6, origin_x=ORIGIN_X) -> tuple[FeatureGrid, CostGrid]:
    """Density features and costs with a high-density blob (a standing pedestrian) at ``blob_xy`` (robot frame)."""
    f = np.zeros((ROWS, COLS, 3), np.uint8)
    f[..., 2] = 1
    if blob_xy is not None:
        rr, cc = np.mgrid[:ROWS, :COLS]
        x, y = origin_x + cc * RES, ORIGIN_Y + rr * RES
        near = np.hypot(x - blob_xy[0], y - blob_xy[1]) < radius_m
        f[near] = (1, 0, 0)
    cost = (2.0 + 8.0 * f[..., 0]).astype(np.float32)
    kw = dict(resolution_m=RES, origin_x_m=origin_x, origin_y_m=ORIGIN_Y, frame_id="base")
    return FeatureGrid(features=f, names=NAMES, **kw), CostGrid(cost=cost, **kw)


def run(features, costs, goal=(8.0, 0.0), pose=(0.0, 0.0, 0.0), map_msg=None):
    h = Harness(DijkstraPlanner)
    events = [(0.0, "goal", Goal2D(x_m=goal[0], y_m=goal[1]))]
    if map_msg is not None:
        events.append((0.0, "map", map_msg))
    events += [(0.01, "odom", odom(*pose, stamp_ns=10_000_000)), (0.02, "features", features),
               (0.03, "costs", costs), (0.04, "odom", odom(*pose, stamp_ns=40_000_000))]
    h.feed(events)
    return h


def test_no_crowd_follows_the_global_path_straight_to_the_goal():
    h = run(*crowd(None))
    status = h.of("status")[-1]
    assert status.state == "following" and status.reason.startswith("global")
    cmd = h.of("cmd")[-1]
    assert cmd.vx_mps > 0.5 and abs(cmd.wz_radps) < 1e-6


def test_standing_pedestrian_on_the_path_triggers_a_local_detour():
    h = run(*crowd((2.0, 0.0)))
    status = h.of("status")[-1]
    assert status.state == "replanned" and "local" in status.reason and status.plan_ms > 0
    path = h.of("path")[-1].poses[:, :2]
    assert np.min(np.hypot(path[:, 0] - 2.0, path[:, 1])) >= 0.6     # goes around the person
    assert abs(h.of("cmd")[-1].wz_radps) > 0.05                          # and starts turning to do so


def test_robot_behind_the_grid_border_still_plans():
    h = run(*crowd((2.5, 0.0), origin_x=1.0))       # the grid starts 1 m ahead: the robot's cell is clamped
    assert h.of("status")[-1].state == "replanned" and len(h.of("path")[-1].poses) > 2


def test_goal_walled_off_on_the_map_is_reported_unreachable():
    occ = np.zeros((60, 120), np.float32)
    occ[10:50, 90] = occ[10:50, 110] = occ[10, 90:111] = occ[49, 90:111] = 1.0     # a closed room around the goal
    grid = Grid(data=occ, resolution_m=0.1, origin_x_m=-1.0, origin_y_m=-3.0)
    h = run(*crowd(None), goal=(9.0, 0.0), map_msg=grid)
    status = h.of("status")[-1]
    assert status.state == "unreachable" and "global" in status.reason
    assert h.of("cmd")[-1].vx_mps == 0.0


def test_safe_zone_keeps_the_waypoint_until_reached_then_replans():
    planner = SocialPlanner(PlannerParams(memory_s=0.0))
    planner.set_goal((8.0, 0.0))
    frame = GridFrame((ROWS, COLS), RES, ORIGIN_X, ORIGIN_Y)
    f, c = crowd((2.0, 0.0))
    high = f.features[..., 0] > 0
    first = planner.update((0.0, 0.0, 0.0), c.cost, frame, high, 0.0)
    assert first.mode == "local" and first.event == "new_goal"
    held = planner.update((0.1, 0.0, 0.0), c.cost, frame, high, 0.1)
    assert held.event == "" and np.allclose(held.waypoint, first.waypoint)
    wp = first.waypoint
    again = planner.update((wp[0] - 0.1, wp[1], 0.0), c.cost, frame, np.zeros_like(high), 0.2)
    assert again.event == "safe_zone" and again.mode == "global"      # crowd gone: back to the global path


def test_goal_reached_stops():
    h = run(*crowd(None), goal=(0.1, 0.0))
    assert h.of("status")[-1].state == "reached" and h.of("cmd")[-1].vx_mps == 0.0


def test_pedestrian_leaving_the_field_of_view_is_remembered():
    planner = SocialPlanner(PlannerParams(memory_s=1.0))
    planner.set_goal((8.0, 0.0))
    frame = GridFrame((ROWS, COLS), RES, ORIGIN_X, ORIGIN_Y)
    f, c = crowd((2.0, 1.2), radius_m=0.3)            # ahead-left, inside the 57 degree view
    planner.update((0.0, 0.0, 0.0), c.cost, frame, f.features[..., 0] > 0, 0.0)
    empty_f, empty_c = crowd(None)
    # 1.4 m further on, the person is beside the robot (bearing ~ 60 deg): the camera sees nothing there now
    pose = (1.4, 0.0, 0.0)
    fused_cost, fused_high = planner._remember(pose, empty_c.cost.astype(float), frame,
                                               empty_f.features[..., 0] > 0, 0.5)
    cell = frame.cell_of(np.array([[0.6, 1.2]]))[0]
    assert fused_high[cell[0], cell[1]] and fused_cost[cell[0], cell[1]] > 2.0
    ahead = frame.cell_of(np.array([[3.0, 0.0]]))[0]      # in view: what the camera sees now wins
    assert not fused_high[ahead[0], ahead[1]]
    later_cost, later_high = planner._remember(pose, empty_c.cost.astype(float), frame,
                                               empty_f.features[..., 0] > 0, 2.0)
    assert not later_high.any() and later_cost.max() == 2.0        # forgotten after memory_s


def test_crossing_pedestrian_is_predicted_where_the_robot_would_meet_it():
    from nodes.nav.plan_geometry import predict_conflicts
    frame = GridFrame((ROWS, COLS), RES, ORIGIN_X, ORIGIN_Y)
    pts = np.array([[3.0, -2.0, 1.0]] * 20)              # 3 m ahead, 2 m to the right, walking left at 1 m/s
    vel = np.array([[0.0, 1.0, 0.0]] * 20)
    mask = predict_conflicts(pts, vel, frame, robot_speed_mps=1.0, horizon_s=3.0)
    hit = frame.xy_of(np.argwhere(mask))
    assert len(hit) and np.all(np.abs(hit[:, 0] - 3.0) < 0.2)      # on the person's line ...
    assert hit[:, 1].min() > -1.6 and hit[:, 1].max() < 1.6           # ... around where the robot gets in ~3 s
    still = predict_conflicts(pts, np.zeros_like(vel), frame, robot_speed_mps=1.0)
    assert not still.any()                                            # a standing person is the features' job
    assert not predict_conflicts(np.zeros((0, 3)), np.zeros((0, 3)), frame, robot_speed_mps=1.0).any()


def test_footprint_dilation_spreads_the_dearest_cost_over_the_robot_disc():
    from nodes.nav.plan_geometry import footprint_cost
    cost = np.full((9, 9), 2.0)
    cost[4, 4] = 10.0
    out = footprint_cost(cost, 2.0)
    assert out[4, 6] == 10.0 and out[2, 4] == 10.0 and out[4, 7] == 2.0 and out[2, 2] == 2.0


def test_turning_toward_a_waypoint_is_not_passing_it():
    """A waypoint briefly behind the heading while the robot turns to it is kept; one driven past re-plans."""
    planner = SocialPlanner(PlannerParams(memory_s=0.0))
    planner.set_goal((8.0, 0.0))
    frame = GridFrame((ROWS, COLS), RES, ORIGIN_X, ORIGIN_Y)
    f, c = crowd((2.0, 0.0))
    high = f.features[..., 0] > 0
    first = planner.update((0.0, 0.0, 0.0), c.cost, frame, high, 0.0)
    assert first.mode == "local"
    wp = first.waypoint
    facing_away = float(np.arctan2(wp[1], wp[0])) + np.pi         # the waypoint is behind the heading
    held = planner.update((0.0, 0.0, facing_away), c.cost, frame, high, 0.1)
    assert held.event == "" and np.allclose(held.waypoint, wp)
    beyond = wp + np.array([0.3, 0.0])                            # driven on past it
    passed = planner.update((beyond[0], beyond[1], 0.0), c.cost, frame, np.zeros_like(high), 0.2)
    assert passed.event == "waypoint_behind"


def test_a_planner_with_nothing_to_plan_to_turns_in_place_toward_the_global_path():
    planner = SocialPlanner(PlannerParams(memory_s=0.0))
    planner.set_goal((8.0, 0.0))
    frame = GridFrame((ROWS, COLS), RES, ORIGIN_X, ORIGIN_Y)
    f, c = crowd(None)
    planner.update((0.0, 0.0, 0.0), c.cost, frame, f.features[..., 0] > 0, 0.0)
    planner.mode = "hold"                                        # no reachable cell in view
    v, w = planner.command((0.0, 0.0, np.pi / 2))                # facing away from the path
    assert v == 0.0 and w < 0.0                                  # turns back toward it on the spot


def test_walls_of_the_map_are_grown_by_the_robot_radius_once():
    """A 4 m corridor (walls at y = +-2) leaves the robot centre ~3.1 m: a plan may run 1.3 m off the axis."""
    from nodes.nav.grid_frame import GridFrame as F
    occ = np.zeros((41, 121), np.uint8)
    occ[0, :] = occ[-1, :] = 1                                   # walls at y = -2 and +2 (0.1 m cells)
    planner = SocialPlanner(PlannerParams(memory_s=0.0))
    planner.set_map(occ, F(occ.shape, 0.1, -1.0, -2.0))
    planner.set_goal((10.0, 0.0))
    frame = GridFrame((ROWS, COLS), RES, -0.5, ORIGIN_Y)
    f, c = crowd((2.0, 0.0), radius_m=1.1, origin_x=-0.5)        # a group across the middle of the corridor
    d = planner.update((0.0, 0.0, 0.0), c.cost, frame, f.features[..., 0] > 0, 0.0)
    assert d.mode == "local" and np.abs(d.path_xy[:, 1]).max() > 1.2     # passes the group near a wall
    assert np.abs(d.path_xy[:, 1]).max() < 2.0 - 0.35
