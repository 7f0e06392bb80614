"""Space-time MaxEnt IRL: exact partition function, learning a same-time proximity price, errors."""
import itertools

import numpy as np
import pytest

from nodes.nav.irl_spacetime import (ACTIONS, WAIT, SpaceTimeDemo, demo_from_track, demo_nll, evaluate,
                                     feature_counts, learn_spacetime, near_features, project_cells, sample_path,
                                     soft_policy)
from sim.pedestrian_data import Tracks


def _brute_force(features, start, goal, theta):
    """log sum over every action sequence that first reaches ``goal`` within K steps of exp(-cost)."""
    steps, rows, cols, _ = features.shape
    total = []
    for seq in itertools.product(range(9), repeat=steps - 1):
        r, c = start
        cost = 0.0
        for k, a in enumerate(seq):
            dr, dc = ACTIONS[a]
            r, c = r + dr, c + dc
            if not (0 <= r < rows and 0 <= c < cols):
                break
            length = np.hypot(dr, dc)
            phi = features[k + 1, r, c] @ theta[2:]
            cost += theta[1] + phi if a == WAIT else length * (theta[0] + phi)
            if (r, c) == goal:
                # count a sequence once: the actions after arrival must be the canonical 'wait' filler
                if all(b == WAIT for b in seq[k + 1:]):
                    total.append(-cost)
                break
    return np.logaddexp.reduce(total)


def test_soft_value_iteration_equals_enumeration_3x3x3():
    rng = np.random.default_rng(0)
    f = rng.uniform(0, 1, (4, 3, 3, 2))
    theta = np.array([0.7, 0.4, 1.3, -0.5])
    demo = SpaceTimeDemo(f, np.array([[0, 0], [1, 1], [2, 2]]))
    _, log_z = soft_policy(demo, theta)
    assert log_z[0, 0, 0] == pytest.approx(_brute_force(f, (0, 0), (2, 2), theta), rel=1e-10)


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    f = rng.uniform(0, 1, (6, 4, 5, 2))
    demo = SpaceTimeDemo(f, np.array([[0, 0], [0, 0], [1, 1], [1, 2], [2, 3], [3, 4]]))
    theta = np.array([1.1, 0.6, 0.8, -0.3])
    nll, grad, log_pi = demo_nll(demo, theta)
    eps = 1e-6
    for j in range(4):
        d = np.zeros(4)
        d[j] = eps
        num = (demo_nll(demo, theta + d)[0] - demo_nll(demo, theta - d)[0]) / (2 * eps)
        assert grad[j] == pytest.approx(num, abs=1e-5)
    per_step = -sum(log_pi[k, a, r, c] for k, (a, (r, c)) in enumerate(zip(demo.actions, demo.path[:-1])))
    assert nll == pytest.approx(per_step, rel=1e-10)


def _crossing_scene(cross_k: int, rows: int = 5, cols: int = 9, steps: int = 15) -> np.ndarray:
    """A walker crossing column 4 top to bottom, at the walker's row 2 at step ``cross_k``; feature:
    the crossing walker within one cell of a cell at that step."""
    others = np.full((steps, 1, 2), np.nan)
    for k in range(steps):
        others[k, 0] = (4.0, 2.0 + (k - cross_k))       # (x = col, y = row), one cell per step
    cr, cc = np.meshgrid(np.arange(rows, dtype=float), np.arange(cols, dtype=float), indexing="ij")
    return near_features(np.stack([cc, cr], axis=-1), others, (1.5,))


def _synthetic(theta_true, n, seed):
    rng = np.random.default_rng(seed)
    demos = []
    for _ in range(n):
        f = _crossing_scene(int(rng.integers(3, 7)))
        demos.append(SpaceTimeDemo(f, sample_path(f, (2, 0), (2, 8), theta_true, rng)))
    return demos


def test_expert_who_waits_for_a_crossing_walker_is_learnt():
    truth = np.array([2.0, 0.5, 3.0])
    demos = _synthetic(truth, 40, seed=2)
    assert sum(int(np.sum(d.actions == WAIT)) for d in demos) > 20        # the experts did wait
    res = learn_spacetime(demos, ("near",))
    assert res.theta[2] > 1.0                                            # same-time proximity priced
    assert res.ratio("near") == pytest.approx(truth[2] / truth[0], rel=0.5)
    assert res.theta[1] < 2 * (np.sqrt(2) - 1) * res.theta[0] * 2         # a wait is cheaper than a side-step detour
    # in the scene where the crosser reaches the walker's row at step 3, the walker (at column 2 by step 2)
    # is told to wait rather than step into the crossing
    f = _crossing_scene(4)
    log_pi, _ = soft_policy(SpaceTimeDemo(f, np.array([[2, 0], [2, 1], [2, 2], [2, 3], [2, 4], [2, 5], [2, 6],
                                                       [2, 7], [2, 8]])), res.theta)
    assert int(np.argmax(log_pi[2, :, 2, 2])) == WAIT
    assert evaluate(demos, res.theta)["nll_per_step"] < evaluate(demos, np.array([res.theta[0], res.theta[1], 0.0]))[
        "nll_per_step"]


