"""Object dictionary and SDO server of a simulated CiA 402 drive, and the faults it can show.

:func:`object_dictionary` is what a fresh drive holds (CiA 301 communication objects, the
CiA 402 objects, default PDO mapping); :class:`SdoServer` answers expedited and
segmented SDO requests on it as a real drive does, abort codes included; :class:`DriveFaults`
switches on the misbehaviours of real drives (fault at start, vendor statusword bits,
SDO aborts / silence, junk after the indicated size, segmented transfers that abort, fall
silent or break the toggle bit half-way, mute, deaf, missed SYNC, sticky faults).
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
    segment_fault: str = ""                 # segmented SDO misbehaviour: 'abort' | 'silent' | 'toggle'
    segment_fault_at: int = 2               # ... from this segment (1-based) of every segmented transfer
    sync_deaf: bool = False                 # misses every SYNC (its SYNC watchdog must stop it)
    encoder_offset: int = 0                 # position actual - physical position before homing (counts)
    home_switch: int | None = 0             # physical position of the home switch edge (None: no switch)


@dataclass
class Entry:
    size: int           # bytes; 0 = variable-length string (VISIBLE_STRING / OCTET_STRING / DOMAIN)
    value: int | bytes
    writable: bool = True
    signed: bool = False


def object_dictionary(node_id: int, role: str) -> dict[tuple[int, int], Entry]:
    """Objects of a freshly booted drive of ``role`` (wheel / steer) at ``node_id``."""
    od: dict[tuple[int, int], Entry] = {
        (0x1000, 0): Entry(4, 0x00020192, False), (0x1001, 0): Entry(1, 0, False),
        (0x1008, 0): Entry(0, f"tether sim {role} drive".encode(), False),
        (0x1009, 0): Entry(0, b"sim hw rev 1", False), (0x100A, 0): Entry(0, b"tether cia402 sim 2", False),
        (p.COB_ID_SYNC, 0): Entry(4, p.SYNC), (p.COMM_CYCLE_PERIOD, 0): Entry(4, 0),
        (0x1023, 0): Entry(1, 3, False), (0x1023, 1): Entry(0, b""), (0x1023, 2): Entry(1, 0, False),
        (0x1023, 3): Entry(0, b"", False),
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
        (p.HOME_OFFSET, 0): Entry(4, 0, signed=True), (p.HOMING_METHOD, 0): Entry(1, 37, signed=True),
        (p.HOMING_SPEEDS, 0): Entry(1, 2, False), (p.HOMING_SPEEDS, 1): Entry(4, 50_000),
        (p.HOMING_SPEEDS, 2): Entry(4, 5_000), (p.HOMING_ACCEL, 0): Entry(4, 500_000),
        (p.INTERPOLATION_PERIOD, 0): Entry(1, 2, False), (p.INTERPOLATION_PERIOD, 1): Entry(1, 0),
        (p.INTERPOLATION_PERIOD, 2): Entry(1, -3 & 0xFF, signed=True),
        (0x6502, 0): Entry(4, 0x1A5, False),       # PP, PV, homing, CSP, CSV
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
ALLOWED_VALUES = {(p.MODES_OF_OPERATION, 0): (p.MODE_PP, p.MODE_PV, p.MODE_HOMING, p.MODE_CSP, p.MODE_CSV),
                  (p.HOMING_METHOD, 0): tuple(p.HOMING_METHODS)}

ABORT_TOGGLE, ABORT_TIMEOUT, ABORT_COMMAND = 0x05030000, 0x05040000, 0x05040001
ABORT_LENGTH, ABORT_GENERAL, ABORT_STORE = 0x06070010, 0x08000000, 0x08000020


@dataclass
class _Transfer:
    """A segmented transfer in progress (one per server: CiA 301 allows one per SDO channel)."""

    upload: bool
    key: tuple[int, int]
    data: bytearray
    size: int | None             # download: the size the client indicated (None: not indicated)
    toggle: int = 0              # expected toggle bit of the next segment
    segments: int = 0


class SdoServer:
    """SDO server over an object dictionary: :meth:`handle` takes a request, returns the responses.

    Expedited and segmented upload and download (CiA 301 7.2.4.3): a segmented transfer
    checks the toggle bit of every segment (abort 0x05030000 when it does not alternate),
    the indicated size against the data (0x06070010), a segment with no transfer open
    (0x05040001); a client abort (``80 ..``) or a new initiate ends the open transfer. A
    download is committed to the object only with its last segment, so a transfer aborted
    half-way leaves the object as it was. Block transfer is not served (0x05040001: the
    client falls back to segmented).

    ``on_write(key, value)`` is called after every successful download (the drive applies a
    controlword written by SDO); ``read_hook(key)`` may supply a live value for an upload.
    """

    def __init__(self, od: dict[tuple[int, int], Entry], faults: DriveFaults, *,
                 on_write: Callable[[tuple[int, int], int | bytes], None] = lambda key, value: None,
                 read_hook: Callable[[tuple[int, int]], int | None] = lambda key: None) -> None:
        self._od, self._faults = od, faults
        self._on_write, self._read_hook = on_write, read_hook
        self._transfer: _Transfer | None = None
        self.aborts_sent: list[int] = []
        self.aborts_received: list[int] = []

    @property
    def busy(self) -> bool:
        """A segmented transfer is open."""
        return self._transfer is not None

    def handle(self, req: bytes) -> list[bytes]:
        """Responses (SDO_TX payloads) to one request (SDO_RX payload); none for a silenced object."""
        if len(req) < 8:
            return []                                      # not an SDO frame: a real server ignores it
        cmd = req[0]
        ccs = cmd >> 5
        if ccs == 4:                                       # client abort: close the transfer, never answer
            self.aborts_received.append(struct.unpack_from("<I", req, 4)[0])
            self._transfer = None
            return []
        if ccs in (0, 3):
            return self._segment(cmd, req)
        index, sub = struct.unpack_from("<HB", req, 1)
        key = (index, sub)
        if key in self._faults.sdo_silent:
            return []
        self._transfer = None                              # a new initiate ends any open transfer
        code = self._faults.sdo_abort.get(key)
        entry = self._od.get(key)
        if code is None and entry is None:
            code = 0x06090011 if any(k[0] == index for k in self._od) else 0x06020000
        if code is None and ccs == 2:
            return [self._initiate_upload(key, entry)]     # type: ignore[arg-type]
        if code is None and ccs == 1:
            return [self._initiate_download(key, entry, cmd, req)]  # type: ignore[arg-type]
        return [self._abort(key, code if code is not None else ABORT_COMMAND)]

    def _abort(self, key: tuple[int, int], code: int) -> bytes:
        self._transfer = None
        self.aborts_sent.append(code)
        return p.sdo_abort(key[0], key[1], code)

    def _initiate_upload(self, key: tuple[int, int], entry: Entry) -> bytes:
        index, sub = key
        if entry.size == 0 and len(entry.value) > 4:  # type: ignore[arg-type]
            self._transfer = _Transfer(True, key, bytearray(entry.value), None)  # type: ignore[arg-type]
            return struct.pack("<BHBI", 0x41, index, sub, len(entry.value))  # type: ignore[arg-type]
        if entry.size == 0:                                # a short string goes expedited, size indicated
            raw = bytes(entry.value)  # type: ignore[arg-type]
            if not raw:
                self._transfer = _Transfer(True, key, bytearray(), None)
                return struct.pack("<BHBI", 0x41, index, sub, 0)
            return struct.pack("<BHB", 0x43 | (4 - len(raw)) << 2, index, sub) + raw.ljust(4, b"\0")
        live = self._read_hook(key)
        value = live if live is not None else int(entry.value)  # type: ignore[arg-type]
        raw = (value & (1 << 8 * entry.size) - 1).to_bytes(entry.size, "little")
        resp = struct.pack("<BHB", 0x43 | (4 - entry.size) << 2, index, sub) + raw
        return (resp + self._faults.junk)[:8].ljust(8, b"\0")

    def _initiate_download(self, key: tuple[int, int], entry: Entry, cmd: int, req: bytes) -> bytes:
        if not entry.writable:
            return self._abort(key, 0x06010002)
        if cmd & 0x02:                                     # expedited
            size = 4 - (cmd >> 2 & 0x3) if cmd & 0x01 else (entry.size or 4)
            if entry.size and size != entry.size:
                return self._abort(key, ABORT_LENGTH)
            return self._commit(key, entry, bytes(req[4:4 + size]))
        size = struct.unpack_from("<I", req, 4)[0] if cmd & 0x01 else None
        if entry.size and size is not None and size != entry.size:
            return self._abort(key, ABORT_LENGTH)
        self._transfer = _Transfer(False, key, bytearray(), size)
        return struct.pack("<BHB4x", 0x60, *key)

    def _commit(self, key: tuple[int, int], entry: Entry, raw: bytes) -> bytes:
        if entry.size == 0:
            value: int | bytes = raw
        else:
            if len(raw) != entry.size:
                return self._abort(key, ABORT_LENGTH)
            value = int.from_bytes(raw, "little", signed=entry.signed)
            allowed = ALLOWED_VALUES.get(key)
            if allowed is not None and value not in allowed:
                return self._abort(key, 0x06090030)
        entry.value = value
        self._transfer = None
        self._on_write(key, value)
        return struct.pack("<BHB4x", 0x60, *key)

    def _segment(self, cmd: int, req: bytes) -> list[bytes]:
        t = self._transfer
        upload = cmd >> 5 == 3
        if t is None or t.upload != upload:
            return [self._abort(t.key if t else (0, 0), ABORT_COMMAND)]
        toggle = cmd >> 4 & 1
        if toggle != t.toggle:
            return [self._abort(t.key, ABORT_TOGGLE)]
        t.segments += 1
        fault = self._faults.segment_fault if t.segments >= self._faults.segment_fault_at else ""
        if fault == "silent":
            return []                                      # the client times out and aborts
        if fault == "abort":
            return [self._abort(t.key, ABORT_GENERAL)]
        t.toggle ^= 1
        sent_toggle = toggle ^ (fault == "toggle")
        if upload:
            chunk, rest = bytes(t.data[:7]), t.data[7:]
            t.data = rest
            if not rest:
                self._transfer = None
            return [p.sdo_segment(chunk, toggle=sent_toggle, last=not rest)]
        n = cmd >> 1 & 0x7
        t.data += req[1:8 - n]
        if not cmd & 0x01:
            return [bytes([0x20 | sent_toggle << 4]) + bytes(7)]
        entry = self._od[t.key]
        if t.size is not None and len(t.data) != t.size:
            return [self._abort(t.key, ABORT_LENGTH)]
        done = self._commit(t.key, entry, bytes(t.data))
        return [bytes([0x20 | sent_toggle << 4]) + bytes(7)] if done[0] == 0x60 else [done]
