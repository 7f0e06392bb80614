"""SlimeVolley as a learning environment: the replica as a VecSim, the original behind PettingZoo.

* :class:`SlimeVsOpponent` -- a :class:`~nodes.learn.vec_sim.VecSim` of N replica games
  (:mod:`nodes.learn.slime_game`) where the right slime is the learner and the left slime is
  ``opponent``, a callable ``(N, 12) obs -> (N, 3) buttons`` (default: the built-in baseline),
  replaceable at run time for self-play. Instance ``i`` seeded with ``s`` replays the original
  ``SlimeVolleyEnv`` after ``env.seed(s)`` serve for serve (the same generator, drawn in the
  same order, including the serve the original draws and throws away when it builds its game).
* :class:`SlimeParallelEnv` -- the ORIGINAL ``slimevolleygym.slimevolley.SlimeVolleyEnv``
  (constructed directly: ``gym.make`` fails under NumPy 2) as a PettingZoo parallel env with
  two agents, ``"right"`` and ``"left"``, each seeing the game from its own side.
"""
from __future__ import annotations

import warnings
from typing import Any, Callable, ClassVar

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

from nodes.learn import slime_game as sg
from nodes.learn.vec_sim import VecSim

#: an opponent: (N, 12) float64 observations of the left slime -> (N, 3) buttons
Opponent = Callable[[np.ndarray], np.ndarray]

OBS_SPACE = gymnasium.spaces.Box(-np.inf, np.inf, shape=(12,), dtype=np.float32)
ACT_SPACE = gymnasium.spaces.MultiBinary(3)


def draw_serves(rngs: list[np.random.Generator], idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One serve per game ``idx``, each from its own generator, as ``Game.newMatch`` draws it (vx, then vy)."""
    vx = np.empty(len(idx))
    vy = np.empty(len(idx))
    for k, i in enumerate(idx):
        vx[k] = rngs[i].uniform(*sg.SERVE_VX)
        vy[k] = rngs[i].uniform(*sg.SERVE_VY)
    return vx, vy


class SlimeVsOpponent(VecSim):
    """N SlimeVolley games: the action is the right slime's buttons, the left slime is ``opponent``.

    Rewards are the right slime's points (+1 won, -1 lost); an episode terminates when either
    slime has lost 5 points and is truncated at 3000 steps, as in the original. ``opponent`` may
    expose ``reset(mask)`` (a recurrent policy): it is called for every instance that starts a
    new episode. The built-in baseline's recurrent state is cleared at each episode here (the
    original env keeps it across ``reset()``).
    """

    observation_space = OBS_SPACE
    action_space = ACT_SPACE
    metric_names: ClassVar[tuple[str, ...]] = ("lives_right", "lives_left")
    DT_S: ClassVar[float] = sg.TIMESTEP
    MAX_STEPS: ClassVar[int] = sg.T_LIMIT

    def configure(self, **params: Any) -> None:
        super().configure(**params)
        self.games = sg.new_games(np.zeros(self.n), np.full(self.n, 10.0))
        self.opponent: Opponent = sg.BaselineBatch(self.n)

    def reset(self, seeds: np.ndarray | list[int] | None = None) -> np.ndarray:
        """As :meth:`VecSim.reset`; a reseeded instance first draws the serve ``Game()`` throws away."""
        if seeds is not None:
            seeds = np.asarray(seeds, np.int64).reshape(-1)
            if seeds.size != self.n:
                raise ValueError(f"give one seed per instance ({self.n}), got {seeds.size}")
            for i in np.flatnonzero(seeds >= 0):
                self.rngs[i] = np.random.default_rng(int(seeds[i]))
                draw_serves(self.rngs, np.array([i]))
        return super().reset(None)

    def _reset(self, mask: np.ndarray) -> None:
        vx, vy = draw_serves(self.rngs, np.flatnonzero(mask))
        sg.reset_games(self.games, mask, vx, vy)
        reset = getattr(self.opponent, "reset", None)
        if callable(reset):
            reset(mask)

    def _observe(self) -> np.ndarray:
        return sg.observe(self.games)[0].astype(np.float32)

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        left = np.asarray(self.opponent(sg.observe(self.games)[1]))
        if left.shape != (self.n, 3):
            raise ValueError(f"the opponent returned actions of shape {left.shape}: give ({self.n}, 3)")
        reward = sg.step_games(self.games, left, actions)
        scored = reward != 0
        if scored.any():
            sg.serve(self.games, scored, *draw_serves(self.rngs, np.flatnonzero(scored)))
        life = self.games.life
        terminated = (life[0] <= 0) | (life[1] <= 0)
        metrics = np.stack([life[1], life[0]], axis=1).astype(np.float64)
        return reward.astype(np.float64), terminated, metrics


def make_original_env() -> Any:
    """The original ``SlimeVolleyEnv`` (old gym's deprecation banner silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from slimevolleygym.slimevolley import SlimeVolleyEnv
    return SlimeVolleyEnv()


class SlimeParallelEnv(ParallelEnv):
    """The original SlimeVolley as a PettingZoo parallel env: agents ``"right"`` and ``"left"``.

    Observations are each slime's own view (12 floats, float32); actions MultiBinary(3)
    (forward, backward, jump); rewards are zero-sum (+1 to the slime that won the point).
    An episode terminates when a slime has lost 5 points and is truncated at 3000 steps.
    """

    metadata: ClassVar[dict[str, Any]] = {"name": "slimevolley_v0", "render_modes": []}
    possible_agents: ClassVar[list[str]] = ["right", "left"]

    def __init__(self) -> None:
        self.env = make_original_env()
        self.agents: list[str] = []
        self.render_mode = None
        self._obs_space = {a: gymnasium.spaces.Box(-np.inf, np.inf, shape=(12,), dtype=np.float32)
                           for a in self.possible_agents}
        self._act_space = {a: gymnasium.spaces.MultiBinary(3) for a in self.possible_agents}
        self._seeded = False

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._obs_space[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.MultiBinary:
        return self._act_space[agent]

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None or not self._seeded:
            # seed() builds a new Game on its own generator; an unseeded first reset draws OS entropy
            self.env.seed(None if seed is None else int(seed))
            for k, agent in enumerate(self.possible_agents):
                self._act_space[agent].seed(None if seed is None else int(seed) + k)
            self._seeded = True
        obs_right = self.env.reset()
        obs_left = self.env.game.agent_left.getObservation()
        self.agents = list(self.possible_agents)
        return ({"right": obs_right.astype(np.float32), "left": obs_left.astype(np.float32)},
                {a: {} for a in self.agents})

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset()")
        missing = set(self.agents) - set(actions)
        if missing:
            raise ValueError(f"give an action for every live agent; missing {sorted(missing)}")
        a_right = np.asarray(actions["right"])
        a_left = np.asarray(actions["left"])
        obs_right, reward, _, info = self.env.step(a_right, a_left)
        game = self.env.game
        terminated = game.agent_left.life <= 0 or game.agent_right.life <= 0
        truncated = (self.env.t >= self.env.t_limit) and not terminated
        obs = {"right": np.asarray(obs_right, np.float32), "left": np.asarray(info["otherObs"], np.float32)}
        rewards = {"right": float(reward), "left": -float(reward)}
        terms = {a: bool(terminated) for a in self.agents}
        truncs = {a: bool(truncated) for a in self.agents}
        infos = {"right": {"lives": game.agent_right.life}, "left": {"lives": game.agent_left.life}}
        if terminated or truncated:
            self.agents = []
        return obs, rewards, terms, truncs, infos

    def close(self) -> None:
        pass
