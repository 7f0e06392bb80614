"""Bring-up of one CiA 402 drive by SDO: what the master knows about a drive, checked SDO
reads / writes (to the indicated size only; byte strings of any length through the
``canopen`` SDO client's segmented transfer), the CiA 301 PDO mapping procedure, and the
configuration sequence (device type and name, heartbeats, SYNC period, PDOs, mode or homing,
ramps, safe set-point, NMT start).
"""
from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass

import canopen

from drivers import cia402 as p
from drivers.cia402_config import STEER_MODES, WHEEL_MODES, Config, DriveConfig
from tether import DriverError

log = logging.getLogger("drivers.canopen402")


EMCY_HISTORY = 32


@dataclass(frozen=True)
class EmcyRecord:
    """One emergency message as received: when (master clock, s), code, error register, text."""

    time_s: float
    code: int
    register: int
    text: str


class Drive:
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
        self.last_feedback: float | None = None     # clock of the last statusword / position PDO
        self.emcy_history: collections.deque[EmcyRecord] = collections.deque(maxlen=EMCY_HISTORY)
        self.error_code: int | None = None          # 0x603F, read after an in-service fault
        self.read_error_code = False
        self.last_fault_reset = -math.inf
        self.op_mode = 0                 # the operating mode (PV / PP / CSV / CSP) once homed
        self.homing = ""                 # '' (none or done), 'pending', 'running', 'switch' (homed: set op_mode)
        self.homing_since = 0.0
        self.device_name = ""            # 0x1008, read by a segmented upload

    @property
    def cyclic(self) -> bool:
        """Set-points act at SYNC (CSP / CSV)."""
        return self.op_mode in (p.MODE_CSP, p.MODE_CSV)

    @property
    def name(self) -> str:
        return self.spec.name

    def set_statusword(self, sw: int) -> None:
        self.statusword, self.state = sw, p.decode_state(sw)
        if self.state == p.OPERATION_ENABLED:
            self.was_enabled = True


def sdo_read(d: Drive, index: int, sub: int, size: int, signed: bool = False) -> int:
    """Upload an object and keep its first ``size`` bytes (junk after the indicated size is ignored)."""
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


def sdo_write(d: Drive, index: int, sub: int, value: int, size: int) -> None:
    """Download ``value`` as ``size`` little-endian bytes (DriverError on abort or timeout)."""
    raw = (value & ((1 << 8 * size) - 1)).to_bytes(size, "little")
    try:
        d.node.sdo.download(index, sub, raw)
    except canopen.SdoAbortedError as exc:
        raise DriverError(f"write 0x{index:04X}:{sub:02X} = {value} aborted: 0x{exc.code:08X} "
                          f"{p.SDO_ABORT_CODES.get(exc.code, '')}") from None
    except canopen.SdoCommunicationError as exc:
        raise DriverError(f"write 0x{index:04X}:{sub:02X}: {exc}") from None


SdoError = (canopen.SdoAbortedError, canopen.SdoCommunicationError)


def first_sdo_error(exc: BaseException) -> BaseException:
    """The SDO error that ended a transfer. canopen's stream, closed by ``with`` after an abort or a
    timeout half-way, sends one more segment, which the server (its transfer gone) answers with
    0x05040001: that answer masks the real cause, which stays in ``__context__``."""
    while isinstance(exc.__context__, SdoError):
        exc = exc.__context__
    return exc


def _sdo_failure(what: str, exc: BaseException) -> DriverError:
    exc = first_sdo_error(exc)
    if isinstance(exc, canopen.SdoAbortedError):
        return DriverError(f"{what} aborted: 0x{exc.code:08X} {p.SDO_ABORT_CODES.get(exc.code, '')}".rstrip())
    return DriverError(f"{what}: {exc}")


def sdo_read_bytes(d: Drive, index: int, sub: int) -> bytes:
    """Upload an object of any length (segmented when longer than 4 bytes); DriverError on abort or timeout."""
    try:
        return bytes(d.node.sdo.upload(index, sub))
    except SdoError as exc:
        raise _sdo_failure(f"read 0x{index:04X}:{sub:02X}", exc) from None


def sdo_write_bytes(d: Drive, index: int, sub: int, data: bytes) -> None:
    """Download a byte string of any length (segmented when longer than 4 bytes); DriverError with the first cause."""
    try:
        d.node.sdo.download(index, sub, bytes(data))
    except SdoError as exc:
        raise _sdo_failure(f"write 0x{index:04X}:{sub:02X} ({len(data)} bytes)", exc) from None


