"""UAV servo node (seed 11): geo fixes and the INS -> velocity commands, by the homing law of
:mod:`nodes.control.uav_homing` (servo on the fix, hold on a rejected fix, search on the INS)."""
from __future__ import annotations

from typing import Any

import msgspec

from msgs.uav import GeoFix, UavCommand, UavState
from nodes.control.uav_homing import Gains, Homing
from tether import Input, Node


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
    """Inputs ``fix`` and ``ins`` (latest); timer ``tick``; output ``command``. A fix's age is
    taken from its stamp (the frame's time), against this node's clock."""

    Config = Config
    inputs = {"fix": GeoFix, "ins": Input(UavState, depth=1, latest=True)}
    outputs = {"command": UavCommand}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.homing = Homing((c.target_e_m, c.target_n_m, c.target_yaw_rad, c.target_alt_m),
                             Gains(k_pos=c.k_pos, speed_mps=c.speed_mps, search_speed_mps=c.search_speed_mps),
                             hold_s=c.hold_s, fix_timeout_s=c.fix_timeout_s, arrive_m=c.arrive_m)
        self.ins: UavState | None = None
        self.modes = {"search": 0, "localise": 0, "hold": 0}

    @property
    def mode(self) -> str:
        return self.homing.mode

    def on_ins(self, msg: UavState) -> None:
        self.ins = msg

    def on_fix(self, msg: GeoFix) -> None:
        ins_en = None if self.ins is None else (self.ins.e_m, self.ins.n_m)
        self.homing.on_fix(msg.ok, msg.stamp_ns / 1e9, (msg.e_m, msg.n_m), ins_en)

    def on_tick(self, tick: Any) -> dict[str, UavCommand] | None:
        if self.ins is None:
            return None
        now = self.now_ns()
        before = self.homing.mode
        i = self.ins
        cmd = self.homing.command(now / 1e9, (i.e_m, i.n_m, i.yaw_rad, i.alt_m), 1.0 / self.config.rate_hz)
        if self.homing.mode != before:
            self.log.info("uav servo: %s -> %s", before, self.homing.mode)
        self.modes[self.homing.mode] += 1
        return {"command": UavCommand(stamp_ns=now, forward_mps=float(cmd[0]), right_mps=float(cmd[1]),
                                      yaw_rate_radps=float(cmd[2]), climb_mps=float(cmd[3]))}

    def teardown(self) -> None:
        self.log.info("uav servo: ticks per mode %s", self.modes)