def test_indifferent_expert_learns_no_proximity_price():
    demos = _synthetic(np.array([2.0, 0.5, 0.0]), 40, seed=3)
    res = learn_spacetime(demos, ("near",))
    assert abs(res.theta[2]) < 0.5
    emp, exp = feature_counts(demos, np.array([2.0, 0.5, 0.0]))
    assert emp[2] == pytest.approx(exp[2], rel=0.5)          # truth: walkers meet the crosser as often as expected


def test_fixed_ratio_and_single_demo_give_finite_answers():
    demos = _synthetic(np.array([2.0, 0.5, 3.0]), 1, seed=4)
    res = learn_spacetime(demos, ("near",), fixed_ratios={"near": 2.0})
    assert np.all(np.isfinite(res.theta)) and res.theta[2] == pytest.approx(2.0 * res.theta[0])
    with pytest.raises(ValueError, match="not features"):
        learn_spacetime(demos, ("near",), fixed_ratios={"far": 1.0})
    with pytest.raises(ValueError, match="no demonstrations"):
        learn_spacetime([], ("near",))
    with pytest.raises(ValueError, match="names"):
        learn_spacetime(demos, ("near", "far"))


def test_bad_demos_raise_clear_errors():
    f = np.zeros((5, 3, 4, 1))
    with pytest.raises(ValueError, match="jumps more than one cell"):
        SpaceTimeDemo(f, np.array([[0, 0], [0, 2], [0, 3]]))                   # a gap in the track
    with pytest.raises(ValueError, match="first arrival"):
        SpaceTimeDemo(f, np.array([[0, 0], [0, 1], [0, 0], [0, 1]]))
    with pytest.raises(ValueError, match="leaves"):
        SpaceTimeDemo(f, np.array([[0, 0], [-1, 0]]))
    with pytest.raises(ValueError, match="horizon"):
        SpaceTimeDemo(f, np.array([[0, 0], [0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]))
    with pytest.raises(ValueError, match="rows >= 1"):
        SpaceTimeDemo(np.zeros((5, 0, 4, 1)), np.array([[0, 0], [0, 1]]))     # an empty grid
    short = SpaceTimeDemo(np.zeros((3, 1, 4, 1)), np.array([[0, 0], [0, 1], [0, 3]][:2]))
    assert np.isfinite(demo_nll(short, np.array([1.0, 1.0, 0.0]))[0])
    far = SpaceTimeDemo(np.zeros((2, 1, 4, 1)), np.array([[0, 2], [0, 3]]))
    assert np.isfinite(demo_nll(far, np.array([1.0, 1.0, 0.0]))[0])


def test_unreachable_goal_is_a_value_error():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="within the horizon"):
        sample_path(np.zeros((3, 1, 6, 1)), (0, 0), (0, 5), np.array([1.0, 1.0, 0.0]), rng)


def test_projection_and_track_demo():
    cells, clipped = project_cells(np.array([[0, 0], [0, 2], [0, 3], [0, 3]]))
    assert clipped == 2 and cells.tolist() == [[0, 0], [0, 1], [0, 2], [0, 3]]     # lags two steps, catches up
    t = np.arange(13) * 0.25
    walker = np.column_stack([t * 1.0, np.zeros_like(t)])                  # 1 m/s along x, 3 m
    others = np.full((20, 2, 2), np.nan)
    others[:, 0] = (1.5, 0.0)                                              # someone standing on the line
    demo, clipped = demo_from_track(walker, others, radii_m=(0.5, 1.0))
    assert clipped == 0 and demo.features.shape[0] == 20
    on_path = demo.features[np.arange(1, len(demo.path)), demo.path[1:, 0], demo.path[1:, 1]]
    assert on_path[:, 0].sum() >= 2                                        # it walks through the stander
    with pytest.raises(ValueError, match="demonstrates nothing"):
        demo_from_track(np.zeros((5, 2)), others)
    with pytest.raises(ValueError, match="radii"):
        near_features(np.zeros((2, 2, 2)), others, (1.0, 0.5))
    assert not near_features(np.zeros((2, 2, 2)), np.zeros((3, 0, 2)), (0.5,)).any()


