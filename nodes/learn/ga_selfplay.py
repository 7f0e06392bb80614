"""Self-play by tournament selection (the seed's Algorithm 3) on the SlimeVolley replica.

Algorithm 3, as estool's ``train_ga_selfplay.py`` runs it for the leaderboard: a population
of 128 random agents (the 273-parameter ``slimevolleylite`` MLP, parameters ~ N(0, 0.5^2));
for every game, two distinct random players meet (the first on the right, the second on the
left); a tie adds N(0, 0.1^2) noise to the second one's parameters; otherwise the loser is
replaced by a clone of the winner plus that noise. Each agent carries its lineage (games won
by it and the ancestors it was cloned from: estool's ``winning_streak``); the agent with the
longest lineage is the champion, a proxy for the best that costs no extra games.

``pairs_per_round=1`` is Algorithm 3 exactly, one game at a time. ``pairs_per_round=P/2`` is
the asynchronous-parallel variant the paper invites: each round draws P/2 *disjoint* pairs
(a permutation of the population, i.e. without replacement within the round), plays them
together on the vectorised replica, then applies Algorithm 3's rule to each pair. It differs
from the sequential algorithm only in that an agent plays at most once per round, and a clone
made in a round plays from the next round on, instead of possibly at the very next game.

Everything random (pairing, serves, noise) comes from one seeded generator, whose state the
``.npz`` checkpoint carries (as JSON text: nothing is pickled), so a run resumed from a
checkpoint continues exactly as if it had not stopped.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from nodes.learn.slime_match import play_matches
from nodes.learn.slime_game import SERVE_VX, SERVE_VY
from nodes.learn.slime_policy import HIDDEN_LITE, PerGameMlp, param_count

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GAConfig:
    """The leaderboard's settings (train_ga_selfplay.py)."""

    population: int = 128
    sigma: float = 0.1           # mutation noise std
    init_std: float = 0.5        # initial parameters ~ N(0, init_std^2)
    hidden: tuple[int, ...] = HIDDEN_LITE
    snapshot_every: int = 1000   # games between champion snapshots (estool's save_freq)


@dataclass
class Snapshots:
    """The champion every ``snapshot_every`` games, for the historical curve."""

    games: list[int] = field(default_factory=list)
    lineage: list[int] = field(default_factory=list)
    params: list[np.ndarray] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)      # training CPU seconds spent so far
    steps: list[int] = field(default_factory=list)        # game steps simulated so far


