"""Configuration of the CiA 402 master: drives on the bus, timing, ramps, and the object
dictionary check an EDS / DCF must pass before a drive is used in a role.

Shared by the master (:mod:`drivers.cia402_master`), its node (:mod:`drivers.canopen402`)
and the simulated drives (:mod:`sim.cia402_drive`), which read the same drive list.
"""
from __future__ import annotations

import math

import canopen
import msgspec

from drivers import cia402 as p
from nodes.control.can_axles import AxleDrive

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
    sync_hz: float = 0.0                 # > 0: the cyclic step produces SYNC (after the RPDOs); synchronous TPDOs
    wheel_mode: str = "pv"               # pv (profile velocity) | csv (cyclic synchronous velocity: needs sync_hz)
    steer_mode: str = "pp"               # pp (profile position) | csp (cyclic synchronous position: needs sync_hz)
    homing_method: int = 0               # 0: none; else steer drives home with this CiA 402 method (0x6098) first
    homing_speed_radps: float = 0.5      # homing search speed (0x6099:1; :2 is a tenth of it)
    homing_timeout_s: float = 10.0       # a homing run longer than this trips the master
    measured_hz: float = 0.0             # > 0: publish 'measured' at this rate (the control rate), else at state_hz
    sdo_timeout_s: float = 0.3
    boot_timeout_s: float = 1.0
    retry_s: float = 1.0                 # bring-up retry of a missing drive
    reset_comm: bool = True              # NMT reset communication before configuring
    max_fault_resets: int = 3            # for faults present before a drive was ever enabled
    fault_reset_interval_s: float = 0.5  # between two of those resets (a drive needs time to clear)
    feedback_timeout_ms: int = 200       # statusword/position PDOs older than this (or 3 PDO periods) trip
    max_speed_mps: float = 3.0           # wheel speed commands beyond this are scaled down (counted)
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
_CYCLIC_OBJECTS = (p.COMM_CYCLE_PERIOD, p.INTERPOLATION_PERIOD)
OPTIONAL_OBJECTS = {"wheel": (p.PROFILE_ACCEL, p.PROFILE_DECEL, p.QUICK_STOP_DECEL, *_CYCLIC_OBJECTS),
                    "steer": (p.PROFILE_VELOCITY, p.PROFILE_ACCEL, p.PROFILE_DECEL, p.QUICK_STOP_DECEL,
                              *_CYCLIC_OBJECTS, p.HOMING_METHOD, p.HOMING_SPEEDS, p.HOMING_ACCEL)}
WHEEL_MODES = {"pv": p.MODE_PV, "csv": p.MODE_CSV}
STEER_MODES = {"pp": p.MODE_PP, "csp": p.MODE_CSP}


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


def check_config(cfg: Config) -> None:
    """Raise ValueError on duplicate names / node ids, bad roles or scales, or non-positive timing."""
    names, ids = [d.name for d in cfg.drives], [d.node_id for d in cfg.drives]
    if len(set(names)) != len(names) or len(set(ids)) != len(ids):
        raise ValueError(f"drive names and node ids must be unique, got {names} / {ids}")
    for d in cfg.drives:
        d.axle_drive()                               # validates role / axle / scale
        if not 1 <= d.node_id <= 127 or d.node_id == cfg.master_node_id:
            raise ValueError(f"drive {d.name!r}: node id must be 1..127 and differ from master_node_id")
    if cfg.rate_hz <= 0 or cfg.cmd_timeout_s <= 0 or cfg.heartbeat_ms <= 0:
        raise ValueError("rate_hz, cmd_timeout_s and heartbeat_ms must be > 0")
    if cfg.feedback_timeout_ms < 0 or cfg.max_speed_mps <= 0 or cfg.fault_reset_interval_s < 0 \
            or cfg.steer_speed_radps <= 0:
        raise ValueError("feedback_timeout_ms and fault_reset_interval_s must be >= 0 (0: off), "
                         "max_speed_mps and steer_speed_radps > 0")
    if cfg.wheel_mode not in WHEEL_MODES or cfg.steer_mode not in STEER_MODES:
        raise ValueError(f"wheel_mode must be one of {sorted(WHEEL_MODES)} and steer_mode one of "
                         f"{sorted(STEER_MODES)}, "
                         f"not {cfg.wheel_mode!r} / {cfg.steer_mode!r}")
    cyclic = cfg.wheel_mode == "csv" or cfg.steer_mode == "csp"
    if cfg.sync_hz < 0 or (cyclic and not 0 < cfg.sync_hz <= cfg.rate_hz * (1 + 1e-9)):
        raise ValueError(f"cyclic synchronous modes need 0 < sync_hz <= rate_hz (the step produces SYNC), "
                         f"got sync_hz {cfg.sync_hz} with rate_hz {cfg.rate_hz}")
    if not -128 <= cfg.homing_method <= 127:
        raise ValueError(f"homing_method is an int8 (0x6098), got {cfg.homing_method}; e.g. 37 current position, "
                         "19 home switch, 0 for no homing")
    if cfg.homing_speed_radps <= 0 or cfg.homing_timeout_s <= 0 or cfg.measured_hz < 0:
        raise ValueError("homing_speed_radps and homing_timeout_s must be > 0, measured_hz >= 0")


def feedback_bound_s(cfg: Config) -> float:
    """How long a drive's feedback PDOs may be silent: ``feedback_timeout_ms`` or three PDO periods."""
    period_s = 1.0 / cfg.sync_hz if cfg.sync_hz > 0 else cfg.tpdo_event_ms / 1000.0
    return max(cfg.feedback_timeout_ms / 1000.0, 3.0 * period_s)


def bus_options(cfg: Config) -> dict:
    """Extra python-can arguments of the configured interface."""
    return {"port": cfg.port} if cfg.interface == "udp_multicast" else {}
