"""Ping360 scanning-sonar driver over pyserial: configure, scan, publish each beam as ``ping``.

``Ping360`` (a source node) opens ``port`` with ``serial.serial_for_url`` -- a device path
(``/dev/ttyUSB0``), a pseudo-terminal, or a URL pyserial knows (``socket://host:port`` for a
Ping360 behind a TCP bridge) -- at ``baudrate``, asks for the device information, then
scans ``sector`` (gradians, 0-399; 0 ahead, increasing to starboard) either with
``auto_transmit`` (``mode = "auto"``: the device streams beams) or with one ``transducer``
request per angle (``mode = "request"``: works on every firmware). Every reply becomes a
one-beam :class:`msgs.sonar.SonarPing` (``intensities`` (N, 1) uint8, ``bearings_rad``
[angle], ``range_m`` from the sample period). Garbage is skipped to the next ``BR``,
frames with a wrong checksum or an impossible length are dropped, replies that cannot be a
beam (short payload, angle outside 0-399) are counted: each kind counted and logged once
per power of ten. A port that disappears or falls silent for ``data_timeout_s`` is closed
and reopened with exponential backoff. On stop the driver sends ``motor_off`` so the head
does not keep turning uncommanded.
"""
from __future__ import annotations

import math
import threading
import time

import msgspec
import numpy as np

from drivers import ping_protocol as pp
from msgs.sonar import SonarPing
from tether import DriverError, Node

MODES = ("auto", "request")


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    port: str = "/dev/ttyUSB0"         # device path, pty, or pyserial URL (socket://host:port)
    baudrate: int = 115200
    mode: str = "auto"                 # auto: auto_transmit; request: one transducer request per angle
    range_m: float = 20.0
    number_of_samples: int = 1200
    gain_setting: int = 0              # 0 low, 1 normal, 2 high
    transmit_frequency_khz: int = 740
    sector_start_grad: int = 0
    sector_stop_grad: int = 399
    step_grad: int = 1
    sound_speed_mps: float = 1500.0
    frame_id: str = "ping360"
    data_timeout_s: float = 2.0
    info_timeout_s: float = 1.0
    backoff_initial_s: float = 0.25
    backoff_max_s: float = 4.0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("sector_start_grad", "sector_stop_grad"):
            if not 0 <= getattr(self, name) < pp.GRADIANS:
                raise ValueError(f"{name} must be 0-{pp.GRADIANS - 1}, got {getattr(self, name)}")
        if not 1 <= self.step_grad <= 10 or self.baudrate <= 0 or self.range_m <= 0:
            raise ValueError("step_grad must be 1-10, baudrate and range_m positive")
        pp.Settings(gain_setting=self.gain_setting, number_of_samples=self.number_of_samples)


def settings_of(cfg: Config) -> pp.Settings:
    return pp.Settings.for_range(cfg.range_m, number_of_samples=cfg.number_of_samples, sound_speed_mps=cfg.sound_speed_mps,
                                 gain_setting=cfg.gain_setting, transmit_frequency_khz=cfg.transmit_frequency_khz)


def beam_ping(beam: pp.Beam, *, stamp_ns: int, sound_speed_mps: float, frame_id: str, seq_id: int) -> SonarPing:
    """A one-beam SonarPing of a Ping360 reply (row i at (i + 0.5) * resolution)."""
    s = beam.settings
    n = max(len(beam.samples), 1)
    range_m = s.range_m(sound_speed_mps)
    return SonarPing(stamp_ns=stamp_ns, frame_id=frame_id, intensities=beam.samples.reshape(-1, 1).copy(),
                     bearings_rad=np.array([2 * math.pi * beam.angle / pp.GRADIANS], np.float32),
                     range_resolution_m=range_m / n, range_m=range_m, frequency_hz=1e3 * s.transmit_frequency_khz,
                     sound_speed_mps=sound_speed_mps, ping_id=seq_id, gain_percent=50.0 * s.gain_setting,
                     horizontal_aperture_rad=math.radians(2.0), vertical_aperture_rad=math.radians(25.0))


