"""Gestures to velocity commands with a dead man's rule (seed 13: gestures as a controller).

A gesture maps to a body velocity (forward m/s, yaw rate rad/s); the command holds only while
a confident hand was seen within ``deadman_s``: otherwise (no hand, low confidence, an
unmapped gesture, a stalled camera or recogniser) the command is zero.

    law = GestureDrive({"point": (0.5, 0.0), "fist": (0.0, 0.0)}, deadman_s=0.3)
    law.observe("point", 0.9, t_s=10.0)
    law.command(t_s=10.1)      # (0.5, 0.0, "point")
    law.command(t_s=10.4)      # (0.0, 0.0, "dead man: no confident hand for 0.40 s")
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

__all__ = ["DEFAULT_MAP", "GestureDrive"]

# point: forward; victory: forward turning left; L: forward turning right; thumb: turn left on
# the spot; four: reverse; open palm and fist: stop.
DEFAULT_MAP: dict[str, tuple[float, float]] = {
    "point": (0.5, 0.0), "victory": (0.4, 0.5), "L": (0.4, -0.5), "thumb": (0.0, 0.6),
    "four": (-0.2, 0.0), "open": (0.0, 0.0), "fist": (0.0, 0.0)}


@dataclass
class GestureDrive:
    """The mapping (gesture -> (v_mps, w_radps)), ``min_confidence`` and ``deadman_s``."""

    mapping: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(DEFAULT_MAP))
    min_confidence: float = 0.6
    deadman_s: float = 0.3
    _gesture: str = "none"
    _t_s: float | None = None

    def __post_init__(self) -> None:
        if not self.deadman_s > 0:
            raise ValueError("deadman_s must be > 0 (seconds without a confident hand before stopping)")

    def observe(self, gesture: str, confidence: float, *, t_s: float) -> bool:
        """A recognised gesture at (image) time ``t_s``; True when it counts (confident and mapped)."""
        ok = gesture in self.mapping and confidence >= self.min_confidence
        if ok and (self._t_s is None or t_s >= self._t_s):
            self._gesture, self._t_s = gesture, t_s
        return ok

    def command(self, *, t_s: float) -> tuple[float, float, str]:
        """(v_mps, w_radps, why) at ``t_s``: the last confident gesture's, or zero after ``deadman_s``."""
        if self._t_s is None:
            return 0.0, 0.0, "dead man: no confident hand yet"
        age = t_s - self._t_s
        if age > self.deadman_s:
            return 0.0, 0.0, f"dead man: no confident hand for {age:.2f} s"
        v, w = self.mapping[self._gesture]
        return float(v), float(w), self._gesture
