"""Grid Dijkstra: equal costs to a reference heap Dijkstra, ties, walls, borders, frames, waypoints."""
from __future__ import annotations

import heapq

import numpy as np
import pytest

from nodes.nav.dijkstra import (MOVES, GridFrame, GridGraph, cost_to_go, extract_waypoint, inflate, line_cells,
                                path_cost, pick_subgoal, plan_dijkstra, plan_on_map, smooth_path, steer, to_robot,
                                to_world)


def reference_cost(cost: np.ndarray, s: tuple[int, int], g: tuple[int, int]) -> float:
    """Textbook heap Dijkstra with the same cost model (entering cost x step length, no corner cutting)."""
    rows, cols = cost.shape
    dist = {s: 0.0}
    heap = [(0.0, s)]
    done = set()
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        done.add(u)
        if u == g:
            return d
        for dr, dc in MOVES:
            v = (u[0] + dr, u[1] + dc)
            if not (0 <= v[0] < rows and 0 <= v[1] < cols):
                continue
            if dr and dc and (np.isinf(cost[u[0], v[1]]) or np.isinf(cost[v[0], u[1]])):
                continue
            nd = d + np.hypot(dr, dc) * cost[v]
            if nd < dist.get(v, np.inf):
                dist[v] = nd
                heapq.heappush(heap, (nd, v))
    return np.inf


def test_costs_equal_reference_on_random_grids():
    rng = np.random.default_rng(3)
    for _ in range(25):
        rows, cols = rng.integers(1, 25, 2)
        cost = rng.uniform(0.5, 3.0, (rows, cols))
        cost[rng.random((rows, cols)) < 0.2] = np.inf
        s = tuple(int(v) for v in rng.integers(0, [rows, cols]))
        g = tuple(int(v) for v in rng.integers(0, [rows, cols]))
        res = plan_dijkstra(cost, s, g)
        ref = reference_cost(cost, s, g) if np.isfinite(cost[g]) or s == g else np.inf
        if s == g:
            assert res.cost == 0.0 and res.reachable
            continue
        assert res.reachable == np.isfinite(ref)
        if res.reachable:
            assert res.cost == pytest.approx(ref, rel=1e-9)
            assert path_cost(cost, res.cells) == pytest.approx(res.cost, rel=1e-9)
            assert tuple(res.cells[0]) == s and tuple(res.cells[-1]) == g


def test_uniform_cost_ties_are_deterministic_and_optimal():
    cost = np.full((30, 40), 2.0)                # every cell has the same features
    a = plan_dijkstra(cost, (3, 2), (25, 35))
    b = plan_dijkstra(cost, (3, 2), (25, 35), graph=GridGraph.of(cost.shape))
    np.testing.assert_array_equal(a.cells, b.cells)
    octile = 2.0 * (22 * np.sqrt(2) + (33 - 22))
    assert a.cost == pytest.approx(octile)


def test_goal_inside_obstacle_and_walled_off_goal_give_clear_answers():
    cost = np.ones((20, 20))
    cost[10, 10] = np.inf
    res = plan_dijkstra(cost, (0, 0), (10, 10))
    assert not res.reachable and "obstacle" in res.reason and len(res.cells) == 0
    cost = np.ones((20, 20))
    cost[5:10, 5] = cost[5:10, 9] = cost[5, 5:10] = cost[9, 5:10] = np.inf     # a closed box around (7, 7)
    res = plan_dijkstra(cost, (0, 0), (7, 7))
    assert not res.reachable and "not reachable" in res.reason and np.isinf(res.cost)


def test_no_corner_cutting_between_two_obstacles():
    cost = np.ones((3, 3))
    cost[0, 1] = cost[1, 0] = np.inf
    res = plan_dijkstra(cost, (0, 0), (1, 1))
    assert not res.reachable       # the only way out is the diagonal squeezed between two blocked cells


def test_standing_pedestrian_on_the_path_is_bypassed():
    cost = np.ones((21, 41))
    rr, cc = np.mgrid[:21, :41]
    cost += 20.0 * (np.hypot(rr - 10, cc - 20) < 3)     # a person standing on the straight line
    res = plan_dijkstra(cost, (10, 0), (10, 40))
    assert res.reachable
    assert np.min(np.hypot(res.cells[:, 0] - 10, res.cells[:, 1] - 20)) >= 3
    assert res.cost < path_cost(cost, line_cells((10, 0), (10, 40)))


def test_robot_at_grid_border_and_start_on_obstacle():
    cost = np.ones((10, 10))
    cost[0, 0] = np.inf                          # the robot's own cell may look blocked
    res = plan_dijkstra(cost, (0, 0), (9, 9))
    assert res.reachable and tuple(res.cells[0]) == (0, 0)
    res = plan_dijkstra(np.ones((1, 7)), (0, 6), (0, 0))      # a one-row grid, start on the edge
    assert res.reachable and len(res.cells) == 7


