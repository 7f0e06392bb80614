"""PPO: advantages, determinism, checkpoints, and learning on a task it must solve."""
from __future__ import annotations

import jax
import numpy as np
import pytest

from nodes.learn.bus_env import BusVecEnv
from nodes.learn.ppo import PPO, PPOConfig, gae

TINY = PPOConfig(n_steps=32, epochs=2, minibatches=2, hidden=(16,))


def test_gae_matches_the_recursion_by_hand():
    rew = np.array([[1.0], [2.0], [3.0]])
    val = np.array([[0.5], [0.4], [0.3]])
    done = np.array([[False], [True], [False]])
    adv, ret = gae(rew, val, done, np.array([0.2]), gamma=0.9, lam=0.8)
    d2 = 3.0 + 0.9 * 0.2 - 0.3
    d1 = 2.0 - 0.4                                      # the episode ends after step 1
    d0 = 1.0 + 0.9 * 0.4 - 0.5
    assert adv[:, 0] == pytest.approx([d0 + 0.72 * d1, d1, d2])
    assert np.allclose(ret, adv + val)


def _train(seed: int) -> list[float]:
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space, TINY, seed=seed)
    hist = agent.learn(env, 256, seed=seed)
    env.close()
    return [h["policy_loss"] for h in hist] + [float(np.asarray(agent.params["log_std"]).sum())]


def test_training_is_deterministic_for_a_seed():
    first = _train(3)
    assert _train(3) == first and _train(4) != first


def test_checkpoint_round_trip_and_wrong_observation_size(tmp_path):
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space, TINY, seed=0)
    agent.learn(env, 64)
    agent.save(tmp_path / "a.ppo")
    back = PPO.load(tmp_path / "a.ppo", observation_space=env.single_observation_space)
    obs, _ = env.reset(seed=1)
    assert np.array_equal(agent.act(obs), back.act(obs)) and back.steps_done == agent.steps_done
    maze = BusVecEnv("sim.car_env:MazeCar", 1)
    with pytest.raises(ValueError, match=r"trained on observations of shape \(11,\).*gives \(27,\)"):
        PPO.load(tmp_path / "a.ppo", observation_space=maze.single_observation_space)
    with pytest.raises(ValueError, match="observations of shape"):
        back.act(np.zeros((1, 27), np.float32))
    (tmp_path / "junk").write_bytes(b"\x81\xa1a\x01")
    with pytest.raises(ValueError, match="not a tether PPO checkpoint"):
        PPO.load(tmp_path / "junk")
    env.close(), maze.close()


def test_resumed_training_continues_where_it_stopped(tmp_path):
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    a = PPO(env.single_observation_space, env.single_action_space, TINY, seed=0)
    a.learn(env, 128)
    a.save(tmp_path / "a.ppo")
    b = PPO.load(tmp_path / "a.ppo")
    assert b.steps_done == 128 and len(b.history) == 2
    b.learn(env, 64)
    assert b.steps_done == 192 and len(b.history) == 3
    seconds = [h["seconds"] for h in b.history]
    assert seconds == sorted(seconds) and b.train_seconds >= seconds[-1]    # time adds up across resumes
    env.close()


