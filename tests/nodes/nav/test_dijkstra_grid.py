"""Grid Dijkstra: equal costs to a reference heap Dijkstra, ties, walls, borders, frames, waypoints."""
from __future__ import annotations

import heapq

import numpy as np
import pytest

from nodes.nav.dijkstra import MOVES, GridGraph, cost_to_go, line_cells, path_cost, plan_dijkstra, smooth_path
from nodes.nav.grid_frame import GridFrame, extract_waypoint, inflate, pick_subgoal, plan_on_map, steer, to_robot, to_world


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


def _random_grid(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    if rng.random() < 0.5:
        cost = rng.integers(1, 4, (rows, cols)).astype(float)         # integer costs: many equal-cost ties
    else:
        cost = rng.uniform(0.5, 3.0, (rows, cols))
    cost[rng.random((rows, cols)) < rng.uniform(0.0, 0.4)] = np.inf
    return cost


def test_in_place_search_equals_csgraph_on_the_plain_matrix_ties_included():
    """The in-place 3 x 3 stencil graph must give exactly what csgraph gives on GridGraph.matrix:
    same distances, same predecessors (so the same path among equal-cost ones), both directions."""
    from scipy.sparse.csgraph import dijkstra
    rng = np.random.default_rng(11)
    shapes = [(1, 1), (1, 7), (7, 1), (2, 2), (3, 2)] + [tuple(int(v) for v in rng.integers(1, 22, 2)) for _ in range(40)]
    for rows, cols in shapes:
        graph = GridGraph.of((rows, cols))
        for _ in range(2):                               # the same graph reused with other costs
            cost = _random_grid(rng, rows, cols)
            src = int(rng.integers(0, rows * cols))
            for reverse in (False, True):
                want_d, want_p = dijkstra(graph.matrix(cost, reverse=reverse), indices=src, return_predecessors=True)
                got_d, got_p = graph.search(cost, src, reverse=reverse)
                np.testing.assert_array_equal(got_d, want_d)
                np.testing.assert_array_equal(got_p, want_p)


def test_plan_matches_csgraph_reference_path_and_cost():
    from scipy.sparse.csgraph import dijkstra
    rng = np.random.default_rng(12)
    for _ in range(30):
        rows, cols = (int(v) for v in rng.integers(2, 30, 2))
        cost = _random_grid(rng, rows, cols)
        s, g = (int(rng.integers(rows)), 0), (int(rng.integers(rows)), cols - 1)
        cost[g] = 1.0
        res = plan_dijkstra(cost, s, g)
        graph = GridGraph.of(cost.shape)
        dist, pred = dijkstra(graph.matrix(cost), indices=s[0] * cols + s[1], return_predecessors=True)
        want = dist[g[0] * cols + g[1]]
        assert res.reachable == np.isfinite(want)
        if res.reachable:
            assert abs(res.cost - want) <= 1e-9 * want
            chain = [g[0] * cols + g[1]]
            while chain[-1] != s[0] * cols + s[1]:
                chain.append(int(pred[chain[-1]]))
            np.testing.assert_array_equal(res.cells, np.stack(np.divmod(chain[::-1], cols), axis=1))


def test_reused_graph_forgets_the_previous_obstacles():
    graph = GridGraph.of((12, 12))
    walled = np.ones((12, 12))
    walled[:, 6] = np.inf
    assert not plan_dijkstra(walled, (5, 0), (5, 11), graph=graph).reachable
    corners = np.ones((12, 12))
    corners[4, 6] = corners[6, 6] = np.inf               # cut the diagonals into and out of (5, 6)
    for cost, want in ((np.ones((12, 12)), 11.0), (corners, 11.0), (walled, np.inf), (np.ones((12, 12)), 11.0)):
        fresh = plan_dijkstra(cost, (5, 0), (5, 11))
        reused = plan_dijkstra(cost, (5, 0), (5, 11), graph=graph)
        assert reused.cost == fresh.cost == pytest.approx(want)
        np.testing.assert_array_equal(reused.cells, fresh.cells)
    value, _ = cost_to_go(np.ones((12, 12)), (0, 0), graph=graph)
    assert value[11, 11] == pytest.approx(11 * np.sqrt(2))


def test_threads_sharing_one_graph_get_their_own_answers():
    from concurrent.futures import ThreadPoolExecutor
    rng = np.random.default_rng(13)
    graph = GridGraph.of((40, 40))
    grids = [_random_grid(rng, 40, 40) for _ in range(8)]
    for cost in grids:
        cost[20, 0] = cost[20, 39] = 1.0
    want = [plan_dijkstra(cost, (20, 0), (20, 39)) for cost in grids]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda k: plan_dijkstra(grids[k % 8], (20, 0), (20, 39), graph=graph), range(64)))
    for k, res in enumerate(got):
        assert res.cost == want[k % 8].cost or (np.isinf(res.cost) and np.isinf(want[k % 8].cost))
        np.testing.assert_array_equal(res.cells, want[k % 8].cells)
