"""Gymnasium over the bus: API conformance, seeding, lockstep replies, ipc, faults, record and replay."""
from __future__ import annotations

import os
import signal

import msgspec
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from msgs.learn import EnvAction, EnvReset
from nodes.learn.bus_env import BusEnv, BusVecEnv, SimulatorError, replay_log
from nodes.learn.sim_node import SimNode
from tether.errors import ConfigError
from tether.testing import Harness

REACH, MAZE = "sim.car_env:ReachCar", "sim.car_env:MazeCar"


def _rollout(env: BusVecEnv, seed: int, steps: int) -> list[np.ndarray]:
    rng = np.random.default_rng(99)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        obs, rew, term, trunc, info = env.step(rng.uniform(-1.2, 1.2, (env.num_envs, 2)))
        out += [obs, rew, term, trunc, info["final_obs"]]
    return out


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_passes_gymnasium_env_checker():
    env = BusEnv(MAZE)
    check_env(env, skip_render_check=True)
    env.close()


def test_same_seed_same_episode_and_no_seed_continues():
    env = BusVecEnv(REACH, 3)
    a = _rollout(env, 7, 120)
    b = _rollout(env, 7, 120)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    first, _ = env.reset(seed=7)
    again, _ = env.reset()                          # no seed: the generators continue
    assert not np.array_equal(first, again)
    env.close()


def test_instance_i_depends_only_on_its_seed():
    many, one = BusVecEnv(REACH, 4), BusVecEnv(REACH, 1)
    obs4, _ = many.reset(seed=10)
    obs1, _ = one.reset(seed=12)
    assert np.array_equal(obs4[2], obs1[0])
    many.close(), one.close()


def test_truncation_is_not_termination_and_final_obs_is_kept():
    env = BusVecEnv(REACH, 2)
    env.reset(seed=0)
    for _ in range(99):
        _, _, term, trunc, info = env.step(np.zeros((2, 2)))
        assert not trunc.any()
    obs, _, term, trunc, info = env.step(np.zeros((2, 2)))
    assert trunc.all() and not term.any() and info["_final_obs"].all()
    assert not np.array_equal(obs, info["final_obs"]) and np.all(info["sim_time_s"] == 0.0)
    env.close()


def test_single_env_asks_for_a_reset_after_the_end():
    env = BusEnv(REACH, max_steps=3)
    env.reset(seed=1)
    for _ in range(3):
        _, _, term, trunc, _ = env.step(np.zeros(2))
    assert trunc and not term
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(2))
    env.close()


def test_nan_action_refused_out_of_range_clipped():
    env = BusVecEnv(REACH, 2)
    env.reset(seed=3)
    with pytest.raises(ValueError, match="refused the request: non-finite action for instance"):
        env.step(np.array([[0.0, 0.0], [np.nan, 0.0]]))
    clipped = BusVecEnv(REACH, 2)
    clipped.reset(seed=3)
    # the refused step moved nothing: both envs are at their first step
    a, *_ = env.step(np.array([[5.0, -5.0], [2.0, 0.5]]))
    b, *_ = clipped.step(np.array([[1.0, -1.0], [1.0, 0.5]]))
    assert np.array_equal(a, b)
    env.close(), clipped.close()


def test_sim_node_answers_a_repeat_without_stepping_twice_and_refuses_out_of_order():
    h = Harness(SimNode, params={"sim": REACH, "n_envs": 1})
    h.feed([(0.0, "reset", EnvReset(epoch=1, seeds=np.array([4])))])
    act = EnvAction(epoch=1, step=1, actions=np.array([[1.0, 0.0]]))
    h.feed([(0.1, "action", act), (0.2, "action", act)])
    first, repeat = h.of("step")[-2:]
    assert np.array_equal(first.obs, repeat.obs) and h.node.sim.steps[0] == 1
    h.feed([(0.3, "action", EnvAction(epoch=1, step=5, actions=np.zeros((1, 2))))])
    assert "expected step 2" in h.of("step")[-1].error


def test_sim_must_come_from_the_project():
    with pytest.raises(ConfigError, match="module under"):
        BusVecEnv("os:system", 1)


def test_ipc_shards_give_the_in_process_episode_bit_for_bit():
    inproc = BusVecEnv(MAZE, 4)
    ipc = BusVecEnv(MAZE, 4, mode="ipc", shards=2)
    try:
        a, b = _rollout(inproc, 5, 40), _rollout(ipc, 5, 40)
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    finally:
        inproc.close(), ipc.close()


def test_a_simulator_that_dies_mid_episode_raises_without_hanging():
    # the deadline is far beyond the test's own timeout: the error must come from noticing the death,
    # not from waiting out the reply deadline (whose message says "no reply")
    env = BusVecEnv(REACH, 2, mode="ipc", timeout_s=3600)
    try:
        env.reset(seed=0)
        env.step(np.zeros((2, 2)))
        os.kill(env._link.procs[0].pid, signal.SIGKILL)
        with pytest.raises(SimulatorError, match="exited with code -9 mid-episode"):
            for _ in range(10):
                env.step(np.zeros((2, 2)))
    finally:
        env.close()


@pytest.mark.parametrize("mode,shards", [("inproc", 1), ("ipc", 2)])
def test_recorded_episodes_replay_bit_identically(tmp_path, mode, shards):
    path = tmp_path / "ep.mcap"
    env = BusVecEnv(MAZE, 3, record=path, mode=mode, shards=shards)
    _rollout(env, 11, 30)
    env.close()
    assert replay_log(path) == {"replies": 31 * shards, "instances": 3}     # replayed in-process


def test_a_tampered_log_is_caught(tmp_path):
    from tether.log import LogReader, LogWriter

    path, bad = tmp_path / "ep.mcap", tmp_path / "bad.mcap"
    env = BusVecEnv(REACH, 2, record=path)
    _rollout(env, 1, 5)
    env.close()
    reader = LogReader(path)
    with LogWriter(bad) as out:
        for rec in reader.messages():
            msg = reader.decode(rec)
            if rec.topic == "sim0/step" and msg.step == 3:
                msg = msgspec.structs.replace(msg, rewards=msg.rewards + 1e-12)
            out.write(rec.topic, msg, log_time_ns=rec.log_time_ns)
    with pytest.raises(ValueError, match="step 3: field rewards differs on replay"):
        replay_log(bad)
