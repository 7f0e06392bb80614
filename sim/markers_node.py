"""Marker-world simulator node: the robot of :mod:`sim.markers` stepped on a timer.

Each tick: ``odom`` (sets.BoundedOdometry: the step just made), ``ranges``
(sets.MarkerRanges: what was measured at the new pose, possibly nothing) and ``truth``
(geometry.Pose2D). After ``steps`` ticks it stops publishing.
"""
from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from msgs.geometry import Pose2D
from msgs.sets import BoundedOdometry, MarkerRanges
from sim.markers import SCENES, Bounds, MarkerWorld
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    scene: str = "seed"
    seed: int = 0
    steps: int = 100                  # the seed's k in 0..100
    rate_hz: float = 20.0
    max_range_m: float = 15.0
    nearest_only: bool = False
    bearings: bool = True             # publish bearings (NaN otherwise)
    outlier_rate: float = 0.0
    range_err_m: float = 0.1
    bearing_err_rad: float = 0.02
    heading_err_rad: float = 0.03

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise ValueError(f"scene must be one of {SCENES}, got {self.scene!r}")
        if self.steps < 1 or self.rate_hz <= 0:
            raise ValueError("steps must be >= 1 and rate_hz positive")
        if not 0 <= self.outlier_rate <= 1:
            raise ValueError(f"outlier_rate must be in [0, 1], got {self.outlier_rate}")


class MarkerSim(Node):
    """Timer ``tick``; outputs ``odom``, ``ranges``, ``truth``."""

    Config = Config
    outputs = {"odom": BoundedOdometry, "ranges": MarkerRanges, "truth": Pose2D}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        bounds = Bounds(heading_rad=c.heading_err_rad, range_m=c.range_err_m, bearing_rad=c.bearing_err_rad)
        self.world = MarkerWorld(c.scene, seed=c.seed, bounds=bounds, max_range_m=c.max_range_m,
                                 nearest_only=c.nearest_only, outlier_rate=c.outlier_rate)
        self.outliers = 0

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        c = self.config
        if self.world.k >= c.steps:
            return []
        s = self.world.step()
        stamp = self.now_ns()
        self.outliers += sum(o.outlier for o in s.observed)
        odom = BoundedOdometry(stamp_ns=stamp, frame_id="world", step=s.k, distance_m=sum(s.distance_m) / 2,
                               distance_err_m=(s.distance_m[1] - s.distance_m[0]) / 2,
                               heading_rad=sum(s.heading_rad) / 2, heading_err_rad=(s.heading_rad[1] - s.heading_rad[0]) / 2)
        n = len(s.observed)
        mid = lambda pair: (pair[0] + pair[1]) / 2          # noqa: E731
        ranges = MarkerRanges(
            stamp_ns=stamp, frame_id="robot", step=s.k,
            marker_id=np.array([o.marker for o in s.observed], np.int32),
            range_m=np.array([mid(o.range_m) for o in s.observed]),
            range_err_m=np.full(n, c.range_err_m),
            bearing_rad=np.array([mid(o.bearing_rad) if c.bearings else math.nan for o in s.observed]),
            bearing_err_rad=np.full(n, c.bearing_err_rad),
            heading_rad=sum(s.compass_rad) / 2, heading_err_rad=(s.compass_rad[1] - s.compass_rad[0]) / 2)
        truth = Pose2D(stamp_ns=stamp, frame_id="world", x_m=float(s.truth_xy[0]), y_m=float(s.truth_xy[1]),
                       yaw_rad=self.world.theta)
        if self.world.k == c.steps:
            self.log.info("marker world: %d steps done, %d outlier ranges injected", c.steps, self.outliers)
        return [("odom", odom), ("ranges", ranges), ("truth", truth)]
