"""Blue Robotics Ping protocol (Ping360 scanning sonar): framing, the messages a driver and
a simulator exchange, and a resynchronising stream parser (``../shared/specs/ping360.md``).

Frame (little-endian): ``'B' 'R'`` | u16 payload length | u16 message id | u8 source id |
u8 destination id | payload | u16 checksum = sum of every preceding byte & 0xFFFF.

Layouts (from the protocol's definitions, as in the MIT ``bluerobotics-ping`` package):

* 2601 transducer: mode u8, gain u8, angle u16, transmit_duration u16, sample_period u16,
  transmit_frequency u16, number_of_samples u16, transmit u8, reserved u8;
* 2300 device_data: the same settings up to number_of_samples, then u16 data_length and
  the samples (u8);
* 2602 auto_transmit: mode, gain, transmit_duration, sample_period, transmit_frequency,
  number_of_samples, start_angle, stop_angle (u16), num_steps u8, delay u8;
* 2301 auto_device_data: mode, gain, angle, transmit_duration, sample_period,
  transmit_frequency, start_angle, stop_angle, num_steps u8, delay u8, number_of_samples,
  data_length, samples;
* 6 general_request (u16 requested id), 4 device_information (6 u8: device type 2 = Ping360),
  5 protocol_version (4 u8), 1 ack (u16), 2 nack (u16 + text), 2903 motor_off, 2600 reset.

The framing is ours (a few lines of ``struct``): ``bench/ping360.py`` measures it against the
package's byte-at-a-time ``PingParser``.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

SYNC = b"BR"
HEADER = struct.Struct("<2sHHBB")
HEADER_SIZE = HEADER.size                      # 8
MAX_PAYLOAD = 4096                             # 1200 samples + 20 bytes; anything longer is garbage

ACK, NACK, GENERAL_REQUEST, DEVICE_INFORMATION, PROTOCOL_VERSION = 1, 2, 6, 4, 5
DEVICE_DATA, AUTO_DEVICE_DATA, RESET, TRANSDUCER, AUTO_TRANSMIT, MOTOR_OFF = 2300, 2301, 2600, 2601, 2602, 2903
DEVICE_TYPE_PING360 = 2
GRADIANS = 400                                 # angles per revolution
SAMPLE_TICK_S = 25e-9                          # sample_period unit

_TRANSDUCER = struct.Struct("<BBHHHHHBB")
_DEVICE_DATA = struct.Struct("<BBHHHHHH")
_AUTO_TRANSMIT = struct.Struct("<BBHHHHHHBB")
_AUTO_DEVICE_DATA = struct.Struct("<BBHHHHHHBBHH")


class PingProtocolError(ValueError):
    """A frame that cannot be what it claims (wrong length, angle, field)."""


def checksum(data: bytes | bytearray | memoryview) -> int:
    return sum(data) & 0xFFFF


def encode(message_id: int, payload: bytes = b"", *, src: int = 0, dst: int = 0) -> bytes:
    body = HEADER.pack(SYNC, len(payload), message_id, src, dst) + payload
    return body + struct.pack("<H", checksum(body))


@dataclass(frozen=True)
class Settings:
    """What the driver asks for: gain 0-2, transmit duration (us), sample period (25 ns
    ticks, 80-40000), transmit frequency (kHz), number of samples (200-1200)."""

    mode: int = 1
    gain_setting: int = 0
    transmit_duration_us: int = 32
    sample_period_ticks: int = 80
    transmit_frequency_khz: int = 740
    number_of_samples: int = 1200

    def __post_init__(self) -> None:
        if not 0 <= self.gain_setting <= 2:
            raise PingProtocolError(f"gain_setting must be 0, 1 or 2, got {self.gain_setting}")
        if not 80 <= self.sample_period_ticks <= 40000:
            raise PingProtocolError(f"sample_period must be 80-40000 ticks of 25 ns, got {self.sample_period_ticks}")
        if not 200 <= self.number_of_samples <= 1200:
            raise PingProtocolError(f"number_of_samples must be 200-1200, got {self.number_of_samples}")
        if not 1 <= self.transmit_duration_us <= 1000:
            raise PingProtocolError(f"transmit_duration must be 1-1000 us, got {self.transmit_duration_us}")

    def range_m(self, sound_speed_mps: float = 1500.0) -> float:
        """Range of the last sample: samples x period x 25 ns x c / 2."""
        return self.number_of_samples * self.sample_period_ticks * SAMPLE_TICK_S * sound_speed_mps / 2

    @classmethod
    def for_range(cls, range_m: float, *, number_of_samples: int = 1200, sound_speed_mps: float = 1500.0,
                  **kw) -> "Settings":
        """The sample period that puts the last sample at ``range_m`` (clipped to the device's
        80-40000 ticks), and a transmit duration that grows with range as Ping Viewer's does."""
        ticks = int(round(2 * range_m / (sound_speed_mps * number_of_samples * SAMPLE_TICK_S)))
        ticks = min(max(ticks, 80), 40000)
        duration = int(min(max(round(8 * range_m / 1.5), 5), 500))   # ~8 us per 1.5 m of range
        return cls(sample_period_ticks=ticks, number_of_samples=number_of_samples,
                   transmit_duration_us=kw.pop("transmit_duration_us", duration), **kw)


def encode_transducer(s: Settings, angle: int, *, transmit: bool = True) -> bytes:
    _check_angle(angle)
    return encode(TRANSDUCER, _TRANSDUCER.pack(s.mode, s.gain_setting, angle, s.transmit_duration_us,
                                               s.sample_period_ticks, s.transmit_frequency_khz,
                                               s.number_of_samples, int(transmit), 0))


