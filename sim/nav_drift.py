"""Dead-reckoning navigation error: the true pose, offset by a bias and a seeded random walk.

A localisation demo needs a navigation pose that is wrong in the ways a real one is
(a DVL/INS drifts in x, y and heading; depth and attitude are measured directly), so
that ICP has something to correct. The drift is applied in the world frame:
``nav = D(t) @ truth`` with ``D`` a rotation about the vertical by ``yaw(t)`` followed by
a translation ``(x(t), y(t))``; the ideal correction is ``D(t)^-1``.
"""
from __future__ import annotations

import math

import msgspec
import numpy as np

from msgs.geometry import Pose3D
from tether import Input, Node


def drift_matrix(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """4x4 world-frame drift: rotate about z by ``yaw_rad``, then translate by (x, y)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:2, 3] = (x_m, y_m)
    return out


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    bias_x_m: float = 0.4
    bias_y_m: float = -0.3
    bias_yaw_deg: float = 3.0
    walk_m_per_sqrt_s: float = 0.01      # random-walk growth of the position error
    walk_deg_per_sqrt_s: float = 0.05
    seed: int = 0


class DriftingNav(Node):
    """Input ``truth`` (Pose3D); output ``pose`` (the drifted navigation pose, same stamp)."""

    Config = Config
    inputs = {"truth": Input(Pose3D, depth=64)}
    outputs = {"pose": Pose3D, "drift": Pose3D}

    def setup(self) -> None:
        self._rng = np.random.default_rng(self.config.seed)
        self._walk = np.zeros(3)
        self._last_ns: int | None = None

    def on_truth(self, truth: Pose3D) -> dict[str, Pose3D]:
        if self._last_ns is not None and truth.stamp_ns > self._last_ns:
            dt = (truth.stamp_ns - self._last_ns) / 1e9
            sig = np.array([self.config.walk_m_per_sqrt_s] * 2 + [math.radians(self.config.walk_deg_per_sqrt_s)])
            self._walk += self._rng.normal(0.0, 1.0, 3) * sig * math.sqrt(dt)
        self._last_ns = truth.stamp_ns
        d = drift_matrix(self.config.bias_x_m + self._walk[0], self.config.bias_y_m + self._walk[1],
                         math.radians(self.config.bias_yaw_deg) + self._walk[2])
        header = {"stamp_ns": truth.stamp_ns, "frame_id": truth.frame_id}
        return {"pose": Pose3D.from_matrix(d @ truth.matrix(), **header), "drift": Pose3D.from_matrix(d, **header)}
