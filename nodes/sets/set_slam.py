"""Set-membership SLAM node: bounded odometry and ranges to unknown markers -> the robot
tube and the marker boxes, contracted jointly over the whole history at every step."""
from __future__ import annotations

import time

import msgspec
import numpy as np

from msgs.sets import BoundedOdometry, MarkerRanges, SetMap
from nodes.sets.localize import predict
from nodes.sets.obs import observations, step_box
from nodes.sets.tube import SetSlam
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    n_markers: int = 4                # marker ids 0 .. n_markers - 1
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    start_err_m: float = 0.0
    max_sweeps: int = 50

    def __post_init__(self) -> None:
        if self.n_markers < 1 or self.max_sweeps < 1 or not self.start_err_m >= 0:
            raise ValueError("n_markers and max_sweeps must be >= 1, start_err_m >= 0")


class SetSlamNode(Node):
    """Inputs ``odom`` and ``ranges`` (closes the step); output ``map``."""

    Config = Config
    inputs = {"odom": BoundedOdometry, "ranges": MarkerRanges}
    outputs = {"map": SetMap}

    def setup(self) -> None:
        c = self.config
        centre = np.asarray(c.start_xy_m, np.float64)
        self.slam = SetSlam(np.stack([centre - c.start_err_m, centre + c.start_err_m]), c.n_markers)
        self._step: np.ndarray | None = None
        self._inconsistent_logged = False

    def on_odom(self, msg: BoundedOdometry) -> None:
        box = step_box(msg)
        self._step = box if self._step is None else predict(self._step, box)

    def on_ranges(self, msg: MarkerRanges) -> dict[str, SetMap] | None:
        if self._step is None:
            self.log.warning("step %d: ranges without an odometry step since the last ones; ignored", msg.step)
            return None
        obs, bad = observations(msg, None)
        ids = [int(o.marker[0]) for o in obs]
        bad += [j for j in ids if not 0 <= j < self.config.n_markers]
        if bad:
            self.log.warning("step %d: ignored measurement(s) of markers %s (n_markers %d)", msg.step, bad,
                             self.config.n_markers)
        t0 = time.perf_counter()
        self.slam.add_step(self._step, [(j, *o.range_m) for j, o in zip(ids, obs) if 0 <= j < self.config.n_markers])
        self._step = None
        sweeps = self.slam.contract(max_iter=self.config.max_sweeps)
        s = self.slam
        if not s.consistent and not self._inconsistent_logged:
            self._inconsistent_logged = True
            self.log.warning("step %d: the tube became empty: some measurement broke its bound", msg.step)
        return {"map": SetMap(stamp_ns=msg.stamp_ns, frame_id="world", step=msg.step,
                              tube=np.stack([s.x_lo, s.x_hi], 1), markers=np.stack([s.m_lo, s.m_hi], 1),
                              consistent=s.consistent, sweeps=sweeps, compute_ms=1e3 * (time.perf_counter() - t0))}
