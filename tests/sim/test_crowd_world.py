"""Crowd world and CrowdSim node: unicycle limits, watchdog, walls, contacts, outputs through the harness."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.geometry import Twist2D
from sim.crowd import CrowdSim, CrowdWorld, RobotLimits, add_depth_noise, unicycle_step
from sim.crowd_render import CameraModel
from tether.testing import Harness

SMALL = CameraModel(width_px=80, height_px=60, fx_px=65.6, fy_px=65.6, cx_px=39.5, cy_px=29.5)
SMALL_PARAMS = {"width_px": 80, "height_px": 60, "fx_px": 65.6, "fy_px": 65.6}


def room(**kw):
    data = {"name": "room", "bounds_m": [-5, -5, 5, 5], "robot": {"x_m": 0, "y_m": 0, "yaw_rad": 0},
            "goal": {"x_m": 3, "y_m": 0, "tolerance_m": 0.3},
            "walls": [{"points": [[-5, -5], [5, -5], [5, 5], [-5, 5], [-5, -5]], "height_m": 2.5}]}
    data.update(kw)
    return data


def test_unicycle_respects_acceleration_and_speed_limits_and_integrates_arcs_exactly():
    lim = RobotLimits(max_speed_mps=1.0, max_accel_mps2=0.8, max_yaw_rate_radps=1.0, max_yaw_accel_radps2=100.0)
    pose, twist = (0.0, 0.0, 0.0), (0.0, 0.0)
    pose, twist = unicycle_step(pose, twist, (5.0, 0.0), 0.5, lim)
    assert twist[0] == pytest.approx(0.4)                          # 0.8 m/s^2 * 0.5 s, not 5 m/s
    for _ in range(10):
        pose, twist = unicycle_step(pose, twist, (5.0, 0.0), 0.5, lim)
    assert twist[0] == pytest.approx(1.0)                          # clipped to max speed
    # a full circle at v = 1, w = 1 comes back to the start (exact arc integration)
    pose, twist = (0.0, 0.0, 0.0), (1.0, 1.0)
    for _ in range(100):
        pose, twist = unicycle_step(pose, twist, (1.0, 1.0), 2 * np.pi / 100, lim)
    np.testing.assert_allclose(pose[:2], (0.0, 0.0), atol=1e-6)


def test_world_drives_to_the_goal_and_reports_it():
    world = CrowdWorld(room(), camera=SMALL)
    for _ in range(100):
        world.step(0.6, 0.0, 0.1)
        if world.goal_reached:
            break
    assert world.goal_reached and abs(world.pose[0] - 3.0) <= 0.3 and world.collisions == 0


def test_robot_is_stopped_by_a_wall_not_pushed_through_it():
    world = CrowdWorld(room(), camera=SMALL)
    for _ in range(200):
        world.step(1.0, 0.0, 0.05)
    assert world.pose[0] <= 5.0 - world.limits.radius_m + 1e-9
    assert world.pose[0] > 4.0 and world.blocked_steps > 0 and world.twist == (0.0, 0.0)


def test_standing_pedestrian_on_the_path_is_one_collision_however_long_the_contact():
    world = CrowdWorld(room(pedestrians=[{"id": 5, "waypoints": [[1.5, 0.0]], "speed_mps": 0}]), camera=SMALL)
    for _ in range(60):
        world.step(0.5, 0.0, 0.1)
    assert world.collisions == 1
    assert world.min_clearance_m < 0.65
    np.testing.assert_array_equal(world.pedestrians().xy_m, [[1.5, 0.0]])    # it never moved
    rgb, depth = world.render()
    assert rgb.shape == (60, 80, 3) and np.all(np.isfinite(depth))


def test_non_finite_command_is_refused():
    world = CrowdWorld(room(), camera=SMALL)
    with pytest.raises(ValueError, match="finite"):
        world.step(float("nan"), 0.0, 0.1)


def test_depth_noise_and_dropout():
    rng = np.random.default_rng(3)
    depth = np.full((100, 100), 4.0, np.float32)
    noisy = add_depth_noise(depth, rng, noise_per_m2=0.002, dropout=0.1)
    assert noisy.dtype == np.float32
    assert 0.07 < np.mean(noisy == 0) < 0.13
    kept = noisy[noisy > 0]
    assert kept.std() == pytest.approx(0.002 * 16, rel=0.15)


def test_node_publishes_map_goal_odom_pedestrians_and_frames_with_consistent_stamps():
    with Harness(CrowdSim, params={"scene": "crossing", "rate_hz": 20, "camera_hz": 10, "wait_for_cmd_s": 0,
                                   **SMALL_PARAMS}) as h:
        h.feed([(0.05 * i, "cmd", Twist2D(vx_mps=0.5)) for i in range(20)], until_s=1.0)
        assert len(h.of("map")) == 1 and len(h.of("goal")) == 1
        grid = h.of("map")[0]
        assert grid.data.shape == (100, 160) and grid.data.max() == 1.0 and grid.frame_id == "world"
        assert (h.of("goal")[0].x_m, h.of("goal")[0].y_m) == (10.0, 0.0)
        frames = h.of("rgbd")
        assert len(frames) == 11 and frames[0].rgb.shape == (60, 80, 3) and frames[0].info.cx_px == 39.5
        odom_stamps = {o.stamp_ns for o in h.of("odom")}
        assert all(f.stamp_ns in odom_stamps for f in frames)             # a pose exactly at every frame
        odom = h.of("odom")[-1]
        assert odom.twist.vx_mps == pytest.approx(0.5) and odom.pose.x_m > 0.2
        peds = h.of("pedestrians")[-1]
        assert list(peds.ids) == [1] and peds.positions_m.shape == (1, 2)      # the crosser appears at t = 1 s
        h.advance_to(2.5)
        assert len(h.of("map")) == 2                                     # re-published every map_period_s


def test_node_watchdog_brakes_when_commands_stop_and_drops_non_finite_commands():
    with Harness(CrowdSim, params={"scene": "toward", "rate_hz": 20, "camera_hz": 1, "watchdog_s": 0.5,
                                   **SMALL_PARAMS}) as h:
        h.feed([(0.05 * i, "cmd", Twist2D(vx_mps=0.8)) for i in range(40)])
        h.feed([(2.0, "cmd", Twist2D(vx_mps=float("nan")))])
        speed_at_2s = h.of("odom")[-1].twist.vx_mps
        h.advance_to(4.0)
        assert speed_at_2s > 0.7
        assert h.of("odom")[-1].twist.vx_mps == 0.0


def test_node_world_holds_still_until_the_first_command_then_counts_who_closed_each_contact():
    with Harness(CrowdSim, params={"scene": "toward", "rate_hz": 20, "camera_hz": 1, "wait_for_cmd_s": 5.0,
                                   **SMALL_PARAMS}) as h:
        h.advance_to(2.0)                                              # the pipeline is still starting
        still = h.of("pedestrians")[-1].positions_m.copy()
        assert h.node.world.t_s == 0.0 and np.allclose(still, h.of("pedestrians")[0].positions_m)
        h.feed([(2.0 + 0.05 * i, "cmd", Twist2D(vx_mps=1.0)) for i in range(140)])   # drive at the walker
        w = h.node.world
        assert w.t_s == pytest.approx(6.95, abs=0.06)                  # the clock started with the first cmd
        assert w.collisions == 1 and len(w.contacts) == 1
        c = w.contacts[0]
        assert c.by_robot and c.robot_closing_mps > 0.5 and c.ped_closing_mps > 0.5 and w.collisions_by_robot == 1


def test_world_blames_the_pedestrian_who_walks_into_a_stopped_robot():
    w = CrowdWorld(room(pedestrians=[{"id": 7, "waypoints": [[3.0, 0.0], [-3.0, 0.0]], "speed_mps": 1.0}],
                        pedestrian_model="linear", pedestrians_see_robot=False),
                   camera=SMALL)
    for _ in range(60):
        w.step(0.0, 0.0, 0.1)
    assert w.collisions == 1 and w.collisions_by_robot == 0
    assert w.contacts[0].ped_id == 7 and w.contacts[0].ped_closing_mps > 0.5 and w.contacts[0].robot_closing_mps == 0.0


def test_contact_attribution_rule_and_no_respawn_inside_the_robot():
    from sim.crowd import robot_drove_in
    assert robot_drove_in(0.3, 0.0) and robot_drove_in(0.97, 1.06)       # into someone standing; head-on
    assert not robot_drove_in(0.14, 0.7) and not robot_drove_in(0.05, 0.0) and not robot_drove_in(-0.5, 1.0)
    # a respawning walker whose start point is where the robot stands waits at its goal instead
    w = CrowdWorld(room(pedestrians=[{"id": 3, "waypoints": [[0.0, 0.0], [2.0, 0.0]], "speed_mps": 1.0,
                                      "at_goal": "respawn"}], robot={"x_m": -3.0, "y_m": 0.0, "yaw_rad": 3.1416},
                        pedestrian_model="linear", pedestrians_see_robot=False), camera=SMALL)
    w.pose, w.walkers.xy[0] = (0.0, 0.0, 3.1416), (1.0, 0.0)       # the robot now stands on the start point
    for _ in range(40):
        w.step(0.0, 0.0, 0.1)
    assert w.collisions == 0 and np.hypot(*w.pedestrians().xy_m[0]) > 1.5


def test_the_crowd_can_walk_before_the_robot_appears_and_nobody_meets_the_absent_robot():
    """A clear start (bench/social_nav_humans.py clear_start_s): a walker crossing the start passes before the robot is there."""
    w = CrowdWorld(room(pedestrians=[{"id": 7, "waypoints": [[3.0, 0.0], [-4.5, 0.0]], "speed_mps": 1.0}],
                        pedestrian_model="linear", pedestrians_see_robot=False), camera=SMALL)
    w.advance_crowd(5.0)
    assert w.t_s == pytest.approx(5.0) and w.collisions == 0 and w.min_clearance_m > 1.0
    assert w.pose == w.scene.robot_start and w.pedestrians().xy_m[0, 0] < -1.5
    w.advance_crowd(0.0)                                   # nothing to do is fine
    assert w.t_s == pytest.approx(5.0)
