"""CiA 301 / CiA 402 protocol logic without I/O: statusword decoding, the power state
machine, SDO / EMCY / heartbeat frame codecs and int32 position unwrapping.

Shared by the driver (:mod:`drivers.canopen402`), the simulated drive
(:mod:`sim.cia402_drive`) and the log tools (:mod:`drivers.candump`). Byte layouts follow
``specs/cia402.md``: 11-bit COB-IDs, little-endian payloads.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

# -- CiA 301 function codes (pre-defined connection set) --------------------------------
NMT = 0x000
SYNC = 0x080
EMCY = 0x080
TPDO_BASE = (0x180, 0x280, 0x380, 0x480)
RPDO_BASE = (0x200, 0x300, 0x400, 0x500)
SDO_TX = 0x580            # drive -> master (response)
SDO_RX = 0x600            # master -> drive (request)
HEARTBEAT = 0x700

NMT_START, NMT_STOP, NMT_PRE_OPERATIONAL, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
NMT_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}

# -- CiA 402 objects -------------------------------------------------------------------
CONTROLWORD, STATUSWORD = 0x6040, 0x6041
MODES_OF_OPERATION, MODES_DISPLAY = 0x6060, 0x6061
POSITION_ACTUAL, VELOCITY_ACTUAL = 0x6064, 0x606C
TARGET_POSITION, TARGET_VELOCITY = 0x607A, 0x60FF
PROFILE_VELOCITY, PROFILE_ACCEL, PROFILE_DECEL, QUICK_STOP_DECEL = 0x6081, 0x6083, 0x6084, 0x6085
ERROR_CODE = 0x603F
HOME_OFFSET, HOMING_METHOD, HOMING_SPEEDS, HOMING_ACCEL = 0x607C, 0x6098, 0x6099, 0x609A
INTERPOLATION_PERIOD = 0x60C2     # :01 value, :02 exponent of ten (s): 10 ms = (10, -3)
COB_ID_SYNC, COMM_CYCLE_PERIOD = 0x1005, 0x1006    # SYNC COB-ID; SYNC period in microseconds
MODE_PP, MODE_PV, MODE_HOMING, MODE_CSP, MODE_CSV = 1, 3, 6, 8, 9
MODE_NAMES = {MODE_PP: "profile position", MODE_PV: "profile velocity", MODE_HOMING: "homing",
              MODE_CSP: "cyclic synchronous position", MODE_CSV: "cyclic synchronous velocity"}
#: Homing methods the simulated drive and the master know: home switch (search its edge) or current position.
HOMING_METHODS = {19: "home switch, positive", 20: "home switch, positive (other edge)",
                  21: "home switch, negative", 22: "home switch, negative (other edge)",
                  35: "current position (CiA 402-2 before 2012)", 37: "current position"}

CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080
CW_NEW_SET_POINT = 0x0010      # PP: rising edge latches 0x607A
CW_CHANGE_IMMEDIATELY = 0x0020  # PP: new set-point replaces the running one
CW_HALT = 0x0100
CW_HOMING_START = 0x0010        # homing: bit 4 high starts (and keeps) the homing run

SW_TARGET_REACHED = 0x0400
SW_HOMING_ATTAINED = 0x1000     # homing mode: bit 12
SW_HOMING_ERROR = 0x2000        # homing mode: bit 13

NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY_TO_SWITCH_ON = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
FAULT = "FAULT"

# Order matters: the 0x6F masks first, so 0x07 (quick stop) is not read as 0x4F-masked.
STATE_MASKS: tuple[tuple[str, int, int], ...] = (
    (READY_TO_SWITCH_ON, 0x6F, 0x21),
    (SWITCHED_ON, 0x6F, 0x23),
    (OPERATION_ENABLED, 0x6F, 0x27),
    (QUICK_STOP_ACTIVE, 0x6F, 0x07),
    (NOT_READY, 0x4F, 0x00),
    (SWITCH_ON_DISABLED, 0x4F, 0x40),
    (FAULT_REACTION_ACTIVE, 0x4F, 0x0F),
    (FAULT, 0x4F, 0x08),
)
STATE_BITS = {name: value for name, _, value in STATE_MASKS}

SDO_ABORT_CODES = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "command specifier not valid or unknown",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "number and length of objects to be mapped exceeds PDO length",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06090011: "sub-index does not exist",
    0x06090030: "value range of parameter exceeded",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000022: "data cannot be transferred because of the present device state",
}

EMCY_CODES = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x3210: "DC link over-voltage",
    0x4210: "excess temperature device",
    0x5530: "EEPROM data error",
    0x7300: "sensor (encoder) error",
    0x8100: "communication error",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x8611: "following error",
    0x8700: "sync controller (SYNC lost)",
    0xFF00: "device specific",
}


def decode_state(statusword: int) -> str:
    """Power state named by a statusword (CiA 402 masks; vendor bits 8, 14, 15 ignored).

    >>> decode_state(0x0737), decode_state(0x0218), decode_state(0x0740)
    ('OPERATION ENABLED', 'FAULT', 'SWITCH ON DISABLED')
    """
    for name, mask, value in STATE_MASKS:
        if statusword & mask == value:
            return name
    return NOT_READY   # unreachable: the 0x4F masks cover every pattern of bits 0-3, 6


@dataclass(frozen=True)
class StatusBits:
    """The non-state statusword bits (bit 5 quick stop is active **low**)."""

    voltage_enabled: bool
    quick_stop: bool
    warning: bool
    remote: bool
    target_reached: bool
    internal_limit: bool
    bit12: bool          # PV: speed is zero; PP: set-point acknowledge
    bit13: bool          # PV: max slippage; PP: following error
    vendor: int          # bits 8, 14, 15 (manufacturer specific)

    @classmethod
    def of(cls, statusword: int) -> "StatusBits":
        b = lambda n: bool(statusword >> n & 1)  # noqa: E731
        return cls(voltage_enabled=b(4), quick_stop=not b(5), warning=b(7), remote=b(9), target_reached=b(10),
                   internal_limit=b(11), bit12=b(12), bit13=b(13), vendor=statusword & 0xC100)


def next_controlword(state: str, target: str, previous: int) -> int:
    """Controlword that moves a drive in ``state`` one transition toward ``target``.

    Parameters
    ----------
    state : str
        Current power state (from :func:`decode_state`).
    target : str
        ``OPERATION ENABLED``, ``QUICK STOP ACTIVE`` or ``SWITCH ON DISABLED``.
    previous : int
        Controlword sent last; a fault reset needs a *rising* edge of bit 7, so when it is
        already high this returns 0x0000 first.

    Returns
    -------
    int
        Controlword bits 0-3 and 7 only; mode bits (4-6, 8) are the caller's.

    Quick stop never powers a drive up: from any state that is not enabled it holds the
    state (``SWITCH ON DISABLED`` etc. do not drive the motor). A drive in ``FAULT`` is
    only reset when the target is ``OPERATION ENABLED`` or ``SWITCH ON DISABLED``.
    """
    if target not in (OPERATION_ENABLED, QUICK_STOP_ACTIVE, SWITCH_ON_DISABLED):
        raise ValueError(f"target must be OPERATION ENABLED, QUICK STOP ACTIVE or SWITCH ON DISABLED, not {target!r}")
    if state == FAULT:
        if target == QUICK_STOP_ACTIVE:
            return CW_QUICK_STOP
        return CW_DISABLE_VOLTAGE if previous & CW_FAULT_RESET else CW_FAULT_RESET
    if state in (FAULT_REACTION_ACTIVE, NOT_READY):
        return CW_DISABLE_VOLTAGE     # the drive leaves these states by itself
    if target == QUICK_STOP_ACTIVE:
        return CW_QUICK_STOP if state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) else (
            CW_SHUTDOWN if state in (READY_TO_SWITCH_ON, SWITCHED_ON) else CW_DISABLE_VOLTAGE)
    if target == SWITCH_ON_DISABLED:
        return CW_DISABLE_VOLTAGE
    return {
        SWITCH_ON_DISABLED: CW_SHUTDOWN,
        READY_TO_SWITCH_ON: CW_SWITCH_ON,
        SWITCHED_ON: CW_ENABLE_OPERATION,
        OPERATION_ENABLED: CW_ENABLE_OPERATION,
        # Leave quick stop through SWITCH ON DISABLED (transition 12): transition 16 is
        # optional (0x605A) and would restart the motor on a stale set-point.
        QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,
    }[state]


# -- SDO -------------------------------------------------------------------------------
@dataclass(frozen=True)
class SdoResponse:
    """A decoded SDO server -> client frame."""

    kind: str            # 'upload', 'download', 'abort', 'upload-segmented', 'segment', 'download-segment', 'other'
    index: int = 0
    subindex: int = 0
    data: bytes = b""    # upload: the *indicated* bytes only; upload-segmented: the size (u32 LE)
    abort_code: int = 0
    toggle: int = 0      # segments: the toggle bit (0 / 1)
    last: bool = False   # upload segment: no more segments follow

    @property
    def abort_text(self) -> str:
        return SDO_ABORT_CODES.get(self.abort_code, "unknown abort code")

    def value(self, signed: bool = False) -> int:
        """The uploaded bytes as a little-endian integer."""
        return int.from_bytes(self.data, "little", signed=signed)


def sdo_upload_request(index: int, subindex: int) -> bytes:
    """Initiate-upload (read) request ``40 ii ii ss 00 00 00 00``."""
    return struct.pack("<BHB4x", 0x40, index, subindex)


def sdo_download_request(index: int, subindex: int, value: int, size: int) -> bytes:
    """Expedited download (write) of a ``size``-byte (1-4) integer: ``2F/2B/27/23 ii ii ss dd..``."""
    if size not in (1, 2, 3, 4):
        raise ValueError(f"expedited SDO carries 1-4 bytes, not {size}; use a segmented transfer for longer data")
    data = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")
    return struct.pack("<BHB", 0x23 | (4 - size) << 2, index, subindex) + data.ljust(4, b"\0")


def sdo_abort(index: int, subindex: int, code: int) -> bytes:
    """Abort transfer frame ``80 ii ii ss cc cc cc cc``."""
    return struct.pack("<BHBI", 0x80, index, subindex, code)


def sdo_segment(data: bytes, *, toggle: int, last: bool) -> bytes:
    """One segment of a segmented transfer: ``000 t nnn c`` then up to 7 data bytes.

    The same layout serves a client's download segment and a server's upload segment
    (command specifier 0 both ways); ``toggle`` (0 / 1) alternates from 0 on the first
    segment of each transfer, ``last`` sets c (no more segments).
    """
    if len(data) > 7:
        raise ValueError(f"an SDO segment carries at most 7 bytes, got {len(data)}")
    return bytes([(toggle & 1) << 4 | (7 - len(data)) << 1 | int(last)]) + bytes(data).ljust(7, b"\0")


def sdo_segment_request(toggle: int) -> bytes:
    """Upload-segment request ``60/70 00..`` (toggle 0 / 1)."""
    return bytes([0x60 | (toggle & 1) << 4]) + bytes(7)


def sdo_download_initiate(index: int, subindex: int, size: int) -> bytes:
    """Initiate a segmented download of ``size`` bytes: ``21 ii ii ss <size u32>``."""
    return struct.pack("<BHBI", 0x21, index, subindex, size)


def parse_sdo_response(data: bytes) -> SdoResponse:
    """Decode an SDO response; an expedited upload keeps **only the indicated size**.

    A real drive answered ``4B 41 60 00 18 02 8F AF``: command 0x4B says 2 valid bytes,
    so the value is 0x0218 and ``8F AF`` is junk. Raises ``ValueError`` on a frame
    shorter than 8 bytes (CiA 301 SDO frames always are 8).
    """
    data = bytes(data)
    if len(data) < 8:
        raise ValueError(f"SDO frame must be 8 bytes, got {len(data)} ({data.hex()}); the frame is truncated")
    cmd = data[0]
    ccs = cmd >> 5
    index, subindex = struct.unpack_from("<HB", data, 1)
    if cmd == 0x80:
        return SdoResponse("abort", index, subindex, abort_code=struct.unpack_from("<I", data, 4)[0])
    if ccs == 3:
        return SdoResponse("download", index, subindex)
    if ccs == 2:
        expedited, sized = bool(cmd & 0x02), bool(cmd & 0x01)
        if not expedited:
            return SdoResponse("upload-segmented", index, subindex, data=data[4:8])
        size = 4 - (cmd >> 2 & 0x3) if sized else 4
        return SdoResponse("upload", index, subindex, data=data[4:4 + size])
    if ccs == 0:
        return SdoResponse("segment", data=data[1:8 - (cmd >> 1 & 0x7)], toggle=cmd >> 4 & 1, last=bool(cmd & 1))
    if ccs == 1:
        return SdoResponse("download-segment", toggle=cmd >> 4 & 1)
    return SdoResponse("other", index, subindex)


# -- EMCY / heartbeat ------------------------------------------------------------------
@dataclass(frozen=True)
class Emergency:
    code: int
    register: int
    vendor: bytes

    @property
    def text(self) -> str:
        return EMCY_CODES.get(self.code, EMCY_CODES.get(self.code & 0xFF00, f"error 0x{self.code:04X}"))

    @property
    def is_reset(self) -> bool:
        return self.code & 0xFF00 == 0


def parse_emcy(data: bytes) -> Emergency:
    """EMCY payload: u16 error code, u8 error register (0x1001), 5 vendor bytes."""
    if len(data) < 3:
        raise ValueError(f"EMCY needs at least 3 bytes (code, register), got {len(data)}: {bytes(data).hex()}")
    code, register = struct.unpack_from("<HB", data)
    return Emergency(code, register, bytes(data[3:8]))


def emcy_frame(code: int, register: int, vendor: bytes = b"") -> bytes:
    return struct.pack("<HB", code, register) + bytes(vendor[:5]).ljust(5, b"\0")


def parse_heartbeat(data: bytes) -> str:
    """NMT state from a heartbeat / boot-up payload (toggle bit 7 masked)."""
    if not data:
        raise ValueError("heartbeat frame has no data byte")
    return NMT_STATES.get(data[0] & 0x7F, f"UNKNOWN 0x{data[0] & 0x7F:02X}")


def pdo_mapping_entry(index: int, subindex: int, bits: int) -> int:
    """Mapping-object value ``index<<16 | sub<<8 | bits`` (e.g. 0x60410010)."""
    return index << 16 | subindex << 8 | bits


def unwrap_int32(previous: int | None, raw: int) -> int:
    """Continue a 32-bit counter across wrap-around.

    ``previous`` is the last unwrapped value (None at start); ``raw`` the new reading
    as a signed or unsigned 32-bit number. The step between readings is taken as the
    shortest one modulo 2**32, so readings must be less than 2**31 counts apart.
    """
    raw = (raw + 2**31) % 2**32 - 2**31
    if previous is None:
        return raw
    step = (raw - previous + 2**31) % 2**32 - 2**31
    return previous + step


def describe_frame(arbitration_id: int, data: bytes) -> str:
    """One-line CANopen reading of a frame (for logs and ``candump`` replays)."""
    data = bytes(data)
    fn, node = arbitration_id & 0x780, arbitration_id & 0x7F
    if arbitration_id == NMT:
        cmd = {1: "start", 2: "stop", 0x80: "pre-operational", 0x81: "reset node", 0x82: "reset communication"}
        return f"NMT {cmd.get(data[0], hex(data[0])) if data else '?'} node {data[1] if len(data) > 1 else '?'}"
    if arbitration_id == SYNC:
        return "SYNC"
    if fn == EMCY and node:
        try:
            e = parse_emcy(data)
        except ValueError as exc:
            return f"EMCY node {node}: malformed ({exc})"
        return f"EMCY node {node}: 0x{e.code:04X} {e.text} (register 0x{e.register:02X})"
    if fn == HEARTBEAT:
        return f"heartbeat node {node}: {parse_heartbeat(data) if data else '?'}"
    if fn in (SDO_TX, SDO_RX) and len(data) == 8:
        if fn == SDO_RX:
            idx, sub = struct.unpack_from("<HB", data, 1)
            kind = "read" if data[0] == 0x40 else "write" if data[0] >> 5 == 1 else f"cmd 0x{data[0]:02X}"
            return f"SDO request node {node}: {kind} 0x{idx:04X}:{sub:02X}"
        r = parse_sdo_response(data)
        if r.kind == "abort":
            return f"SDO abort node {node} 0x{r.index:04X}:{r.subindex:02X}: 0x{r.abort_code:08X} {r.abort_text}"
        if r.kind == "upload":
            return f"SDO response node {node}: 0x{r.index:04X}:{r.subindex:02X} = 0x{r.value():0{2 * len(r.data)}X}"
        return f"SDO response node {node}: {r.kind} 0x{r.index:04X}:{r.subindex:02X}"
    for i, base in enumerate(TPDO_BASE):
        if fn == base:
            return f"TPDO{i + 1} node {node}: {data.hex()}"
    for i, base in enumerate(RPDO_BASE):
        if fn == base:
            return f"RPDO{i + 1} node {node}: {data.hex()}"
    return f"0x{arbitration_id:03X}: {data.hex()}"
