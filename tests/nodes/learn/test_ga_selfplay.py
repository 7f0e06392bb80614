"""Tournament-selection self-play (Algorithm 3): update rules, seeding, checkpoints, policy files."""
import numpy as np
import pytest

from nodes.learn.ga_selfplay import GAConfig, TournamentGA
from nodes.learn.slime_policy import MlpPolicy, load_policy, param_count, save_policy

TINY = GAConfig(population=8, snapshot_every=4)


def test_tie_adds_noise_to_the_second_only():
    ga = TournamentGA(TINY, seed=0)
    ga.lineage[:] = [3, 1, 0, 0, 0, 0, 0, 0]
    before = ga.population.copy()
    ga.update(0, 1, 0.0)
    changed = np.flatnonzero(np.any(ga.population != before, axis=1))
    assert changed.tolist() == [1]
    step = ga.population[1] - before[1]
    assert 0.05 < step.std() < 0.15                     # sigma 0.1 over 273 parameters
    assert ga.lineage.tolist() == [3, 1, 0, 0, 0, 0, 0, 0]


@pytest.mark.parametrize("score, winner, loser", [(2.0, 0, 1), (-1.0, 1, 0)])
def test_win_clones_the_winner_over_the_loser(score, winner, loser):
    ga = TournamentGA(TINY, seed=1)
    ga.lineage[:] = [5, 2, 0, 0, 0, 0, 0, 0]
    before, streak = ga.population.copy(), ga.lineage.copy()
    ga.update(0, 1, score)
    np.testing.assert_array_equal(ga.population[winner], before[winner])
    clone_noise = ga.population[loser] - before[winner]
    assert 0.05 < clone_noise.std() < 0.15 and np.abs(clone_noise).max() < 1.0
    np.testing.assert_array_equal(ga.population[2:], before[2:])
    assert ga.lineage[winner] == streak[winner] + 1
    assert ga.lineage[loser] == streak[winner]          # the clone inherits the lineage
    assert ga.champion()[0] == winner


def test_pairs_are_distinct_and_rounds_disjoint():
    ga = TournamentGA(TINY, seed=2)
    for _ in range(20):
        a, b = ga.draw_pairs(1)[0]
        assert a != b
    pairs = ga.draw_pairs(4)
    assert sorted(pairs.ravel().tolist()) == list(range(8))
    with pytest.raises(ValueError, match="disjoint pairs"):
        ga.draw_pairs(5)


def test_seeded_runs_are_reproducible():
    a, b, c = TournamentGA(TINY, seed=3), TournamentGA(TINY, seed=3), TournamentGA(TINY, seed=4)
    for ga in (a, b, c):
        ga.run(8, pairs_per_round=4)
    np.testing.assert_array_equal(a.population, b.population)
    np.testing.assert_array_equal(a.lineage, b.lineage)
    assert not np.array_equal(a.population, c.population)
    assert a.games == 8 and a.steps > 8 * 100 and a.lineage.sum() > 0


def test_sequential_algorithm_plays_one_game_at_a_time():
    ga = TournamentGA(TINY, seed=5)
    before = ga.population.copy()
    ga.run(3, pairs_per_round=1)
    assert ga.games == 3 and ga.steps > 3 * 100
    changed = np.any(ga.population != before, axis=1).sum()
    assert 1 <= changed <= 3                 # every game rewrites exactly one agent


def test_resume_from_checkpoint_equals_uninterrupted(tmp_path):
    whole = TournamentGA(TINY, seed=6)
    whole.run(12, pairs_per_round=4)
    part = TournamentGA(TINY, seed=6)
    part.run(8, pairs_per_round=4, checkpoint=tmp_path / "ga.npz")
    resumed = TournamentGA.load(tmp_path / "ga.npz")
    assert resumed.games == 8
    resumed.run(12, pairs_per_round=4)
    np.testing.assert_array_equal(whole.population, resumed.population)
    np.testing.assert_array_equal(whole.lineage, resumed.lineage)
    assert whole.snapshots.games == resumed.snapshots.games == [4, 8, 12]
    np.testing.assert_array_equal(np.array(whole.snapshots.params), np.array(resumed.snapshots.params))


def test_policy_file_round_trip_and_wrong_size_refused(tmp_path):
    params = np.random.default_rng(0).normal(size=param_count())
    save_policy(tmp_path / "lite.npz", params, lineage=4)
    policy = load_policy(tmp_path / "lite.npz", hidden=(10, 10))
    np.testing.assert_array_equal(policy.params, params)
    obs = np.random.default_rng(1).normal(size=(4, 12))
    np.testing.assert_array_equal(policy(obs), [policy.predict(o) for o in obs])
    big = np.zeros(param_count((20, 20)))
    save_policy(tmp_path / "big.npz", big, hidden=(20, 20))
    with pytest.raises(ValueError, match=r"hidden layers \(20, 20\) \(743 parameters\), expected \(10, 10\)"):
        load_policy(tmp_path / "big.npz", hidden=(10, 10))
    np.savez(tmp_path / "bad.npz", params=np.zeros(100), hidden=np.array([10, 10]))
    with pytest.raises(ValueError, match="100 parameters where hidden layers"):
        load_policy(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="273 parameters, got 100"):
        MlpPolicy(np.zeros(100))
