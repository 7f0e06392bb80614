"""CAN messages: raw frames (so any bus is recordable) and CiA 402 drive states."""
from __future__ import annotations

from tether.message import Message


class CanFrame(Message, tag="can.CanFrame"):
    """One CAN frame; ``stamp_ns`` is when it was seen on the bus."""

    arbitration_id: int = 0
    data: bytes = b""
    is_extended_id: bool = False
    is_remote_frame: bool = False
    is_error_frame: bool = False
    is_rx: bool = True
    channel: str = ""
    is_fd: bool = False           # appended: CAN FD frame (data up to 64 bytes)
    dlc: int = 0                  # appended: data length code; what a remote frame requests


class DriveState(Message, tag="can.DriveState"):
    """State of one CiA 402 drive as its driver sees it."""

    node_id: int = 0
    name: str = ""
    statusword: int = 0
    state: str = ""               # 'NOT READY TO SWITCH ON', 'OPERATION ENABLED', 'FAULT', ...
    mode: int = 0                 # 0x6061 modes of operation display
    position: int = 0             # 0x6064, counts
    velocity: int = 0             # 0x606C, counts/s (or drive units)
    heartbeat_ok: bool = True
    emcy_code: int = 0
    fault: str = ""
    # appended fields
    role: str = ""                # 'wheel' or 'steer'
    nmt_state: str = ""           # 'OPERATIONAL', 'PRE-OPERATIONAL', 'STOPPED', ...
    position_unit: float = 0.0    # position in the drive's unit (m of wheel travel, rad of steer)
    velocity_unit: float = 0.0    # velocity in unit/s
    target_unit: float = 0.0      # last commanded set-point (unit/s for wheels, unit for steering)
    quick_stop: bool = False      # the driver holds this drive in quick stop (watchdog, fault elsewhere)
