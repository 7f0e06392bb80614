"""ReachCar's training-signal options: the paper's reward by default, potential-based shaping (Ng et al.
1999) that telescopes, a step cost that moves every return by the same amount."""
import numpy as np
import pytest

from sim.car_env import ReachCar, reward


def _episode(sim: ReachCar, seed: int, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Rewards and distances (after each step) of one seeded episode, and the starting distance."""
    sim.reset([seed])
    d0 = float(np.hypot(*(sim.target[0] - sim.pose[0, :2])))
    rews, dists = [], []
    for a in actions:
        b = sim.step(a[None])
        rews.append(b.rewards[0])
        dists.append(b.metrics[0, 0])
    return np.array(rews), np.array(dists), d0


ACTS = np.random.default_rng(3).uniform(-1, 1, (100, 2))


def test_default_is_the_papers_reward():
    rews, dists, _ = _episode(ReachCar(1), 7, ACTS)
    assert np.allclose(rews, reward(dists), rtol=0, atol=1e-12)


@pytest.mark.parametrize("gamma", [1.0, 0.99])
def test_shaping_telescopes_to_the_potential_difference(gamma):
    paper, _, _ = _episode(ReachCar(1), 7, ACTS)
    shaped, dists, d0 = _episode(ReachCar(1, shaping=2.5, shaping_gamma=gamma), 7, ACTS)
    f = shaped - paper
    # sum_t gamma^t F_t = gamma^T Phi(s_T) - Phi(s_0), Phi = -2.5 distance
    assert np.sum(gamma ** np.arange(100) * f) == pytest.approx(2.5 * (d0 - gamma**100 * dists[-1]), abs=1e-9)
    closer = np.diff(np.concatenate([[d0], dists])) < 0
    if gamma == 1.0:
        assert np.all((f > 0) == closer)          # approaching pays, leaving costs
    assert closer.any() and (~closer).any()


def test_step_cost_shifts_every_return_alike():
    other = np.random.default_rng(4).uniform(-1, 1, (100, 2))
    paper = [_episode(ReachCar(1), 7, acts)[0] for acts in (ACTS, other)]
    free = [_episode(ReachCar(1, step_cost=0.0), 7, acts)[0] for acts in (ACTS, other)]
    assert np.allclose(free[0], paper[0] + 1.0, rtol=0, atol=1e-12)
    # every episode lasts 100 steps: the two action sequences' returns differ by the same amount
    assert free[0].sum() - free[1].sum() == pytest.approx(paper[0].sum() - paper[1].sum(), abs=1e-9)
    assert paper[0].sum() < -50 < free[0].sum()     # the paper's returns are all negative


def test_bad_shaping_is_refused():
    with pytest.raises(ValueError, match="shaping >= 0"):
        ReachCar(1, shaping=-1.0)
    with pytest.raises(ValueError, match="shaping_gamma"):
        ReachCar(1, shaping=1.0, shaping_gamma=0.0)
    with pytest.raises(ValueError, match="step_cost must be finite"):
        ReachCar(1, step_cost=float("nan"))
