"""PPO on SlimeVolley: against the built-in baseline, or by self-play with a champion list.

Self-play is the seed's Algorithm 2 as estool's ``train_ppo_selfplay.py`` runs it: the
champion list starts with a random-action agent; the trainee plays the most recent champion
(the left slime of :class:`~nodes.learn.slime.SlimeVsOpponent`); every ``check_every_steps``
it plays ``check_episodes`` games against that champion and, when its mean score is above
``threshold`` (0.5), a frozen copy of it is appended to the list and becomes the opponent.
Against the baseline (Algorithm 1 with the expert as the fixed champion) the opponent
never changes. As in estool, the trainee and the champions *sample* their actions in the
challenge games and as opponents (stable-baselines' ``predict`` default); the curve and the
final scores against the baseline use the deterministic policy (the leaderboard's
``eval_agents.py``).

Training stops when the training CPU time (process CPU, evaluation excluded) reaches the
budget. The learning curve evaluates, every ``curve_every_steps``, the policy the method
would deliver -- the latest champion for self-play, the trainee otherwise -- against the
baseline on the replica.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nodes.learn.ppo import PPO
from nodes.learn.slime_match import evaluate_replica, play_matches, seeded_server, stateless

log = logging.getLogger(__name__)


def ppo_policy(agent: PPO, deterministic: bool = True) -> Callable[[np.ndarray], np.ndarray]:
    """``act(obs (k, 12)) -> (k, 3)`` of a PPO agent on float32 observations, as trained."""
    return lambda obs: agent.act(np.asarray(obs, np.float32), deterministic=deterministic)


class RandomPolicy:
    """The first champion: uniformly random buttons, from a seeded generator."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.integers(0, 2, size=(len(obs), 3)).astype(np.int8)


@dataclass
class PPORun:
    """What a run produced: curve rows (steps, games, cpu_s, score mean, score std, champions)."""

    mode: str
    curve: list[dict[str, float]] = field(default_factory=list)
    champions: list[str] = field(default_factory=list)    # checkpoint paths, oldest first
    train_cpu_s: float = 0.0
    eval_cpu_s: float = 0.0
    steps: int = 0
    games: int = 0
    final: Any = None                                       # the delivered policy (a PPO)


def train_ppo_slime(agent: PPO, env: Any, *, mode: str, cpu_budget_s: float, out_dir: str | Path,
                    threshold: float = 0.5, check_every_steps: int = 100_000, check_episodes: int = 100,
                    curve_every_steps: int = 100_000, curve_episodes: int = 200, seed: int = 0,
                    progress: Callable[[str], None] | None = None) -> PPORun:
    """Train ``agent`` on ``env`` (a :class:`~nodes.learn.bus_env.BusVecEnv` in-process over
    ``SlimeVsOpponent``) for ``cpu_budget_s`` training CPU seconds.

    Parameters
    ----------
    mode : {"selfplay", "baseline"}
        Opponent: the champion list, or the built-in baseline throughout.
    out_dir : path
        Champions are saved there as ``champion_NNNN.ppo`` (msgpack), the final agent as ``final.ppo``.
    """
    if mode not in ("selfplay", "baseline"):
        raise ValueError(f"mode must be 'selfplay' or 'baseline', got {mode!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = PPORun(mode)
    sim = env.sim
    champion: PPO | None = None
    if mode == "selfplay":
        sim.opponent = RandomPolicy(seed)
    cpu0 = time.process_time()
    next_check, next_curve, n_checks = check_every_steps, 0, 0

    def evaluate(steps: int, games: int, train_return: float = float("nan")) -> None:
        nonlocal next_curve
        delivered = agent if mode == "baseline" else champion
        policy = RandomPolicy(seed + 1) if delivered is None else ppo_policy(delivered)
        scores = evaluate_replica(stateless(policy), curve_episodes, seed=10_000_000 + seed)
        row = {"steps": steps, "games": games, "cpu_s": run.train_cpu_s, "score": float(scores.mean()),
               "score_std": float(scores.std()), "champions": len(run.champions), "train_return": train_return}
        run.curve.append(row)
        if progress is not None:
            progress(f"ppo-{mode} {steps:>9d} steps {games:>6d} games {run.train_cpu_s / 60:6.1f} cpu-min "
                     f"score {row['score']:+.3f} champions {len(run.champions)} training return {train_return:+.2f}")
        next_curve = steps + curve_every_steps

    def challenge(steps: int) -> None:
        nonlocal champion, next_check, n_checks
        n_checks += 1
        opponent = RandomPolicy(seed + 2) if champion is None else ppo_policy(champion, False)
        serve = seeded_server(20_000_000 + seed * 1000 + n_checks * check_episodes + np.arange(check_episodes))
        scores, _ = play_matches(stateless(ppo_policy(agent, False)), stateless(opponent), serve, check_episodes)
        next_check = steps + check_every_steps
        if scores.mean() > threshold:
            path = out_dir / f"champion_{len(run.champions) + 1:04d}.ppo"
            agent.save(path)
            champion = PPO.load(path)
            run.champions.append(str(path))
            sim.opponent = ppo_policy(champion, False)
        log.info("ppo self-play: %d steps, %.2f against champion %d%s", steps, scores.mean(), len(run.champions)
                 - (scores.mean() > threshold), ": a new champion" if scores.mean() > threshold else "")

    def callback(entry: dict[str, float]) -> bool:
        run.steps, run.games = int(entry["steps"]), int(entry["episodes"])
        e0 = time.process_time()
        if mode == "selfplay" and run.steps >= next_check:
            challenge(run.steps)
        if run.steps >= next_curve:
            evaluate(run.steps, run.games, entry["return_mean"])
        run.eval_cpu_s += time.process_time() - e0
        run.train_cpu_s = time.process_time() - cpu0 - run.eval_cpu_s
        return run.train_cpu_s < cpu_budget_s

    e0 = time.process_time()
    evaluate(0, 0)
    run.eval_cpu_s += time.process_time() - e0
    agent.learn(env, 10**12, seed=seed, callback=callback)
    e0 = time.process_time()
    evaluate(run.steps, run.games)
    run.eval_cpu_s += time.process_time() - e0
    agent.save(out_dir / "final.ppo")
    run.final = agent if mode == "baseline" else champion
    return run