class Ping360(Node):
    """Output ``ping`` (one beam per message). Counters in ``self.counters``; a summary at teardown."""

    Config = Config
    outputs = {"ping": SonarPing}

    def setup(self) -> None:
        self.settings = settings_of(self.config)
        self.counters = dict(beams=0, checksum_errors=0, bad_lengths=0, bytes_skipped=0, bad_beams=0, nacks=0,
                             reconnects=0, other=0)
        self._logged: dict[str, int] = {}
        self._lock = threading.Lock()
        self._serial = None
        self.device_type: int | None = None
        self._angle = self.config.sector_start_grad
        self._dir = 1

    # -- the session ----------------------------------------------------------------------------
    def run(self) -> None:
        cfg: Config = self.config
        backoff = cfg.backoff_initial_s
        while not self.stopping.is_set():
            beams_before = self.counters["beams"]
            try:
                self._session()
            except (OSError, DriverError, ValueError) as exc:      # serial.SerialException is an OSError
                self._close()
                if self.stopping.is_set():
                    break
                self.counters["reconnects"] += 1
                if self.counters["beams"] > beams_before:
                    backoff = cfg.backoff_initial_s
                self.log.warning("ping360 on %s: %s; reopening in %.2f s", cfg.port, exc, backoff)
                self.stopping.wait(backoff)
                backoff = min(2 * backoff, cfg.backoff_max_s)
        self._motor_off()
        self._close()

    def _session(self) -> None:
        import serial

        cfg: Config = self.config
        ser = serial.serial_for_url(cfg.port, baudrate=cfg.baudrate, timeout=0.02)
        with self._lock:
            self._serial = ser
        parser = pp.PingParser()
        self._seen = dict(checksum_errors=0, bad_lengths=0, bytes_skipped=0)
        self._send(pp.encode_request(pp.DEVICE_INFORMATION))
        self._start_scan()
        last = time.monotonic()
        asked_info = last
        while not self.stopping.is_set():
            data = ser.read(max(1, ser.in_waiting))
            now = time.monotonic()
            if data:
                last = now
                for frame in parser.feed(data):
                    self._handle(frame)
                self._count_parser(parser)
            if self.device_type is None and now - asked_info > cfg.info_timeout_s:
                self._send(pp.encode_request(pp.DEVICE_INFORMATION))      # old firmware may drop the first
                asked_info = now
            if now - last > cfg.data_timeout_s:
                raise DriverError(f"no data for {cfg.data_timeout_s:.1f} s")

    def _start_scan(self) -> None:
        cfg: Config = self.config
        if cfg.mode == "auto":
            self._send(pp.encode_auto_transmit(self.settings, cfg.sector_start_grad, cfg.sector_stop_grad, cfg.step_grad))
        else:
            self._send(pp.encode_transducer(self.settings, self._angle))

    def _next_angle(self) -> int:
        cfg: Config = self.config
        lo, hi = cfg.sector_start_grad, cfg.sector_stop_grad
        if (lo, hi) == (0, pp.GRADIANS - 1) or lo > hi:
            return (self._angle + cfg.step_grad) % pp.GRADIANS
        nxt = self._angle + self._dir * cfg.step_grad
        if not lo <= nxt <= hi:
            self._dir = -self._dir
            nxt = self._angle + self._dir * cfg.step_grad
        return min(max(nxt, lo), hi)

    def _handle(self, frame: pp.Frame) -> None:
        cfg: Config = self.config
        if frame.message_id in (pp.DEVICE_DATA, pp.AUTO_DEVICE_DATA):
            try:
                beam = pp.decode_beam(frame.message_id, frame.payload)
            except pp.PingProtocolError as exc:
                self._count("bad_beams", f"dropped a reply that is not a beam: {exc}")
                return
            if len(beam.samples):
                self.counters["beams"] += 1
                self.publish("ping", beam_ping(beam, stamp_ns=self.now_ns(), sound_speed_mps=cfg.sound_speed_mps,
                                               frame_id=cfg.frame_id, seq_id=self.counters["beams"]))
            if cfg.mode == "request" and frame.message_id == pp.DEVICE_DATA:
                self._angle = self._next_angle()
                self._send(pp.encode_transducer(self.settings, self._angle))
        elif frame.message_id == pp.DEVICE_INFORMATION and frame.payload:
            self.device_type = frame.payload[0]
            if self.device_type != pp.DEVICE_TYPE_PING360:
                self.log.warning("device type %d is not a Ping360 (2); scanning anyway", self.device_type)
            else:
                self.log.info("Ping360 on %s, firmware %d.%d.%d; %s scan, %.1f m", cfg.port, *frame.payload[2:5],
                              cfg.mode, self.settings.range_m(cfg.sound_speed_mps))
        elif frame.message_id == pp.NACK:
            reason = frame.payload[2:].split(b"\0")[0].decode(errors="replace")
            self._count("nacks", f"device refused a request: {reason}")
        elif frame.message_id != pp.ACK:
            self.counters["other"] += 1

    def _count_parser(self, parser: pp.PingParser) -> None:
        for key, total in (("checksum_errors", parser.checksum_errors), ("bad_lengths", parser.bad_lengths),
                           ("bytes_skipped", parser.skipped_bytes)):
            new = total - self._seen[key]
            if new:
                self._seen[key] = total
                self._count(key, f"{key.replace('_', ' ')} in the stream", new)

    def _count(self, key: str, message: str, n: int = 1) -> None:
        """Count; log the first and then at every power of ten, so a noisy line cannot flood the log."""
        self.counters[key] += n
        total, shown = self.counters[key], self._logged.get(key, 0)
        if shown == 0 or total >= 10 * shown:
            self._logged[key] = total
            self.log.warning("%s (%d so far)", message, total)

    def _send(self, data: bytes) -> None:
        with self._lock:
            if self._serial is None:
                raise DriverError("port not open")
            self._serial.write(data)

    def _motor_off(self) -> None:
        with self._lock:
            if self._serial is None:
                return
            try:
                self._serial.write(pp.encode(pp.MOTOR_OFF))
                self._serial.flush()
                self.log.info("sent motor_off")
            except OSError as exc:
                self.log.warning("could not send motor_off: %s", exc)

    def _close(self) -> None:
        with self._lock:
            ser, self._serial = self._serial, None
        if ser is not None:
            try:
                ser.close()
            except OSError:
                pass

    def teardown(self) -> None:
        self._motor_off()
        self._close()
        self.log.info("ping360 driver: %s", ", ".join(f"{k} {v}" for k, v in self.counters.items()))
