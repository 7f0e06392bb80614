"""SlimeVolley matches to the end: many at once on the replica, or one by one on the original.

A policy for :func:`play_matches` is a callable ``policy(obs, idx) -> buttons`` where ``obs``
(k, 12) are the observations of the games still playing and ``idx`` (k,) their numbers among
all n games, so a policy can hold per-game parameters or recurrent state. Finished games are
dropped from the batch, so a round costs what its live games cost.

Evaluation follows the leaderboard's ``eval_agents.py``: episode ``i`` is played after
``env.seed(seed + i)`` (seed 721), the policy on the right, the built-in baseline on the left,
the score being the right slime's points won minus lost.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from nodes.learn import slime_game as sg
from nodes.learn.slime import draw_serves, make_original_env

BatchPolicy = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: serves for games idx (k,) -> (vx (k,), vy (k,))
Server = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

LEADERBOARD_SEED = 721


def play_matches(right: BatchPolicy, left: BatchPolicy, serve: Server, n: int, *,
                 t_limit: int = sg.T_LIMIT) -> tuple[np.ndarray, np.ndarray]:
    """Play n games to the end (5 points lost or ``t_limit`` steps).

    Returns
    -------
    scores : ndarray, shape (n,)
        The right slime's points won minus lost, in [-5, 5].
    lengths : ndarray, shape (n,)
        Steps each game lasted.
    """
    games = sg.new_games(*serve(np.arange(n)))
    idx = np.arange(n)
    scores = np.zeros(n)
    lengths = np.zeros(n, np.int64)
    t = 0
    while idx.size:
        obs_right, obs_left = sg.observe(games)
        reward = sg.step_games(games, left(obs_left, idx), right(obs_right, idx))
        t += 1
        scores[idx] += reward
        scored = reward != 0
        if scored.any():
            sg.serve(games, scored, *serve(idx[scored]))
        done = (games.life.min(axis=0) <= 0) | (t >= t_limit)
        if done.any():
            lengths[idx[done]] = t
            idx = idx[~done]
            games = games.take(~done)
    return scores, lengths


def stateless(act: Callable[[np.ndarray], np.ndarray]) -> BatchPolicy:
    """A batch policy from a plain ``act(obs (k, 12)) -> (k, 3)``."""
    return lambda obs, idx: act(obs)


def seeded_server(seeds: np.ndarray) -> Server:
    """Serves drawn like the original env after ``env.seed(seeds[i])`` then ``reset()``: one
    generator per game, the serve ``Game()`` draws at construction thrown away."""
    rngs = [np.random.default_rng(int(s)) for s in seeds]
    draw_serves(rngs, np.arange(len(rngs)))
    return lambda idx: draw_serves(rngs, idx)


def evaluate_replica(policy: BatchPolicy, episodes: int = 1000, *, seed: int = LEADERBOARD_SEED) -> np.ndarray:
    """Scores (episodes,) of ``policy`` (right) against the baseline (left) on the replica,
    episode i served as the original env after ``env.seed(seed + i)``; the baseline's
    recurrent state starts at zero in every episode."""
    baseline = sg.BaselineBatch(episodes)
    return play_matches(policy, baseline, seeded_server(seed + np.arange(episodes)), episodes)[0]


def evaluate_original(predict: Callable[[np.ndarray], np.ndarray], episodes: int = 1000, *,
                      seed: int = LEADERBOARD_SEED, fresh_baseline: bool = False) -> np.ndarray:
    """Scores (episodes,) of ``predict(obs (12,)) -> (3,)`` against the built-in baseline on the
    ORIGINAL ``SlimeVolleyEnv``, as ``eval_agents.py`` plays them (one env, ``env.seed(seed + i)``
    before episode i). The env's baseline keeps its recurrent state from one episode to the
    next, as there; ``fresh_baseline`` starts it at zero each episode (then every episode equals
    :func:`evaluate_replica`'s)."""
    from slimevolleygym.slimevolley import BaselinePolicy

    env = make_original_env()
    scores = np.zeros(episodes)
    for i in range(episodes):
        env.seed(seed + i)
        if fresh_baseline:
            env.policy = BaselinePolicy()
        obs = env.reset()
        done = False
        while not done:
            obs, reward, done, _ = env.step(predict(obs))
            scores[i] += reward
    return scores
