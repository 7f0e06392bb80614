"""Train, evaluate and export PPO policies on bus environments: what ``tether learn`` runs.

Training is resumable: the checkpoint is rewritten every ``checkpoint_every`` env steps
(parameters, optimiser, normalisers, generator, history), and ``resume=True`` continues
from it to the requested total. A learning-curve PNG is written beside the checkpoint.
Evaluation runs one seeded episode in each of ``episodes`` instances at once (instance
``i`` seeded ``seed + i``) with the deterministic policy, and reports each scenario metric
at the episode's end.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nodes.learn.bus_env import BusVecEnv
from nodes.learn.ppo import PPO, PPOConfig

log = logging.getLogger(__name__)


def train(sim: str, out: str | Path, *, steps: int, n_envs: int = 16, params: dict[str, Any] | None = None,
          config: PPOConfig | None = None, seed: int = 0, mode: str = "inproc", shards: int = 1,
          resume: bool = False, checkpoint_every: int = 200_000,
          progress: Callable[[str], None] | None = None) -> PPO:
    """Train until the agent has seen ``steps`` env steps in all; checkpoint to ``out``."""
    out = Path(out)
    env = BusVecEnv(sim, n_envs, mode=mode, shards=shards, params=params)
    try:
        if resume and out.exists():
            agent = PPO.load(out, observation_space=env.single_observation_space)
            if progress:
                progress(f"resuming {out} at {agent.steps_done} steps")
        else:
            agent = PPO(env.single_observation_space, env.single_action_space, config, seed=seed)
        chunk = max(checkpoint_every, agent.config.n_steps * n_envs)
        first = True
        while agent.steps_done < steps:
            todo = min(chunk, steps - agent.steps_done)
            if todo < agent.config.n_steps * n_envs:
                break
            # the first chunk resets with the seed; later ones continue the episodes' generators
            agent.learn(env, todo, seed=seed + agent.steps_done if first else None, progress=progress,
                        total_steps=steps)
            first = False
            agent.save(out)
            plot_curve(agent.history, out.with_suffix(".png"), title=f"PPO on {sim}")
    finally:
        env.close()
    return agent


def evaluate(agent: PPO, sim: str, *, episodes: int = 100, seed: int = 10_000, params: dict[str, Any] | None = None,
             max_steps: int = 0, record: str | Path | None = None) -> dict[str, Any]:
    """Metrics at the end of one deterministic episode per instance: mean, std and the values.
    ``record``: an MCAP log of every request and reply (``tether learn replay`` checks it)."""
    env = BusVecEnv(sim, episodes, params=params, max_steps=max_steps, record=record)
    try:
        obs, _ = env.reset(seed=seed)
        final: dict[str, np.ndarray] = {name: np.full(episodes, np.nan) for name in env.metric_names}
        returns, ret = np.full(episodes, np.nan), np.zeros(episodes)
        steps = np.zeros(episodes, np.int64)
        pending = np.ones(episodes, bool)
        while pending.any():
            obs, rew, term, trunc, info = env.step(agent.act(obs))
            ret += rew * pending
            steps += pending
            ended = pending & (term | trunc)
            for name in env.metric_names:
                final[name][ended] = info[name][ended]
            returns[ended] = ret[ended]
            pending &= ~ended
    finally:
        env.close()
    report: dict[str, Any] = {"episodes": episodes, "seed": seed, "return_mean": float(returns.mean()),
                              "steps_mean": float(steps.mean())}
    for name, values in final.items():
        report[f"{name}_mean"], report[f"{name}_std"] = float(values.mean()), float(values.std())
        report[name] = values.tolist()
    return report


def export(checkpoint: str | Path, out: str | Path) -> int:
    """A deployable copy: the policy, its normaliser and spaces, without optimiser state or history."""
    agent = PPO.load(checkpoint)
    doc = agent.state_dict()
    doc["opt_state"] = None
    doc["history"] = {}
    from flax import serialization

    Path(out).parent.mkdir(parents=True, exist_ok=True)
    data = serialization.msgpack_serialize(doc)
    Path(out).write_bytes(data)
    return len(data)


def plot_curve(history: list[dict[str, float]], path: str | Path, *, title: str = "PPO") -> None:
    """Mean episode return against env steps and wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    steps = np.array([h["steps"] for h in history])
    ret = np.array([h["return_mean"] for h in history])
    secs = np.array([h["seconds"] for h in history])
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].plot(steps, ret)
    ax[0].set_xlabel("env steps")
    ax[0].set_ylabel("mean episode return (last 20)")
    ax[1].plot(secs / 60.0, ret)
    ax[1].set_xlabel("training wall minutes (resumed runs added)")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def report_json(report: dict[str, Any]) -> str:
    """The report without its per-episode lists (one line)."""
    return json.dumps({k: v for k, v in report.items() if not isinstance(v, list)})
