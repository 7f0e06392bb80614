"""SlimeVolley environments: the VecSim on the replica, the PettingZoo adapter on the original."""
import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from nodes.learn.slime import SlimeParallelEnv, SlimeVsOpponent, make_original_env
from nodes.learn.slime_match import evaluate_original, evaluate_replica
from nodes.learn.slime_policy import MlpPolicy, param_count

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from slimevolleygym.slimevolley import BaselinePolicy


def test_parallel_api():
    parallel_api_test(SlimeParallelEnv(), num_cycles=600)


def test_parallel_env_seeded_and_zero_sum():
    env = SlimeParallelEnv()
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 2, size=(400, 2, 3))
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=5)
        trace = [obs["right"].copy()]
        for a in actions:
            obs, rew, term, trunc, _ = env.step({"right": a[0], "left": a[1]})
            assert rew["right"] == -rew["left"]
            trace.append(obs["left"].copy())
            if not env.agents:
                break
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])
    # each side sees itself first: the left slime's own x is positive in its own frame
    assert obs["left"][0] > 0 and obs["right"][0] > 0


def test_vecsim_replays_the_seeded_original_env():
    n = 3
    sim = SlimeVsOpponent(n)
    obs = sim.reset(seeds=100 + np.arange(n))
    envs = []
    for i in range(n):
        env = make_original_env()
        env.seed(100 + i)
        np.testing.assert_array_equal(env.reset().astype(np.float32), obs[i])
        envs.append(env)
    rng = np.random.default_rng(1)
    episodes = 0
    for t in range(2500):
        a = rng.integers(0, 2, size=(n, 3))
        batch = sim.step(a)
        for i, env in enumerate(envs):
            o, r, done, _ = env.step(a[i])
            np.testing.assert_array_equal(o.astype(np.float32), batch.final_obs[i], err_msg=f"step {t}")
            assert r == batch.rewards[i]
            assert done == (batch.terminated[i] or batch.truncated[i])
            if done:
                episodes += 1
                env.policy = BaselinePolicy()     # the replica restarts the baseline's memory too
                np.testing.assert_array_equal(env.reset().astype(np.float32), batch.obs[i])
    assert episodes >= 6
    assert batch.metrics.shape == (n, 2)


def test_vecsim_opponent_is_replaceable():
    sim = SlimeVsOpponent(2)
    sim.reset(seeds=[0, 1])
    sim.opponent = lambda obs: np.tile([0, 0, 1], (len(obs), 1))    # a left slime that only jumps
    heights = [sim.step(np.zeros((2, 3), int)).obs[:, 9] for _ in range(10)]
    assert np.max(heights) > 0.3          # opponent y (m / 10) well above the ground (0.15)
    sim.opponent = lambda obs: np.zeros((3, 3))
    with pytest.raises(ValueError, match="opponent"):
        sim.step(np.zeros((2, 3), int))


def test_replica_evaluation_equals_original():
    params = np.random.default_rng(7).normal(size=param_count()) * 0.5
    policy = MlpPolicy(params)
    fast = evaluate_replica(policy, 12, seed=721)
    slow = evaluate_original(policy.predict, 12, seed=721, fresh_baseline=True)
    np.testing.assert_array_equal(fast, slow)
    assert fast.min() >= -5 and fast.max() <= 5
