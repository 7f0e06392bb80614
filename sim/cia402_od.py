"""Object dictionary and SDO server of a simulated CiA 402 drive, and the faults it can show.

:func:`object_dictionary` is what a fresh drive holds (CiA 301 communication objects, the
CiA 402 objects, default PDO mapping); :class:`SdoServer` answers expedited and
segmented SDO requests on it as a real drive does, abort codes included; :class:`DriveFaults`
switches on the misbehaviours of real drives (fault at start, vendor statusword bits,
SDO aborts / silence, junk after the indicated size, mute, deaf, sticky faults).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Callable

from drivers import cia402 as p


@dataclass
class DriveFaults:
    """Misbehaviours a real drive shows, switched on per drive."""

    start_in_fault: int = 0                 # error code the drive boots with (statusword 0x0218-like)
    vendor_bits: int = 0                    # OR-ed into the statusword, e.g. 0x0100 (Maxon EPOS)
    sdo_abort: dict[tuple[int, int], int] = field(default_factory=dict)   # (index, sub) -> abort code
    sdo_silent: set[tuple[int, int]] = field(default_factory=set)         # never answered (timeout)
    junk: bytes = b"\0\0\0\0"               # bytes after the indicated size in upload responses
    mute: bool = False                      # transmits nothing (heartbeat loss)
    pdo_mute: bool = False                  # transmits no PDO; heartbeat, EMCY and SDO go on
    deaf: bool = False                      # receives nothing (cable cut with mute)
    position_offset: int = 0                # initial position actual, e.g. near 2**31 for wrap tests
    sticky_fault: bool = False              # fault reset does not clear the fault


@dataclass
class Entry:
    size: int           # bytes; 0 = variable-length string
    value: int | bytes
    writable: bool = True
    signed: bool = False


def object_dictionary(node_id: int, role: str) -> dict[tuple[int, int], Entry]:
    """Objects of a freshly booted drive of ``role`` (wheel / steer) at ``node_id``."""
    od: dict[tuple[int, int], Entry] = {
        (0x1000, 0): Entry(4, 0x00020192, False), (0x1001, 0): Entry(1, 0, False),
        (0x1008, 0): Entry(0, f"tether sim {role} drive".encode(), False),
        (0x1016, 0): Entry(1, 1, False), (0x1016, 1): Entry(4, 0), (0x1017, 0): Entry(2, 0),
        (0x1018, 0): Entry(1, 4, False), (0x1018, 1): Entry(4, 0x555, False), (0x1018, 2): Entry(4, 0x402, False),
        (0x1018, 3): Entry(4, 0x00010000, False), (0x1018, 4): Entry(4, node_id, False),
        (p.ERROR_CODE, 0): Entry(2, 0, False), (0x605A, 0): Entry(2, 6, signed=True),
        (p.CONTROLWORD, 0): Entry(2, 0), (p.STATUSWORD, 0): Entry(2, 0, False),
        (p.MODES_OF_OPERATION, 0): Entry(1, 0, signed=True), (p.MODES_DISPLAY, 0): Entry(1, 0, False, True),
        (p.POSITION_ACTUAL, 0): Entry(4, 0, False, True), (p.VELOCITY_ACTUAL, 0): Entry(4, 0, False, True),
        (p.TARGET_POSITION, 0): Entry(4, 0, signed=True), (p.TARGET_VELOCITY, 0): Entry(4, 0, signed=True),
        (p.PROFILE_VELOCITY, 0): Entry(4, 100_000), (p.PROFILE_ACCEL, 0): Entry(4, 1_000_000),
        (p.PROFILE_DECEL, 0): Entry(4, 1_000_000), (p.QUICK_STOP_DECEL, 0): Entry(4, 2_000_000),
        (0x6502, 0): Entry(4, 0b101, False),
    }
    for i in range(4):
        od[(0x1400 + i, 0)] = Entry(1, 2, False)
        od[(0x1400 + i, 1)] = Entry(4, p.RPDO_BASE[i] + node_id | (0 if i == 0 else 0x80000000))
        od[(0x1400 + i, 2)] = Entry(1, 0xFF)
        od[(0x1800 + i, 0)] = Entry(1, 6, False)
        od[(0x1800 + i, 1)] = Entry(4, p.TPDO_BASE[i] + node_id | (0 if i == 0 else 0x80000000))
        for sub, size, value in ((2, 1, 0xFF), (3, 2, 0), (5, 2, 0), (6, 1, 0)):
            od[(0x1800 + i, sub)] = Entry(size, value)
        for base, first in ((0x1600, 0x60400010), (0x1A00, 0x60410010)):
            od[(base + i, 0)] = Entry(1, 1 if i == 0 else 0)
            for sub in range(1, 9):
                od[(base + i, sub)] = Entry(4, first if (i, sub) == (0, 1) else 0)
    return od




#: Values an SDO download may write, where a drive restricts them (others abort 0x06090030).
ALLOWED_VALUES = {(p.MODES_OF_OPERATION, 0): (p.MODE_PP, p.MODE_PV)}


class SdoServer:
    """SDO server over an object dictionary: :meth:`handle` takes a request, returns the responses.

    ``on_write(key, value)`` is called after every successful download (the drive applies a
    controlword written by SDO); ``read_hook(key)`` may supply a live value for an upload.
    """

    def __init__(self, od: dict[tuple[int, int], Entry], faults: DriveFaults, *,
                 on_write: Callable[[tuple[int, int], int], None] = lambda key, value: None,
                 read_hook: Callable[[tuple[int, int]], int | None] = lambda key: None) -> None:
        self._od, self._faults = od, faults
        self._on_write, self._read_hook = on_write, read_hook
        self._segment: bytes | None = None

    def handle(self, req: bytes) -> list[bytes]:
        """Responses (SDO_TX payloads) to one request (SDO_RX payload); none for a silenced object."""
        out: list[bytes] = []
        self._serve(req, out)
        return out

    def _serve(self, req: bytes, out: list[bytes]) -> None:
        if len(req) < 8:
            return
        cmd, index, sub = req[0], *struct.unpack_from("<HB", req, 1)
        key = (index, sub)
        if key in self._faults.sdo_silent or cmd == 0x80:     # never answer an abort
            return
        if cmd >> 5 == 3 and self._segment is not None:        # upload segment request
            chunk, rest = self._segment[:7], self._segment[7:]
            self._segment = rest or None
            last = int(not rest)
            out.append(bytes([cmd & 0x10 | (7 - len(chunk)) << 1 | last]) + chunk.ljust(7, b"\0"))
            return
        code = self._faults.sdo_abort.get(key)
        entry = self._od.get(key)
        if code is None and entry is None:
            code = 0x06090011 if any(k[0] == index for k in self._od) else 0x06020000
        if code is None and cmd == 0x40:
            assert entry is not None
            if entry.size == 0:
                self._segment = bytes(entry.value)  # type: ignore[arg-type]
                out.append(struct.pack("<BHBI", 0x41, index, sub, len(self._segment)))
                return
            live = self._read_hook(key)
            value = live if live is not None else int(entry.value)  # type: ignore[arg-type]
            raw = (value & (1 << 8 * entry.size) - 1).to_bytes(entry.size, "little")
            resp = struct.pack("<BHB", 0x43 | (4 - entry.size) << 2, index, sub) + raw
            out.append((resp + self._faults.junk)[:8].ljust(8, b"\0"))
            return
        if code is None and cmd >> 5 == 1 and cmd & 0x02:
            assert entry is not None
            size = 4 - (cmd >> 2 & 0x3) if cmd & 0x01 else entry.size
            if not entry.writable:
                code = 0x06010002
            elif size != entry.size:
                code = 0x06070010
            elif key in ALLOWED_VALUES and req[4] not in ALLOWED_VALUES[key]:
                code = 0x06090030
            else:
                entry.value = int.from_bytes(req[4:4 + size], "little", signed=entry.signed)
                self._on_write(key, int(entry.value))
                out.append(struct.pack("<BHB4x", 0x60, index, sub))
                return
        out.append(p.sdo_abort(index, sub, code if code is not None else 0x05040001))
