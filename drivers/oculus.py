"""Oculus M-series multibeam sonar driver: discover, connect, fire, publish ``ping``; standby on stop.

``OculusSonar`` (a source node) finds the sonar from its UDP status broadcast (port 52102) unless
``address`` is given, connects TCP ``port`` (52100), sends a SimpleFire (V1 or V2: range, gain,
gamma, ping rate, low/high frequency, 8/16-bit, 256/512 beams, per-row gain) and re-sends it every
``refire_s`` (the sonar stops pinging without requests). Every SimplePingResult becomes a
:class:`msgs.sonar.SonarPing` on output ``ping``. Garbage in the stream is skipped up to the next
``0x4F53`` magic; a silent data stream (``data_timeout_s``) or a silent status broadcast
(``status_timeout_s``, once the sonar has been heard) drops the connection and reconnects with
exponential backoff. On stop the driver sends the fire request with ``pingRate = 5`` (standby).

Stamps: ``stamp="receive"`` stamps a ping when its last byte arrives; ``stamp="device"`` uses the
V2 ``pingStartTime`` (seconds, kept to the microsecond), which the simulator ``sim.fls`` sets to its
own acquisition stamp, so pings then carry exactly the stamp of the simulator's ``pose``/``truth``.
"""
from __future__ import annotations

import select
import socket
import threading
import time

import msgspec
import numpy as np

from drivers.oculus_protocol import (DATA_PORT, MSG_DUMMY, MSG_PING, MSG_STATUS, PING_RATES, STATUS_PORT,
                                     FireSettings, PingResult, ProtocolError, decode_ping, decode_status, encode_fire)
from drivers.oculus_stream import Frame, Problem, StreamParser
from msgs.sonar import SonarPing
from tether import DriverError, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    address: str = ""                  # sonar IPv4; empty = discover from the UDP status broadcast
    port: int = DATA_PORT
    status_port: int = STATUS_PORT     # 0 = an ephemeral port (tests read node.status_port_bound)
    status_bind: str = "0.0.0.0"
    range_m: float = 20.0
    gain_percent: float = 50.0
    gamma_correction: int = 127        # 0..255 as the device takes it; 127 -> gamma 0.5
    ping_rate: str = "high"            # normal 10 Hz, high 15, highest 40, low 5, lowest 2
    frequency: str = "low"             # low = wide aperture, high = narrow
    bits: int = 8
    beams: int = 512
    fire_version: int = 2
    row_gain: bool = True
    gain_assist: bool = False
    sound_speed_mps: float = 0.0       # 0 = from salinity
    salinity_ppt: float = 35.0
    row_gain_encoding: str = "float"   # or "u32": the 4-byte row gain is disputed (see the spec)
    stamp: str = "receive"             # or "device" (V2 pingStartTime; exact with sim.fls)
    refire_s: float = 1.0
    connect_timeout_s: float = 2.0
    discovery_timeout_s: float = 3.0
    data_timeout_s: float = 10.0
    status_timeout_s: float = 5.0      # 0 disables the status watchdog
    backoff_initial_s: float = 0.5
    backoff_max_s: float = 8.0
    vertical_aperture_low_deg: float = 20.0
    vertical_aperture_high_deg: float = 12.0
    max_message_mb: float = 32.0
    frame_id: str = "sonar"

    def __post_init__(self) -> None:
        if self.ping_rate not in PING_RATES or self.ping_rate == "standby":
            raise ValueError(f"ping_rate must be one of normal, high, highest, low, lowest; got {self.ping_rate!r}")
        if self.stamp not in ("receive", "device"):
            raise ValueError(f"stamp must be 'receive' or 'device', got {self.stamp!r}")
        if self.fire_version not in (1, 2):
            raise ValueError(f"fire_version must be 1 or 2, got {self.fire_version}")
        if min(self.data_timeout_s, self.backoff_initial_s, self.connect_timeout_s, self.discovery_timeout_s) <= 0:
            raise ValueError("timeouts and backoff must be positive")


