"""CiA 402 drives over CANopen (the ``canopen`` package on any python-can interface).

:class:`Cia402Master` brings each drive up (NMT reset communication, boot-up, device
type check, heartbeat producer / consumer, PDO mapping by SDO, mode, ramps, NMT start)
in a background thread, then runs the power state machine cyclically over RPDO1
(controlword + target) from TPDO1 (statusword, mode display) and TPDO2 (position,
velocity). Wheels run in profile velocity, steering in profile position.

Safety: the master quick-stops **every** drive when commands go stale (watchdog), a
heartbeat is lost, a drive reboots, an EMCY arrives or a drive faults in service; those
latch until :meth:`Cia402Master.reset`. Faults already present at start are reset (rising
edge of controlword bit 7) a bounded number of times. The master also produces its own
heartbeat *from the cyclic step*, and each drive is told to consume it, so a stalled or
killed master makes the drives fault and stop by themselves.

:class:`Cia402Bus` is the node: input ``cmd`` (control.WheelCommand), outputs ``drives``
(can.DriveState), ``frames`` (can.CanFrame, both directions) and ``measured``.
"""
from __future__ import annotations

import collections
import logging
import math
import struct
import threading
import time
from typing import Callable

import can
import canopen
import msgspec

from drivers import cia402 as p
from drivers.can_bus import EchoFilterBus, frame_from_message, open_bus
from msgs.can import CanFrame, DriveState
from msgs.control import WheelCommand
from msgs.std import Empty
from nodes.control.can_axles import AxleDrive, command_from_actuals, setpoints_from_command
from tether import DriverError, Input, Node

log = logging.getLogger(__name__)

WHEEL_COUNTS_PER_M = 4096 * 10 / (2 * math.pi * 0.1)     # 4096-count encoder, 10:1 gear, 0.1 m wheel
STEER_COUNTS_PER_RAD = 4096 * 50 / (2 * math.pi)          # 4096-count encoder, 50:1 gear


class DriveConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """One drive on the bus: wheels run profile velocity, steer motors profile position."""

    node_id: int
    name: str
    role: str = "wheel"              # 'wheel' or 'steer'
    axle: str = "front"              # 'front' or 'rear'
    counts_per_unit: float = WHEEL_COUNTS_PER_M   # counts per m (wheel) or per rad (steer)
    eds: str = ""                    # EDS / DCF of this drive ('' = the bus-wide one, if any)

    def axle_drive(self) -> AxleDrive:
        return AxleDrive(self.name, self.role, self.axle, self.counts_per_unit)


DEFAULT_DRIVES = [
    DriveConfig(node_id=1, name="front_wheel", role="wheel", axle="front"),
    DriveConfig(node_id=2, name="front_steer", role="steer", axle="front", counts_per_unit=STEER_COUNTS_PER_RAD),
    DriveConfig(node_id=3, name="rear_wheel", role="wheel", axle="rear"),
    DriveConfig(node_id=4, name="rear_steer", role="steer", axle="rear", counts_per_unit=STEER_COUNTS_PER_RAD),
]


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    interface: str = "udp_multicast"     # any python-can interface: socketcan, pcan, kvaser, slcan, virtual
    channel: str = "239.74.163.2"        # can0, PCAN_USBBUS1, /dev/ttyACM0, or the multicast group
    bitrate: int = 500_000
    port: int = 43113                    # udp_multicast only
    drives: list[DriveConfig] = msgspec.field(default_factory=lambda: list(DEFAULT_DRIVES))
    rate_hz: float = 100.0               # cyclic set-points, state machine, watchdog
    state_hz: float = 20.0               # DriveState publishing
    cmd_timeout_s: float = 0.25          # watchdog: quick stop when commands are older
    heartbeat_ms: int = 100              # producer heartbeat asked of each drive
    heartbeat_loss_factor: float = 3.0   # lost after factor x heartbeat_ms
    master_node_id: int = 127            # our own heartbeat (0: none); drives consume it
    master_heartbeat_ms: int = 100       # drives fault after factor x this without it
    tpdo_event_ms: int = 10              # TPDO event timer
    sync_hz: float = 0.0                 # > 0: produce SYNC and use synchronous TPDOs
    sdo_timeout_s: float = 0.3
    boot_timeout_s: float = 1.0
    retry_s: float = 1.0                 # bring-up retry of a missing drive
    reset_comm: bool = True              # NMT reset communication before configuring
    max_fault_resets: int = 3            # for faults present before a drive was ever enabled
    wheel_accel_mps2: float = 3.0
    quick_stop_decel_mps2: float = 6.0
    steer_speed_radps: float = 4.0
    steer_accel_radps2: float = 40.0
    steer_quick_stop_radps2: float = 80.0
    steer_limit_rad: float = 2.5             # fold commands beyond this (turn the wheel half a turn, reverse)
    publish_frames: bool = True
    eds: str = ""                        # EDS / DCF for every drive: checked before use, sizes SDO reads


