"""UAV homing viewer: the path over the map (truth, INS, fixes) and the errors over time, as a PNG."""
from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from msgs.uav import GeoFix, UavState
from nodes.vision.draw import draw_homing
from nodes.vision.geomap import load_map
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/uav_homing.png"
    map: str = "procedural"
    map_seed: int = 0
    target_e_m: float = 0.0
    target_n_m: float = 0.0
    rate_hz: float = 0.5


class UavView(Node):
    """Inputs ``truth``, ``ins``, ``fix``; writes ``path``; logs the final distance to the target."""

    Config = Config
    inputs = {"truth": UavState, "ins": UavState, "fix": GeoFix}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.gm = load_map(c.map, c.map_seed)
        self.truth: list[tuple[int, float, float]] = []
        self.ins: list[tuple[int, float, float]] = []
        self.fixes: list[tuple[int, bool, float, float]] = []

    def on_truth(self, m: UavState) -> None:
        self.truth.append((m.stamp_ns, m.e_m, m.n_m))

    def on_ins(self, m: UavState) -> None:
        self.ins.append((m.stamp_ns, m.e_m, m.n_m))

    def on_fix(self, m: GeoFix) -> None:
        self.fixes.append((m.stamp_ns, m.ok, m.e_m, m.n_m))

    def on_draw(self, tick: Any) -> None:
        if self.truth:
            self.write()

    def teardown(self) -> None:
        if self.truth:
            self.write()
            t = self.truth[-1]
            self.log.info("uav view: final distance to the target %.2f m", math.hypot(t[1] - self.config.target_e_m,
                                                                                     t[2] - self.config.target_n_m))

    def write(self) -> None:
        c = self.config
        draw_homing(c.path, self.gm, truth=np.array(self.truth), ins=np.array(self.ins).reshape(-1, 3),
                    fixes=np.array(self.fixes, float).reshape(-1, 4), target=(c.target_e_m, c.target_n_m))
