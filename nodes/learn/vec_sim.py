"""N instances of one simulator stepped together: the pure core a bus environment serves.

A scenario subclasses :class:`VecSim` and writes three batched methods -- ``_reset(mask)``
(new episodes for the masked instances, drawn from their own generators), ``_observe()``
and ``_advance(actions)`` -- over numpy arrays of all ``N`` instances. The base class owns
what every scenario must get right the same way: per-instance seeding (instance ``i``'s
episodes depend only on its seed, not on ``N`` or on the other instances), action checking
(NaN rejected, out-of-range clipped), the time limit (truncation, apart from termination)
and Gymnasium's same-step autoreset.

No bus, no clock, no messages here: :mod:`nodes.learn.sim_node` puts a VecSim on the bus and
:mod:`nodes.learn.bus_env` serves it to Gymnasium.
"""
from __future__ import annotations

import abc
import inspect
import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium
import numpy as np


@dataclass(frozen=True)
class Batch:
    """What one step of all instances returns (arrays over the N instances)."""

    obs: np.ndarray            # (N, *obs_shape): after autoreset
    final_obs: np.ndarray      # (N, *obs_shape): before autoreset (== obs where not done)
    rewards: np.ndarray        # (N,) float64
    terminated: np.ndarray     # (N,) bool
    truncated: np.ndarray      # (N,) bool
    metrics: np.ndarray        # (N, M): scenario figures before autoreset
    sim_time_s: np.ndarray     # (N,): each instance's time in its (possibly new) episode


def _number_param(sim: str, key: str, value: Any, annotation: Any) -> Any:
    """A scenario parameter declared ``float`` or ``int``: a number of that kind (text such as '1e-3'
    or 'nan', which YAML 1.1 reads as strings, becomes one; configure() judges its range). Raises
    ValueError naming the parameter ('nan' from the command line reached configure() as text: a
    TypeError traceback)."""
    kind = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", "")
    if kind not in ("float", "int"):
        return value
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"{sim}: parameter {key}={value!r}: give a number") from None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{sim}: parameter {key}={value!r}: give a number")
    if kind == "int":
        if not (np.isfinite(value) and value == int(value)):
            raise ValueError(f"{sim}: parameter {key}={value!r}: give a whole number")
        return int(value)
    return value