def test_learns_cartpole_beyond_a_random_policy():
    import gymnasium
    from gymnasium.vector import AutoresetMode

    env = gymnasium.make_vec("CartPole-v1", num_envs=4, vectorization_mode="sync",
                             vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    cfg = PPOConfig(n_steps=128, epochs=4, minibatches=4, lr=2.5e-3, ent_coef=0.01, norm_reward=False)
    agent = PPO(env.single_observation_space, env.single_action_space, cfg, seed=0)
    agent.learn(env, 12_288)
    ev = gymnasium.make("CartPole-v1")
    lengths = []
    for ep in range(5):
        o, _ = ev.reset(seed=100 + ep)
        n, done = 0, False
        while not done:
            o, _, te, tr, _ = ev.step(int(agent.act(o[None])[0]))
            n, done = n + 1, te or tr
        lengths.append(n)
    assert np.mean(lengths) > 100                 # a random policy balances ~22 steps


def test_tanh_squash_keeps_a_gradient_past_the_bounds_and_clip_does_not():
    import gymnasium

    box = gymnasium.spaces.Box(np.array([0.0, -2.0], np.float32), np.array([2.0, 2.0], np.float32))
    obs = gymnasium.spaces.Box(-1.0, 1.0, (3,), np.float32)
    clip = PPO(obs, box, TINY, seed=0)
    tanh = PPO(obs, box, PPOConfig(**{**TINY.__dict__, "squash": "tanh"}), seed=0)
    assert PPOConfig().squash == "clip"                                 # CleanRL's default is kept
    u = np.array([[0.0, 0.0], [0.5, 1.0], [3.0, -3.0], [3.5, -3.5]])
    assert np.allclose(tanh.to_env(u[:2]), [[1.0, 0.0], [1.0 + np.tanh(0.5), 2.0 * np.tanh(1.0)]], atol=1e-6)
    assert np.allclose(clip.to_env(u[:2]), [[0.0, 0.0], [0.5, 1.0]])
    # a mean that has drifted past a bound: clipped, two such samples are the same env action
    # (no advantage can tell them apart); squashed, they still differ, inside the bounds
    c, t = clip.to_env(u[2:]), tanh.to_env(u[2:])
    assert np.array_equal(c[0], c[1]) and np.all(t[0] != t[1])
    assert np.all((t >= box.low) & (t <= box.high)) and np.all(np.abs(t[1] - [2.0, -2.0]) > 0)
    with pytest.raises(ValueError, match="squash"):
        PPO(obs, box, PPOConfig(squash="sigmoid"))
    with pytest.raises(ValueError, match="finite"):
        PPO(obs, gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float32), PPOConfig(squash="tanh"))


def test_tanh_squash_trains_and_survives_a_checkpoint(tmp_path):
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space,
                PPOConfig(**{**TINY.__dict__, "squash": "tanh"}), seed=1)
    agent.learn(env, 128, seed=1)
    obs, _ = env.reset(seed=5)
    env.close()
    agent.save(tmp_path / "t.ppo")
    back = PPO.load(tmp_path / "t.ppo")
    assert back.config.squash == "tanh"
    assert np.array_equal(back.act(obs), agent.act(obs)) and np.all(np.abs(back.act(obs)) < 1.0)


def test_a_checkpoint_from_before_the_squash_option_loads_as_clipped(tmp_path):
    from flax import serialization

    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space, TINY, seed=0)
    env.close()
    doc = agent.state_dict()
    del doc["config"]["squash"], doc["config"]["target_kl"]
    (tmp_path / "old.ppo").write_bytes(serialization.msgpack_serialize(doc))
    old = PPO.load(tmp_path / "old.ppo")
    assert old.config.squash == "clip" and old.config.target_kl == 0.0


def _params_after(cfg: PPOConfig) -> tuple[list[float], np.ndarray]:
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space, cfg, seed=5)
    hist = agent.learn(env, 192, seed=5)
    env.close()
    flat = np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(agent.params)])
    return [h["epochs_run"] for h in hist], flat


def test_target_kl_stops_the_epochs_of_an_update_once_the_policy_has_moved_that_far():
    cfg = PPOConfig(n_steps=32, epochs=4, minibatches=2, hidden=(16,), lr=3e-3)
    epochs_off, off = _params_after(cfg)
    epochs_never, never = _params_after(PPOConfig(**{**cfg.__dict__, "target_kl": 1e9}))
    epochs_first, first = _params_after(PPOConfig(**{**cfg.__dict__, "target_kl": 1e-12}))
    assert epochs_off == [4, 4, 4] and epochs_never == [4, 4, 4]
    assert np.array_equal(never, off)                  # a bound never reached changes nothing
    assert epochs_first == [1, 1, 1]                   # any move at all stops after the first epoch
    init = _params_after(PPOConfig(**{**cfg.__dict__, "lr": 0.0}))[1]
    assert 0 < np.abs(first - init).sum() < np.abs(off - init).sum()


def test_target_kl_survives_a_checkpoint(tmp_path):
    env = BusVecEnv("sim.car_env:ReachCar", 2)
    agent = PPO(env.single_observation_space, env.single_action_space,
                PPOConfig(n_steps=32, epochs=2, minibatches=2, hidden=(16,), target_kl=0.02), seed=0)
    env.close()
    agent.save(tmp_path / "k.ppo")
    assert PPO.load(tmp_path / "k.ppo").config.target_kl == 0.02
    for bad in (-0.01, float("nan")):
        with pytest.raises(ValueError, match="target_kl must be >= 0"):
            PPO(agent.observation_space, agent.action_space, PPOConfig(target_kl=bad))
