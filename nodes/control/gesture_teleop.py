"""Gesture teleoperation node (seed 13): recognised hand gestures -> velocity commands for the
wheelchair (geometry.Twist2D), by :class:`nodes.control.gesture_map.GestureDrive`. Dead man's
rule: no confident hand for ``deadman_s`` (judged by the image's stamp against this node's
clock, so a stalled camera or a dead recogniser stops the robot too) commands zero."""
from __future__ import annotations

from typing import Any

import msgspec

from msgs.geometry import Twist2D
from msgs.hand import HandGesture
from nodes.control.gesture_map import DEFAULT_MAP, GestureDrive
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    mapping: dict[str, list[float]] = msgspec.field(default_factory=lambda: {k: list(v) for k, v in DEFAULT_MAP.items()})
    min_confidence: float = 0.6
    deadman_s: float = 0.3
    rate_hz: float = 20.0

    def __post_init__(self) -> None:
        if any(len(v) != 2 for v in self.mapping.values()):
            raise ValueError("mapping: each gesture maps to [v_mps, w_radps]")
        if self.deadman_s <= 0 or self.rate_hz <= 0:
            raise ValueError("deadman_s and rate_hz must be > 0")


class GestureTeleop(Node):
    """Input ``gesture`` (latest); timer ``tick``; output ``cmd``."""

    Config = Config
    inputs = {"gesture": Input(HandGesture, depth=1, latest=True)}
    outputs = {"cmd": Twist2D}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.law = GestureDrive({k: (v[0], v[1]) for k, v in c.mapping.items()}, min_confidence=c.min_confidence,
                                deadman_s=c.deadman_s)
        self.why = ""
        self.stops = 0

    def on_gesture(self, msg: HandGesture) -> None:
        self.law.observe(msg.gesture if msg.present else "none", msg.confidence, t_s=msg.stamp_ns / 1e9)

    def on_tick(self, tick: Any) -> dict[str, Twist2D]:
        v, w, why = self.law.command(t_s=self.now_ns() / 1e9)
        if why.startswith("dead man") and not self.why.startswith("dead man"):
            self.stops += 1
            self.log.info("gesture teleop: %s: stop", why)
        self.why = why
        return {"cmd": Twist2D(stamp_ns=self.now_ns(), frame_id="base", vx_mps=v, wz_radps=w)}

    def teardown(self) -> None:
        self.log.info("gesture teleop: %d dead-man stops", self.stops)