class VecSim(abc.ABC):
    """Base of a batched simulator. Subclasses set the class attributes and the three methods.

    Parameters
    ----------
    n : int
        Number of instances.
    max_steps : int, optional
        Episode length before truncation (0: the class default ``MAX_STEPS``).
    """

    #: one instance's spaces (class attributes, or set by ``configure`` when parameters shape them)
    observation_space: gymnasium.spaces.Space
    action_space: gymnasium.spaces.Space
    #: names of the columns of ``metrics``
    metric_names: ClassVar[tuple[str, ...]] = ()
    DT_S: ClassVar[float] = 0.1
    MAX_STEPS: ClassVar[int] = 200

    def __init__(self, n: int = 1, *, max_steps: int = 0, **params: Any) -> None:
        if n < 1:
            raise ValueError(f"n must be >= 1 instances, got {n}")
        if max_steps < 0:
            raise ValueError(f"max_steps must be >= 0 (0: the default {self.MAX_STEPS}), got {max_steps}")
        self.n = int(n)
        self.max_steps = int(max_steps or self.MAX_STEPS)
        self.steps = np.zeros(self.n, np.int64)
        self.rngs = [np.random.default_rng() for _ in range(self.n)]
        known = inspect.signature(self.configure).parameters
        if not any(p.kind is p.VAR_KEYWORD for p in known.values()):     # a name of the user's: say which
            unknown = sorted(set(params) - set(known))
            if unknown:
                raise ValueError(f"{type(self).__name__}: unknown scenario parameter(s) {unknown} "
                                 f"(known: {', '.join(known) or 'none'})")
        self.configure(**{key: _number_param(type(self).__name__, key, value, known[key].annotation)
                          if key in known else value for key, value in params.items()})

    # -- scenario (override) ------------------------------------------------------------
    def configure(self, **params: Any) -> None:
        """Scenario parameters (keyword arguments of the constructor beyond n and max_steps)."""
        if params:
            raise TypeError(f"{type(self).__name__} takes no parameters {sorted(params)}")

    @abc.abstractmethod
    def _reset(self, mask: np.ndarray) -> None:
        """Start new episodes for the instances where ``mask`` (N,) is True, with ``self.rngs[i]``."""

    @abc.abstractmethod
    def _observe(self) -> np.ndarray:
        """(N, *obs_shape) observations of the current states, in the observation space's dtype."""

    @abc.abstractmethod
    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apply checked actions to every instance: rewards (N,), terminated (N,), metrics (N, M)."""

    # -- driving --------------------------------------------------------------------------
    def reset(self, seeds: np.ndarray | list[int] | None = None) -> np.ndarray:
        """Start a new episode in every instance; ``seeds[i] >= 0`` reseeds instance ``i``."""
        if seeds is not None:
            seeds = np.asarray(seeds, np.int64).reshape(-1)
            if seeds.size != self.n:
                raise ValueError(f"give one seed per instance ({self.n}), got {seeds.size}")
            for i, s in enumerate(seeds):
                if s >= 0:
                    self.rngs[i] = np.random.default_rng(int(s))
        self.steps[:] = 0
        self._reset(np.ones(self.n, bool))
        return self._observe()

    def check_actions(self, actions: Any) -> np.ndarray:
        """Actions as (N, *action_shape): a Box's clipped to its bounds (float64: the simulators
        integrate in float64), a NaN refused (``ValueError`` naming the instance), a discrete or
        binary one out of range refused too."""
        space = self.action_space
        a = np.asarray(actions)
        shape = (self.n, *space.shape)
        if a.shape != shape:
            if a.size == np.prod(shape):
                a = a.reshape(shape)
            else:
                raise ValueError(f"actions of shape {a.shape}: give {shape} (instances x action)")
        if isinstance(space, gymnasium.spaces.Box):
            a = np.asarray(a, np.float64)
            if not np.isfinite(a).all():
                bad = ~np.isfinite(a).reshape(self.n, -1).all(axis=1)
                raise ValueError(f"non-finite action for instance(s) {np.flatnonzero(bad).tolist()}: "
                                 "refused (out-of-range finite actions are clipped, NaN/inf are not)")
            return np.clip(a, space.low, space.high)
        if isinstance(space, gymnasium.spaces.Discrete):
            a = a.astype(np.int64)
            bad = (a < space.start) | (a >= space.start + space.n)
        elif isinstance(space, gymnasium.spaces.MultiBinary):
            a = a.astype(np.int8)
            bad = ((a != 0) & (a != 1)).reshape(self.n, -1).any(axis=1)
        else:
            raise TypeError(f"unsupported action space {space}")
        if np.any(bad):
            raise ValueError(f"action out of {space} for instance(s) {np.flatnonzero(bad).tolist()}: refused")
        return a

    def step(self, actions: Any) -> Batch:
        """Advance every instance one step; ended episodes restart at once (same-step autoreset)."""
        a = self.check_actions(actions)
        rewards, terminated, metrics = self._advance(a)
        self.steps += 1
        terminated = np.asarray(terminated, bool)
        truncated = (self.steps >= self.max_steps) & ~terminated
        final_obs = self._observe()
        done = terminated | truncated
        obs = final_obs
        if done.any():
            self.steps[done] = 0
            self._reset(done)
            obs = self._observe()
        return Batch(obs=obs, final_obs=final_obs, rewards=np.asarray(rewards, np.float64),
                     terminated=terminated, truncated=truncated,
                     metrics=np.asarray(metrics, np.float64).reshape(self.n, len(self.metric_names)),
                     sim_time_s=self.steps * self.DT_S)
