"""Oculus M-series network protocol: pure byte codec (no sockets), per ``shared/specs/oculus-protocol.md``.

What is here:

* :class:`FireSettings` with :func:`encode_fire` / :func:`decode_fire` (SimpleFire V1 53 B, V2 89 B);
* :class:`PingResult` with :func:`decode_ping` / :func:`encode_ping` (SimplePingResult V1 and V2;
  msgVersion 0 is V1; bearings in 0.01 deg, image at ``imageOffset``, optional 4-byte per-row gain
  prefix, 8/16/24/32-bit samples, the ``16 + payloadSize == imageOffset + imageSize`` check);
* :class:`StatusInfo` with :func:`encode_status` / :func:`decode_status` (the 142 B UDP status).

Framing a TCP byte stream (resync on the magic) is :mod:`drivers.oculus_stream`.

All structs are little-endian and packed. Range of image row ``i`` is ``(i + 0.5) * rangeResolution``
(the convention of ``msgs.sonar.SonarPing``). The 4-byte row gain is read as an IEEE float
(liboculus) or a u32 (ENSTA, oculus-python), chosen by ``gain_encoding``; the spec says it is disputed.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field, replace

import numpy as np

MAGIC = 0x4F53
MAGIC_BYTES = b"SO"                     # 0x4F53 little-endian
DATA_PORT = 52100
STATUS_PORT = 52102

MSG_STATUS, MSG_FIRE, MSG_PING_FULL, MSG_PING, MSG_USER_CONFIG, MSG_LOGS, MSG_DUMMY = (
    0x01, 0x15, 0x22, 0x23, 0x55, 0x80, 0xFF)

FLAG_RANGE_METRES, FLAG_16BIT, FLAG_ROW_GAIN, FLAG_SIMPLE, FLAG_GAIN_ASSIST = 0x01, 0x02, 0x04, 0x08, 0x10
FLAG_LOW_POWER, FLAG_512_BEAMS, FLAG_NETWORK_TRIGGER = 0x20, 0x40, 0x80
EXT_FLAG_32BIT = 0x200

MODE_LOW_FREQUENCY, MODE_HIGH_FREQUENCY = 1, 2
PING_RATES = {"normal": 0, "high": 1, "highest": 2, "low": 3, "lowest": 4, "standby": 5}
PING_RATE_HZ = {0: 10.0, 1: 15.0, 2: 40.0, 3: 5.0, 4: 2.0, 5: 0.0}
STANDBY = PING_RATES["standby"]

HEADER = struct.Struct("<HHHHHIH")                     # 16 B
FIRE_V1 = struct.Struct("<BBBBBdddd")                  # 37 B after the header
FIRE_V2_EXT = struct.Struct("<I8I")                    # 36 B more in V2
PING_V1 = struct.Struct("<IIddddIBdHHIII")             # 69 B after the 53 B fire echo
PING_V2 = struct.Struct("<IIddddddddBdHH4IIII")        # 113 B after the 89 B fire echo
STATUS = struct.Struct("<IHHI6IIII6s8dd")              # 126 B after the header
FIRE_V1_SIZE = HEADER.size + FIRE_V1.size              # 53
FIRE_V2_SIZE = FIRE_V1_SIZE + FIRE_V2_EXT.size         # 89
PING_V1_SIZE = FIRE_V1_SIZE + PING_V1.size             # 122: bearings start here
PING_V2_SIZE = FIRE_V2_SIZE + PING_V2.size             # 202
STATUS_SIZE = HEADER.size + STATUS.size                # 142
BYTES_PER_SAMPLE = {0: 1, 1: 2, 2: 3, 3: 4}
MAX_SMALL_PAYLOAD = {MSG_STATUS: STATUS.size, MSG_FIRE: FIRE_V2_EXT.size + FIRE_V1.size,
                      MSG_DUMMY: 4096, MSG_LOGS: 1 << 16, MSG_USER_CONFIG: 4096}


class ProtocolError(ValueError):
    """A message that does not follow the protocol (the text says which field and why)."""


@dataclass(frozen=True)
class Header:
    """The 16-byte OculusMessageHeader."""

    msg_id: int
    payload_size: int
    src: int = 0
    dst: int = 0
    version: int = 0
    spare: int = 0
    oculus_id: int = MAGIC

    def pack(self) -> bytes:
        return HEADER.pack(self.oculus_id, self.src, self.dst, self.msg_id, self.version,
                           self.payload_size, self.spare)

    @classmethod
    def unpack(cls, buf: bytes | bytearray | memoryview) -> "Header":
        oid, src, dst, mid, ver, size, spare = HEADER.unpack_from(buf, 0)
        return cls(msg_id=mid, payload_size=size, src=src, dst=dst, version=ver, spare=spare, oculus_id=oid)


@dataclass(frozen=True)
class FireSettings:
    """A SimpleFire request (and the echo the sonar puts in each ping)."""

    master_mode: int = MODE_HIGH_FREQUENCY
    ping_rate: int = PING_RATES["normal"]
    network_speed: int = 0xFF
    gamma: int = 127                   # 0..255; 127 -> gamma 0.5, 0 or 255 -> 1.0
    flags: int = FLAG_RANGE_METRES | FLAG_SIMPLE
    range: float = 10.0                # metres when flag bit0, else percent
    gain_percent: float = 50.0
    speed_of_sound: float = 0.0        # m/s, 0 = from salinity
    salinity: float = 0.0              # ppt
    ext_flags: int = 0                 # V2 only
    reserved: tuple[int, ...] = (0,) * 8   # V2 only; reserved[2] is the beacon locator frequency (Hz)

    @classmethod
    def make(cls, *, range_m: float, gain_percent: float = 50.0, gamma: int = 127, ping_rate: int = 0,
             frequency: str = "high", bits: int = 8, beams: int = 512, row_gain: bool = True,
             gain_assist: bool = False, network_trigger: bool = False, sound_speed_mps: float = 0.0,
             salinity_ppt: float = 0.0, network_speed: int = 0xFF) -> "FireSettings":
        """Build a fire request from plain settings (ranges in metres)."""
        if frequency not in ("low", "high"):
            raise ValueError(f"frequency must be 'low' or 'high', got {frequency!r}")
        if bits not in (8, 16, 32) or beams not in (256, 512):
            raise ValueError(f"bits must be 8, 16 or 32 and beams 256 or 512, got {bits}, {beams}")
        if not (range_m > 0 and 0 <= gain_percent <= 100 and 0 <= gamma <= 255 and ping_rate in PING_RATE_HZ):
            raise ValueError(f"need range_m > 0, 0 <= gain <= 100, 0 <= gamma <= 255, ping_rate in 0..5; got "
                             f"{range_m}, {gain_percent}, {gamma}, {ping_rate}")
        flags = FLAG_RANGE_METRES | FLAG_SIMPLE
        flags |= (FLAG_16BIT if bits == 16 else 0) | (FLAG_ROW_GAIN if row_gain else 0)
        flags |= (FLAG_GAIN_ASSIST if gain_assist else 0) | (FLAG_512_BEAMS if beams == 512 else 0)
        flags |= FLAG_NETWORK_TRIGGER if network_trigger else 0
        return cls(master_mode=MODE_LOW_FREQUENCY if frequency == "low" else MODE_HIGH_FREQUENCY,
                   ping_rate=ping_rate, network_speed=network_speed, gamma=gamma, flags=flags,
                   range=float(range_m), gain_percent=float(gain_percent), speed_of_sound=float(sound_speed_mps),
                   salinity=float(salinity_ppt), ext_flags=EXT_FLAG_32BIT if bits == 32 else 0)

    @property
    def bits(self) -> int:
        return 32 if self.ext_flags & EXT_FLAG_32BIT else 16 if self.flags & FLAG_16BIT else 8

    @property
    def beams(self) -> int:
        return 512 if self.flags & FLAG_512_BEAMS else 256

    @property
    def row_gain(self) -> bool:
        return bool(self.flags & FLAG_ROW_GAIN)

    def standby(self) -> "FireSettings":
        """The same request with ``pingRate = 5`` (standby)."""
        return replace(self, ping_rate=STANDBY)


def encode_fire(fire: FireSettings, *, version: int = 2, src: int = 0, dst: int = 0) -> bytes:
    """A SimpleFire message (V1: 53 B, V2: 89 B)."""
    if version not in (1, 2):
        raise ValueError(f"SimpleFire version is 1 or 2, got {version}")
    body = FIRE_V1.pack(fire.master_mode, fire.ping_rate, fire.network_speed, fire.gamma, fire.flags,
                        fire.range, fire.gain_percent, fire.speed_of_sound, fire.salinity)
    if version == 2:
        body += FIRE_V2_EXT.pack(fire.ext_flags, *fire.reserved)
    return Header(MSG_FIRE, len(body), src=src, dst=dst, version=version).pack() + body


def decode_fire(buf: bytes | bytearray | memoryview, version: int | None = None) -> FireSettings:
    """Fire settings from a message that starts with a fire (a SimpleFire or a ping's echo)."""
    head = Header.unpack(buf)
    version = head.version if version is None else version
    mode, rate, speed, gamma, flags, rng, gain, sos, sal = FIRE_V1.unpack_from(buf, HEADER.size)
    ext, reserved = 0, (0,) * 8
    if version == 2:
        ext, *rest = FIRE_V2_EXT.unpack_from(buf, FIRE_V1_SIZE)
        reserved = tuple(rest)
    return FireSettings(master_mode=mode, ping_rate=rate, network_speed=speed, gamma=gamma, flags=flags,
                        range=rng, gain_percent=gain, speed_of_sound=sos, salinity=sal, ext_flags=ext,
                        reserved=reserved)


@dataclass(frozen=True)
class PingResult:
    """A decoded SimplePingResult. ``image`` is nRanges x nBeams (row 0 nearest), ``bearings_cdeg`` i16."""

    header: Header
    fire: FireSettings
    version: int                       # 1 or 2 (msgVersion 0 decodes as 1)
    ping_id: int
    status: int
    frequency_hz: float
    temperature_c: float
    pressure_bar: float
    sound_speed_mps: float
    ping_start_time: float             # V2: seconds since power-up; V1: u32 counter of undocumented unit
    data_size: int
    range_resolution_m: float
    image_offset: int
    image_size: int
    message_size: int
    bearings_cdeg: np.ndarray
    image: np.ndarray
    row_gains: np.ndarray | None = None    # (nRanges,) float, when the per-row gain prefix is present
    heading_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    spare: tuple[int, ...] = field(default=(0, 0, 0, 0))

    @property
    def n_ranges(self) -> int:
        return int(self.image.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.image.shape[1])


def _ping_fields(buf: bytes | bytearray | memoryview, version: int) -> tuple:
    return (PING_V2.unpack_from(buf, FIRE_V2_SIZE) if version == 2 else PING_V1.unpack_from(buf, FIRE_V1_SIZE))


def ping_layout_error(buf: bytes | bytearray | memoryview) -> str | None:
    """Check a SimplePingResult's fixed part (needs its first 202 B, or 122 B for V1).

    Returns ``None`` when the sizes and offsets agree, else what is wrong. Used by the stream
    parser to reject a false magic before waiting for ``payloadSize`` bytes.
    """
    head = Header.unpack(buf)
    if head.version not in (0, 1, 2):
        return f"ping msgVersion {head.version} is not 0, 1 or 2"
    version = 2 if head.version == 2 else 1
    f = _ping_fields(buf, version)
    data_size, n_ranges, n_beams = (f[10], f[12], f[13]) if version == 2 else (f[7], f[9], f[10])
    offset, size, msg_size = f[-3:]
    total = HEADER.size + head.payload_size
    if data_size not in BYTES_PER_SAMPLE:
        return f"dataSize {data_size} is not 0..3"
    if msg_size != total:
        return f"messageSize {msg_size} != 16 + payloadSize ({total})"
    if offset + size != total:
        return f"imageOffset + imageSize = {offset + size} != 16 + payloadSize = {total}"
    struct_end = (PING_V2_SIZE if version == 2 else PING_V1_SIZE) + 2 * n_beams
    if n_beams == 0 or n_ranges == 0 or offset < struct_end:
        return f"nBeams {n_beams}, nRanges {n_ranges}, imageOffset {offset} (bearings end at {struct_end})"
    bps = BYTES_PER_SAMPLE[data_size]
    if size not in (n_ranges * n_beams * bps, n_ranges * (4 + n_beams * bps)):
        return (f"imageSize {size} fits neither {n_ranges}x{n_beams}x{bps} B nor rows with a 4 B gain prefix")
    return None


def _samples(raw: np.ndarray, bps: int) -> np.ndarray:
    """(rows, beams * bps) uint8 -> (rows, beams) little-endian unsigned samples."""
    if bps == 1:
        return raw.copy()
    if bps == 3:
        r = raw.reshape(raw.shape[0], -1, 3).astype(np.uint32)
        return r[..., 0] | (r[..., 1] << 8) | (r[..., 2] << 16)
    return np.ascontiguousarray(raw).view("<u2" if bps == 2 else "<u4").astype(np.uint16 if bps == 2 else np.uint32)


def decode_ping(buf: bytes | bytearray | memoryview, *, gain_encoding: str = "float") -> PingResult:
    """Decode one whole SimplePingResult message (V1 or V2).

    Raises :class:`ProtocolError` when the sizes disagree (never reads outside ``buf``).
    """
    if gain_encoding not in ("float", "u32"):
        raise ValueError(f"gain_encoding is 'float' or 'u32', got {gain_encoding!r}")
    mv = memoryview(buf).cast("B")
    if len(mv) < PING_V1_SIZE:
        raise ProtocolError(f"ping message of {len(mv)} B is shorter than the 122 B V1 struct")
    head = Header.unpack(mv)
    if head.oculus_id != MAGIC or head.msg_id != MSG_PING:
        raise ProtocolError(f"not a SimplePingResult: oculusId {head.oculus_id:#x}, msgId {head.msg_id:#x}")
    version = 2 if head.version == 2 else 1
    if version == 2 and len(mv) < PING_V2_SIZE:
        raise ProtocolError(f"V2 ping message of {len(mv)} B is shorter than the 202 B struct")
    problem = ping_layout_error(mv)
    if problem:
        raise ProtocolError(problem)
    if len(mv) != HEADER.size + head.payload_size:
        raise ProtocolError(f"ping message has {len(mv)} B, header says {HEADER.size + head.payload_size}")
    f = _ping_fields(mv, version)
    if version == 2:
        (pid, status, freq, temp, press, heading, pitch, roll, sos, start, dsize, res, nr, nb,
         s0, s1, s2, s3, offset, size, msize) = f
        spare = (s0, s1, s2, s3)
    else:
        pid, status, freq, temp, press, sos, start, dsize, res, nr, nb, offset, size, msize = f
        heading = pitch = roll = 0.0
        spare = (0, 0, 0, 0)
    struct_end = PING_V2_SIZE if version == 2 else PING_V1_SIZE
    bearings = np.frombuffer(mv, "<i2", nb, struct_end).astype(np.int16)
    bps = BYTES_PER_SAMPLE[dsize]
    has_gain = size == nr * (4 + nb * bps)
    stride = nb * bps + (4 if has_gain else 0)
    block = np.frombuffer(mv, np.uint8, size, offset).reshape(nr, stride)
    gains = None
    if has_gain:
        gains = np.ascontiguousarray(block[:, :4]).view("<f4" if gain_encoding == "float" else "<u4")
        gains = gains.reshape(nr).astype(np.float64)
        block = block[:, 4:]
    image = _samples(block, bps)
    return PingResult(header=head, fire=decode_fire(mv, version), version=version, ping_id=pid, status=status,
                      frequency_hz=freq, temperature_c=temp, pressure_bar=press, sound_speed_mps=sos,
                      ping_start_time=start, data_size=dsize, range_resolution_m=res, image_offset=offset,
                      image_size=size, message_size=msize, bearings_cdeg=bearings, image=image, row_gains=gains,
                      heading_deg=heading, pitch_deg=pitch, roll_deg=roll, spare=spare)


def encode_ping(image: np.ndarray, bearings_cdeg: np.ndarray, *, fire: FireSettings, version: int = 2,
                ping_id: int = 0, range_resolution_m: float, frequency_hz: float = 1.2e6,
                sound_speed_mps: float = 1500.0, ping_start_time: float = 0.0, status: int = 0,
                row_gains: np.ndarray | None = None, gain_encoding: str = "float", image_align: int = 0,
                src: int = 0, temperature_c: float = 0.0, pressure_bar: float = 0.0) -> bytes:
    """Build a SimplePingResult (what a sonar sends; used by the simulator and the tests).

    ``image`` is nRanges x nBeams uint8 / uint16 / uint32; ``row_gains`` (nRanges,) adds the 4-byte
    prefix per row. ``version`` 0 or 1 gives the V1 layout (real V1 pings say 0), 2 the V2 one.
    The image starts right after the bearings, or at the next multiple of
    ``image_align`` bytes (real sonars pad: our sample puts it at 2048). Padding bytes are zero.
    """
    image = np.asarray(image)
    if version not in (0, 1, 2):
        raise ValueError(f"ping msgVersion is 0 or 1 (V1) or 2 (V2), got {version}")
    if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16, np.uint32):
        raise ValueError(f"image must be 2-D uint8/uint16/uint32, got {image.dtype} {image.shape}")
    nr, nb = image.shape
    bearings = np.asarray(bearings_cdeg, dtype="<i2")
    if bearings.shape != (nb,):
        raise ValueError(f"need one bearing per beam: {nb} beams, {bearings.shape} bearings")
    bps = image.dtype.itemsize
    data_size = {1: 0, 2: 1, 4: 3}[bps]
    rows = image.astype(image.dtype.newbyteorder("<"), copy=False).reshape(nr, nb).view(np.uint8).reshape(nr, nb * bps)
    if row_gains is not None:
        g = np.asarray(row_gains, dtype=np.float64).reshape(nr)
        g = g.astype("<f4") if gain_encoding == "float" else np.round(g).astype("<u4")
        rows = np.concatenate([g.view(np.uint8).reshape(nr, 4), rows], axis=1)
    struct_end = (PING_V2_SIZE if version == 2 else PING_V1_SIZE) + 2 * nb
    offset = -(-struct_end // image_align) * image_align if image_align > 0 else struct_end
    size = rows.size
    total = offset + size
    out = bytearray(total)
    out[:HEADER.size] = Header(MSG_PING, total - HEADER.size, src=src, version=version).pack()
    out[HEADER.size:FIRE_V2_SIZE if version == 2 else FIRE_V1_SIZE] = encode_fire(
        fire, version=2 if version == 2 else 1)[HEADER.size:]
    if version == 2:
        PING_V2.pack_into(out, FIRE_V2_SIZE, ping_id, status, frequency_hz, temperature_c, pressure_bar, 0.0, 0.0,
                          0.0, sound_speed_mps, float(ping_start_time), data_size, range_resolution_m, nr, nb,
                          0, 0, 0, 0, offset, size, total)
    else:
        PING_V1.pack_into(out, FIRE_V1_SIZE, ping_id, status, frequency_hz, temperature_c, pressure_bar,
                          sound_speed_mps, int(ping_start_time) & 0xFFFFFFFF, data_size, range_resolution_m,
                          nr, nb, offset, size, total)
    out[struct_end - 2 * nb:struct_end] = bearings.tobytes()
    out[offset:] = rows.tobytes()
    return bytes(out)


@dataclass(frozen=True)
class StatusInfo:
    """The useful part of the 142 B UDP status broadcast."""

    device_id: int
    ip_address: str
    part_number: int = 1042            # M1200d
    device_type: int = 1               # imaging sonar
    status: int = 3                    # bits 2:0 = 3: main application running
    ip_mask: str = "255.255.255.0"
    connected_ip: str = "0.0.0.0"
    mac: bytes = b"\0" * 6
    temperatures_c: tuple[float, ...] = (0.0,) * 8
    pressure_bar: float = 0.0


def _ip_bytes(ip: str) -> bytes:
    parts = [int(p) for p in ip.split(".")]
    if len(parts) != 4 or not all(0 <= p <= 255 for p in parts):
        raise ValueError(f"not an IPv4 address: {ip!r}")
    return bytes(parts)


def encode_status(info: StatusInfo) -> bytes:
    """The 142 B status datagram (ipAddr bytes in network order)."""
    ip, mask, conn = (struct.unpack("<I", _ip_bytes(a))[0] for a in (info.ip_address, info.ip_mask, info.connected_ip))
    body = STATUS.pack(info.device_id, info.device_type, info.part_number, info.status, 0, 0, 0, 0, 0, 0,
                       ip, mask, conn, info.mac, *info.temperatures_c, info.pressure_bar)
    return Header(MSG_STATUS, len(body), src=info.device_id, version=0).pack() + body


def decode_status(buf: bytes | bytearray | memoryview) -> StatusInfo:
    """Decode a status datagram; raises :class:`ProtocolError` unless it is exactly 142 B with the magic."""
    if len(buf) != STATUS_SIZE:
        raise ProtocolError(f"status datagram has {len(buf)} B, expected {STATUS_SIZE}")
    head = Header.unpack(buf)
    if head.oculus_id != MAGIC or head.msg_id != MSG_STATUS:
        raise ProtocolError(f"not a status message: oculusId {head.oculus_id:#x}, msgId {head.msg_id:#x}")
    f = STATUS.unpack_from(buf, HEADER.size)
    ips = [".".join(str(b) for b in struct.pack("<I", v)) for v in f[10:13]]
    return StatusInfo(device_id=f[0], device_type=f[1], part_number=f[2], status=f[3], ip_address=ips[0],
                      ip_mask=ips[1], connected_ip=ips[2], mac=f[13], temperatures_c=tuple(f[14:22]),
                      pressure_bar=f[22])
