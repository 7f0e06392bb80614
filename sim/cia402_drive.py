"""Simulated CiA 402 drives that answer on a CAN bus as real ones do.

Each :class:`SimDrive` is one motor (a wheel in profile velocity or a steer motor in
profile position) with first-order motor dynamics behind a CiA 301 / 402 protocol stack:
boot-up, heartbeat producer and consumer, an SDO server over an object dictionary
(expedited and segmented upload, abort codes), configurable RPDO / TPDO mapping, the
power state machine with its statusword bits (optionally vendor bits such as the Maxon
EPOS bit 8) and EMCY on faults. Faults are injected through :class:`DriveFaults` and
:meth:`SimDrive.inject_fault`.

:class:`SimDriveBank` runs several drives on one python-can bus in a thread;
:class:`Cia402DriveSim` is the node: it publishes the speeds and steer angles the drives
actually achieve (``achieved``, a ``control.WheelCommand`` for the vehicle simulator).
"""
from __future__ import annotations

import math
import struct
import threading
import time
from dataclasses import dataclass, field

import can
import msgspec

from drivers import cia402 as p
from drivers.can_bus import open_bus
from drivers.canopen402 import DEFAULT_DRIVES, DriveConfig
from msgs.control import WheelCommand
from nodes.control.can_axles import AxleDrive, command_from_actuals
from tether import Node

Frame = tuple[int, bytes]


@dataclass
class DriveFaults:
    """Misbehaviours a real drive shows, switched on per drive."""

    start_in_fault: int = 0                 # error code the drive boots with (statusword 0x0218-like)
    vendor_bits: int = 0                    # OR-ed into the statusword, e.g. 0x0100 (Maxon EPOS)
    sdo_abort: dict[tuple[int, int], int] = field(default_factory=dict)   # (index, sub) -> abort code
    sdo_silent: set[tuple[int, int]] = field(default_factory=set)         # never answered (timeout)
    junk: bytes = b"\0\0\0\0"               # bytes after the indicated size in upload responses
    mute: bool = False                      # transmits nothing (heartbeat loss)
    deaf: bool = False                      # receives nothing (cable cut with mute)
    position_offset: int = 0                # initial position actual, e.g. near 2**31 for wrap tests
    sticky_fault: bool = False              # fault reset does not clear the fault


@dataclass
class _Entry:
    size: int           # bytes; 0 = variable-length string
    value: int | bytes
    writable: bool = True
    signed: bool = False


def _object_dictionary(node_id: int, role: str) -> dict[tuple[int, int], _Entry]:
    od: dict[tuple[int, int], _Entry] = {
        (0x1000, 0): _Entry(4, 0x00020192, False), (0x1001, 0): _Entry(1, 0, False),
        (0x1008, 0): _Entry(0, f"tether sim {role} drive".encode(), False),
        (0x1016, 0): _Entry(1, 1, False), (0x1016, 1): _Entry(4, 0), (0x1017, 0): _Entry(2, 0),
        (0x1018, 0): _Entry(1, 4, False), (0x1018, 1): _Entry(4, 0x555, False), (0x1018, 2): _Entry(4, 0x402, False),
        (0x1018, 3): _Entry(4, 0x00010000, False), (0x1018, 4): _Entry(4, node_id, False),
        (p.ERROR_CODE, 0): _Entry(2, 0, False), (0x605A, 0): _Entry(2, 6, signed=True),
        (p.CONTROLWORD, 0): _Entry(2, 0), (p.STATUSWORD, 0): _Entry(2, 0, False),
        (p.MODES_OF_OPERATION, 0): _Entry(1, 0, signed=True), (p.MODES_DISPLAY, 0): _Entry(1, 0, False, True),
        (p.POSITION_ACTUAL, 0): _Entry(4, 0, False, True), (p.VELOCITY_ACTUAL, 0): _Entry(4, 0, False, True),
        (p.TARGET_POSITION, 0): _Entry(4, 0, signed=True), (p.TARGET_VELOCITY, 0): _Entry(4, 0, signed=True),
        (p.PROFILE_VELOCITY, 0): _Entry(4, 100_000), (p.PROFILE_ACCEL, 0): _Entry(4, 1_000_000),
        (p.PROFILE_DECEL, 0): _Entry(4, 1_000_000), (p.QUICK_STOP_DECEL, 0): _Entry(4, 2_000_000),
        (0x6502, 0): _Entry(4, 0b101, False),
    }
    for i in range(4):
        od[(0x1400 + i, 0)] = _Entry(1, 2, False)
        od[(0x1400 + i, 1)] = _Entry(4, p.RPDO_BASE[i] + node_id | (0 if i == 0 else 0x80000000))
        od[(0x1400 + i, 2)] = _Entry(1, 0xFF)
        od[(0x1800 + i, 0)] = _Entry(1, 6, False)
        od[(0x1800 + i, 1)] = _Entry(4, p.TPDO_BASE[i] + node_id | (0 if i == 0 else 0x80000000))
        for sub, size, value in ((2, 1, 0xFF), (3, 2, 0), (5, 2, 0), (6, 1, 0)):
            od[(0x1800 + i, sub)] = _Entry(size, value)
        for base, first in ((0x1600, 0x60400010), (0x1A00, 0x60410010)):
            od[(base + i, 0)] = _Entry(1, 1 if i == 0 else 0)
            for sub in range(1, 9):
                od[(base + i, sub)] = _Entry(4, first if (i, sub) == (0, 1) else 0)
    return od


