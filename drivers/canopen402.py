"""CiA 402 drives over CANopen (the ``canopen`` package on any python-can interface): the node.

:class:`Cia402Bus` wraps :class:`drivers.cia402_master.Cia402Master` (bring-up, power state
machine, watchdog, heartbeats, EMCY; see there) for a pipeline: input ``cmd``
(control.WheelCommand), outputs ``drives`` (can.DriveState), ``frames`` (can.CanFrame, both
directions), ``measured`` (achieved per-axle speeds and steer angles) and ``ready``
(std.Bool: every drive OPERATION ENABLED and nothing latched -- what a trajectory waits for).

The configuration (:class:`Config`, :class:`DriveConfig`, :data:`DEFAULT_DRIVES`) lives in
:mod:`drivers.cia402_config` and the SDO bring-up in :mod:`drivers.cia402_bringup`; they
are re-exported here.
"""
from __future__ import annotations

import collections
import math
from typing import Callable

import can

from drivers import cia402 as p
from drivers.can_bus import EchoFilterBus, frame_from_message, open_bus
from drivers.cia402_config import (DEFAULT_DRIVES, OPTIONAL_OBJECTS, REQUIRED_OBJECTS, STEER_COUNTS_PER_RAD,
                                   WHEEL_COUNTS_PER_M, Config, DriveConfig, bus_options, check_object_dictionary)
from drivers.cia402_master import Cia402Master
from msgs.can import CanFrame, DriveState
from msgs.control import WheelCommand
from msgs.std import Bool, Empty
from nodes.control.can_axles import command_from_actuals, setpoints_from_command
from tether import Input, Node

__all__ = ["Cia402Bus", "Cia402Master", "Config", "DriveConfig", "DEFAULT_DRIVES", "WHEEL_COUNTS_PER_M",
           "STEER_COUNTS_PER_RAD", "REQUIRED_OBJECTS", "OPTIONAL_OBJECTS", "check_object_dictionary", "bus_options"]


