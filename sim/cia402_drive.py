"""Simulated CiA 402 drives that answer on a CAN bus as real ones do: the node.

:class:`Cia402DriveSim` runs one :class:`sim.cia402_device.SimDrive` per configured drive
(wheels in profile velocity or CSV, steer motors in profile position or CSP, homing; first-order motor dynamics,
the CiA 301 / 402 protocol stack with injectable faults) on a python-can bus, and publishes
the speeds and steer angles the motors actually achieve (``achieved``, a
``control.WheelCommand`` for the vehicle simulator) at ``publish_hz``.

The pieces live in :mod:`sim.cia402_od` (object dictionary, SDO server, faults),
:mod:`sim.cia402_device` (the drive) and :mod:`sim.cia402_bank` (serving drives on a bus,
in real time or in lockstep); they are re-exported here.
"""
from __future__ import annotations

import time

import can
import msgspec

from drivers.can_bus import open_bus
from drivers.cia402 import COMM_CYCLE_PERIOD
from drivers.cia402_config import DEFAULT_DRIVES, DriveConfig
from msgs.control import WheelCommand
from nodes.control.can_axles import AxleDrive, command_from_actuals
from sim.cia402_bank import LockstepDriveBank, SimDriveBank, SyncCanBus, SyncCanHub
from sim.cia402_device import SYNC_LOSS_CYCLES, Frame, SimDrive
from sim.cia402_od import DriveFaults
from tether import Node, Tick

__all__ = ["Cia402DriveSim", "DriveFaults", "Frame", "LockstepDriveBank", "SimDrive", "SimDriveBank",
           "SimDriveConfig", "SyncCanBus", "SyncCanHub", "make_drive"]


class SimDriveConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Per-drive simulation knobs (faults by name, see :class:`DriveFaults`)."""

    time_constant_s: float = 0.02
    start_in_fault: int = 0
    vendor_bits: int = 0
    junk_hex: str = "00000000"
    position_offset: int = 0
    sdo_abort: dict[str, int] = {}        # "0x1017:0" -> abort code
    sdo_silent: list[str] = []            # "0x1017:0"
    segment_fault: str = ""               # segmented SDO half-way: 'abort' | 'silent' | 'toggle'
    segment_fault_at: int = 2
    sync_deaf: bool = False               # misses every SYNC
    encoder_offset: int = 0               # position actual - physical position until homed (counts)
    home_switch: int | None = 0           # physical position of the home switch (counts; None: none)


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
                         sdo_silent={_object_key(key) for key in k.sdo_silent}, segment_fault=k.segment_fault,
                         segment_fault_at=k.segment_fault_at, sync_deaf=k.sync_deaf,
                         encoder_offset=k.encoder_offset, home_switch=k.home_switch)
    return SimDrive(spec.node_id, role=spec.role, time_constant_s=k.time_constant_s, faults=faults, now_s=now_s)


class Cia402DriveSim(Node):
    """Simulated drives on a CAN bus. Timer ``publish`` -> output ``achieved``: the per-axle
    wheel speeds and steer angles the motors actually reach (for ``sim.vehicle4ws``).

    The drives are served by a thread on the bus :meth:`open_bus` returns, or, on a
    synchronous lockstep bus (:class:`sim.cia402_bank.SyncCanBus`), by its hub's clock.
    """

    Config = Config
    outputs = {"achieved": WheelCommand}
    timers = {"publish": "publish_hz"}

    def setup(self) -> None:
        cfg: Config = self.config  # type: ignore[assignment]
        self._axles: list[AxleDrive] = [d.axle_drive() for d in cfg.drives]
        self._bus = self.open_bus()
        if getattr(self._bus, "synchronous", False):
            now = self._bus.hub.now_s
            drives = {d.name: make_drive(d, cfg.sim.get(d.name), now, cfg.time_constant_s) for d in cfg.drives}
            self.bank: SimDriveBank | LockstepDriveBank = LockstepDriveBank(self._bus, drives)
        else:
            now = time.monotonic()
            drives = {d.name: make_drive(d, cfg.sim.get(d.name), now, cfg.time_constant_s) for d in cfg.drives}
            self.bank = SimDriveBank(self._bus, drives, step_s=cfg.step_s).start()

    def open_bus(self) -> can.BusABC:
        """The python-can bus of the configured interface (echo-filtered; see drivers.can_bus)."""
        cfg: Config = self.config  # type: ignore[assignment]
        return open_bus(cfg.interface, cfg.channel, cfg.bitrate,
                        **({"port": cfg.port} if cfg.interface == "udp_multicast" else {}))

    def achieved(self) -> WheelCommand:
        vf, df, vr, dr = command_from_actuals(self.bank.actuals(), self._axles)
        return WheelCommand(v_front_mps=vf, delta_front_rad=df, v_rear_mps=vr, delta_rear_rad=dr)

    def on_publish(self, tick: Tick) -> dict[str, WheelCommand]:
        return {"achieved": self.achieved()}

    def teardown(self) -> None:
        self.bank.stop()
        self._bus.shutdown()
        gaps = {name: d.max_sync_gap_s for name, d in self.bank.drives.items() if d.max_sync_gap_s > 0}
        if gaps:        # only drives that ran in CSP / CSV watch SYNC
            name = max(gaps, key=gaps.__getitem__)
            drive = self.bank.drives[name]
            limit = SYNC_LOSS_CYCLES * drive.od[(COMM_CYCLE_PERIOD, 0)].value * 1e-6
            self.log.info("largest SYNC gap seen by the drives' watchdogs: %.1f ms (%s; quick stop beyond %.1f ms)",
                          gaps[name] * 1e3, name, limit * 1e3)
