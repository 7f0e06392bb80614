"""Swarm viewer node: rewrites a PNG of the arena and the delivery curve while the swarm runs."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import cv2
import msgspec
import numpy as np

from msgs.swarm import SwarmMetrics, SwarmState
from nodes.swarm.view import render_swarm
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/swarm.png"
    rate_hz: float = 1.0              # how often the PNG is rewritten
    px_per_m: float = 200.0


class SwarmView(Node):
    """Inputs ``state`` (latest only) and ``metrics``; writes ``path`` every ``1/rate_hz`` s and at the end."""

    Config = Config
    inputs = {"state": Input(SwarmState, depth=1, latest=True), "metrics": SwarmMetrics}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        self._state: SwarmState | None = None
        self._metrics: SwarmMetrics | None = None
        self._curve: list[tuple[float, float]] = []
        self.written = 0

    def on_state(self, msg: SwarmState) -> None:
        self._state = msg

    def on_metrics(self, msg: SwarmMetrics) -> None:
        self._metrics = msg
        self._curve.append((msg.t_s, float(msg.food)))
        if msg.done:
            self.on_draw(None)

    def on_draw(self, tick: Any) -> None:
        s, m = self._state, self._metrics
        if s is None:
            return
        title = f"t = {s.t_s:.1f} s   N = {len(s.carrying)}"
        if m is not None:
            title += (f"   food {m.food}   F/N {m.efficiency:.2f}   contact {100 * m.contact_frac:.0f} %"
                      f"   waiting {100 * m.waiting_frac:.0f} %")
        img = render_swarm(s.xy_m, s.heading_rad, s.carrying, s.waiting, length_m=s.length_m, width_m=s.width_m,
                           radius_m=s.radius_m, source_m=s.source_m, nest_m=s.nest_m, zones_m=s.zones_m,
                           zone_width_m=s.zone_width_m, gate_width_m=s.gate_width_m, gate_y_m=s.gate_y_m,
                           px_per_m=self.config.px_per_m, title=title,
                           food_curve=np.asarray(self._curve) if len(self._curve) > 1 else None)
        path = Path(self.config.path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp.png")
        cv2.imwrite(str(tmp), img)
        os.replace(tmp, path)            # a viewer never sees a half-written file
        self.written += 1

    def teardown(self) -> None:
        self.on_draw(None)
        if self.written:
            self.log.info("swarm picture: %s", self.config.path)