def _write_optional(d: Drive, index: int, sub: int, value: int, size: int, skip: set[int], what: str) -> None:
    """Write an object a drive may lack (its EDS says so, or it aborts): a warning, not a failure."""
    if index in skip:
        log.warning("%s: no %s 0x%04X in its object dictionary", d.name, what, index)
        return
    try:
        sdo_write(d, index, sub, value, size)
    except DriverError as exc:
        log.warning("%s: no %s (%s)", d.name, what, exc)


def set_mode(d: Drive, mode: int) -> None:
    """Write 0x6060 and wait for 0x6061 to show it (DriverError when it never does)."""
    sdo_write(d, p.MODES_OF_OPERATION, 0, mode, 1)
    for _ in range(20):
        if sdo_read(d, p.MODES_DISPLAY, 0, 1, signed=True) == mode:
            return
        time.sleep(0.01)
    raise DriverError(f"mode display 0x6061 never showed mode {mode} ({p.MODE_NAMES.get(mode, '?')})")


def finish_homing(d: Drive) -> None:
    """After homing: the operating mode, and a set-point where the drive now stands (in its new counts)."""
    set_mode(d, d.op_mode)
    d.position = p.unwrap_int32(None, sdo_read(d, p.POSITION_ACTUAL, 0, 4, signed=True))
    d.target = int(d.position)
    sdo_write(d, p.TARGET_POSITION, 0, d.target, 4)
    d.latched_target = None
    d.homing = ""
    log.info("%s: homed, position actual %d counts; mode %s", d.name, d.position, p.MODE_NAMES[d.op_mode])


def map_pdo(d: Drive, comm: int, cob: int, entries: list[tuple[int, int, int]],
            trans: int, event_ms: int = 0) -> None:
    """CiA 301 mapping procedure: disable, clear, write entries, set count, enable."""
    sdo_write(d, comm, 1, cob | 0x80000000, 4)
    sdo_write(d, comm, 2, trans, 1)
    if comm >= 0x1800 and trans >= 0xFE:
        sdo_write(d, comm, 5, event_ms, 2)
    mapping = comm + 0x200
    sdo_write(d, mapping, 0, 0, 1)
    for i, (index, sub, bits) in enumerate(entries, start=1):
        sdo_write(d, mapping, i, p.pdo_mapping_entry(index, sub, bits), 4)
    sdo_write(d, mapping, 0, len(entries), 1)
    if entries:
        sdo_write(d, comm, 1, cob, 4)