def fire_settings(cfg: Config) -> FireSettings:
    """The SimpleFire request a config asks for."""
    return FireSettings.make(range_m=cfg.range_m, gain_percent=cfg.gain_percent, gamma=cfg.gamma_correction,
                             ping_rate=PING_RATES[cfg.ping_rate], frequency=cfg.frequency, bits=cfg.bits,
                             beams=cfg.beams, row_gain=cfg.row_gain, gain_assist=cfg.gain_assist,
                             sound_speed_mps=cfg.sound_speed_mps, salinity_ppt=cfg.salinity_ppt)


def sonar_ping_from(result: PingResult, *, stamp_ns: int, vertical_aperture_rad: float = 0.0,
                    frame_id: str = "sonar") -> SonarPing:
    """A decoded SimplePingResult as a ``SonarPing`` (raw intensities, nRanges x nBeams, row 0 nearest).

    ``range_m`` is the image extent ``nRanges * rangeResolution``; row i is at ``(i + 0.5) * res``.
    ``horizontal_aperture_rad`` spans the beam centres plus one mean beam spacing. ``gain_percent`` is
    the echoed value as sent (in HF the device may report ``40 + 0.6 g``; not rescaled here).
    ``device_stamp_ns`` is V2 ``pingStartTime`` rounded to the microsecond, 0 for V1 (unknown unit).
    """
    bearings = np.radians(result.bearings_cdeg.astype(np.float64) / 100.0)
    n = bearings.size
    span = float(bearings.max() - bearings.min()) if n else 0.0
    aperture = span * n / (n - 1) if n > 1 else 0.0
    device_ns = device_stamp_ns(result)
    gamma = result.fire.gamma / 255.0 if result.fire.gamma not in (0, 255) else 1.0
    gains = (result.row_gains.astype(np.float32) if result.row_gains is not None else np.zeros(0, np.float32))
    return SonarPing(stamp_ns=stamp_ns, frame_id=frame_id, intensities=result.image,
                     bearings_rad=bearings.astype(np.float32), range_resolution_m=result.range_resolution_m,
                     range_m=result.n_ranges * result.range_resolution_m, frequency_hz=result.frequency_hz,
                     sound_speed_mps=result.sound_speed_mps, ping_id=result.ping_id,
                     gain_percent=result.fire.gain_percent, gamma=gamma,
                     vertical_aperture_rad=vertical_aperture_rad, horizontal_aperture_rad=aperture,
                     device_stamp_ns=device_ns, row_gains=gains, master_mode=result.fire.master_mode,
                     device_id=result.header.src)


#: Latest device time accepted (s): pingStartTime counts seconds since the sonar booted, so a
#: century is far beyond any real value while keeping the stamp inside int64 nanoseconds.
MAX_DEVICE_TIME_S = 100 * 365.25 * 86400


def device_stamp_ns(result: PingResult) -> int:
    """V2 ``pingStartTime`` in ns rounded to the microsecond; 0 when unknown (V1) or not a valid time.

    The field is a double straight off the wire: inf, NaN, negative or absurd values occur in
    corrupted streams and must not reach integer arithmetic (``int(inf)`` raises).
    """
    t = result.ping_start_time
    if result.version != 2 or not valid_device_time(t):
        return 0
    return int(round(t * 1e6)) * 1000


def valid_device_time(t: float) -> bool:
    return bool(np.isfinite(t)) and 0.0 <= t <= MAX_DEVICE_TIME_S


