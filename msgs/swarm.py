"""Swarm messages: the robots of a foraging swarm and its running score (seed 09)."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class SwarmState(Message, tag="swarm.SwarmState"):
    """Every robot at one tick, in the arena frame (origin at the source's lower-left corner, x to the nest).

    ``xy_m`` (N, 2) float32, ``heading_rad`` (N,) float32, ``carrying`` / ``waiting`` (N,) bool,
    ``segment`` (N,) int16 (0 = between the source and the first exchange zone). The arena is
    repeated in every message so a viewer needs nothing else.
    """

    t_s: float = 0.0
    xy_m: np.ndarray = const(np.zeros((0, 2), np.float32))
    heading_rad: np.ndarray = const(np.zeros(0, np.float32))
    carrying: np.ndarray = const(np.zeros(0, bool))
    waiting: np.ndarray = const(np.zeros(0, bool))
    segment: np.ndarray = const(np.zeros(0, np.int16))
    length_m: float = 4.0
    width_m: float = 1.0
    radius_m: float = 0.07
    source_m: float = 0.5
    nest_m: float = 0.5
    zones_m: list[float] = []
    zone_width_m: float = 0.3
    gate_width_m: float = -1.0        # < 0: no wall at the zones
    gate_y_m: float = 0.5
    cache: list[int] = []             # items in each zone's cache (transfer "cache")


class SwarmMetrics(Message, tag="swarm.SwarmMetrics"):
    """The swarm's score so far: food delivered, individual efficiency F/N and where the time went."""

    t_s: float = 0.0
    n_robots: int = 0
    food: int = 0
    efficiency: float = 0.0           # food / n_robots
    handovers: int = 0
    contact_frac: float = 0.0         # robot-time spent in contact (bouncing) / total robot-time
    waiting_frac: float = 0.0         # robot-time spent waiting at exchange zones / total robot-time
    done: bool = False                # t_s reached the node's duration_s: the world no longer moves