class SimDrive:
    """One simulated CiA 402 drive, driven by frames and time (seconds, any origin).

    ``receive`` and ``advance`` return the frames the drive transmits in response.
    Units: counts, counts/s, counts/s^2 (``max_velocity`` clips the set-point).
    """

    def __init__(self, node_id: int, *, role: str = "wheel", time_constant_s: float = 0.02,
                 max_velocity: float = 2_000_000.0, faults: DriveFaults | None = None, now_s: float = 0.0,
                 target_window: int = 50) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"CANopen node id must be 1..127, got {node_id}")
        if time_constant_s <= 0:
            raise ValueError("time_constant_s must be > 0 (first-order motor lag)")
        self.node_id, self.role, self.tau, self.vmax = node_id, role, time_constant_s, max_velocity
        self.faults = faults or DriveFaults()
        self.window = target_window
        self._t = now_s
        self.velocity = 0.0                # counts/s, actual
        self.position = float(self.faults.position_offset)
        self._demand_v = 0.0               # ramped velocity demand
        self.emcy_sent: list[int] = []
        self._boot(now_s)

    # -- state -----------------------------------------------------------------------
    def _boot(self, now_s: float) -> None:
        self.od = _object_dictionary(self.node_id, self.role)
        self.nmt = "PRE-OPERATIONAL"
        self.state = p.SWITCH_ON_DISABLED
        self._cw = 0
        self._setpoint_ack = False
        self._pp_target: float | None = None
        self._hb_next = now_s
        self._master_hb: float | None = None
        self._tpdo_next = [now_s] * 4
        self._last_sw: list[int | None] = [None] * 4
        self._sync_count = [0] * 4
        self._segment: bytes | None = None
        self._out: list[Frame] = [(p.HEARTBEAT + self.node_id, b"\x00")]
        if self.faults.start_in_fault:
            self._enter_fault(self.faults.start_in_fault)
            self.state = p.FAULT

    def _get(self, index: int, sub: int = 0) -> int:
        return int(self.od[(index, sub)].value)  # type: ignore[arg-type]

    def _set(self, index: int, value: int, sub: int = 0) -> None:
        self.od[(index, sub)].value = value

    def statusword(self) -> int:
        sw = p.STATE_BITS[self.state] | 0x0200 | self.faults.vendor_bits          # bit 9 remote
        if self.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE, p.FAULT, p.FAULT_REACTION_ACTIVE):
            sw |= 0x0010                                                          # voltage enabled
        if self.state in (p.READY_TO_SWITCH_ON, p.SWITCHED_ON, p.OPERATION_ENABLED):
            sw |= 0x0020                                                          # quick stop (active low)
        if self.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE) and self._target_reached():
            sw |= 0x0400
        if self.mode == p.MODE_PP and self._setpoint_ack:
            sw |= 0x1000
        return sw

    @property
    def mode(self) -> int:
        return self._get(p.MODES_OF_OPERATION)

    def _target_reached(self) -> bool:
        if self.state != p.OPERATION_ENABLED:
            return abs(self.velocity) < self.window
        if self.mode == p.MODE_PP:
            return self._pp_target is None or (abs(self.position - self._pp_target) < self.window
                                               and abs(self.velocity) < 10 * self.window)
        return abs(self.velocity - self._target_velocity()) < 10 * self.window

    def _target_velocity(self) -> float:
        return max(-self.vmax, min(self.vmax, float(self._get(p.TARGET_VELOCITY))))

    def _emcy(self, code: int, register: int) -> None:
        self.emcy_sent.append(code)
        self._out.append((p.EMCY + self.node_id, p.emcy_frame(code, register)))

    def _enter_fault(self, code: int) -> None:
        self._set(p.ERROR_CODE, code)
        self._set(0x1001, 0x01)
        self.state = p.FAULT_REACTION_ACTIVE
        self._emcy(code, 0x01)

    def reboot(self, now_s: float) -> None:
        """A power glitch: the drive restarts (boot-up, default configuration, motor unpowered)."""
        self._boot(now_s)

    def inject_fault(self, code: int = 0x2310) -> None:
        """A fault from the power stage: fault reaction (quick-stop ramp), EMCY, then FAULT."""
        if self.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE):
            self._enter_fault(code)

    # -- controlword -----------------------------------------------------------------
    def _apply_controlword(self, cw: int) -> None:
        prev, self._cw = self._cw, cw
        s = self.state
        if s == p.FAULT:
            if cw & 0x80 and not prev & 0x80 and not self.faults.sticky_fault:
                self._set(p.ERROR_CODE, 0)
                self._set(0x1001, 0)
                self._emcy(0x0000, 0)
                self.state = p.SWITCH_ON_DISABLED
            return
        if s in (p.FAULT_REACTION_ACTIVE, p.NOT_READY):
            return
        disable_voltage = not cw & 0x02
        quick_stop = cw & 0x06 == 0x02
        if s == p.SWITCH_ON_DISABLED:
            if cw & 0x87 == 0x06:
                self.state = p.READY_TO_SWITCH_ON
        elif s == p.QUICK_STOP_ACTIVE:
            if disable_voltage:
                self.state = p.SWITCH_ON_DISABLED
            elif cw & 0x8F == 0x0F:
                self.state = p.OPERATION_ENABLED          # transition 16
        elif disable_voltage or (quick_stop and s != p.OPERATION_ENABLED):
            self.state = p.SWITCH_ON_DISABLED
        elif quick_stop:
            self.state = p.QUICK_STOP_ACTIVE
        elif cw & 0x87 == 0x06:
            self.state = p.READY_TO_SWITCH_ON
        elif cw & 0x8F == 0x07:
            self.state = p.SWITCHED_ON
        elif cw & 0x8F == 0x0F and s in (p.SWITCHED_ON, p.OPERATION_ENABLED):
            if s == p.SWITCHED_ON:
                self._pp_target = None                    # no stale move on enable
            self.state = p.OPERATION_ENABLED
        if self.state == p.OPERATION_ENABLED and self.mode == p.MODE_PP:
            if cw & p.CW_NEW_SET_POINT and not prev & p.CW_NEW_SET_POINT:
                self._pp_target = float(self._get(p.TARGET_POSITION))
                self._setpoint_ack = True
            elif not cw & p.CW_NEW_SET_POINT:
                self._setpoint_ack = False

    # -- frames in -------------------------------------------------------------------
    def receive(self, arbitration_id: int, data: bytes, now_s: float) -> list[Frame]:
        """Handle one frame seen on the bus; return the frames sent in reply."""
        if self.faults.deaf:
            return []
        self._update(now_s)
        data = bytes(data)
        fn = arbitration_id & 0x780
        if arbitration_id == p.NMT and len(data) >= 2 and data[1] in (0, self.node_id):
            self._nmt(data[0], now_s)
        elif arbitration_id == p.SYNC:
            self._on_sync()
        elif arbitration_id == p.SDO_RX + self.node_id and self.nmt != "STOPPED":
            self._sdo(data)
        elif fn == p.HEARTBEAT and self._get(0x1016, 1) >> 16 & 0x7F == arbitration_id & 0x7F:
            self._master_hb = now_s
        elif self.nmt == "OPERATIONAL":
            for i in range(4):
                cob = self._get(0x1400 + i, 1)
                if not cob & 0x80000000 and arbitration_id == cob & 0x7FF:
                    self._write_mapped(0x1600 + i, data)
        return self._flush()

    def _nmt(self, cs: int, now_s: float) -> None:
        if cs in (p.NMT_RESET_NODE, p.NMT_RESET_COMM):
            keep = {k: e.value for k, e in self.od.items() if k[0] >= 0x2000} if cs == p.NMT_RESET_COMM else {}
            state, fault = self.state, self._get(p.ERROR_CODE)
            self._boot(now_s)
            for k, v in keep.items():
                self.od[k].value = v
            if cs == p.NMT_RESET_COMM:
                self.state = state if state != p.FAULT_REACTION_ACTIVE else p.FAULT
                self._set(p.ERROR_CODE, fault)
            return
        new = {p.NMT_START: "OPERATIONAL", p.NMT_STOP: "STOPPED", p.NMT_PRE_OPERATIONAL: "PRE-OPERATIONAL"}.get(cs)
        if new is None:
            return
        if self.nmt == "OPERATIONAL" and new != "OPERATIONAL" and self.state == p.OPERATION_ENABLED:
            self.state = p.QUICK_STOP_ACTIVE          # 0x6007 abort connection: quick stop
        self.nmt = new

    def _write_mapped(self, map_index: int, data: bytes) -> None:
        offset = 0
        for sub in range(1, self._get(map_index, 0) + 1):
            entry = self._get(map_index, sub)
            index, subindex, nbytes = entry >> 16, entry >> 8 & 0xFF, (entry & 0xFF) // 8
            if offset + nbytes > len(data):
                return                                 # short RPDO: ignore (a real drive sends EMCY 0x8210)
            obj = self.od.get((index, subindex))
            if obj is not None:
                obj.value = int.from_bytes(data[offset:offset + nbytes], "little", signed=obj.signed)
                if index == p.CONTROLWORD:
                    self._apply_controlword(int(obj.value))
            offset += nbytes

    def _sdo(self, req: bytes) -> None:
        if len(req) < 8:
            return
        cmd, index, sub = req[0], *struct.unpack_from("<HB", req, 1)
        key, cob = (index, sub), p.SDO_TX + self.node_id
        if key in self.faults.sdo_silent or cmd == 0x80:     # never answer an abort
            return
        if cmd >> 5 == 3 and self._segment is not None:        # upload segment request
            chunk, rest = self._segment[:7], self._segment[7:]
            self._segment = rest or None
            last = int(not rest)
            self._out.append((cob, bytes([cmd & 0x10 | (7 - len(chunk)) << 1 | last]) + chunk.ljust(7, b"\0")))
            return
        code = self.faults.sdo_abort.get(key)
        entry = self.od.get(key)
        if code is None and entry is None:
            code = 0x06090011 if any(k[0] == index for k in self.od) else 0x06020000
        if code is None and cmd == 0x40:
            assert entry is not None
            if entry.size == 0:
                self._segment = bytes(entry.value)  # type: ignore[arg-type]
                self._out.append((cob, struct.pack("<BHBI", 0x41, index, sub, len(self._segment))))
                return
            value = self.statusword() if key == (p.STATUSWORD, 0) else int(entry.value)  # type: ignore[arg-type]
            raw = (value & (1 << 8 * entry.size) - 1).to_bytes(entry.size, "little")
            resp = struct.pack("<BHB", 0x43 | (4 - entry.size) << 2, index, sub) + raw
            self._out.append((cob, (resp + self.faults.junk)[:8].ljust(8, b"\0")))
            return
        if code is None and cmd >> 5 == 1 and cmd & 0x02:
            assert entry is not None
            size = 4 - (cmd >> 2 & 0x3) if cmd & 0x01 else entry.size
            if not entry.writable:
                code = 0x06010002
            elif size != entry.size:
                code = 0x06070010
            elif key == (p.MODES_OF_OPERATION, 0) and req[4] not in (p.MODE_PP, p.MODE_PV):
                code = 0x06090030
            else:
                entry.value = int.from_bytes(req[4:4 + size], "little", signed=entry.signed)
                if key == (p.CONTROLWORD, 0):
                    self._apply_controlword(int(entry.value))
                self._out.append((cob, struct.pack("<BHB4x", 0x60, index, sub)))
                return
        self._out.append((cob, p.sdo_abort(index, sub, code if code is not None else 0x05040001)))

    # -- time ------------------------------------------------------------------------
    def advance(self, now_s: float) -> list[Frame]:
        """Integrate the motor up to ``now_s`` and emit due heartbeats / TPDOs."""
        self._update(now_s)
        return self._flush()

    def _update(self, now_s: float) -> None:
        dt = now_s - self._t
        if dt > 0:
            self._t = now_s
            self._integrate(dt)
        self._set(p.MODES_DISPLAY, self.mode)
        self._set(p.STATUSWORD, self.statusword())
        self._set(p.POSITION_ACTUAL, (int(round(self.position)) + 2**31) % 2**32 - 2**31)
        self._set(p.VELOCITY_ACTUAL, int(round(self.velocity)))
        period = self._get(0x1017) / 1000.0
        if period > 0 and now_s >= self._hb_next:
            self._hb_next = now_s + period
            self._out.append((p.HEARTBEAT + self.node_id, bytes([{"OPERATIONAL": 5, "STOPPED": 4}.get(self.nmt, 0x7F)])))
        consumer = self._get(0x1016, 1)
        if consumer & 0xFFFF and self._master_hb is not None and now_s - self._master_hb > (consumer & 0xFFFF) / 1000:
            self._master_hb = None
            if self.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE):
                self._enter_fault(0x8130)             # master lost: stop on the fault ramp
        if self.nmt == "OPERATIONAL":
            for i in range(4):
                if self._get(0x1800 + i, 2) >= 0xFE and not self._get(0x1800 + i, 1) & 0x80000000:
                    timer = self._get(0x1800 + i, 5) / 1000.0
                    sw_changed = self._last_sw[i] != self._get(p.STATUSWORD)
                    if (timer > 0 and now_s >= self._tpdo_next[i]) or sw_changed:
                        self._tpdo_next[i] = now_s + timer
                        self._send_tpdo(i)

    def _on_sync(self) -> None:
        if self.nmt != "OPERATIONAL":
            return
        for i in range(4):
            n = self._get(0x1800 + i, 2)
            if 1 <= n <= 240 and not self._get(0x1800 + i, 1) & 0x80000000:
                self._sync_count[i] += 1
                if self._sync_count[i] % n == 0:
                    self._send_tpdo(i)

    def _send_tpdo(self, i: int) -> None:
        data = b""
        for sub in range(1, self._get(0x1A00 + i, 0) + 1):
            entry = self._get(0x1A00 + i, sub)
            obj = self.od.get((entry >> 16, entry >> 8 & 0xFF))
            nbytes = (entry & 0xFF) // 8
            value = int(obj.value) if obj is not None else 0  # type: ignore[arg-type]
            data += (value & (1 << 8 * nbytes) - 1).to_bytes(nbytes, "little")
        self._last_sw[i] = self._get(p.STATUSWORD)
        self._out.append((self._get(0x1800 + i, 1) & 0x7FF, data[:8]))

    def _integrate(self, dt: float) -> None:
        s = self.state
        if s == p.OPERATION_ENABLED and self.mode == p.MODE_PV and not self._cw & p.CW_HALT:
            goal, accel = self._target_velocity(), float(self._get(p.PROFILE_ACCEL))
            if abs(goal) < abs(self._demand_v) or goal * self._demand_v < 0:
                accel = float(self._get(p.PROFILE_DECEL))
        elif s == p.OPERATION_ENABLED and self.mode == p.MODE_PP and self._pp_target is not None:
            error = self._pp_target - self.position
            vprof, accel = float(self._get(p.PROFILE_VELOCITY)), float(self._get(p.PROFILE_ACCEL))
            # Brake in time: v^2 = 2 a d, and never faster than the profile velocity.
            goal = math.copysign(min(vprof, math.sqrt(2 * accel * abs(error)), abs(error) / self.tau), error)
        else:                                         # quick stop, fault reaction, disabled, halt
            goal, accel = 0.0, float(self._get(p.QUICK_STOP_DECEL))
        step = accel * dt
        self._demand_v += max(-step, min(step, goal - self._demand_v))
        alpha = 1.0 - math.exp(-dt / self.tau)
        self.velocity += alpha * (self._demand_v - self.velocity)
        self.position += self.velocity * dt
        if s != p.OPERATION_ENABLED and self._demand_v == 0.0 and abs(self.velocity) < 0.5:
            self.velocity = 0.0                       # at rest (below half a count per second)
            if s == p.FAULT_REACTION_ACTIVE:
                self.state = p.FAULT

    def _flush(self) -> list[Frame]:
        out, self._out = self._out, []
        return [] if self.faults.mute else out


