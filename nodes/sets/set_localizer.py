"""Set-membership localisation node: bounded odometry and marker ranges -> a guaranteed set per step."""
from __future__ import annotations

import math

import msgspec
import numpy as np

from msgs.sets import BoundedOdometry, MarkerRanges, SetEstimate
from nodes.sets.localize import ENGINES, SetLocalizer, predict
from nodes.sets.obs import observations, step_box
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    markers: list[list[float]] = []   # known marker positions [x, y] (m), indexed by marker_id
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    start_err_m: float = 0.0          # half-width of the start box; inf: unknown start
    eps_m: float = 0.05               # paving resolution
    engine: str = "codac"             # codac | numpy (see nodes.sets.localize)
    max_outliers: int = 1             # on an empty set, retry allowing this many wrong observations

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {self.engine!r}")
        if not self.eps_m > 0 or self.max_outliers < 0 or not self.start_err_m >= 0:
            raise ValueError("eps_m must be positive, max_outliers and start_err_m non-negative")
        if any(len(m) != 2 for m in self.markers):
            raise ValueError("markers are [x, y] pairs")


class SetLocalizerNode(Node):
    """Inputs ``odom`` (a step) and ``ranges`` (closes the step); output ``estimate``."""

    Config = Config
    inputs = {"odom": BoundedOdometry, "ranges": MarkerRanges}
    outputs = {"estimate": SetEstimate}

    def setup(self) -> None:
        c = self.config
        centre = np.asarray(c.start_xy_m, np.float64)
        err = c.start_err_m
        box = np.stack([centre - err, centre + err]) if math.isfinite(err) else np.array([[-np.inf] * 2, [np.inf] * 2])
        self.filter = SetLocalizer(box, eps=c.eps_m, engine=c.engine, max_outliers=c.max_outliers)
        self.markers = {i: (float(m[0]), float(m[1])) for i, m in enumerate(c.markers)}
        self._step: np.ndarray | None = None
        self.unknown_markers = 0

    def on_odom(self, msg: BoundedOdometry) -> None:
        box = step_box(msg)
        self._step = box if self._step is None else predict(self._step, box)

    def on_ranges(self, msg: MarkerRanges) -> dict[str, SetEstimate]:
        obs, unknown = observations(msg, self.markers)
        if unknown:
            self.unknown_markers += len(unknown)
            self.log.warning("step %d: ignored %d measurement(s) of unknown or invalid markers %s",
                             msg.step, len(unknown), unknown)
        r = self.filter.step(self._step, obs)
        self._step = None
        if not r.consistent:
            self.log.warning("step %d: measurements inconsistent with the bounds (%s)", msg.step,
                             f"kept the set allowing {r.outliers_allowed} outlier(s)" if r.outliers_allowed
                             else "no set: published the prediction")
        return {"estimate": SetEstimate(stamp_ns=msg.stamp_ns, frame_id="world", step=msg.step, box=r.box,
                                        inner=r.paving.inner, boundary=r.paving.boundary, width_m=r.width_m,
                                        consistent=r.consistent, outliers_allowed=r.outliers_allowed,
                                        compute_ms=1e3 * r.seconds)}
