"""Collision guard (layer 3): pass velocity commands through, but stop when anything is within 1 m.

It sits between a planner's ``cmd`` and the robot and overrides whatever the planners
say: when the nearest obstacle point (from the depth image and/or 3D points, robot
frame, horizontal distance from the robot centre, floor and ceiling excluded) is closer
than ``stop_distance_m``, forward motion is zeroed (turning in place stays allowed unless
``allow_turn_in_place`` is false). It releases only after ``release_s`` of continuous
clearance (a person inside the camera's minimum range shows as a depth hole, not as a
near point, so a single clear frame is not trusted). A depth frame with almost no valid
pixels counts as blind and stops the robot; so do a silent sensor (``sensor_timeout_s``)
and a silent planner (``cmd_timeout_s``, checked on a timer).
"""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.geometry import Twist2D
from msgs.nav import FlowPoints, PlanStatus
from msgs.sensor import RgbdFrame
from nodes.nav.dwa_core import depth_to_robot
from tether import Node


def nearest_obstacle_m(points_m: np.ndarray, *, z_min_m: float = 0.1, z_max_m: float = 2.0) -> float:
    """Horizontal distance (m) from the robot centre to the nearest point with z in [z_min, z_max]; inf if none."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] >= z_min_m) & (p[:, 2] <= z_max_m)]
    return float(np.hypot(p[:, 0], p[:, 1]).min()) if len(p) else float("inf")


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    stop_distance_m: float = 1.0
    release_s: float = 0.5
    allow_turn_in_place: bool = True
    camera_x_m: float = 0.3
    camera_y_m: float = 0.0
    camera_z_m: float = 1.0
    stride_px: int = 4
    z_min_m: float = 0.1
    z_max_m: float = 2.0
    min_valid_fraction: float = 0.02
    sensor_timeout_s: float = 0.5
    cmd_timeout_s: float = 0.5
    watchdog_hz: float = 10.0


class CollisionGuard(Node):
    """Inputs ``cmd`` (planner), ``rgbd`` and/or ``points`` (robot-frame FlowPoints); outputs ``cmd``, ``status``."""

    Config = Config
    inputs = {"cmd": Twist2D, "rgbd": RgbdFrame, "points": FlowPoints}
    outputs = {"cmd": Twist2D, "status": PlanStatus}
    timers = {"tick": "watchdog_hz"}

    def setup(self) -> None:
        self.nearest_m = float("inf")
        self.blocked_reason = "no sensor data yet"
        self._clear_since_ns: int | None = None
        self._sensor_ns: int | None = None
        self._cmd_ns: int | None = None
        self._last = Twist2D()
        self._sent_zero = False
        self.stops = 0

    # -- sensing ------------------------------------------------------------------------------
    def _update(self, nearest: float, blind: bool, stamp_ns: int) -> list[tuple[str, object]]:
        now = self.now_ns()
        self._sensor_ns = now
        self.nearest_m = nearest
        was = bool(self.blocked_reason)
        if blind or nearest < self.config.stop_distance_m:
            self.blocked_reason = "depth blind" if blind else f"obstacle at {nearest:.2f} m"
            self._clear_since_ns = None
        else:
            self._clear_since_ns = self._clear_since_ns if self._clear_since_ns is not None else now
            if (now - self._clear_since_ns) * 1e-9 >= self.config.release_s or self.blocked_reason == "no sensor data yet":
                self.blocked_reason = ""
        if self.blocked_reason and not was:
            self.stops += 1
            self.log.info("stop: %s", self.blocked_reason)
            return self._emit(self._last, stamp_ns)
        return []

    def on_rgbd(self, msg: RgbdFrame) -> list[tuple[str, object]]:
        i = msg.info
        depth = np.asarray(msg.depth_m)
        if depth.ndim != 2 or i.fx_px <= 0 or i.fy_px <= 0:
            self.log.error("RGB-D frame without depth or intrinsics: treated as blind")
            return self._update(float("inf"), True, msg.stamp_ns)
        c = self.config
        pts, valid = depth_to_robot(depth, i.fx_px, i.fy_px, i.cx_px, i.cy_px, stride=max(1, c.stride_px),
                                    mount_xyz_m=(c.camera_x_m, c.camera_y_m, c.camera_z_m))
        nearest = nearest_obstacle_m(pts, z_min_m=c.z_min_m, z_max_m=c.z_max_m)
        return self._update(nearest, valid < c.min_valid_fraction, msg.stamp_ns)

    def on_points(self, msg: FlowPoints) -> list[tuple[str, object]]:
        nearest = nearest_obstacle_m(np.asarray(msg.points_m), z_min_m=self.config.z_min_m, z_max_m=self.config.z_max_m)
        return self._update(nearest, False, msg.stamp_ns)

    # -- commands -----------------------------------------------------------------------------
    def _stale(self, since_ns: int | None, timeout_s: float) -> bool:
        return since_ns is None or (self.now_ns() - since_ns) * 1e-9 > timeout_s

    def _emit(self, cmd: Twist2D, stamp_ns: int) -> list[tuple[str, object]]:
        reason = self.blocked_reason
        if not reason and self._stale(self._sensor_ns, self.config.sensor_timeout_s):
            reason = "sensor silent"
        v, w = cmd.vx_mps, cmd.wz_radps
        if not (np.isfinite(v) and np.isfinite(w)):
            reason, v, w = "non-finite command", 0.0, 0.0
        out: list[tuple[str, object]] = []
        if reason:
            v = 0.0
            w = w if self.config.allow_turn_in_place and reason.startswith("obstacle") else 0.0
            out.append(("status", PlanStatus(stamp_ns=stamp_ns, state="stopped", reason=reason)))
        self._sent_zero = v == 0.0 and w == 0.0
        out.append(("cmd", Twist2D(stamp_ns=stamp_ns, frame_id=cmd.frame_id or "base", vx_mps=float(v), wz_radps=float(w))))
        return out

    def on_cmd(self, msg: Twist2D) -> list[tuple[str, object]]:
        self._cmd_ns = self.now_ns()
        self._last = msg
        return self._emit(msg, msg.stamp_ns)

    def on_tick(self, msg: object) -> list[tuple[str, object]] | None:
        if self._cmd_ns is not None and self._stale(self._cmd_ns, self.config.cmd_timeout_s) and not self._sent_zero:
            self._last = Twist2D()
            out = self._emit(self._last, self.now_ns())
            return [("status", PlanStatus(stamp_ns=self.now_ns(), state="stopped", reason="planner silent"))] + out
        return None

    def teardown(self) -> None:
        self.log.info("collision guard: %d stops, nearest obstacle last seen at %.2f m", self.stops, self.nearest_m)