def test_bad_inputs_raise_helpful_errors():
    with pytest.raises(ValueError, match="NaN"):
        plan_dijkstra(np.array([[1.0, np.nan]]), (0, 0), (0, 1))
    with pytest.raises(ValueError, match="strictly positive"):
        plan_dijkstra(np.array([[1.0, 0.0]]), (0, 0), (0, 1))
    with pytest.raises(ValueError, match="outside"):
        plan_dijkstra(np.ones((4, 4)), (0, 0), (4, 0))
    with pytest.raises(ValueError, match="non-empty"):
        plan_dijkstra(np.ones((0, 0)), (0, 0), (0, 0))


def test_cost_to_go_matches_forward_plans():
    rng = np.random.default_rng(5)
    cost = rng.uniform(1, 4, (12, 15))
    cost[rng.random(cost.shape) < 0.15] = np.inf
    cost[6, 7] = 1.0
    value, succ = cost_to_go(cost, (6, 7))
    assert value[6, 7] == 0 and succ[6, 7] == 6 * 15 + 7
    for s in [(0, 0), (11, 14), (3, 9)]:
        fwd = plan_dijkstra(cost, s, (6, 7))
        assert value[s] == pytest.approx(fwd.cost) or (np.isinf(value[s]) and not fwd.reachable)
        if fwd.reachable:        # following successors reaches the goal at the same cost
            cells, cur = [s], s[0] * 15 + s[1]
            while cur != 6 * 15 + 7:
                cur = int(succ.flat[cur])
                cells.append(divmod(cur, 15))
            assert path_cost(cost, np.array(cells)) == pytest.approx(fwd.cost)


def test_frames_waypoints_and_subgoals():
    frame = GridFrame((16, 20), 0.25, origin_x_m=0.5, origin_y_m=-2.0)
    cells = np.array([[0, 0], [8, 4], [15, 19]])
    np.testing.assert_array_equal(frame.cell_of(frame.xy_of(cells)), cells)
    assert frame.inside(np.array([[16, 0], [0, -1], [3, 3]])).tolist() == [False, False, True]
    np.testing.assert_array_equal(frame.clamp(frame.cell_of(np.zeros((1, 2)))), [[8, 0]])   # robot behind the grid
    pose = (2.0, -1.0, 0.7)
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    np.testing.assert_allclose(to_robot(pose, to_world(pose, pts)), pts)
    path = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(extract_waypoint(path, 2.0), [1.0, 1.0])
    np.testing.assert_allclose(extract_waypoint(path, 10.0), [1.0, 2.0])
    line = np.stack([np.linspace(0, 10, 41), np.zeros(41)], axis=1)
    assert line[pick_subgoal(line, np.array([2.0, 0.3]), 4.0), 0] == pytest.approx(5.75, abs=0.25)
    assert pick_subgoal(line, np.array([9.0, 0.0]), 4.0) == 40


def test_global_plan_on_map_moves_goal_out_of_obstacles():
    occ = np.zeros((40, 60), bool)
    occ[10:30, 30] = True
    frame = GridFrame(occ.shape, 0.1)
    grown = inflate(occ, 3.0)
    assert grown.sum() > occ.sum() and grown[20, 33] and not grown[20, 34]
    path, res = plan_on_map(grown, frame, (1.0, 2.0), (5.0, 2.0))
    assert res.reachable and np.allclose(path[-1], (5.0, 2.0))
    assert not grown[tuple(frame.cell_of(path[1:-1]).T)].any()
    path, res = plan_on_map(grown, frame, (1.0, 2.0), (3.0, 2.0))       # goal on the wall
    assert res.reachable and not grown[tuple(frame.cell_of(path[-2:-1]).T)].any()


def test_steer_turns_toward_target_and_stops_on_goal():
    v, w = steer((0, 0, 0), np.array([2.0, 2.0]), v_max_mps=1.0, w_max_radps=1.0)
    assert w > 0 and 0 < v < 1.0
    v, w = steer((0, 0, 0), np.array([-2.0, 0.1]), v_max_mps=1.0, w_max_radps=1.0)
    assert v == 0 and w > 0                                    # behind: turn in place
    v, _ = steer((0, 0, 0), np.array([0.1, 0.0]), v_max_mps=1.0, w_max_radps=1.0, stop_at_m=0.3)
    assert v == 0


def test_string_pulling_keeps_cost_and_removes_staircases():
    cost = np.ones((20, 30))
    res = plan_dijkstra(cost, (2, 0), (15, 29))
    np.testing.assert_array_equal(smooth_path(cost, res.cells), [[2, 0], [15, 29]])
    rr, cc = np.mgrid[:20, :30]
    cost = 1.0 + 50.0 * (np.hypot(rr - 10, cc - 15) < 4)
    res = plan_dijkstra(cost, (10, 0), (10, 29))
    corners = smooth_path(cost, res.cells)
    assert 2 < len(corners) < len(res.cells)
    pulled = np.vstack([line_cells(tuple(a), tuple(b))[:-1] for a, b in zip(corners[:-1], corners[1:])] + [corners[-1:]])
    assert path_cost(cost, pulled) <= res.cost * 1.02 + 1e-9
