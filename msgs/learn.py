"""Learning messages: a Gymnasium environment stepped over the bus in lockstep.

A client (:class:`nodes.learn.bus_env.BusVecEnv`) publishes :class:`EnvReset` and
:class:`EnvAction`; a simulator node answers each with one :class:`EnvStep`. Every message
is batched over the simulator's ``N`` instances (row ``i`` is instance ``i``), carries the
client's episode and step counters (a reply echoes them: a late or duplicated reply is
recognised, never mistaken for the next one) and the simulation time, never the wall clock.
"""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class EnvReset(Message, tag="learn.EnvReset"):
    """Reset every instance. ``seeds`` (N,) int64: instance ``i`` is reseeded with ``seeds[i]``,
    or keeps its generator when it is negative. ``epoch`` counts the client's resets."""

    epoch: int = 0
    seeds: np.ndarray = const(np.zeros(0, np.int64))


class EnvAction(Message, tag="learn.EnvAction"):
    """One action per instance, (N, *action_shape), in the action space's dtype."""

    epoch: int = 0
    step: int = 0
    actions: np.ndarray = const(np.zeros((0, 0)))


class EnvStep(Message, tag="learn.EnvStep"):
    """The reply to a reset (``step`` 0) or an action. An instance whose episode ended is reset
    at once (Gymnasium's same-step autoreset): ``obs`` is then its next episode's first
    observation and ``final_obs`` the last one of the ended episode (equal to ``obs`` elsewhere).
    ``metrics`` (N, M) are named by ``metric_names`` (scenario figures such as the distance to
    the target, taken before any autoreset). ``error`` non-empty: the simulator refused the
    request (the text says why); the other fields are then meaningless."""

    epoch: int = 0
    step: int = 0
    sim_time_s: np.ndarray = const(np.zeros(0))
    obs: np.ndarray = const(np.zeros((0, 0), np.float32))
    final_obs: np.ndarray = const(np.zeros((0, 0), np.float32))
    rewards: np.ndarray = const(np.zeros(0))
    terminated: np.ndarray = const(np.zeros(0, bool))
    truncated: np.ndarray = const(np.zeros(0, bool))
    metrics: np.ndarray = const(np.zeros((0, 0)))
    metric_names: list[str] = []
    error: str = ""


class Observation(Message, tag="learn.Observation"):
    """A deployed simulator's (or robot's) observation for a policy, (obs_dim,), with its
    episode, step and scenario metrics (named by ``metric_names``)."""

    episode: int = 0
    step: int = 0
    sim_time_s: float = 0.0
    obs: np.ndarray = const(np.zeros(0, np.float32))
    metrics: np.ndarray = const(np.zeros(0))
    metric_names: list[str] = []


class PolicyAction(Message, tag="learn.PolicyAction"):
    """A policy's action for the observation of ``episode``/``step`` (in the action space's units)."""

    episode: int = 0
    step: int = 0
    action: np.ndarray = const(np.zeros(0, np.float32))


class EpisodeSummary(Message, tag="learn.EpisodeSummary"):
    """An episode's end: its return, length, why it ended, and the metrics at its last step."""

    episode: int = 0
    steps: int = 0
    return_: float = 0.0
    terminated: bool = False
    truncated: bool = False
    metrics: np.ndarray = const(np.zeros(0))
    metric_names: list[str] = []
