"""Crowd features: the 12-dim layout, density / speed / Figure-3 direction / goal bins, hard cases."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.features import (FEATURE_NAMES, HIGH, LOW, MEDIUM, GridSpec, Thresholds, extract_features,
                                goal_in_robot_frame)

GRID = GridSpec(x_min_m=0.0, x_max_m=2.0, y_min_m=-1.0, y_max_m=1.0, resolution_m=0.25)     # 8 x 8
TH = Thresholds(density_points=(5, 20), speed_mps=(0.3, 0.8), moving_mps=0.25, flow_points=3)


def cloud(x, y, n, vel=(0.0, 0.0), z=1.0):
    pts = np.tile([x, y, z], (n, 1)).astype(float)
    return pts, np.tile([vel[0], vel[1], 0.0], (n, 1))


def cell(x, y, grid=GRID):
    return int(np.floor((y - grid.y_min_m) / grid.resolution_m)), int(np.floor((x - grid.x_min_m) / grid.resolution_m))


def group(f, r, c, g):
    """Level (HIGH / MEDIUM / LOW) of feature group g at cell (r, c)."""
    return int(np.flatnonzero(f.features[r, c, 3 * g:3 * g + 3])[0])


def test_layout_is_four_one_hot_groups_of_high_medium_low():
    assert len(FEATURE_NAMES) == 12
    assert FEATURE_NAMES[:3] == ["density_high", "density_medium", "density_low"]
    assert FEATURE_NAMES[6:9] == ["direction_high", "direction_medium", "direction_low"]
    assert FEATURE_NAMES[9:] == ["goal_high", "goal_medium", "goal_low"]
    pts, vel = cloud(1.1, 0.1, 30, (1.0, 0.0))
    f = extract_features(pts, vel, (5.0, 0.0), GRID, TH)
    assert f.features.shape == (8, 8, 12) and f.features.dtype == np.uint8
    for g in range(4):
        assert np.all(f.features[..., 3 * g:3 * g + 3].sum(axis=2) == 1)


def test_no_points_at_all():
    f = extract_features(np.zeros((0, 3)), np.zeros((0, 3)), (5.0, 0.0), GRID, TH)
    assert np.all(f.features[..., 2] == 1) and np.all(f.features[..., 5] == 1) and np.all(f.features[..., 8] == 1)
    assert f.density.sum() == 0 and np.all(f.velocity_mps == 0)


def test_density_and_speed_bins():
    parts = [cloud(0.1, -0.9, 3), cloud(0.6, -0.9, 10, (0.5, 0.0)), cloud(1.1, -0.9, 40, (0.0, 1.2))]
    f = extract_features(np.concatenate([p for p, _ in parts]), np.concatenate([v for _, v in parts]), None, GRID, TH)
    assert [group(f, *cell(x, -0.9), 0) for x in (0.1, 0.6, 1.1)] == [LOW, MEDIUM, HIGH]
    assert [group(f, *cell(x, -0.9), 1) for x in (0.1, 0.6, 1.1)] == [LOW, MEDIUM, HIGH]
    np.testing.assert_allclose(f.velocity_mps[cell(1.1, -0.9)], [0.0, 1.2])


def test_direction_follows_the_figure_3_risk_table():
    pts, vel = cloud(0.6, 0.1, 10, (1.0, 0.0))                     # moving +x from cell (4, 2)
    f = extract_features(pts, vel, None, GRID, TH)
    r, c = cell(0.6, 0.1)
    assert group(f, r, c + 1, 2) == HIGH                            # in-flow from a direct neighbour
    assert group(f, r, c + 2, 2) == MEDIUM                          # from a second-degree neighbour
    assert group(f, r, c, 2) == LOW and f.outflow[r, c] == 10       # its points move out
    assert group(f, r, c - 1, 2) == LOW and group(f, r + 1, c + 1, 2) == LOW
    # a heading of 30 degrees: first ring diagonal (1, 1), second ring (2, 1) in (x, y) cells
    pts, vel = cloud(0.6, 0.1, 10, (np.cos(0.52), np.sin(0.52)))
    f = extract_features(pts, vel, None, GRID, TH)
    assert group(f, r + 1, c + 1, 2) == HIGH and group(f, r + 1, c + 2, 2) == MEDIUM
    assert group(f, r + 2, c + 2, 2) == LOW


def test_standing_pedestrian_is_dense_but_slow_and_not_flowing():
    pts, vel = cloud(1.0, 0.0, 50, (0.05, -0.03))                   # flow noise below moving_mps
    f = extract_features(pts, vel, None, GRID, TH)
    r, c = cell(1.0, 0.0)
    assert group(f, r, c, 0) == HIGH and group(f, r, c, 1) == LOW
    assert f.inflow_first.sum() == 0 and f.inflow_second.sum() == 0 and np.all(f.features[..., 8] == 1)


def test_robot_at_the_grid_border_nothing_wraps_and_points_just_outside_flow_in():
    # robot on the rear edge (x_min = 0): a point just behind it moving ahead flows into the border column
    pts, vel = cloud(-0.1, 0.1, 10, (1.0, 0.0))
    f = extract_features(pts, vel, None, GRID, TH)
    r, _ = cell(0.0, 0.1)
    assert f.density.sum() == 0 and group(f, r, 0, 2) == HIGH and group(f, r, 1, 2) == MEDIUM
    # a point in the far column moving further out must not reappear on the other side
    pts, vel = cloud(1.9, 0.1, 10, (1.0, 0.0))
    f = extract_features(pts, vel, None, GRID, TH)
    assert f.inflow_first.sum() == 0 and f.inflow_second.sum() == 0
    pts, vel = cloud(0.1, 0.9, 10, (-1.0, 1.0))                    # corner, moving out diagonally
    f = extract_features(pts, vel, None, GRID, TH)
    assert f.inflow_first.sum() == 0 and f.inflow_second.sum() == 0


def test_goal_distance_bins_by_thirds_of_the_grid_and_without_goal_is_medium():
    f = extract_features(np.zeros((0, 3)), np.zeros((0, 3)), (10.0, 0.0), GRID, TH)
    goal = f.features[..., 9:12].argmax(axis=2)
    assert np.all(goal[:, -1] == LOW) and np.all(goal[:, 0] == HIGH)
    f_in = extract_features(np.zeros((0, 3)), np.zeros((0, 3)), (1.1, 0.1), GRID, TH)
    assert group(f_in, *cell(1.1, 0.1), 3) == LOW and group(f_in, 0, 0, 3) == HIGH
    for missing in (None, (np.nan, 0.0)):
        f0 = extract_features(np.zeros((0, 3)), np.zeros((0, 3)), missing, GRID, TH)
        assert np.all(f0.features[..., 10] == 1) and np.all(np.isnan(f0.goal_distance_m))
    assert goal_in_robot_frame((1.0, 1.0), (1.0, 0.0, np.pi / 2)) == pytest.approx((1.0, 0.0))


def test_non_finite_and_out_of_height_points_are_ignored_and_mismatch_is_an_error():
    pts, vel = cloud(1.0, 0.0, 30, (1.0, 0.0))
    pts[:10, 0] = np.nan
    vel[10:15, 1] = np.inf
    pts[15:20, 2] = 0.02                                              # floor
    f = extract_features(pts, vel, None, GRID, TH, min_height_m=0.15)
    assert f.density.sum() == 10 and np.all(np.isfinite(f.velocity_mps))
    with pytest.raises(ValueError, match="pair up"):
        extract_features(np.zeros((3, 3)), np.zeros((2, 3)), None, GRID, TH)
    with pytest.raises(ValueError, match="low <= high"):
        Thresholds(density_points=(10, 5))


def test_grid_geometry_matches_the_message_convention():
    g = GridSpec()
    assert g.shape == (24, 24) and g.origin == (-0.375, -2.875)
    x, y = g.centres()
    assert x[0, 1] - x[0, 0] == pytest.approx(0.25) and y[1, 0] - y[0, 0] == pytest.approx(0.25)


def test_conflict_marks_where_people_will_be_when_the_robot_gets_there():
    from nodes.nav.features import conflict_cells

    grid = GridSpec(0.0, 6.0, -3.0, 3.0, 0.25)
    body = np.array([[0.0, 0.0, 1.0]] * 5)
    # a person standing 3 m ahead blocks their cell at any time
    still = conflict_cells(body + [3.1, 0.1, 0.0], np.zeros((5, 3)), grid)
    assert np.argwhere(still).tolist() == [[12, 12]]
    # a person 2 m ahead walking away at the robot's speed: the robot never catches up, nothing marked
    # (the density feature marks their cell now: real walkers follow such people through it)
    away = conflict_cells(body + [2.1, 0.1, 0.0], np.tile([1.0, 0.0, 0.0], (5, 1)), grid)
    assert not away.any()
    # a person crossing from the right at 1 m/s, 3 m ahead: marked near the robot's line, not where they are now
    cross = conflict_cells(body + [3.1, -2.9, 0.0], np.tile([0.0, 1.0, 0.0], (5, 1)), grid)
    hit = np.argwhere(cross)
    assert len(hit) and not cross[0, 12]
    y = -3.0 + (hit[:, 0] + 0.5) * 0.25
    assert np.abs(y).min() < 0.5                          # they reach the robot's path about when it does
    # one flow outlier marks nothing; NaNs and an empty cloud are fine
    assert not conflict_cells(np.array([[3.1, 0.1, 1.0]]), np.zeros((1, 3)), grid).any()
    assert not conflict_cells(np.full((3, 3), np.nan), np.zeros((3, 3)), grid).any()
    assert conflict_cells(np.zeros((0, 3)), np.zeros((0, 3)), grid).shape == grid.shape