def test_spacetime_demos_leave_companions_out():
    from sim.irl_demos import spacetime_demos

    t = np.arange(0, 12.01, 0.4)
    walker = np.column_stack([1.2 * t, np.zeros_like(t)])
    mate = walker + (0.0, 0.7)                                             # walks beside it
    tracks = Tracks("toy", np.array([1, 2]), (t, t), (walker, mate), 0.4, 1.0)
    kept, c_keep = spacetime_demos(tracks, 4, companions="keep", seed=0)
    left, c_left = spacetime_demos(tracks, 4, companions="exclude", seed=0)
    assert c_left["companions_left_out"] > 0 and c_keep["companions_left_out"] == 0
    near = [d.features[..., :2].sum() for d in kept]
    assert min(near) > 0 and all(d.features.sum() == 0 for d in left)
    with pytest.raises(ValueError, match="companions"):
        spacetime_demos(tracks, 4, companions="maybe")


def test_constant_velocity_others_see_a_crossing_that_never_happened():
    from sim.irl_demos import spacetime_demos

    t = np.arange(0, 12.01, 0.4)
    walker = np.column_stack([1.2 * t, np.zeros_like(t)])                 # at x = 6 m at t = 5 s
    t2 = np.arange(0, 5.21, 0.4)
    other = np.column_stack([np.full_like(t2, 6.0), 3.0 - 0.6 * np.minimum(t2, 2.0)])   # heads for the walker, stops
    tracks = Tracks("toy", np.array([1, 2]), (t, t2), (walker, other), 0.4, 1.0)
    kw = {"every_s": 20.0, "radii_m": (0.5, 1.0)}
    recorded, _ = spacetime_demos(tracks, 5, **kw)
    predicted, _ = spacetime_demos(tracks, 5, others="constant_velocity", **kw)
    assert len(recorded) == len(predicted) == 1
    def on_path(d):
        return d.features[np.arange(1, len(d.path)), d.path[1:, 0], d.path[1:, 1]].sum(axis=0)

    assert recorded[0].features.sum() > 0                     # the stopped walker is on the grid ...
    assert on_path(recorded[0]).sum() == 0                      # ... but never near the walker's path
    assert on_path(predicted[0])[0] > 0                         # the prediction puts it on the path
    with pytest.raises(ValueError, match="others"):
        spacetime_demos(tracks, 5, others="guess")


def test_predicted_others_see_only_what_was_observable_at_t0():
    from nodes.nav.predict import OBS_STEPS, PRED_STEPS, STEP_S, BaselinePredictor
    from sim.irl_demos import spacetime_demos

    t = np.arange(0, 12.01, 0.4)
    walker = np.column_stack([1.2 * t, np.zeros_like(t)])                 # at x = 6 m at t = 5 s
    t2 = np.arange(0, 5.21, 0.4)                                           # too short to be a demo itself
    other = np.column_stack([np.full_like(t2, 6.0), 3.0 - 0.6 * np.minimum(t2, 2.0)])  # heads for it, stops
    tracks = Tracks("toy", np.array([1, 2]), (t, t2), (walker, other), 0.4, 1.0)
    seen = []

    class KeepsHeading:
        """Records what it was shown; predicts the other walker keeps heading for the path at 0.6 m/s."""

        def predict(self, hist):
            seen.append(hist.copy())
            return hist[:, -1][:, None] + np.arange(1, PRED_STEPS + 1)[None, :, None] * STEP_S * np.array([0.0, -0.6])

    kw = {"every_s": 20.0, "radii_m": (0.5, 1.0)}
    def on_path(d):
        return d.features[np.arange(1, len(d.path)), d.path[1:, 0], d.path[1:, 1]].sum(axis=0)

    heading, _ = spacetime_demos(tracks, 5, others="predicted", predictor=KeepsHeading(), **kw)
    still, _ = spacetime_demos(tracks, 5, others="predicted", predictor=BaselinePredictor(), **kw)
    recorded, _ = spacetime_demos(tracks, 5, **kw)
    assert len(seen) == 1 and seen[0].shape == (2, OBS_STEPS, 2)
    assert np.isnan(seen[0][:, :-1]).all()                     # t0 = 0: nothing before it, and never the future
    assert np.allclose(seen[0][:, -1], [[0.0, 0.0], [6.0, 3.0]])
    assert on_path(heading[0])[0] > 0                          # the predicted crossing is on the walker's path
    assert on_path(still[0]).sum() == 0 == on_path(recorded[0]).sum()     # seen once: predicted standing
    with pytest.raises(ValueError, match="predictor"):
        spacetime_demos(tracks, 5, others="predicted", **kw)


@pytest.mark.parametrize("scene", ["biwi_eth", "biwi_hotel", "uni_examples", "students003", "crowds_zara03"])
def test_shipped_fold_predictors_never_saw_their_scene(scene):
    from nodes.nav.predict import load_loso

    model = load_loso(scene)
    assert scene in model.meta["held_out"] and scene not in model.meta["trained_on"]
    assert len(model.meta["trained_on"]) == 4