def bring_up(network: canopen.Network, d: Drive, cfg: Config, *, skip: set[int], now_s: float) -> None:
    """Configure one drive and start it (raises DriverError with the step that failed).

    ``skip``: optional objects its EDS lacks (not written); ``now_s``: the master's clock.
    """
    n, wheel = d.spec.node_id, d.spec.role == "wheel"
    if cfg.reset_comm:
        d.booted.clear()
        network.send_message(p.NMT, bytes([p.NMT_RESET_COMM, n]))
        if not d.booted.wait(cfg.boot_timeout_s):
            raise DriverError(f"no boot-up (0x{p.HEARTBEAT + n:03X}#00) within {cfg.boot_timeout_s} s "
                              "of NMT reset communication: is the drive powered and the node id right?")
    device = sdo_read(d, 0x1000, 0, 4)
    if device & 0xFFFF != 402:
        raise DriverError(f"device type 0x{device:08X} is not a CiA 402 drive (low 16 bits must be 0x0192)")
    try:
        d.device_name = sdo_read_bytes(d, 0x1008, 0).decode("ascii", "replace").rstrip("\0")
    except DriverError as exc:   # optional object
        log.info("%s: no device name (%s)", d.name, exc)
    d.op_mode = WHEEL_MODES[cfg.wheel_mode] if wheel else STEER_MODES[cfg.steer_mode]
    sdo_write(d, 0x1017, 0, cfg.heartbeat_ms, 2)
    if cfg.master_node_id:
        consumer_ms = int(cfg.master_heartbeat_ms * cfg.heartbeat_loss_factor)
        try:
            sdo_write(d, 0x1016, 1, cfg.master_node_id << 16 | consumer_ms, 4)
        except DriverError as exc:   # optional object: the master watchdog still protects
            log.warning("%s: no heartbeat consumer (%s)", d.name, exc)
    target = (p.TARGET_VELOCITY if wheel else p.TARGET_POSITION, 0, 32)
    trans = 1 if cfg.sync_hz > 0 else 0xFF
    if cfg.sync_hz > 0:
        period_us = int(round(1e6 / cfg.sync_hz))
        _write_optional(d, p.COMM_CYCLE_PERIOD, 0, period_us, 4, skip, "communication cycle period")
        if d.cyclic and period_us % 1000 == 0:
            _write_optional(d, p.INTERPOLATION_PERIOD, 1, period_us // 1000, 1, skip, "interpolation period")
            _write_optional(d, p.INTERPOLATION_PERIOD, 2, -3, 1, skip, "interpolation period")
    # Cyclic modes: RPDO1 synchronous, so every drive takes its set-point at the same SYNC.
    map_pdo(d, 0x1400, p.RPDO_BASE[0] + n, [(p.CONTROLWORD, 0, 16), target], 1 if d.cyclic else 0xFF)
    map_pdo(d, 0x1800, p.TPDO_BASE[0] + n, [(p.STATUSWORD, 0, 16), (p.MODES_DISPLAY, 0, 8)],
                  trans, cfg.tpdo_event_ms)
    map_pdo(d, 0x1801, p.TPDO_BASE[1] + n, [(p.POSITION_ACTUAL, 0, 32), (p.VELOCITY_ACTUAL, 0, 32)],
                  trans, cfg.tpdo_event_ms)
    for comm, base in ((0x1401, p.RPDO_BASE[1]), (0x1402, p.RPDO_BASE[2]), (0x1403, p.RPDO_BASE[3]),
                       (0x1802, p.TPDO_BASE[2]), (0x1803, p.TPDO_BASE[3])):
        sdo_write(d, comm, 1, base + n | 0x80000000, 4)
    k = abs(d.spec.counts_per_unit)
    d.homing = "pending" if cfg.homing_method and not wheel else ""
    if d.homing:
        # The method is a parameter of the drive: one it does not know aborts (0x06090030) and fails here.
        sdo_write(d, p.HOMING_METHOD, 0, cfg.homing_method, 1)
        fast = int(round(cfg.homing_speed_radps * k))
        _write_optional(d, p.HOMING_SPEEDS, 1, fast, 4, skip, "homing speed")
        _write_optional(d, p.HOMING_SPEEDS, 2, max(1, fast // 10), 4, skip, "homing speed")
        _write_optional(d, p.HOMING_ACCEL, 0, int(round(cfg.steer_accel_radps2 * k)), 4, skip, "homing acceleration")
    set_mode(d, p.MODE_HOMING if d.homing else d.op_mode)
    if wheel:
        ramps = {p.PROFILE_ACCEL: cfg.wheel_accel_mps2, p.PROFILE_DECEL: cfg.wheel_accel_mps2,
                 p.QUICK_STOP_DECEL: cfg.quick_stop_decel_mps2}
    else:
        ramps = {p.PROFILE_VELOCITY: cfg.steer_speed_radps, p.PROFILE_ACCEL: cfg.steer_accel_radps2,
                 p.PROFILE_DECEL: cfg.steer_accel_radps2, p.QUICK_STOP_DECEL: cfg.steer_quick_stop_radps2}
    for index, value in ramps.items():
        if index not in skip:
            sdo_write(d, index, 0, int(round(value * k)), 4)
        elif index == p.PROFILE_VELOCITY:
            log.warning("%s: no profile velocity 0x6081 in its object dictionary: its steering rate is the "
                        "drive's own default, not steer_speed_radps", d.name)
    d.position = p.unwrap_int32(None, sdo_read(d, p.POSITION_ACTUAL, 0, 4, signed=True))
    # A safe set-point before anything can enable: stand still / stay where you are.
    d.target = 0 if wheel else int(d.position)
    sdo_write(d, p.TARGET_VELOCITY if wheel else p.TARGET_POSITION, 0, d.target, 4)
    d.latched_target = None
    d.set_statusword(sdo_read(d, p.STATUSWORD, 0, 2))
    d.was_enabled = False
    d.fault_resets = 0
    if d.state == p.FAULT:
        d.fault = d.fault or f"fault at start, error code 0x{sdo_read(d, p.ERROR_CODE, 0, 2):04X}"
        log.warning("%s: %s (statusword 0x%04X); will reset it", d.name, d.fault, d.statusword)
    network.send_message(p.NMT, bytes([p.NMT_START, n]))
    d.nmt_state = "OPERATIONAL"
    d.last_hb = d.last_hb or now_s      # the heartbeat clock starts now at the latest
    d.configured = True
    log.info("%s (node %d) up: statusword 0x%04X %s", d.name, n, d.statusword, d.state)
