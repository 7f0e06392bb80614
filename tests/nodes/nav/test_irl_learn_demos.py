"""irl_learn: expert paths cut from trajectories into grid demos; npz round trip without pickles."""
from __future__ import annotations

import numpy as np

from nodes.nav.grid_frame import GridFrame
from nodes.nav.irl import Demo
from nodes.nav.demos import DemoSet, demo_path, demos_from_poses, load_demos, save_demos, widen_demo

FRAME = GridFrame((24, 24), 0.25, origin_x_m=-0.375, origin_y_m=-2.875)


def test_demo_path_follows_the_future_track_until_it_leaves_the_grid():
    future = np.stack([np.linspace(0.2, 9.0, 45), np.linspace(0.0, 2.0, 45)], axis=1)   # world = robot frame here
    path = demo_path(FRAME, (0.0, 0.0, 0.0), future)
    start = FRAME.clamp(FRAME.cell_of(np.zeros(2)))[0]
    assert tuple(path[0]) == tuple(start)
    assert np.abs(np.diff(path, axis=0)).max() == 1 and FRAME.inside(path).all()      # 8-connected, in the grid
    end = FRAME.xy_of(path[-1:])[0]
    assert end[0] > 5.0 and 0.9 < end[1] < 1.5                                       # reached the far edge on the track


def test_demo_path_in_a_rotated_robot_frame_and_standing_still():
    pose = (10.0, 5.0, np.pi / 2)                       # facing +y: walking +y in the world is straight ahead
    path = demo_path(FRAME, pose, np.array([[10.0, 6.0], [10.0, 7.0]]))
    assert (np.diff(path[:, 1]) > 0).all() and (path[:, 0] == path[0, 0]).all()
    assert len(demo_path(FRAME, pose, np.zeros((0, 2)))) == 1            # no future: no move, no demo


def test_demos_from_poses_samples_grids_and_skips_ones_without_a_future():
    t = np.arange(0, 6.0, 0.1)
    poses = np.column_stack([t, 1.2 * t, np.zeros_like(t), np.zeros_like(t)])
    f = np.zeros((24, 24, 12), np.uint8)
    grids = [(ts, f, FRAME) for ts in (0.5, 2.0, 5.95, 9.0)]
    demos = demos_from_poses(grids, poses, horizon_s=3.0)
    assert len(demos) == 2                              # 5.95 s has no future left, 9.0 s is past the log
    assert all(len(d.path) > 5 for d in demos)


def test_demo_cache_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    demos = DemoSet({"a": [Demo(rng.integers(0, 2, (4, 5, 12)).astype(np.uint8), np.array([[0, 0], [1, 1]]))],
                     "b": [Demo(np.zeros((4, 5, 12), np.uint8), np.array([[2, 2], [2, 3], [3, 4]]))] * 2})
    save_demos(tmp_path / "d.npz", demos)
    back = load_demos(tmp_path / "d.npz")
    assert sorted(back.scenes) == ["a", "b"] and len(back.scenes["b"]) == 2
    np.testing.assert_array_equal(back.scenes["b"][1].path, [[2, 2], [2, 3], [3, 4]])
    np.testing.assert_array_equal(back.scenes["a"][0].features, demos.scenes["a"][0].features)


def test_widen_demo_spreads_the_high_bin_over_the_footprint_and_stays_one_hot():
    f = np.zeros((9, 9, 12))
    f[..., [2, 5, 8, 11]] = 1.0                  # every group 'low'
    f[4, 4, [0, 2]] = [1.0, 0.0]                 # one high-density cell
    f[4, 7, [1, 2]] = [1.0, 0.0]                 # one medium-density cell, 3 cells away
    f[0, 0, [9, 11]] = [1.0, 0.0]                # a goal feature: not widened
    d = widen_demo(Demo(f, np.array([[0, 0], [0, 1]])), 2.0)
    w = d.features
    assert w[4, 6, 0] == 1 and w[2, 4, 0] == 1 and w[3, 3, 0] == 1      # within 2 cells of the person
    assert w[1, 1, 0] == 0 and w[4, 7, 0] == 0                          # beyond the disc
    assert w[4, 7, 1] == 1 and w[4, 5, 1] == 0                          # high wins over medium
    assert w[0, 1, 9] == 0 and w[0, 0, 9] == 1                          # goal group untouched
    for g in (0, 3, 6, 9):
        assert np.all(w[..., g:g + 3].sum(axis=2) == 1)
    assert widen_demo(d, 0.0) is d


def test_demos_leave_by_the_planners_rim_with_the_distance_left_to_the_goal():
    t = np.arange(0, 10.0, 0.1)
    poses = np.column_stack([t, 1.0 * t, 0.3 * np.sin(t), np.zeros_like(t)])
    f = np.zeros((24, 24, 12), np.uint8)
    far, near = np.array([20.0, 0.0]), np.array([3.0, 0.0])
    d = demos_from_poses([(0.5, f, FRAME)], poses, horizon_s=8.0, goal_xy=far, rim_m=4.0)[0]
    assert d.exit_cells is not None
    end = FRAME.xy_of(d.path[-1:])[0]
    assert 3.4 < np.hypot(*end) <= 4.0 + 1e-9                      # cut where the path first reaches the rim
    assert np.isfinite(d.exit_cells[d.path[-1, 0], d.path[-1, 1]])
    assert np.isinf(d.exit_cells[d.path[:-1, 0], d.path[:-1, 1]]).all()
    rim = np.argwhere(np.isfinite(d.exit_cells))
    left = d.exit_cells[rim[:, 0], rim[:, 1]] * FRAME.resolution_m
    # distance left to the goal from each rim cell (the robot is at x = 0.5 m at t = 0.5 s)
    xy = FRAME.xy_of(rim) + [0.5, 0.3 * np.sin(0.5)]
    np.testing.assert_allclose(left, np.hypot(*(far - xy).T), atol=1e-9)
    # a goal inside the rim: the planner plans to the goal itself, so the demo ends at its last cell
    assert demos_from_poses([(0.5, f, FRAME)], poses, horizon_s=3.0, goal_xy=near, rim_m=4.0)[0].exit_cells is None
    # a path that never reaches the rim within the horizon also ends at its last cell
    assert demos_from_poses([(0.5, f, FRAME)], poses, horizon_s=1.0, goal_xy=far, rim_m=4.0)[0].exit_cells is None


def test_demo_cache_and_widening_keep_the_exits(tmp_path):
    exits = np.full((4, 5), np.inf)
    exits[:, 4] = [5.0, 4.0, 4.5, 6.0]
    d = Demo(np.zeros((4, 5, 12), np.uint8), np.array([[1, 2], [1, 3], [1, 4]]), exit_cells=exits)
    save_demos(tmp_path / "d.npz", DemoSet({"a": [d, Demo(d.features, d.path)]}))
    a, b = load_demos(tmp_path / "d.npz").scenes["a"]
    np.testing.assert_array_equal(a.exit_cells, exits)
    assert b.exit_cells is None
    np.testing.assert_array_equal(widen_demo(d, 2.0).exit_cells, exits)
