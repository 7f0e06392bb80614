"""UAV homing law (seed 11 section 2.2): drive the registration to the identity -- the offset b to
zero and the scale alpha to one (the altitude to the reference's) and the yaw to the target's --
with a rate limit on the velocity; hold position when a fix is rejected; fly on the INS toward
the target (search mode) until the map is recognised.

Pure (numpy only): :func:`servo` is the proportional law, :class:`Homing` the modes around it.
The node is nodes/control/uav_servo.py; bench/uav_register.py flies the same :class:`Homing`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Gains", "Homing", "servo"]


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


@dataclass
class Homing:
    """The modes around :func:`servo`; times in seconds on any one clock.

    Estimate: the last accepted fix moved by what the INS measured since. *search* (no fix
    younger than ``fix_timeout_s``): fly on the INS toward the target at search speed;
    *localise*: servo on the estimate, hover within ``arrive_m`` and 5 degrees; *hold* (the
    fix after an accepted one was rejected): zero velocity for ``hold_s``."""

    target: tuple[float, float, float, float]
    gains: Gains = Gains()
    hold_s: float = 2.0
    fix_timeout_s: float = 3.0
    arrive_m: float = 0.3
    mode: str = "search"
    fix_en: np.ndarray | None = None
    fix_t: float = -math.inf
    fix_ins: np.ndarray | None = None
    rejected_t: float | None = None
    prev: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def on_fix(self, ok: bool, t: float, en: tuple[float, float], ins_en: tuple[float, float] | None) -> None:
        if ok:
            self.fix_en, self.fix_t, self.rejected_t = np.array(en, float), t, None
            self.fix_ins = None if ins_en is None else np.array(ins_en, float)
        elif self.fix_en is not None and self.rejected_t is None:
            self.rejected_t = t

    def command(self, t: float, ins: tuple[float, float, float, float], dt: float) -> np.ndarray:
        """[forward, right, yaw_rate, climb] at time t from the INS (e, n, yaw, alt); sets ``mode``."""
        fresh = self.fix_en is not None and self.fix_ins is not None and t - self.fix_t <= self.fix_timeout_s
        holding = self.rejected_t is not None and t - self.rejected_t <= self.hold_s
        if fresh and holding:
            self.mode, cmd = "hold", np.zeros(4)
        elif fresh:
            est = (*(self.fix_en + np.array(ins[:2]) - self.fix_ins), ins[2], ins[3])
            self.mode, cmd = "localise", servo(est, self.target, self.gains)
            if math.hypot(self.target[0] - est[0], self.target[1] - est[1]) < self.arrive_m and \
                    abs(math.remainder(self.target[2] - est[2], 2 * math.pi)) < math.radians(5):
                cmd[:2] = 0.0
        else:
            self.mode, cmd = "search", servo(ins, self.target, self.gains, speed=self.gains.search_speed_mps)
        step = self.gains.accel_mps2 * dt
        cmd[:2] = self.prev[:2] + np.clip(cmd[:2] - self.prev[:2], -step, step)
        self.prev = cmd
        return cmd