class TournamentGA:
    """Tournament-selection self-play. ``run(n_games)`` plays until ``games >= n_games``."""

    def __init__(self, config: GAConfig = GAConfig(), seed: int = 612) -> None:
        if config.population < 2:
            raise ValueError(f"a tournament needs a population of >= 2, got {config.population}")
        self.config = config
        self.seed = int(seed)
        self.rng = np.random.default_rng(seed)
        d = param_count(config.hidden)
        self.population = self.rng.normal(size=(config.population, d)) * config.init_std
        self.lineage = np.zeros(config.population, np.int64)
        self.games = 0
        self.steps = 0               # game steps simulated
        self.cpu_s = 0.0             # process CPU seconds spent in run(), summed over resumes
        self.snapshots = Snapshots()

    # -- Algorithm 3 -------------------------------------------------------------------
    def update(self, first: int, second: int, score: float) -> None:
        """Apply one game's outcome; ``score`` is the first (right) player's, > 0 if it won."""
        noise = self.rng.normal(size=self.population.shape[1]) * self.config.sigma
        if score == 0:
            self.population[second] += noise
            return
        winner, loser = (first, second) if score > 0 else (second, first)
        self.population[loser] = self.population[winner] + noise
        self.lineage[loser] = self.lineage[winner]
        self.lineage[winner] += 1

    def champion(self) -> tuple[int, np.ndarray]:
        """(index, parameters) of the agent with the longest lineage (first on ties, as np.argmax)."""
        i = int(np.argmax(self.lineage))
        return i, self.population[i].copy()

    def draw_pairs(self, k: int) -> np.ndarray:
        """(k, 2) players (first, second): one random pair, or k disjoint pairs of a permutation."""
        if k == 1:
            return self.rng.choice(self.config.population, 2, replace=False)[None, :]
        if not 1 <= 2 * k <= self.config.population:
            raise ValueError(f"{k} disjoint pairs need a population of >= {2 * k}, have {self.config.population}")
        return self.rng.permutation(self.config.population)[:2 * k].reshape(k, 2)

    def play_round(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Draw k pairs, play them on the replica, update; returns (scores, lengths) of the k games."""
        pairs = self.draw_pairs(k)
        right = PerGameMlp(self.population[pairs[:, 0]], self.config.hidden)
        left = PerGameMlp(self.population[pairs[:, 1]], self.config.hidden)
        rng = self.rng

        def serve(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return rng.uniform(*SERVE_VX, size=idx.size), rng.uniform(*SERVE_VY, size=idx.size)

        scores, lengths = play_matches(right, left, serve, k)
        for (a, b), s in zip(pairs, scores):
            self.update(int(a), int(b), float(s))
        self.games += k
        self.steps += int(lengths.sum())
        return scores, lengths

    # -- driving -------------------------------------------------------------------------
    def run(self, n_games: int, *, pairs_per_round: int = 1, checkpoint: str | Path | None = None,
            checkpoint_every_s: float = 60.0, progress: Callable[[dict], None] | None = None,
            progress_every: int = 1000, cpu_budget_s: float = float("inf")) -> None:
        """Play until ``games >= n_games`` (or ``cpu_budget_s`` more CPU seconds), snapshotting the
        champion every ``snapshot_every`` games and saving ``checkpoint`` every ``checkpoint_every_s``
        and at the end. ``progress(info)`` is called every ``progress_every`` games."""
        every = self.config.snapshot_every
        cpu0, wall0, games0 = time.process_time(), time.perf_counter(), self.games
        last_save, last_report = time.perf_counter(), self.games
        lengths_seen: list[int] = []
        while self.games < n_games and time.process_time() - cpu0 < cpu_budget_s:
            t0 = time.process_time()
            before = self.games
            _, lengths = self.play_round(pairs_per_round)
            self.cpu_s += time.process_time() - t0
            lengths_seen.extend(lengths.tolist())
            if self.games // every > before // every:
                i, params = self.champion()
                self.snapshots.games.append(self.games)
                self.snapshots.lineage.append(int(self.lineage[i]))
                self.snapshots.params.append(params)
                self.snapshots.cpu_s.append(self.cpu_s)
                self.snapshots.steps.append(self.steps)
            if self.games - last_report >= progress_every:
                info = {"games": self.games, "champion_lineage": int(self.lineage.max()),
                        "games_per_s": (self.games - games0) / max(time.perf_counter() - wall0, 1e-9),
                        "mean_length": float(np.mean(lengths_seen)), "cpu_s": self.cpu_s}
                log.info("GA %(games)d games, %(games_per_s).1f games/s, champion lineage %(champion_lineage)d, "
                         "mean game %(mean_length).0f steps", info)
                if progress is not None:
                    progress(info)
                last_report, lengths_seen = self.games, []
            if checkpoint is not None and time.perf_counter() - last_save >= checkpoint_every_s:
                self.save(checkpoint)
                last_save = time.perf_counter()
        if checkpoint is not None:
            self.save(checkpoint)

    # -- checkpoints ---------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the whole run (population, lineage, generator state, snapshots) as ``.npz``, atomically."""
        path = Path(path)
        cfg = self.config
        meta = {"population": cfg.population, "sigma": cfg.sigma, "init_std": cfg.init_std,
                "hidden": list(cfg.hidden), "snapshot_every": cfg.snapshot_every, "seed": self.seed,
                "games": self.games, "steps": self.steps, "cpu_s": self.cpu_s,
                "rng": self.rng.bit_generator.state}
        d = self.population.shape[1]
        snaps = np.array(self.snapshots.params).reshape(-1, d)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, population=self.population, lineage=self.lineage, meta=np.array(json.dumps(meta)),
                 snap_games=np.array(self.snapshots.games, np.int64),
                 snap_lineage=np.array(self.snapshots.lineage, np.int64), snap_params=snaps,
                 snap_cpu_s=np.array(self.snapshots.cpu_s, np.float64), snap_steps=np.array(self.snapshots.steps, np.int64))
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> TournamentGA:
        """A run saved by :meth:`save`, ready to continue."""
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["meta"]))
            cfg = GAConfig(population=meta["population"], sigma=meta["sigma"], init_std=meta["init_std"],
                           hidden=tuple(meta["hidden"]), snapshot_every=meta["snapshot_every"])
            ga = cls(cfg, seed=meta["seed"])
            if f["population"].shape != ga.population.shape:
                raise ValueError(f"{path}: population of shape {f['population'].shape}, its settings say "
                                 f"{ga.population.shape}: the checkpoint is corrupt")
            ga.population = f["population"].copy()
            ga.lineage = f["lineage"].copy()
            ga.snapshots = Snapshots(f["snap_games"].tolist(), f["snap_lineage"].tolist(), list(f["snap_params"]),
                                     f["snap_cpu_s"].tolist(), f["snap_steps"].tolist())
        ga.games, ga.steps, ga.cpu_s = meta["games"], meta["steps"], meta["cpu_s"]
        ga.rng.bit_generator.state = meta["rng"]
        return ga