#: (index, bits, PDO-mapped) a drive of each role must have; ramps are optional.
REQUIRED_OBJECTS = {
    "wheel": ((p.CONTROLWORD, 16, True), (p.STATUSWORD, 16, True), (p.MODES_OF_OPERATION, 8, False),
              (p.MODES_DISPLAY, 8, True), (p.POSITION_ACTUAL, 32, True), (p.VELOCITY_ACTUAL, 32, True),
              (p.TARGET_VELOCITY, 32, True)),
    "steer": ((p.CONTROLWORD, 16, True), (p.STATUSWORD, 16, True), (p.MODES_OF_OPERATION, 8, False),
              (p.MODES_DISPLAY, 8, True), (p.POSITION_ACTUAL, 32, True), (p.VELOCITY_ACTUAL, 32, True),
              (p.TARGET_POSITION, 32, True)),
}
OPTIONAL_OBJECTS = {"wheel": (p.PROFILE_ACCEL, p.PROFILE_DECEL, p.QUICK_STOP_DECEL),
                    "steer": (p.PROFILE_VELOCITY, p.PROFILE_ACCEL, p.PROFILE_DECEL, p.QUICK_STOP_DECEL)}


def check_object_dictionary(od: canopen.ObjectDictionary, role: str) -> tuple[list[str], set[int]]:
    """What rules a drive with this object dictionary out of ``role``, and which optional
    (ramp) objects it lacks (those are then not written)."""
    problems = []
    for index, bits, mapped in REQUIRED_OBJECTS[role]:
        var = od.get_variable(index, 0)
        if var is None:
            problems.append(f"0x{index:04X} missing")
        elif len(var) != bits:
            problems.append(f"0x{index:04X} is {len(var)} bits, expected {bits}")
        elif mapped and not var.pdo_mappable:
            problems.append(f"0x{index:04X} is not PDO-mappable")
    return problems, {i for i in OPTIONAL_OBJECTS[role] if od.get_variable(i, 0) is None}


class _Drive:
    """What the master knows about one drive (written by bus callbacks, read by the step)."""

    def __init__(self, spec: DriveConfig, node: canopen.RemoteNode) -> None:
        self.spec, self.node = spec, node
        self.booted = threading.Event()
        self.configured = False
        self.statusword, self.state, self.mode = 0, "", 0
        self.position: int | None = None
        self.velocity = 0
        self.last_hb: float | None = None
        self.nmt_state = "MISSING"
        self.cw_prev = 0
        self.target = 0                  # counts/s or counts
        self.latched_target: int | None = None
        self.was_enabled = False
        self.fault_resets = 0
        self.emcy_code = 0
        self.fault = ""
        self.next_try = 0.0

    @property
    def name(self) -> str:
        return self.spec.name

    def set_statusword(self, sw: int) -> None:
        self.statusword, self.state = sw, p.decode_state(sw)
        if self.state == p.OPERATION_ENABLED:
            self.was_enabled = True