class Cia402Bus(Node):
    """CANopen CiA 402 driver. Input ``cmd`` (per-axle wheel command), ``reset`` (clear a
    latched quick stop); outputs ``drives`` (one DriveState per drive at ``state_hz``),
    ``frames`` (every frame on the bus, rx and tx), ``measured`` (achieved per-axle
    speeds and steer angles, at ``measured_hz`` -- the control rate -- or else at ``state_hz``)
    and ``ready`` (at ``state_hz`` and on every change).

    The bus is opened by :meth:`open_bus`; a bus with a true ``synchronous`` attribute (the
    in-process lockstep bus of :mod:`sim.cia402_bank`) gets the bring-up inside the cyclic
    step instead of a thread. Times are the node's clock (virtual under test and lockstep).
    """

    Config = Config
    inputs = {"cmd": Input(WheelCommand, latest=True), "reset": Empty}
    outputs = {"drives": DriveState, "frames": CanFrame, "measured": WheelCommand, "ready": Bool}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        cfg: Config = self.config  # type: ignore[assignment]
        self._axles = [d.axle_drive() for d in cfg.drives]
        self._setpoints: dict[str, int] | None = None
        self._cmd_ns: int | None = None
        self._cmd_stamp_ns = 0
        self._rejected = {"bad": 0, "stale": 0}
        self._clamped = 0
        self._last_reject_log_ns = self._last_clamp_log_ns = 0
        self._next_state_ns = self._next_measured_ns = 0
        self._ready: bool | None = None
        self._frames: collections.deque[CanFrame] = collections.deque(maxlen=20_000)
        self._bus = self.open_bus()
        if cfg.publish_frames:
            self._bus.tx_listeners.append(lambda m: self._frames.append(
                frame_from_message(m, stamp_ns=self.now_ns(), channel=cfg.channel, is_rx=False)))
        self.master = Cia402Master(self._bus, cfg, clock=lambda: self.now_ns() * 1e-9)
        if cfg.publish_frames:
            self.master.network.listeners.append(_Tap(self._frames, cfg.channel, self.now_ns))
        self.master.start()

    def open_bus(self) -> EchoFilterBus:
        """The python-can bus of the configured interface (echo-filtered; see drivers.can_bus)."""
        cfg: Config = self.config  # type: ignore[assignment]
        return open_bus(cfg.interface, cfg.channel, cfg.bitrate, **bus_options(cfg))

    def on_cmd(self, cmd: WheelCommand) -> None:
        cfg: Config = self.config  # type: ignore[assignment]
        now = self.now_ns()
        values = (cmd.v_front_mps, cmd.delta_front_rad, cmd.v_rear_mps, cmd.delta_rear_rad)
        if not all(math.isfinite(v) for v in values):   # NaN / inf: not a command; the watchdog runs on
            self._reject("bad", f"non-finite wheel command {values}")
            return
        if cmd.stamp_ns and abs(now - cmd.stamp_ns) > cfg.cmd_timeout_s * 1e9:
            # Judged by its stamp as well as by arrival: a command delayed or replayed is not one.
            self._reject("stale", f"wheel command stamped {(now - cmd.stamp_ns) * 1e-9:+.3f} s from now")
            return
        vf, df, vr, dr = values
        fastest = max(abs(vf), abs(vr))
        if fastest > cfg.max_speed_mps:
            scale = cfg.max_speed_mps / fastest         # both axles alike: the path's curvature is kept
            vf, vr = vf * scale, vr * scale
            self._clamped += 1
            if self._clamped == 1 or now - self._last_clamp_log_ns > 5e9:
                self._last_clamp_log_ns = now
                self.log.warning("wheel command of %.3g m/s scaled to max_speed_mps %.3g (%d so far)",
                                 fastest, cfg.max_speed_mps, self._clamped)
        self._setpoints = setpoints_from_command(vf, df, vr, dr, self._axles, steer_limit_rad=cfg.steer_limit_rad)
        self._cmd_ns = now
        self._cmd_stamp_ns = cmd.stamp_ns

    def _reject(self, kind: str, why: str) -> None:
        count = self._rejected[kind] = self._rejected[kind] + 1
        now = self.now_ns()
        if count == 1 or now - self._last_reject_log_ns > 5e9:
            self._last_reject_log_ns = now
            self.log.error("ignored wheel command (%d %s so far): %s", count, kind, why)

    def _fresh(self, now: int) -> bool:
        """Commands are fresh by arrival *and* by stamp (0 = unstamped: arrival only)."""
        limit = self.config.cmd_timeout_s * 1e9
        if self._cmd_ns is None or now - self._cmd_ns > limit:
            return False
        return not self._cmd_stamp_ns or abs(now - self._cmd_stamp_ns) <= limit

    def on_reset(self, msg: Empty) -> None:
        self.master.reset()

    def on_tick(self, tick: object) -> list[tuple[str, object]]:
        now = self.now_ns()
        fresh = self._fresh(now)
        if not fresh and self._setpoints is not None and self.master.ready() and not self.master.latched:
            self.log.warning("no fresh wheel command (by arrival and stamp) for %.2f s: quick stop",
                             self.config.cmd_timeout_s)
            self._setpoints = None
        self.master.step(now * 1e-9, self._setpoints if fresh else None)
        out: list[tuple[str, object]] = []
        while self._frames:
            out.append(("frames", self._frames.popleft()))
        ready = self.master.enabled()
        if ready != self._ready:
            self.log.info("drives %s", "all OPERATION ENABLED: ready" if ready else "not ready")
        measured_hz = self.config.measured_hz
        if measured_hz > 0 and now >= self._next_measured_ns:      # at the control rate: what the controller reads
            self._next_measured_ns = max(self._next_measured_ns + int(1e9 / measured_hz),
                                         now + int(0.5e9 / measured_hz))
            out.append(("measured", self.measured(now)))
        if now >= self._next_state_ns:
            self._next_state_ns = now + int(1e9 / self.config.state_hz)
            out.extend(("drives", s) for s in self.drive_states(now))
            if measured_hz <= 0:
                out.append(("measured", self.measured(now)))
            out.append(("ready", Bool(stamp_ns=now, data=ready)))
        elif ready != self._ready:
            out.append(("ready", Bool(stamp_ns=now, data=ready)))
        self._ready = ready
        return out

    def drive_states(self, stamp_ns: int) -> list[DriveState]:
        states = []
        for d in self.master.drives.values():
            k = d.spec.counts_per_unit
            states.append(DriveState(
                stamp_ns=stamp_ns, frame_id=d.name, node_id=d.spec.node_id, name=d.name, statusword=d.statusword,
                state=d.state, mode=d.mode, position=d.position or 0, velocity=d.velocity,
                heartbeat_ok=d.nmt_state not in ("LOST", "MISSING"), emcy_code=d.emcy_code, fault=d.fault,
                role=d.spec.role, nmt_state=d.nmt_state, position_unit=(d.position or 0) / k,
                velocity_unit=d.velocity / k, target_unit=d.target / k,
                quick_stop=bool(self.master.latched) or d.state == p.QUICK_STOP_ACTIVE))
        return states

    def measured(self, stamp_ns: int) -> WheelCommand:
        actuals = {d.name: float(d.velocity if d.spec.role == "wheel" else (d.position or 0))
                   for d in self.master.drives.values() if d.configured}
        vf, df, vr, dr = command_from_actuals(actuals, self._axles)
        return WheelCommand(stamp_ns=stamp_ns, v_front_mps=vf, delta_front_rad=df, v_rear_mps=vr, delta_rear_rad=dr)

    def teardown(self) -> None:
        self.master.close()
        if self.master.errors or any(self._rejected.values()) or self._clamped or self._bus.recv_errors:
            self.log.warning("CAN errors: %d bus callbacks, %d undecodable frames; commands: %d non-finite, "
                             "%d stale, %d scaled to max_speed_mps", self.master.errors, self._bus.recv_errors,
                             self._rejected["bad"], self._rejected["stale"], self._clamped)
        for d in self.master.drives.values():
            if d.emcy_history:
                self.log.info("%s EMCY history: %s", d.name, ", ".join(
                    f"0x{e.code:04X} {e.text} @{e.time_s:.3f}s" for e in d.emcy_history))


class _Tap(can.Listener):
    """Queue every received frame for publishing (runs on the notifier thread)."""

    def __init__(self, sink: collections.deque, channel: str, now_ns: Callable[[], int]) -> None:
        self._sink, self._channel, self._now_ns = sink, channel, now_ns

    def on_message_received(self, msg: can.Message) -> None:
        self._sink.append(frame_from_message(msg, stamp_ns=self._now_ns(), channel=self._channel, is_rx=True))
