"""IRL: recovers a known cost from optimal demos, exact gradients, hard cases stay finite, weights files."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from nodes.nav.dijkstra import plan_dijkstra
from nodes.nav.irl import (STEP_COST, CostWeights, Demo, action_agreement, birl_objective, cell_costs, check_demo,
                           cost_to_exits,
                           expected_value_difference, learn, maxent_objective)

# the paper's table (Sec. 4.2.3) with each one-hot group shifted so its cheapest bin is 0
TRUE_W = np.array([2.2, 0.7, 0.0, 0.0, 0.0, 0.0, 4.0, 3.5, 0.0, 0.7, 0.3, 0.0])


def _bins(x: np.ndarray, hi: float, mid: float) -> np.ndarray:
    return np.eye(3)[np.where(x > hi, 0, np.where(x > mid, 1, 2))]


def synthetic_scene(rng: np.random.Generator, rows: int = 12, cols: int = 12) -> Demo:
    """Density / speed / direction / goal-distance bins; the path is optimal under TRUE_W."""
    def field(sigma: float) -> np.ndarray:
        f = gaussian_filter(rng.random((rows, cols)), sigma)
        return (f - f.min()) / (np.ptp(f) + 1e-12)
    goal = (int(rng.integers(0, rows)), cols - 1)
    rr, cc = np.mgrid[:rows, :cols]
    dist = np.hypot(rr - goal[0], cc - goal[1])
    feats = np.concatenate([_bins(field(1.5), 0.7, 0.45), np.eye(3)[rng.integers(0, 3, (rows, cols))],
                            _bins(field(1.0), 0.75, 0.55), _bins(dist / dist.max(), 0.66, 0.33)], axis=2)
    start = (int(rng.integers(0, rows)), 0)
    path = plan_dijkstra(cell_costs(feats, TRUE_W), start, goal).cells
    return Demo(feats.astype(np.uint8), path)


@pytest.fixture(scope="module")
def scenes() -> tuple[list[Demo], list[Demo]]:
    rng = np.random.default_rng(0)
    return [synthetic_scene(rng) for _ in range(14)], [synthetic_scene(rng) for _ in range(14)]


@pytest.fixture(scope="module")
def learnt(scenes) -> dict:
    return {m: learn(scenes[0], method=m, prior="laplace", lam=0.5) for m in ("birl", "maxent")}


@pytest.mark.parametrize("method", ["birl", "maxent"])
def test_learns_a_cost_that_plans_like_the_expert_on_held_out_scenes(scenes, learnt, method):
    _, test = scenes
    res = learnt[method]
    assert res.weights.shape == (12,) and np.all(res.weights >= 0) and res.step_cost >= STEP_COST
    evd = expected_value_difference(test, res.weights, TRUE_W, step_cost=res.step_cost)
    evd_shortest = expected_value_difference(test, np.zeros(12), TRUE_W)
    assert evd < 0.25 * evd_shortest
    assert action_agreement(test, res.weights, step_cost=res.step_cost) > action_agreement(test, np.zeros(12))
    # density high > low and direction high > low, as in the paper's table
    assert res.weights[0] > res.weights[2] and res.weights[6] > res.weights[8]


@pytest.mark.parametrize("method", ["birl", "maxent"])
def test_laplace_prior_finds_the_speed_features_useless(learnt, method):
    w = learnt[method].weights
    assert w[3:6].max() < 0.15 * w.max()


def test_gradients_match_finite_differences(scenes):
    demos = [check_demo(d) for d in scenes[0][:3]]
    rng = np.random.default_rng(1)
    w = rng.uniform(0.2, 2.0, 12)
    for fun in (lambda x: maxent_objective(x, demos, prior="gaussian", lam=0.3),
                lambda x: birl_objective(x, demos, prior="laplace", lam=0.3)):
        f0, g = fun(w)
        for k in range(0, 12, 3):
            e = np.zeros(12)
            e[k] = 1e-6
            num = (fun(w + e)[0] - fun(w - e)[0]) / 2e-6
            assert num == pytest.approx(g[k], rel=1e-3, abs=1e-4)


def test_single_action_demos_and_constant_feature_columns_stay_finite():
    rng = np.random.default_rng(2)
    demos = []
    for _ in range(5):      # every demonstration is the same single move straight ahead
        f = rng.integers(0, 2, (6, 6, 4)).astype(float)
        f[..., 2] = 1.0     # a column that never varies (always on)
        f[..., 3] = 0.0     # a column that never varies (always off)
        demos.append(Demo(f, np.array([[3, 2], [3, 3]])))
    for method in ("birl", "maxent"):
        res = learn(demos, method=method)
        assert np.all(np.isfinite(res.weights)) and np.isfinite(res.step_cost) and np.all(res.weights <= 50)
        assert res.weights[3] == 0.0


def test_demo_validation_and_degenerate_sets():
    f = np.zeros((5, 5, 2))
    assert len(check_demo(Demo(f, np.array([[1, 1], [1, 1], [1, 2]]))).path) == 2     # standing still is dropped
    with pytest.raises(ValueError, match="8-neighbours"):
        check_demo(Demo(f, np.array([[0, 0], [0, 2]])))
    with pytest.raises(ValueError, match="leaves"):
        check_demo(Demo(f, np.array([[0, 0], [0, 5]])))
    with pytest.raises(ValueError, match="no demonstration has a move"):
        learn([Demo(f, np.array([[2, 2]]))])
    with pytest.raises(ValueError, match="step_cost"):
        learn([Demo(f, np.array([[2, 2], [2, 3]]))], step_cost=0.0)
    with pytest.raises(ValueError, match="1.77"):
        learn([Demo(f, np.array([[2, 2], [2, 3]]))], method="maxent", step_cost=1.0)


def test_costs_are_strictly_positive_and_blocked_cells_infinite():
    f = np.random.default_rng(4).integers(0, 2, (4, 5, 3))
    blocked = np.zeros((4, 5), bool)
    blocked[1, 1] = True
    c = cell_costs(f, np.array([0.0, 1.0, 2.0]), step_cost=0.5, blocked=blocked)
    assert np.isinf(c[1, 1]) and np.all(c[~blocked] >= 0.5)


def test_weights_json_roundtrip_and_name_mapping():
    w = CostWeights(("density_high", "density_low", "speed_high"), np.array([2.0, 0.0, 0.5]), 3.0, {"method": "birl"})
    back = CostWeights.from_json(w.to_json())
    assert back.names == w.names and back.step_cost == 3.0 and back.extra == {"method": "birl"}
    np.testing.assert_allclose(back.vector_for(["speed_high", "density_high"], 2), [0.5, 2.0])
    with pytest.raises(ValueError, match="no weight"):
        back.vector_for(["direction_high"], 1)
    with pytest.raises(ValueError, match="strictly positive"):
        CostWeights(("a",), np.array([-1.0]))


# -- demos that leave the grid by a rim (the local planner's problem) -------------------------------

def exit_scene(rng: np.random.Generator, rows: int = 12, cols: int = 12) -> Demo:
    """A person blob ahead; exits on the last column priced by the distance left to a goal beyond it.
    The path is the TRUE_W-optimal way out (walk + exit), found by brute force over exits."""
    feats = synthetic_scene(rng, rows, cols).features
    goal = np.array([rows / 2 + rng.uniform(-2, 2), cols + 6.0])
    rr = np.arange(rows)
    exits = np.full((rows, cols), np.inf)
    exits[:, -1] = np.hypot(rr - goal[0], cols - 1 - goal[1])
    start = (int(rng.integers(0, rows)), 0)
    cost = cell_costs(feats, TRUE_W)
    best = min((plan_dijkstra(cost, start, (r, cols - 1)) for r in rr),
               key=lambda p: p.cost + exits[p.cells[-1][0], -1] * STEP_COST)
    return Demo(feats, best.cells, exit_cells=exits)


def test_cost_to_exits_is_the_best_walk_plus_exit():
    rng = np.random.default_rng(7)
    cost = rng.uniform(1.0, 5.0, (7, 9))
    cost[2, 3:6] = np.inf
    exits = np.full(cost.shape, np.inf)
    exits[:, -1] = rng.uniform(0.0, 10.0, 7)
    exits[0, 0] = 0.5
    value, succ = cost_to_exits(cost, exits)
    for cell in [(3, 0), (6, 4), (2, 8), (0, 0)]:
        brute = min(plan_dijkstra(cost, cell, tuple(t)).cost + exits[tuple(t)] for t in np.argwhere(np.isfinite(exits)))
        assert value[cell] == pytest.approx(brute, rel=1e-9, abs=1e-9)
    assert succ[0] == cost.size                                # (0, 0) leaves right where it is
    with pytest.raises(ValueError, match="no exit"):
        cost_to_exits(cost, np.full(cost.shape, np.inf))


@pytest.mark.parametrize("method", ["birl", "maxent"])
def test_learns_from_demos_that_leave_by_the_rim(method):
    rng = np.random.default_rng(3)
    train, test = [exit_scene(rng) for _ in range(12)], [exit_scene(rng) for _ in range(12)]
    res = learn(train, method=method, prior="laplace", lam=0.5)
    evd = expected_value_difference(test, res.weights, TRUE_W, step_cost=res.step_cost)
    evd_shortest = expected_value_difference(test, np.zeros(12), TRUE_W)
    assert evd < 0.5 * evd_shortest
    assert res.weights[0] > res.weights[2] and res.weights[6] > res.weights[8]
    agreement = action_agreement(test, res.weights, step_cost=res.step_cost)
    assert agreement > action_agreement(test, np.zeros(12))


def test_exit_gradients_match_finite_differences():
    rng = np.random.default_rng(5)
    demos = [check_demo(exit_scene(rng)) for _ in range(3)]
    ones = [Demo(np.concatenate([d.features, np.ones(d.features.shape[:2] + (1,))], axis=2), d.path,
                 exit_cells=d.exit_cells) for d in demos]          # + the learnt step-cost column, as learn() does
    w = rng.uniform(0.2, 2.0, 13)
    for fun in (lambda x: maxent_objective(x, ones, prior="gaussian", lam=0.3, step_col=12),
                lambda x: birl_objective(x, ones, prior="laplace", lam=0.3, step_col=12)):
        _, g = fun(w)
        for k in (0, 6, 9, 12):
            e = np.zeros(13)
            e[k] = 1e-6
            num = (fun(w + e)[0] - fun(w - e)[0]) / 2e-6
            assert num == pytest.approx(g[k], rel=1e-3, abs=1e-4)


def test_exit_demo_validation():
    f = np.zeros((5, 5, 2))
    exits = np.full((5, 5), np.inf)
    exits[:, 4] = 3.0
    check_demo(Demo(f, np.array([[2, 2], [2, 3], [2, 4]]), exit_cells=exits))
    with pytest.raises(ValueError, match="end on one"):
        check_demo(Demo(f, np.array([[2, 2], [2, 3]]), exit_cells=exits))
    with pytest.raises(ValueError, match="exit_cells"):
        check_demo(Demo(f, np.array([[2, 3], [2, 4]]), exit_cells=np.where(np.isinf(exits), np.nan, exits)))