class Cia402Master:
    """CANopen master for a set of CiA 402 drives on one bus (no tether dependency)."""

    def __init__(self, bus: can.BusABC, cfg: Config, *, on_trip: Callable[[str], None] | None = None) -> None:
        _check(cfg)
        self.cfg = cfg
        self.bus = bus
        self.network = canopen.Network(bus)
        self.drives: dict[str, _Drive] = {}
        self.latched = ""                # why every drive is held in quick stop ('' = not)
        self.errors = 0
        self._on_trip = on_trip
        self._stop = threading.Event()
        self._next_master_hb = 0.0
        self._thread: threading.Thread | None = None
        self._skip: dict[str, set[int]] = {}
        for spec in cfg.drives:
            od = canopen.ObjectDictionary()
            if spec.eds or cfg.eds:
                od = canopen.import_od(spec.eds or cfg.eds, node_id=spec.node_id)
                problems, self._skip[spec.name] = check_object_dictionary(od, spec.role)
                if problems:
                    raise ValueError(f"drive {spec.name!r}: {spec.eds or cfg.eds} cannot serve as a {spec.role} "
                                     f"drive: {'; '.join(problems)}")
            node = canopen.RemoteNode(spec.node_id, od)
            node.sdo.RESPONSE_TIMEOUT = cfg.sdo_timeout_s
            self.network.add_node(node)
            d = _Drive(spec, node)
            self.drives[spec.name] = d
            n = spec.node_id
            self.network.unsubscribe(p.EMCY + n)                      # ours decodes short frames too
            self.network.subscribe(p.EMCY + n, self._emcy_cb(d))
            self.network.subscribe(p.TPDO_BASE[0] + n, self._tpdo1_cb(d))
            self.network.subscribe(p.TPDO_BASE[1] + n, self._tpdo2_cb(d))
            node.nmt.add_heartbeat_callback(self._hb_cb(d))

    # -- bus callbacks (notifier thread) ---------------------------------------------
    def _hb_cb(self, d: _Drive) -> Callable[[int], None]:
        def cb(state: int) -> None:
            d.last_hb = time.monotonic()
            d.nmt_state = p.NMT_STATES.get(state, f"0x{state:02X}")
            if state == 0:
                d.booted.set()
                if d.configured:       # rebooted in service: it lost its configuration
                    d.configured = False
                    self.trip(f"{d.name} rebooted")
        return cb

    def _emcy_cb(self, d: _Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            try:
                e = p.parse_emcy(data)
            except ValueError as exc:
                self.errors += 1
                log.error("%s: %s", d.name, exc)
                return
            if e.is_reset:
                d.emcy_code, d.fault = 0, ""
                return
            d.emcy_code, d.fault = e.code, f"EMCY 0x{e.code:04X} {e.text}"
            log.warning("%s: %s (register 0x%02X)", d.name, d.fault, e.register)
            if d.configured and d.was_enabled:
                self.trip(f"{d.name}: {d.fault}")
        return cb

    def _tpdo1_cb(self, d: _Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            if len(data) < 2:
                self.errors += 1
                return
            was_enabled = d.was_enabled
            d.set_statusword(struct.unpack_from("<H", data)[0])
            d.mode = struct.unpack_from("<b", data, 2)[0] if len(data) >= 3 else d.mode
            if d.state in (p.FAULT, p.FAULT_REACTION_ACTIVE) and was_enabled and d.configured:
                self.trip(f"{d.name} faulted in service (statusword 0x{d.statusword:04X})")
        return cb

    def _tpdo2_cb(self, d: _Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            if len(data) < 8:
                self.errors += 1
                return
            raw_pos, d.velocity = struct.unpack_from("<ii", data)
            d.position = p.unwrap_int32(d.position, raw_pos)
        return cb

    # -- bring-up ----------------------------------------------------------------------
    def start(self) -> None:
        """Connect and start bringing drives up in the background."""
        self.network.connect()
        if self.cfg.sync_hz > 0:
            self.network.sync.start(1.0 / self.cfg.sync_hz)
        self._thread = threading.Thread(target=self._bring_up_loop, name="cia402-bring-up", daemon=True)
        self._thread.start()

    def _bring_up_loop(self) -> None:
        while not self._stop.is_set():
            for d in self.drives.values():
                if d.configured or time.monotonic() < d.next_try or self._stop.is_set():
                    continue
                try:
                    self.bring_up(d)
                except (DriverError, canopen.SdoAbortedError, canopen.SdoCommunicationError, can.CanError) as exc:
                    d.next_try = time.monotonic() + self.cfg.retry_s
                    log.error("%s (node %d): bring-up failed: %s; retrying in %.1f s",
                              d.name, d.spec.node_id, exc, self.cfg.retry_s)
                except Exception:  # noqa: BLE001 - the bring-up thread must outlive any surprise
                    d.next_try = time.monotonic() + self.cfg.retry_s
                    log.exception("%s (node %d): bring-up failed unexpectedly", d.name, d.spec.node_id)
            self._stop.wait(0.02)

    def _read(self, d: _Drive, index: int, sub: int, size: int, signed: bool = False) -> int:
        try:
            data = d.node.sdo.upload(index, sub)
        except canopen.SdoAbortedError as exc:
            raise DriverError(f"read 0x{index:04X}:{sub:02X} aborted: 0x{exc.code:08X} "
                              f"{p.SDO_ABORT_CODES.get(exc.code, '')}") from None
        except canopen.SdoCommunicationError as exc:
            raise DriverError(f"read 0x{index:04X}:{sub:02X}: {exc}") from None
        if len(data) < size:
            raise DriverError(f"read 0x{index:04X}:{sub:02X}: {len(data)} bytes, expected {size}")
        return int.from_bytes(data[:size], "little", signed=signed)   # the indicated size, no junk

    def _write(self, d: _Drive, index: int, sub: int, value: int, size: int) -> None:
        raw = (value & ((1 << 8 * size) - 1)).to_bytes(size, "little")
        try:
            d.node.sdo.download(index, sub, raw)
        except canopen.SdoAbortedError as exc:
            raise DriverError(f"write 0x{index:04X}:{sub:02X} = {value} aborted: 0x{exc.code:08X} "
                              f"{p.SDO_ABORT_CODES.get(exc.code, '')}") from None
        except canopen.SdoCommunicationError as exc:
            raise DriverError(f"write 0x{index:04X}:{sub:02X}: {exc}") from None

    def _map_pdo(self, d: _Drive, comm: int, cob: int, entries: list[tuple[int, int, int]],
                 trans: int, event_ms: int = 0) -> None:
        """CiA 301 mapping procedure: disable, clear, write entries, set count, enable."""
        self._write(d, comm, 1, cob | 0x80000000, 4)
        self._write(d, comm, 2, trans, 1)
        if comm >= 0x1800 and trans >= 0xFE:
            self._write(d, comm, 5, event_ms, 2)
        mapping = comm + 0x200
        self._write(d, mapping, 0, 0, 1)
        for i, (index, sub, bits) in enumerate(entries, start=1):
            self._write(d, mapping, i, p.pdo_mapping_entry(index, sub, bits), 4)
        self._write(d, mapping, 0, len(entries), 1)
        if entries:
            self._write(d, comm, 1, cob, 4)

    def bring_up(self, d: _Drive) -> None:
        """Configure one drive and start it (raises DriverError with the step that failed)."""
        cfg, n, wheel = self.cfg, d.spec.node_id, d.spec.role == "wheel"
        if cfg.reset_comm:
            d.booted.clear()
            self.network.send_message(p.NMT, bytes([p.NMT_RESET_COMM, n]))
            if not d.booted.wait(cfg.boot_timeout_s):
                raise DriverError(f"no boot-up (0x{p.HEARTBEAT + n:03X}#00) within {cfg.boot_timeout_s} s "
                                  "of NMT reset communication: is the drive powered and the node id right?")
        device = self._read(d, 0x1000, 0, 4)
        if device & 0xFFFF != 402:
            raise DriverError(f"device type 0x{device:08X} is not a CiA 402 drive (low 16 bits must be 0x0192)")
        self._write(d, 0x1017, 0, cfg.heartbeat_ms, 2)
        if cfg.master_node_id:
            consumer_ms = int(cfg.master_heartbeat_ms * cfg.heartbeat_loss_factor)
            try:
                self._write(d, 0x1016, 1, cfg.master_node_id << 16 | consumer_ms, 4)
            except DriverError as exc:   # optional object: the master watchdog still protects
                log.warning("%s: no heartbeat consumer (%s)", d.name, exc)
        target = (p.TARGET_VELOCITY if wheel else p.TARGET_POSITION, 0, 32)
        trans = 1 if cfg.sync_hz > 0 else 0xFF
        self._map_pdo(d, 0x1400, p.RPDO_BASE[0] + n, [(p.CONTROLWORD, 0, 16), target], 0xFF)
        self._map_pdo(d, 0x1800, p.TPDO_BASE[0] + n, [(p.STATUSWORD, 0, 16), (p.MODES_DISPLAY, 0, 8)],
                      trans, cfg.tpdo_event_ms)
        self._map_pdo(d, 0x1801, p.TPDO_BASE[1] + n, [(p.POSITION_ACTUAL, 0, 32), (p.VELOCITY_ACTUAL, 0, 32)],
                      trans, cfg.tpdo_event_ms)
        for comm, base in ((0x1401, p.RPDO_BASE[1]), (0x1402, p.RPDO_BASE[2]), (0x1403, p.RPDO_BASE[3]),
                           (0x1802, p.TPDO_BASE[2]), (0x1803, p.TPDO_BASE[3])):
            self._write(d, comm, 1, base + n | 0x80000000, 4)
        mode = p.MODE_PV if wheel else p.MODE_PP
        self._write(d, p.MODES_OF_OPERATION, 0, mode, 1)
        for _ in range(20):
            if self._read(d, p.MODES_DISPLAY, 0, 1, signed=True) == mode:
                break
            time.sleep(0.01)
        else:
            raise DriverError(f"mode display 0x6061 never showed mode {mode}")
        k = abs(d.spec.counts_per_unit)
        if wheel:
            ramps = {p.PROFILE_ACCEL: cfg.wheel_accel_mps2, p.PROFILE_DECEL: cfg.wheel_accel_mps2,
                     p.QUICK_STOP_DECEL: cfg.quick_stop_decel_mps2}
        else:
            ramps = {p.PROFILE_VELOCITY: cfg.steer_speed_radps, p.PROFILE_ACCEL: cfg.steer_accel_radps2,
                     p.PROFILE_DECEL: cfg.steer_accel_radps2, p.QUICK_STOP_DECEL: cfg.steer_quick_stop_radps2}
        for index, value in ramps.items():
            if index not in self._skip.get(d.name, ()):
                self._write(d, index, 0, int(round(value * k)), 4)
        d.position = p.unwrap_int32(None, self._read(d, p.POSITION_ACTUAL, 0, 4, signed=True))
        # A safe set-point before anything can enable: stand still / stay where you are.
        d.target = 0 if wheel else int(d.position)
        self._write(d, p.TARGET_VELOCITY if wheel else p.TARGET_POSITION, 0, d.target, 4)
        d.latched_target = None
        d.set_statusword(self._read(d, p.STATUSWORD, 0, 2))
        d.was_enabled = False
        d.fault_resets = 0
        if d.state == p.FAULT:
            d.fault = d.fault or f"fault at start, error code 0x{self._read(d, p.ERROR_CODE, 0, 2):04X}"
            log.warning("%s: %s (statusword 0x%04X); will reset it", d.name, d.fault, d.statusword)
        self.network.send_message(p.NMT, bytes([p.NMT_START, n]))
        d.nmt_state = "OPERATIONAL"
        d.last_hb = d.last_hb or time.monotonic()      # the heartbeat clock starts now at the latest
        d.configured = True
        log.info("%s (node %d) up: statusword 0x%04X %s", d.name, n, d.statusword, d.state)

    # -- cyclic ------------------------------------------------------------------------
    def trip(self, reason: str) -> None:
        """Hold every drive in quick stop until :meth:`reset`."""
        if not self.latched:
            self.latched = reason
            log.error("quick stop of all drives: %s", reason)
            if self._on_trip is not None:
                self._on_trip(reason)

    def reset(self) -> None:
        """Clear the latch; faulted drives get fault resets again."""
        if self.latched:
            log.warning("reset after: %s", self.latched)
        self.latched = ""
        for d in self.drives.values():
            d.fault_resets = 0
            d.was_enabled = False
            if d.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE):
                d.fault, d.emcy_code = "", 0

    def ready(self) -> bool:
        return all(d.configured for d in self.drives.values())

    def step(self, now_s: float, setpoints: dict[str, int] | None) -> None:
        """One cycle: master heartbeat, heartbeat check, controlword + target per drive.

        ``setpoints`` (counts/s for wheels, counts for steering) is None when commands
        are stale or absent; the drives are then quick-stopped.
        """
        cfg = self.cfg
        if cfg.master_node_id and now_s >= self._next_master_hb:
            self._next_master_hb = now_s + cfg.master_heartbeat_ms / 1000.0
            self._send(p.HEARTBEAT + cfg.master_node_id, b"\x05")
        lost_after = cfg.heartbeat_ms * cfg.heartbeat_loss_factor / 1000.0
        for d in self.drives.values():
            if d.configured and d.last_hb is not None and time.monotonic() - d.last_hb > lost_after:
                d.nmt_state = "LOST"
                self.trip(f"heartbeat of {d.name} lost")
        faulted = any(d.state in (p.FAULT, p.FAULT_REACTION_ACTIVE) for d in self.drives.values())
        run = setpoints is not None and not self.latched and self.ready() and not faulted
        for d in self.drives.values():
            if d.configured:
                self._command(d, setpoints if run else None)

    def _command(self, d: _Drive, setpoints: dict[str, int] | None) -> None:
        wheel = d.spec.role == "wheel"
        if setpoints is not None:
            target_state = p.OPERATION_ENABLED
        elif d.state == p.FAULT and not d.was_enabled and d.fault_resets < self.cfg.max_fault_resets:
            target_state = p.SWITCH_ON_DISABLED          # reset a fault we inherited; never powers up
        else:
            target_state = p.QUICK_STOP_ACTIVE
        cw = p.next_controlword(d.state, target_state, d.cw_prev)
        if cw == p.CW_FAULT_RESET:
            d.fault_resets += 1
            if d.fault_resets == self.cfg.max_fault_resets:
                log.error("%s: fault persists after %d resets", d.name, d.fault_resets)
        enabled = d.state == p.OPERATION_ENABLED and setpoints is not None
        if wheel:
            d.target = setpoints[d.name] if enabled and setpoints is not None else 0
            self._rpdo(d, cw, d.target)
            return
        if setpoints is not None:
            d.target = setpoints[d.name]
        if not enabled:
            d.latched_target = None
            self._rpdo(d, cw, d.target)
        elif d.latched_target != d.target:
            # Profile position: a rising edge of bit 4 latches 0x607A; bit 5 replaces the running move.
            self._rpdo(d, cw | p.CW_NEW_SET_POINT | p.CW_CHANGE_IMMEDIATELY, d.target)
            self._rpdo(d, cw | p.CW_CHANGE_IMMEDIATELY, d.target)
            d.latched_target = d.target
        else:
            self._rpdo(d, cw | p.CW_CHANGE_IMMEDIATELY, d.target)

    def _rpdo(self, d: _Drive, cw: int, target: int) -> None:
        d.cw_prev = cw
        target = max(-2**31, min(2**31 - 1, int(target)))
        self._send(p.RPDO_BASE[0] + d.spec.node_id, struct.pack("<Hi", cw, target))

    def _send(self, can_id: int, data: bytes) -> None:
        try:
            self.network.send_message(can_id, data)
        except can.CanError as exc:
            self.errors += 1
            log.error("CAN send 0x%03X failed: %s", can_id, exc)

    def close(self) -> None:
        """Quick-stop enabled drives, stop threads, release the bus (safe to call twice)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.network.bus is None:
            return
        for d in self.drives.values():
            if d.configured and d.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE):
                self._rpdo(d, p.CW_QUICK_STOP, 0 if d.spec.role == "wheel" else d.target)
        try:
            self.network.sync.stop()
        except Exception:  # noqa: BLE001 - stopping a never-started SYNC is fine
            pass
        self.network.disconnect()


def _check(cfg: Config) -> None:
    names, ids = [d.name for d in cfg.drives], [d.node_id for d in cfg.drives]
    if len(set(names)) != len(names) or len(set(ids)) != len(ids):
        raise ValueError(f"drive names and node ids must be unique, got {names} / {ids}")
    for d in cfg.drives:
        d.axle_drive()                               # validates role / axle / scale
        if not 1 <= d.node_id <= 127 or d.node_id == cfg.master_node_id:
            raise ValueError(f"drive {d.name!r}: node id must be 1..127 and differ from master_node_id")
    if cfg.rate_hz <= 0 or cfg.cmd_timeout_s <= 0 or cfg.heartbeat_ms <= 0:
        raise ValueError("rate_hz, cmd_timeout_s and heartbeat_ms must be > 0")


def bus_options(cfg: Config) -> dict:
    return {"port": cfg.port} if cfg.interface == "udp_multicast" else {}


class Cia402Bus(Node):
    """CANopen CiA 402 driver. Input ``cmd`` (per-axle wheel command), ``reset`` (clear a
    latched quick stop); outputs ``drives`` (one DriveState per drive at ``state_hz``),
    ``frames`` (every frame on the bus, rx and tx) and ``measured`` (achieved per-axle
    speeds and steer angles)."""

    Config = Config
    inputs = {"cmd": Input(WheelCommand, latest=True), "reset": Empty}
    outputs = {"drives": DriveState, "frames": CanFrame, "measured": WheelCommand}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        cfg: Config = self.config  # type: ignore[assignment]
        self._axles = [d.axle_drive() for d in cfg.drives]
        self._setpoints: dict[str, int] | None = None
        self._cmd_ns: int | None = None
        self._bad_cmds = 0
        self._next_state_ns = 0
        self._frames: collections.deque[CanFrame] = collections.deque(maxlen=20_000)
        self._bus: EchoFilterBus = open_bus(cfg.interface, cfg.channel, cfg.bitrate, **bus_options(cfg))
        if cfg.publish_frames:
            self._bus.tx_listeners.append(lambda m: self._frames.append(
                frame_from_message(m, stamp_ns=time.time_ns(), channel=cfg.channel, is_rx=False)))
        self.master = Cia402Master(self._bus, cfg)
        if cfg.publish_frames:
            self.master.network.listeners.append(_Tap(self._frames, cfg.channel))
        self.master.start()

    def on_cmd(self, cmd: WheelCommand) -> None:
        try:
            self._setpoints = setpoints_from_command(cmd.v_front_mps, cmd.delta_front_rad, cmd.v_rear_mps,
                                                     cmd.delta_rear_rad, self._axles,
                                                     steer_limit_rad=self.config.steer_limit_rad)
        except ValueError as exc:                    # NaN / inf: not a command; the watchdog runs on
            self._bad_cmds += 1
            self.log.error("ignored wheel command (%d so far): %s", self._bad_cmds, exc)
            return
        self._cmd_ns = self.now_ns()

    def on_reset(self, msg: Empty) -> None:
        self.master.reset()

    def on_tick(self, tick: object) -> list[tuple[str, object]]:
        now = self.now_ns()
        fresh = self._cmd_ns is not None and now - self._cmd_ns <= self.config.cmd_timeout_s * 1e9
        if not fresh and self._setpoints is not None and self.master.ready() and not self.master.latched:
            self.log.warning("no wheel command for %.2f s: quick stop", self.config.cmd_timeout_s)
            self._setpoints = None
        self.master.step(time.monotonic(), self._setpoints if fresh else None)
        out: list[tuple[str, object]] = []
        while self._frames:
            out.append(("frames", self._frames.popleft()))
        if now >= self._next_state_ns:
            self._next_state_ns = now + int(1e9 / self.config.state_hz)
            out.extend(("drives", s) for s in self.drive_states(now))
            out.append(("measured", self.measured(now)))
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
        if self.master.errors or self._bad_cmds or self._bus.recv_errors:
            self.log.warning("CAN errors: %d bus callbacks, %d bad commands, %d undecodable frames",
                             self.master.errors, self._bad_cmds, self._bus.recv_errors)


class _Tap(can.Listener):
    """Queue every received frame for publishing (runs on the notifier thread)."""

    def __init__(self, sink: collections.deque, channel: str) -> None:
        self._sink, self._channel = sink, channel

    def on_message_received(self, msg: can.Message) -> None:
        self._sink.append(frame_from_message(msg, stamp_ns=time.time_ns(), channel=self._channel, is_rx=True))