class OculusSonar(Node):
    """Output ``ping`` (SonarPing). Counters in ``self.counters``; a summary line at teardown."""

    Config = Config
    outputs = {"ping": SonarPing}

    def setup(self) -> None:
        cfg: Config = self.config
        self.fire = fire_settings(cfg)
        self.counters = dict(pings=0, resyncs=0, bytes_skipped=0, bad_messages=0, bad_status=0, reconnects=0,
                             status=0, dummies=0, other=0, bad_times=0)
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._standby_sent = True
        self._last_status: float | None = None
        self._sonar_ip: str | None = None
        self._session_pings = 0
        self._status_sock = self._open_status_socket()
        self.status_port_bound = self._status_sock.getsockname()[1] if self._status_sock else 0

    # -- status broadcast ---------------------------------------------------------------
    def _open_status_socket(self) -> socket.socket | None:
        cfg: Config = self.config
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            sock.bind((cfg.status_bind, cfg.status_port))
        except OSError as exc:
            sock.close()
            self.log.warning("cannot listen for Oculus status on UDP %s:%d (%s): no discovery, no status watchdog",
                             cfg.status_bind, cfg.status_port, exc)
            return None
        sock.setblocking(False)
        return sock

    def _read_status(self) -> str | None:
        """Drain pending status datagrams; return the sonar address from the last good one."""
        found = None
        while self._status_sock is not None:
            try:
                data, (src_ip, _) = self._status_sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return found
            try:
                info = decode_status(data)
            except ProtocolError as exc:
                self.counters["bad_status"] += 1
                self.log.warning("bad status datagram from %s: %s", src_ip, exc)
                continue
            ip = info.ip_address if info.ip_address != "0.0.0.0" else src_ip
            if self._sonar_ip in (None, ip):
                self.counters["status"] += 1
                self._last_status = time.monotonic()
                if found is None and self._sonar_ip is None:
                    self.log.info("discovered Oculus serial %d (part %d) at %s", info.device_id,
                                  info.part_number, ip)
                found = ip
        return found

    def _discover(self) -> str | None:
        cfg: Config = self.config
        if self._status_sock is None:
            self.stopping.wait(cfg.discovery_timeout_s)
            return None
        deadline = time.monotonic() + cfg.discovery_timeout_s
        while not self.stopping.is_set() and time.monotonic() < deadline:
            select.select([self._status_sock], [], [], min(0.1, cfg.discovery_timeout_s))
            ip = self._read_status()
            if ip is not None:
                return ip
        if not self.stopping.is_set():
            self.log.info("no Oculus status on UDP port %d in %.1f s; still listening", self.status_port_bound,
                          cfg.discovery_timeout_s)
        return None

    # -- the connection -------------------------------------------------------------------
    def run(self) -> None:
        cfg: Config = self.config
        backoff = cfg.backoff_initial_s
        while not self.stopping.is_set():
            ip = cfg.address or self._discover()
            if ip is None:
                continue
            self._sonar_ip = ip
            try:
                self._session(ip)
            except (OSError, ValueError, DriverError) as exc:    # ValueError: select on a socket closed under us
                self._close()
                if self.stopping.is_set():
                    break
                self.counters["reconnects"] += 1
                backoff = cfg.backoff_initial_s if self._session_pings else backoff
                self.log.warning("sonar %s:%d: %s; reconnecting in %.1f s", ip, cfg.port, exc, backoff)
                self.stopping.wait(backoff)
                backoff = min(2 * backoff, cfg.backoff_max_s)
                if not cfg.address:
                    self._sonar_ip = None       # rediscover: the sonar may have a new address
        self._send_standby()
        self._close()

    def _session(self, ip: str) -> None:
        cfg: Config = self.config
        sock = socket.create_connection((ip, cfg.port), timeout=cfg.connect_timeout_s)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._lock:
            self._sock, self._standby_sent = sock, False
        self._session_pings = 0
        self.log.info("connected to sonar %s:%d; firing %s", ip, cfg.port, self.fire)
        self._send(encode_fire(self.fire, version=cfg.fire_version))
        parser = StreamParser(max_message_bytes=int(cfg.max_message_mb * (1 << 20)))
        self._parser_seen: dict[str, int] = {}
        start = last_data = last_fire = time.monotonic()
        watch = [sock] + ([self._status_sock] if self._status_sock else [])
        while not self.stopping.is_set():
            readable, _, _ = select.select(watch, [], [], 0.05)
            now = time.monotonic()
            if sock in readable:
                chunk = sock.recv(1 << 20)
                if not chunk:
                    raise DriverError("the sonar closed the connection")
                last_data = now
                self._handle(parser.feed(chunk), parser)
            if self._status_sock is not None and self._status_sock in readable:
                self._read_status()
            if now - last_data > cfg.data_timeout_s:
                raise DriverError(f"no data for {cfg.data_timeout_s:.1f} s")
            if (cfg.status_timeout_s > 0 and self._last_status is not None
                    and now - max(self._last_status, start) > cfg.status_timeout_s):
                raise DriverError(f"no status broadcast for {cfg.status_timeout_s:.1f} s")
            if cfg.refire_s > 0 and now - last_fire >= cfg.refire_s:
                self._send(encode_fire(self.fire, version=cfg.fire_version))
                last_fire = now

    def _handle(self, items: list[Frame | Problem], parser: StreamParser) -> None:
        cfg: Config = self.config
        for key, total in (("resyncs", parser.resyncs), ("bytes_skipped", parser.bytes_skipped),
                           ("bad_messages", parser.bad_messages)):
            self.counters[key] += total - self._parser_seen.get(key, 0)
            self._parser_seen[key] = total
        for item in items:
            if isinstance(item, Problem):
                self.log.warning("oculus stream %s: %s", item.kind, item.detail)
                continue
            mid = item.header.msg_id
            if mid != MSG_PING:
                key = {MSG_DUMMY: "dummies", MSG_STATUS: "status"}.get(mid, "other")
                self.counters[key] += 1
                continue
            try:
                result = decode_ping(item.data, gain_encoding=cfg.row_gain_encoding)
            except ProtocolError as exc:
                self.counters["bad_messages"] += 1
                self.log.warning("bad ping message: %s", exc)
                continue
            if result.version == 2 and not valid_device_time(result.ping_start_time):
                self.counters["bad_times"] += 1          # a corrupted time: skip the ping, never die on it
                if self.counters["bad_times"] in (1, 10, 100, 1000):
                    self.log.warning("skipped ping %d: its time %r is not a valid device time (%d such so far)",
                                     result.ping_id, result.ping_start_time, self.counters["bad_times"])
                continue
            vertical = cfg.vertical_aperture_low_deg if result.fire.master_mode == 1 else cfg.vertical_aperture_high_deg
            ping = sonar_ping_from(result, stamp_ns=self.now_ns(), vertical_aperture_rad=float(np.radians(vertical)),
                                   frame_id=cfg.frame_id)
            if cfg.stamp == "device" and ping.device_stamp_ns:
                ping = msgspec.structs.replace(ping, stamp_ns=ping.device_stamp_ns)
            self.counters["pings"] += 1
            self._session_pings += 1
            self.publish("ping", ping)

    def _send(self, data: bytes) -> None:
        with self._lock:
            if self._sock is None:
                raise DriverError("not connected")
            self._sock.sendall(data)

    def _send_standby(self) -> None:
        with self._lock:
            if self._sock is None or self._standby_sent:
                return
            self._standby_sent = True
            try:
                self._sock.sendall(encode_fire(self.fire.standby(), version=self.config.fire_version))
                self.log.info("sent standby to the sonar")
            except OSError as exc:
                self.log.warning("could not send standby: %s", exc)

    def _close(self) -> None:
        with self._lock:
            sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def teardown(self) -> None:
        self._send_standby()
        self._close()
        if self._status_sock is not None:
            self._status_sock.close()
            self._status_sock = None
        self.log.info("oculus driver: %s", ", ".join(f"{k} {v}" for k, v in self.counters.items()))