class SimDriveBank:
    """Several :class:`SimDrive` on one python-can bus, served by a thread (or by :meth:`poll`).

    Hold :attr:`lock` while touching a drive from another thread (fault injection).
    """

    def __init__(self, bus: can.BusABC, drives: dict[str, SimDrive], *, step_s: float = 0.001) -> None:
        self.bus, self.drives, self.step_s = bus, drives, step_s
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_step = 0.0
        self.send_errors = 0

    def _send(self, frames: list[Frame]) -> None:
        for arb, data in frames:
            try:
                self.bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
            except can.CanError:
                self.send_errors += 1

    def poll(self, duration_s: float) -> None:
        """Serve the bus for ``duration_s`` seconds (frames answered as they come)."""
        end = time.monotonic() + duration_s
        while True:
            now = time.monotonic()
            if now >= self._next_step:
                self._next_step = now + self.step_s
                with self.lock:
                    for drive in self.drives.values():
                        self._send(drive.advance(now))
            if now >= end:
                return
            msg = self.bus.recv(max(0.0, min(self._next_step, end) - now))
            if msg is not None and not msg.is_error_frame and not msg.is_remote_frame:
                now = time.monotonic()
                with self.lock:
                    for drive in self.drives.values():
                        self._send(drive.receive(msg.arbitration_id, bytes(msg.data), now))

    def start(self) -> "SimDriveBank":
        self._thread = threading.Thread(target=self._run, name="sim-cia402", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            self.poll(0.05)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def actuals(self) -> dict[str, float]:
        """Velocity (counts/s) of wheel drives and position (counts) of steer drives."""
        with self.lock:
            return {name: d.velocity if d.role == "wheel" else d.position for name, d in self.drives.items()}


class SimDriveConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Per-drive simulation knobs (faults by name, see :class:`DriveFaults`)."""

    time_constant_s: float = 0.02
    start_in_fault: int = 0
    vendor_bits: int = 0
    junk_hex: str = "00000000"
    position_offset: int = 0
    sdo_abort: dict[str, int] = {}        # "0x1017:0" -> abort code
    sdo_silent: list[str] = []            # "0x1017:0"


def _object_key(text: str) -> tuple[int, int]:
    index, _, sub = text.partition(":")
    return int(index, 0), int(sub or "0", 0)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    interface: str = "udp_multicast"
    channel: str = "239.74.163.2"
    bitrate: int = 500_000
    port: int = 43113
    drives: list[DriveConfig] = msgspec.field(default_factory=lambda: list(DEFAULT_DRIVES))
    sim: dict[str, SimDriveConfig] = {}   # drive name -> knobs
    time_constant_s: float = 0.02         # default first-order motor lag
    step_s: float = 0.001
    publish_hz: float = 100.0


def make_drive(spec: DriveConfig, knobs: SimDriveConfig | None, now_s: float, time_constant_s: float = 0.02
               ) -> SimDrive:
    k = knobs or SimDriveConfig(time_constant_s=time_constant_s)
    faults = DriveFaults(start_in_fault=k.start_in_fault, vendor_bits=k.vendor_bits, junk=bytes.fromhex(k.junk_hex),
                         position_offset=k.position_offset,
                         sdo_abort={_object_key(key): code for key, code in k.sdo_abort.items()},
                         sdo_silent={_object_key(key) for key in k.sdo_silent})
    return SimDrive(spec.node_id, role=spec.role, time_constant_s=k.time_constant_s, faults=faults, now_s=now_s)


class Cia402DriveSim(Node):
    """Simulated drives on a CAN bus. Output ``achieved``: the per-axle wheel speeds and
    steer angles the motors actually reach (for ``sim.vehicle4ws``)."""

    Config = Config
    outputs = {"achieved": WheelCommand}

    def setup(self) -> None:
        cfg: Config = self.config  # type: ignore[assignment]
        self._axles: list[AxleDrive] = [d.axle_drive() for d in cfg.drives]
        now = time.monotonic()
        drives = {d.name: make_drive(d, cfg.sim.get(d.name), now, cfg.time_constant_s) for d in cfg.drives}
        self._bus = open_bus(cfg.interface, cfg.channel, cfg.bitrate, **({"port": cfg.port}
                                                                         if cfg.interface == "udp_multicast" else {}))
        self.bank = SimDriveBank(self._bus, drives, step_s=cfg.step_s)

    def achieved(self) -> WheelCommand:
        counts = {name: (v if name in self.bank.drives else 0.0) for name, v in self.bank.actuals().items()}
        vf, df, vr, dr = command_from_actuals(counts, self._axles)
        return WheelCommand(v_front_mps=vf, delta_front_rad=df, v_rear_mps=vr, delta_rear_rad=dr)

    def run(self) -> None:
        period = 1.0 / self.config.publish_hz
        while not self.stopping.is_set():
            self.bank.poll(period)
            self.publish("achieved", self.achieved())

    def teardown(self) -> None:
        self._bus.shutdown()
