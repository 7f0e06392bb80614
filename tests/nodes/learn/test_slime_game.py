"""The numpy SlimeVolley replica against the original slimevolleygym, step for step."""
import warnings

import numpy as np
import pytest

from nodes.learn import slime_game as sg

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from slimevolleygym import slimevolley as sv


class ScriptedServes:
    """Stands in for the original Game's ``np_random``: hands out given serve velocities."""

    def __init__(self, values):
        self.values = list(values)
        self.used = 0

    def uniform(self, low, high):
        v = self.values[self.used]
        self.used += 1
        assert low <= v <= high
        return v


def original_state(game):
    b, left, right = game.ball, game.agent_left, game.agent_right
    return np.array([b.x, b.y, b.vx, b.vy, b.prev_x, b.prev_y, left.x, left.y, left.vx, left.vy,
                     right.x, right.y, right.vx, right.vy, left.life, right.life, game.delayScreen.life], float)


def replica_state(games, g):
    return np.array([games.bx[g], games.by[g], games.bvx[g], games.bvy[g], games.bpx[g], games.bpy[g],
                     games.x[0, g], games.y[0, g], games.vx[0, g], games.vy[0, g],
                     games.x[1, g], games.y[1, g], games.vx[1, g], games.vy[1, g],
                     games.life[0, g], games.life[1, g], games.delay[g]], float)


@pytest.mark.parametrize("seed", [0, 1])
def test_replica_follows_the_original_exactly(seed, monkeypatch):
    n_games, n_steps = 6, 1500
    rng = np.random.default_rng(seed)
    serves = [[v for _ in range(120) for v in (rng.uniform(-20, 20), rng.uniform(10, 25))] for _ in range(n_games)]
    originals = [sv.Game(np_random=ScriptedServes(s)) for s in serves]
    used = np.full(n_games, 2)
    games = sg.new_games(np.array([s[0] for s in serves]), np.array([s[1] for s in serves]))
    bounces = []
    bounce = sv.Particle.bounce
    monkeypatch.setattr(sv.Particle, "bounce", lambda self, p: (bounces.append(p.r), bounce(self, p)))
    press = rng.uniform(0.1, 0.9, size=(n_games, 1))     # from idle slimes to jumpy ones
    points = 0
    for t in range(n_steps):
        a_left = (rng.random((n_games, 3)) < press).astype(int)
        a_right = (rng.random((n_games, 3)) < press).astype(int)
        expected = []
        for g, game in enumerate(originals):
            game.agent_left.setAction(a_left[g])
            game.agent_right.setAction(a_right[g])
            expected.append(game.step())
        reward = sg.step_games(games, a_left, a_right)
        assert reward.tolist() == expected, f"step {t}"
        scored = np.flatnonzero(reward)
        if scored.size:
            sg.serve(games, reward != 0, np.array([serves[g][used[g]] for g in scored]),
                     np.array([serves[g][used[g] + 1] for g in scored]))
            used[scored] += 2
            points += scored.size
        obs_right, obs_left = sg.observe(games)
        for g, game in enumerate(originals):
            np.testing.assert_array_equal(replica_state(games, g), original_state(game), err_msg=f"step {t} game {g}")
            np.testing.assert_array_equal(obs_right[g], game.agent_right.getObservation())
            np.testing.assert_array_equal(obs_left[g], game.agent_left.getObservation())
    # the run exercised what can go wrong: points, and bounces off both slimes and the fence stub
    assert points > 50
    assert bounces.count(1.5) > 20 and bounces.count(0.5) > 0


def test_baseline_batch_matches_baseline_policy():
    rng = np.random.default_rng(2)
    n = 5
    originals = [sv.BaselinePolicy() for _ in range(n)]
    batch = sg.BaselineBatch(n)
    flips = 0
    for _ in range(400):
        obs = rng.normal(scale=0.8, size=(n, 12))
        got = batch(obs)
        want = np.array([p.predict(o) for p, o in zip(originals, obs)])
        np.testing.assert_array_equal(got, want)
        np.testing.assert_allclose(batch.out, [p.outputState for p in originals], rtol=0, atol=1e-12)
        flips += got.any()
    assert flips > 50


def test_baseline_batch_reset_and_subset():
    batch = sg.BaselineBatch(3)
    obs = np.ones((3, 12))
    batch(obs)
    batch.reset(np.array([False, True, False]))
    assert np.all(batch.out[1] == 0) and np.any(batch.out[0] != 0)
    before = batch.out.copy()
    batch(obs[:1], np.array([2]))
    np.testing.assert_array_equal(batch.out[:2], before[:2])
    with pytest.raises(ValueError, match="recurrent states"):
        batch(np.ones((2, 12)))


def test_take_keeps_games_in_order():
    games = sg.new_games(np.array([1.0, 2.0, 3.0]), np.array([11.0, 12.0, 13.0]))
    sub = games.take(np.array([2, 0]))
    assert sub.g == 2 and sub.bvx.tolist() == [3.0, 1.0] and sub.rel.shape == (2, 12, 2)
    sub.bvx[0] = 99.0
    assert games.bvx[2] == 3.0
