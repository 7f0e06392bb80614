"""The simple car's kinematics and walls, and the seed-14 rewards."""
from __future__ import annotations

import numpy as np
import pytest

from sim.car_env import MazeCar, ReachCar, reward, serpentine
from sim.diff_car import Walls, box_walls, integrate


def test_arc_matches_fine_euler_and_straight_line_has_no_division_by_zero():
    pose = np.array([[0.3, -0.2, 3.0], [0.0, 0.0, -3.1], [1.0, 1.0, 0.5]])
    v, w = np.array([0.8, -0.5, 1.0]), np.array([np.pi, 1e-9, 0.0])
    exact = integrate(pose, v, w, 0.1)
    fine = pose.copy()
    for _ in range(10000):
        x, y, th = fine.T
        fine = np.column_stack([x + v * np.cos(th) * 1e-5, y + v * np.sin(th) * 1e-5, th + w * 1e-5])
    assert np.allclose(exact[:, :2], fine[:, :2], atol=1e-6)
    assert np.all(np.isfinite(exact))
    assert exact[2, 0] == pytest.approx(1.0 + 0.1 * np.cos(0.5)) and exact[2, 2] == pytest.approx(0.5)


def test_yaw_wraps_across_pi():
    out = integrate(np.array([[0.0, 0.0, 3.1]]), np.zeros(1), np.array([np.pi]), 0.1)
    assert -np.pi < out[0, 2] <= np.pi and out[0, 2] == pytest.approx(3.1 + 0.1 * np.pi - 2 * np.pi)


def test_ranges_and_clearance_in_a_box():
    walls = Walls(box_walls(0, 0, 4, 2))
    pose = np.array([[1.0, 0.5, 0.0]])
    r = walls.ranges(pose, np.array([0.0, np.pi / 2, np.pi, -np.pi / 2]), 10.0)
    assert np.allclose(r, [[3.0, 1.5, 1.0, 0.5]])
    assert walls.ranges(pose, np.array([0.0]), 2.0)[0, 0] == 2.0          # capped
    assert walls.clearance(np.array([[1.0, 0.5], [2.0, 1.0]])) == pytest.approx([0.5, 1.0])
    assert np.isinf(Walls(np.zeros((0, 4))).clearance(np.zeros((1, 2))))[0]


def test_reward_is_the_papers_shape():
    d = np.array([0.0, 0.005, 0.02, 0.5, 3.0])
    r = reward(d)
    assert r[0] == pytest.approx(10.0) and np.all(np.diff(r) < 0)
    assert r[-1] == pytest.approx(-1.0, abs=0.08)                       # flat far away (e^-15)
    hit = reward(d, np.ones(5, bool))
    assert np.all(hit[1:] < r[1:]) and hit[0] == r[0]                   # (2 min(x, .5))^eta: 0 on target
    assert np.all(hit >= r - 3.0 - 1e-12)


def test_reach_truncates_and_never_terminates():
    sim = ReachCar(3)
    sim.reset([1, 2, 3])
    for t in range(100):
        b = sim.step(np.zeros((3, 2)))
        if t < 99:
            assert not b.truncated.any()
    assert b.truncated.all() and not b.terminated.any()
    assert np.array_equal(b.sim_time_s, np.zeros(3))                    # autoreset: new episodes at t = 0
    assert not np.array_equal(b.obs, b.final_obs)


def test_out_of_range_actions_are_clipped_nan_refused():
    a, b = ReachCar(1), ReachCar(1)
    a.reset([5]), b.reset([5])
    assert np.array_equal(a.step([[7.0, -9.0]]).obs, b.step([[1.0, -1.0]]).obs)
    with pytest.raises(ValueError, match="non-finite action for instance"):
        a.step([[np.nan, 0.0]])


def test_maze_walls_block_and_the_exit_terminates():
    sim = MazeCar(1, start_jitter_m=0.0)
    sim.reset([0])
    sim.pose[:] = (0.5, 0.5, np.pi / 2)                                   # facing the wall 0.5 m above
    hits = [sim.step([[1.0, 0.0]]).metrics[0, 1] for _ in range(10)]
    assert sum(hits) >= 5 and sim.pose[0, 1] < 1.0 - 0.1 + 1e-9             # never through the wall
    sim.pose[:] = (0.5, 2.4, np.pi / 2)
    b = sim.step([[1.0, 0.0]])
    assert b.terminated[0] and b.metrics[0, 2] == 1.0


def test_geodesic_distance_follows_the_corridors():
    sim = MazeCar(1, distance="geodesic")
    _, start, exit_ = serpentine()
    geo = sim._dist(np.array([start[:2]]))[0]
    assert geo > 1.8 * np.hypot(*(np.array(exit_) - start[:2]))          # 2 m straight, ~4 m around
    assert sim._dist(np.array([exit_]))[0] == pytest.approx(0.0, abs=0.05)


def test_unreachable_exit_is_refused_or_runs_without_success(caplog):
    walls, start, exit_ = serpentine()
    sealed = np.vstack([walls, [[0.0, 2.0, 1.0, 2.0]]])                  # close the last gap
    with pytest.raises(ValueError, match="cannot be reached"):
        MazeCar(1, walls=sealed, distance="geodesic")
    sim = MazeCar(2, walls=sealed, distance="euclidean", max_steps=50)
    assert not sim.reachable and "cannot be reached" in caplog.text
    sim.reset([0, 1])
    rng = np.random.default_rng(0)
    for _ in range(50):
        b = sim.step(rng.uniform(-1, 1, (2, 2)))
        assert np.all(np.isfinite(b.rewards)) and not b.terminated.any()
