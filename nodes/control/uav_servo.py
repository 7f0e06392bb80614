"""UAV servo (seed 11 section 2.2): drive the registration to the identity -- the offset b to
zero and the scale alpha to one (the altitude to the reference's) and the yaw to the target's --
with rate limits; hold position when the fix is rejected; fly on the INS toward the target
(search mode) until the map is recognised.

Pure function :func:`servo` (no tether); node :class:`UavServo`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from msgs.uav import GeoFix, UavCommand, UavState
from tether import Input, Node


@dataclass(frozen=True)
class Gains:
    k_pos: float = 0.4            # 1/s
    k_yaw: float = 0.8            # 1/s
    k_alt: float = 0.5            # 1/s
    speed_mps: float = 5.0
    search_speed_mps: float = 3.0
    yaw_rate_radps: float = math.radians(40)
    climb_mps: float = 1.5
    accel_mps2: float = 2.0       # rate limit on the commanded velocity


def servo(est: tuple[float, float, float, float], target: tuple[float, float, float, float], g: Gains, *,
          speed: float | None = None) -> np.ndarray:
    """Body-frame command [forward, right, yaw_rate, climb] from an estimate (e, n, yaw, alt) and
    a target (e, n, yaw, alt): proportional on each, saturated."""
    e, n, yaw, alt = est
    te, tn, tyaw, talt = target
    d = np.array([te - e, tn - n])
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    right = np.array([math.sin(yaw), -math.cos(yaw)])
    v = g.k_pos * np.array([d @ fwd, d @ right])
    vmax = g.speed_mps if speed is None else speed
    sp = float(np.hypot(*v))
    if sp > vmax:
        v *= vmax / sp
    yr = float(np.clip(g.k_yaw * math.remainder(tyaw - yaw, 2 * math.pi), -g.yaw_rate_radps, g.yaw_rate_radps))
    climb = float(np.clip(g.k_alt * (talt - alt), -g.climb_mps, g.climb_mps))
    return np.array([v[0], v[1], yr, climb])


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    target_e_m: float = 0.0
    target_n_m: float = 0.0
    target_yaw_rad: float = 0.0
    target_alt_m: float = 40.0
    rate_hz: float = 10.0
    hold_s: float = 2.0              # after a rejected fix: hold this long, then search on the INS
    fix_timeout_s: float = 3.0       # a fix older than this is not used
    arrive_m: float = 0.3            # within this (and 5 deg), hover
    k_pos: float = 0.4
    speed_mps: float = 5.0
    search_speed_mps: float = 3.0

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.target_alt_m <= 0:
            raise ValueError("rate_hz and target_alt_m must be positive")


class UavServo(Node):
    """Inputs ``fix`` and ``ins`` (latest); timer ``tick``; output ``command``.

    Estimate: the last accepted fix moved by what the INS measured since (the INS alone drifts).
    Modes: *search* (no usable fix: fly on the INS toward the target), *localise* (servo on the
    estimate), *hold* (the last fix was rejected: zero velocity for ``hold_s``)."""

    Config = Config
    inputs = {"fix": GeoFix, "ins": Input(UavState, depth=1, latest=True)}
    outputs = {"command": UavCommand}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.gains = Gains(k_pos=c.k_pos, speed_mps=c.speed_mps, search_speed_mps=c.search_speed_mps)
        self.ins: UavState | None = None
        self.fix: GeoFix | None = None
        self.fix_ins: np.ndarray | None = None
        self.rejected_ns: int | None = None
        self.prev = np.zeros(4)
        self.mode = "search"
        self.modes = {"search": 0, "localise": 0, "hold": 0}

    def on_ins(self, msg: UavState) -> None:
        self.ins = msg

    def on_fix(self, msg: GeoFix) -> None:
        if msg.ok:
            self.fix, self.rejected_ns = msg, None
            self.fix_ins = None if self.ins is None else np.array([self.ins.e_m, self.ins.n_m])
        elif self.fix is not None and self.rejected_ns is None:
            self.rejected_ns = msg.stamp_ns

    def on_tick(self, tick: Any) -> dict[str, UavCommand] | None:
        if self.ins is None:
            return None
        c, now = self.config, self.now_ns()
        target = (c.target_e_m, c.target_n_m, c.target_yaw_rad, c.target_alt_m)
        fresh = self.fix is not None and now - self.fix.stamp_ns <= c.fix_timeout_s * 1e9 and self.fix_ins is not None
        holding = self.rejected_ns is not None and now - self.rejected_ns <= c.hold_s * 1e9
        if fresh and holding:
            mode, cmd = "hold", np.array([0.0, 0.0, 0.0, 0.0])
        elif fresh:
            moved = np.array([self.ins.e_m, self.ins.n_m]) - self.fix_ins
            est = (self.fix.e_m + moved[0], self.fix.n_m + moved[1], self.ins.yaw_rad, self.ins.alt_m)
            mode, cmd = "localise", servo(est, target, self.gains)
            if math.hypot(target[0] - est[0], target[1] - est[1]) < c.arrive_m and \
                    abs(math.remainder(target[2] - est[2], 2 * math.pi)) < math.radians(5):
                cmd[:2] = 0.0
        else:
            est = (self.ins.e_m, self.ins.n_m, self.ins.yaw_rad, self.ins.alt_m)
            mode, cmd = "search", servo(est, target, self.gains, speed=self.gains.search_speed_mps)
        if mode != self.mode:
            self.log.info("uav servo: %s -> %s", self.mode, mode)
            self.mode = mode
        self.modes[mode] += 1
        step = self.gains.accel_mps2 / c.rate_hz                       # rate limit on the velocity
        cmd[:2] = self.prev[:2] + np.clip(cmd[:2] - self.prev[:2], -step, step)
        self.prev = cmd
        return {"command": UavCommand(stamp_ns=now, forward_mps=float(cmd[0]), right_mps=float(cmd[1]),
                                      yaw_rate_radps=float(cmd[2]), climb_mps=float(cmd[3]))}

    def teardown(self) -> None:
        self.log.info("uav servo: ticks per mode %s", self.modes)
