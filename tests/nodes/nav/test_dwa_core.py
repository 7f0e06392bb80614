"""DWA core: exact arcs, dynamic window limits, admissibility, reaching goals around obstacles."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.dwa_core import DwaParams, depth_to_robot, plan_dwa, rollout, thin_points


def drive(pose, goal, obstacles, params=DwaParams(), steps=150, dt=0.2):
    """Closed loop with perfect tracking of the chosen command; returns the trajectory (n, 3)."""
    pose = np.asarray(pose, float)
    v = (0.0, 0.0)
    traj = [pose.copy()]
    for _ in range(steps):
        r = plan_dwa(pose, v, goal, obstacles, params)
        v = (r.v_mps, r.w_radps)
        pose = rollout(pose, np.array([r.v_mps]), np.array([r.w_radps]), dt, dt)[0, -1]
        traj.append(pose.copy())
        if np.hypot(*(pose[:2] - goal)) < 0.3:
            break
    return np.array(traj)


def test_rollout_is_an_exact_circle():
    arcs = rollout(np.array([1.0, 2.0, 0.3]), np.array([0.5, 0.5]), np.array([0.0, 0.5]), 2.0, 0.1)
    straight, turn = arcs
    np.testing.assert_allclose(straight[-1, :2], [1 + np.cos(0.3), 2 + np.sin(0.3)], atol=1e-12)
    radius = 0.5 / 0.5
    centre = np.array([1.0, 2.0]) + radius * np.array([-np.sin(0.3), np.cos(0.3)])
    np.testing.assert_allclose(np.hypot(*(turn[:, :2] - centre).T), radius, atol=1e-12)


def test_free_space_heads_for_the_goal_within_the_window():
    p = DwaParams()
    r = plan_dwa(np.zeros(3), (0.0, 0.0), np.array([5.0, 0.0]), np.zeros((0, 2)), p)
    assert r.v_mps == pytest.approx(p.acc_v_mps2 * p.dt_s) and abs(r.w_radps) < 1e-9
    r = plan_dwa(np.zeros(3), (0.5, 0.0), np.array([0.0, 5.0]), np.zeros((0, 2)), p)
    assert r.w_radps == pytest.approx(p.acc_w_radps2 * p.dt_s)           # turn left as fast as the window allows


def test_obstacles_too_close_on_every_arc_give_a_stop_with_a_reason():
    ring = np.stack([0.45 * np.cos(np.linspace(0, 2 * np.pi, 60)), 0.45 * np.sin(np.linspace(0, 2 * np.pi, 60))], axis=1)
    r = plan_dwa(np.zeros(3), (0.5, 0.0), np.array([5.0, 0.0]), ring)
    assert r.v_mps == 0.0 and r.w_radps == 0.0 and r.admissible == 0 and "admissible" in r.reason


def test_nan_obstacles_ignored_and_bad_pose_rejected():
    obs = np.array([[np.nan, 0.0], [10.0, 10.0]])
    r = plan_dwa(np.zeros(3), (0.0, 0.0), np.array([5.0, 0.0]), obs)
    assert r.v_mps > 0
    with pytest.raises(ValueError, match="finite"):
        plan_dwa(np.array([np.nan, 0, 0]), (0.0, 0.0), np.array([5.0, 0.0]), obs)
    with pytest.raises(ValueError, match="limits"):
        DwaParams(v_max_mps=0.0)


def test_reaches_goal_around_a_static_obstacle_without_touching_it():
    obstacle = np.array([[4.0, 0.0], [4.0, 0.2], [4.0, -0.2]])
    traj = drive([0, 0, 0], np.array([8.0, 0.0]), obstacle)
    assert np.hypot(*(traj[-1, :2] - (8.0, 0.0))) < 0.3
    gap = np.min(np.hypot(traj[:, None, 0] - obstacle[None, :, 0], traj[:, None, 1] - obstacle[None, :, 1]))
    assert gap > DwaParams().robot_radius_m


def test_depth_to_robot_and_thinning():
    depth = np.zeros((4, 6), np.float32)
    depth[1, 2] = 2.0
    depth[3, 5] = np.nan
    pts, valid = depth_to_robot(depth, 10.0, 10.0, 2.0, 1.0, mount_xyz_m=(0.3, 0.0, 1.0), stride=1)
    np.testing.assert_allclose(pts, [[2.3, 0.0, 1.0]])      # on the optical axis: straight ahead at camera height
    assert valid == pytest.approx(1 / 24)
    xy = np.array([[0.01, 0.01], [0.02, 0.03], [0.5, 0.5]])
    assert len(thin_points(xy, 0.1)) == 2 and len(thin_points(np.zeros((0, 2)))) == 0