def encode_auto_transmit(s: Settings, start: int = 0, stop: int = GRADIANS - 1, num_steps: int = 1, delay: int = 0) -> bytes:
    _check_angle(start)
    _check_angle(stop)
    return encode(AUTO_TRANSMIT, _AUTO_TRANSMIT.pack(s.mode, s.gain_setting, s.transmit_duration_us,
                                                     s.sample_period_ticks, s.transmit_frequency_khz,
                                                     s.number_of_samples, start, stop, num_steps, delay))


def encode_request(message_id: int) -> bytes:
    return encode(GENERAL_REQUEST, struct.pack("<H", message_id))


def _check_angle(angle: int) -> None:
    if not 0 <= angle < GRADIANS:
        raise PingProtocolError(f"angle must be 0-{GRADIANS - 1} gradians, got {angle}")


@dataclass(frozen=True)
class Beam:
    """One reply: the settings it was taken with, its angle (gradians) and samples (uint8)."""

    angle: int
    settings: Settings
    samples: np.ndarray
    auto: bool = False


def decode_transducer(payload: bytes) -> tuple[Settings, int, bool]:
    if len(payload) != _TRANSDUCER.size:
        raise PingProtocolError(f"transducer payload of {len(payload)} bytes, expected {_TRANSDUCER.size}")
    mode, gain, angle, dur, period, freq, n, transmit, _ = _TRANSDUCER.unpack(payload)
    _check_angle(angle)
    return Settings(mode, gain, dur, period, freq, n), angle, bool(transmit)


def decode_auto_transmit(payload: bytes) -> tuple[Settings, int, int, int, int]:
    if len(payload) != _AUTO_TRANSMIT.size:
        raise PingProtocolError(f"auto_transmit payload of {len(payload)} bytes, expected {_AUTO_TRANSMIT.size}")
    mode, gain, dur, period, freq, n, start, stop, steps, delay = _AUTO_TRANSMIT.unpack(payload)
    _check_angle(start)
    _check_angle(stop)
    return Settings(mode, gain, dur, period, freq, n), start, stop, steps, delay


def encode_device_data(s: Settings, angle: int, samples: np.ndarray) -> bytes:
    data = np.asarray(samples, np.uint8).tobytes()
    head = _DEVICE_DATA.pack(s.mode, s.gain_setting, angle, s.transmit_duration_us, s.sample_period_ticks,
                             s.transmit_frequency_khz, s.number_of_samples, len(data))
    return encode(DEVICE_DATA, head + data, src=1)


def encode_auto_device_data(s: Settings, angle: int, samples: np.ndarray, start: int, stop: int, steps: int,
                            delay: int) -> bytes:
    data = np.asarray(samples, np.uint8).tobytes()
    head = _AUTO_DEVICE_DATA.pack(s.mode, s.gain_setting, angle, s.transmit_duration_us, s.sample_period_ticks,
                                  s.transmit_frequency_khz, start, stop, steps, delay, s.number_of_samples, len(data))
    return encode(AUTO_DEVICE_DATA, head + data, src=1)


def decode_beam(message_id: int, payload: bytes) -> Beam:
    """A 2300 or 2301 reply as a :class:`Beam`; raises :class:`PingProtocolError` on a short
    payload, a data length that disagrees with the frame, or an angle outside 0-399."""
    auto = message_id == AUTO_DEVICE_DATA
    st = _AUTO_DEVICE_DATA if auto else _DEVICE_DATA
    if len(payload) < st.size:
        raise PingProtocolError(f"beam payload of {len(payload)} bytes, shorter than its {st.size}-byte header")
    fields = st.unpack_from(payload)
    if auto:
        mode, gain, angle, dur, period, freq, _start, _stop, _steps, _delay, n, length = fields
    else:
        mode, gain, angle, dur, period, freq, n, length = fields
    if length != len(payload) - st.size:
        raise PingProtocolError(f"beam says {length} samples but carries {len(payload) - st.size}")
    _check_angle(angle)
    samples = np.frombuffer(payload, np.uint8, count=length, offset=st.size)
    try:
        settings = Settings(mode, gain, dur, period, freq, n)
    except PingProtocolError:
        settings = Settings(mode, min(gain, 2), max(min(dur, 1000), 1), min(max(period, 80), 40000), freq,
                            min(max(n, 200), 1200))       # report what came, clipped to the valid box
    return Beam(angle, settings, samples, auto)


@dataclass(frozen=True)
class Frame:
    message_id: int
    src: int
    dst: int
    payload: bytes


class PingParser:
    """Bytes in, whole frames out. Garbage before a sync is skipped (counted in bytes), a frame
    whose checksum fails or whose length is impossible is dropped (counted) and the search
    restarts one byte after its sync, so a corrupted length never swallows good frames."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.frames = 0
        self.checksum_errors = 0
        self.bad_lengths = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                keep = n - 1 if n and buf[-1:] == b"B" else n     # a lone 'B' may start the next sync
                self.skipped_bytes += max(0, keep - pos)
                pos = keep
                break
            self.skipped_bytes += start - pos
            if n - start < HEADER_SIZE:
                pos = start
                break
            _, length, mid, src, dst = HEADER.unpack_from(buf, start)
            if length > MAX_PAYLOAD:
                self.bad_lengths += 1
                pos = start + 1
                continue
            end = start + HEADER_SIZE + length
            if n < end + 2:
                pos = start
                break
            (got,) = struct.unpack_from("<H", buf, end)
            if got != checksum(memoryview(buf)[start:end]):
                self.checksum_errors += 1
                pos = start + 1
                continue
            out.append(Frame(mid, src, dst, bytes(buf[start + HEADER_SIZE:end])))
            self.frames += 1
            pos = end + 2
        del buf[:pos]
        return out
