"""Swarm simulator node: the foraging swarm of :mod:`sim.swarm` stepped on a timer, one world.

Outputs ``state`` (swarm.SwarmState, every tick) and ``metrics`` (swarm.SwarmMetrics, every
simulated second and at the end). Each tick advances the world by ``dt_s``; ``rate_hz``
sets how many ticks run per wall second, so ``rate_hz = 10 * speedup`` for ``dt_s = 0.1``.
At ``duration_s`` (the seed's t_max = 200 s) the world stops and the final metrics go out
with ``done``.
"""
from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from msgs.swarm import SwarmMetrics, SwarmState
from sim.swarm import POLICIES, TRANSFERS, SwarmWorld, seed_scene
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    n_robots: int = 20
    zones: int = 1                    # 0, 1 or 2 exchange zones (the seed's placements)
    transfer: str = "direct"          # direct | cache | p2p (p2p needs zones: 0)
    policy: str = "fixed"             # fixed | adaptive
    theta_s: float = 30.0             # waiting threshold; < 0 means wait forever
    gate_width_m: float = -1.0        # > 0: a wall with a gate this wide at each zone
    cache_capacity: int = 10
    seed: int = 0
    dt_s: float = 0.1
    rate_hz: float = 100.0            # ticks per wall second
    duration_s: float = 200.0

    def __post_init__(self) -> None:
        if not 0 <= self.n_robots <= 1000:
            raise ValueError(f"n_robots must be in [0, 1000], got {self.n_robots}")
        if self.transfer not in TRANSFERS or self.policy not in POLICIES:
            raise ValueError(f"transfer must be one of {TRANSFERS}, policy one of {POLICIES}")
        if self.zones not in (0, 1, 2) or (self.transfer == "p2p" and self.zones):
            raise ValueError(f"zones must be 0, 1 or 2 (0 with transfer p2p), got {self.zones}")
        if not 0 < self.dt_s <= 1 or self.duration_s <= 0:
            raise ValueError("dt_s must be in (0, 1] s and duration_s positive")


class SwarmSim(Node):
    """Foraging swarm: timer ``tick``; outputs ``state`` and ``metrics``."""

    Config = Config
    outputs = {"state": SwarmState, "metrics": SwarmMetrics}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        scene = seed_scene(c.zones, transfer=c.transfer, policy=c.policy, cache_capacity=c.cache_capacity,
                           theta_s=math.inf if c.theta_s < 0 else c.theta_s,
                           gate_width_m=c.gate_width_m if c.gate_width_m > 0 else None)
        self.world = SwarmWorld(scene, c.n_robots, seeds=[c.seed])
        self._next_metrics_s = 1.0
        self._done = False

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        if self._done:
            return []
        c, w = self.config, self.world
        w.step(c.dt_s)
        out: list[tuple[str, Any]] = [("state", self.state())]
        self._done = w.t_s >= c.duration_s - 1e-9
        if self._done or w.t_s >= self._next_metrics_s - 1e-9:
            self._next_metrics_s += 1.0
            out.append(("metrics", self.metrics()))
        if self._done:
            m = out[-1][1]
            self.log.info("swarm of %d after %.0f s: food %d, F/N %.2f, contact %.1f %%, waiting %.1f %%",
                          m.n_robots, m.t_s, m.food, m.efficiency, 100 * m.contact_frac, 100 * m.waiting_frac)
        return out

    def state(self) -> SwarmState:
        w, s = self.world, self.world.scene
        return SwarmState(stamp_ns=self.now_ns(), frame_id="arena", t_s=w.t_s,
                          xy_m=np.stack([w.x[0], w.y[0]], axis=1).astype(np.float32),
                          heading_rad=w.th[0].astype(np.float32), carrying=w.carrying[0].copy(),
                          waiting=w.waiting[0].copy(), segment=w.seg[0].astype(np.int16),
                          length_m=s.length_m, width_m=s.width_m, radius_m=s.radius_m, source_m=s.source_m,
                          nest_m=s.nest_m, zones_m=list(s.zones_m), zone_width_m=s.zone_width_m,
                          gate_width_m=-1.0 if s.gate_width_m is None else s.gate_width_m, gate_y_m=s.gate_y_m,
                          cache=[int(v) for v in w.cache[0]])

    def metrics(self) -> SwarmMetrics:
        w = self.world
        robot_time = max(w.n * w.t_s, 1e-9)
        return SwarmMetrics(stamp_ns=self.now_ns(), frame_id="arena", t_s=w.t_s, n_robots=w.n,
                            food=int(w.food[0]), efficiency=float(w.efficiency()[0]),
                            handovers=int(w.handovers[0]), contact_frac=float(w.contact_s[0].sum() / robot_time),
                            waiting_frac=float(w.wait_s[0].sum() / robot_time), done=self._done)
