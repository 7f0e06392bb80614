"""FLS simulator node: a fake Oculus sonar on 127.0.0.1 that renders a scene, plus ground truth.

Node ``sim.fls:FlsSonar`` serves the real protocol: a UDP status datagram (142 B) to
``status_address:status_port`` every second and a TCP server on ``bind_address:port``. A client
(``drivers.oculus:OculusSonar``, unchanged) connects and sends a SimpleFire; the simulator then
renders pings with the requested range, gain, gamma, frequency, beams and bits at the requested
ping rate (one per request when the network-trigger flag is set; dummies in standby) and sends
SimplePingResults (V1 or V2, as fired; image padded to ``image_align``; per-row gain of 1.0 when
asked, or rising ``row_gain_db_per_m`` dB per metre of range, 0 dB at mid-range, encoded as
``row_gain_encoding``). For every ping it publishes, stamped alike:

* ``ping``  (SonarPing): what the driver will decode from that ping (a launch may skip the driver);
* ``pose``  (geometry.Pose3D, frame ``world``): the sonar head (FRD: x boresight, y starboard,
  z down) in the world (x east, y north, z up, surface z = 0);
* ``truth`` (sensor.PointCloud, frame ``world``): the true first-hit points, intensity = echo.

The stamp is the render time to the microsecond; V2 ``pingStartTime`` carries it in seconds, so
a driver with ``stamp: device`` gives its pings exactly the stamp of ``pose`` and ``truth``. With
``self_fire: true`` the simulator pings on its own (no client needed) with its own settings.

Pure API (no sockets, no tether), for tests and benchmarks::

    from sim.fls import load_scene, render_ping, PingSettings, sample_structures
    scene = load_scene("tripod")                 # sim/scenes/fls_tripod.yaml (also "flat", "cylinder")
    pose = scene.sonar_pose(14.0)                # 4x4 sonar(FRD) -> world at t = 14 s of the run
    ping = render_ping(scene, pose, PingSettings(n_beams=512, range_m=20), rng=np.random.default_rng(0))
    ping.intensities      # (R, B) uint8, row i at (i + 0.5) * ping.range_resolution_m
    ping.bearings_rad     # (B,) real non-uniform table; ping.level = noise-free level (rng=None: no noise)
    ping.hits_m           # (K, 3) true first hits, world; hit_labels 0 = seafloor, k = structures[k-1]
    model_pts, model_normals = sample_structures(scene, spacing_m=0.1)   # the structures' surfaces
"""
from __future__ import annotations

import select
import socket
import time
from dataclasses import replace

import msgspec
import numpy as np

from drivers.oculus import sonar_ping_from
from drivers.oculus_protocol import (FLAG_NETWORK_TRIGGER, FLAG_RANGE_METRES, MSG_DUMMY, MSG_FIRE, PING_RATE_HZ,
                                     PING_RATES, STANDBY, FireSettings, Header, StatusInfo, decode_fire, decode_ping,
                                     encode_ping, encode_status)
from drivers.oculus_stream import Frame, StreamParser
from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from msgs.sonar import SonarPing
from sim.fls_render import PingSettings, RenderedPing, bearing_table, render_ping
from sim.fls_scene import Scene, cast_rays, load_scene, sample_structures, sonar_frame
from tether import Node

__all__ = ["FlsSonar", "FakeOculus", "PingSettings", "RenderedPing", "Scene", "bearing_table", "cast_rays",
           "load_scene", "render_ping", "sample_structures", "settings_from_fire", "sonar_frame"]


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    scene: str = "tripod"              # name in sim/scenes (fls_<name>.yaml) or a YAML path
    bind_address: str = "127.0.0.1"
    port: int = 52100                  # 0 = ephemeral (read node.port_bound)
    status_address: str = "127.0.0.1"
    status_port: int = 52102
    status_rate_hz: float = 1.0
    serial: int = 4242
    seed: int = 0
    time_offset_s: float = 0.0         # where on the back-and-forth run the boat starts
    elevation_rays: int = 0            # 0 = the scene's
    image_align: int = 2048
    row_gain_encoding: str = "float"
    row_gain_db_per_m: float = 0.0     # per-row gain slope the device applies and reports (0: gain 1 everywhere)
    truth_structures_only: bool = False
    self_fire: bool = False            # ping without a client, with the settings below
    range_m: float = 20.0
    gain_percent: float = 50.0
    gamma_correction: int = 127
    ping_rate: str = "high"
    frequency: str = "low"
    bits: int = 8
    beams: int = 512

    def __post_init__(self) -> None:
        if self.ping_rate not in PING_RATES:
            raise ValueError(f"ping_rate must be one of {sorted(PING_RATES)}, got {self.ping_rate!r}")
        if self.row_gain_encoding not in ("float", "u32"):
            raise ValueError(f"row_gain_encoding must be 'float' or 'u32', got {self.row_gain_encoding!r}")


def settings_from_fire(fire: FireSettings, scene: Scene, elevation_rays: int = 0,
                       row_gain_db_per_m: float = 0.0) -> PingSettings:
    """What to render for a SimpleFire (range in % of the mode's maximum when flag bit0 is clear)."""
    frequency = "low" if fire.master_mode == 1 else "high"
    max_range = scene.sonar.modes[frequency]["max_range_m"]
    range_m = fire.range if fire.flags & FLAG_RANGE_METRES else fire.range / 100.0 * max_range
    gamma = fire.gamma / 255.0 if fire.gamma not in (0, 255) else 1.0
    return PingSettings(n_beams=fire.beams, range_m=max(min(range_m, max_range), 0.1), frequency=frequency,
                        gain_percent=min(max(fire.gain_percent, 0.0), 100.0), gamma=gamma,
                        bits=16 if fire.bits > 8 else 8, elevation_rays=elevation_rays,
                        row_gain_db_per_m=row_gain_db_per_m if fire.row_gain else 0.0)


class FakeOculus:
    """The sonar's sockets: a TCP server for one client at a time and the UDP status sender."""

    def __init__(self, cfg: Config, log) -> None:
        self.log = log
        self.server = socket.create_server((cfg.bind_address, cfg.port))
        self.server.setblocking(False)
        self.port = self.server.getsockname()[1]
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        ip = cfg.bind_address if cfg.bind_address not in ("", "0.0.0.0") else "127.0.0.1"
        self.status = StatusInfo(device_id=cfg.serial, ip_address=ip)
        self.status_target = (cfg.status_address, cfg.status_port)
        self.client: socket.socket | None = None
        self.parser = StreamParser(accept=(MSG_FIRE,))
        self.fire: FireSettings | None = None
        self.fire_version = 2
        self.triggers = 0
        self.clients = 0

    def poll(self, timeout: float) -> None:
        """Accept a client (a new one replaces the old), read its fire requests."""
        watch = [self.server] + ([self.client] if self.client else [])
        readable, _, _ = select.select(watch, [], [], max(timeout, 0.0))
        if self.server in readable:
            conn, peer = self.server.accept()
            self.drop()
            conn.setblocking(True)
            conn.settimeout(2.0)
            self.client, self.parser, self.clients = conn, StreamParser(accept=(MSG_FIRE,)), self.clients + 1
            self.log.info("client %s:%d connected", *peer)
        elif self.client is not None and self.client in readable:
            try:
                data = self.client.recv(65536)
            except OSError:
                data = b""
            if not data:
                self.drop()
                return
            for item in self.parser.feed(data):
                if isinstance(item, Frame):
                    self.fire_version = 2 if item.header.version == 2 else 1
                    self.fire = decode_fire(item.data)
                    self.triggers += bool(self.fire.flags & FLAG_NETWORK_TRIGGER and self.fire.ping_rate != STANDBY)
                else:
                    self.log.warning("client stream %s: %s", item.kind, item.detail)

    def send(self, data: bytes) -> None:
        if self.client is None:
            return
        try:
            self.client.sendall(data)
        except OSError as exc:
            self.log.info("client gone (%s)", exc)
            self.drop()

    def broadcast_status(self) -> None:
        conn = "0.0.0.0"
        if self.client is not None:
            try:
                conn = self.client.getpeername()[0]
            except OSError as exc:      # the client hung up between two polls: it is gone, not an error
                self.log.info("client gone (%s)", exc)
                self.drop()
        try:
            self.udp.sendto(encode_status(replace(self.status, connected_ip=conn)), self.status_target)
        except OSError as exc:
            self.log.debug("status broadcast failed: %s", exc)

    def drop(self) -> None:
        if self.client is not None:
            self.client.close()
        self.client, self.fire, self.triggers = None, None, 0

    def close(self) -> None:
        self.drop()
        self.server.close()
        self.udp.close()


class FlsSonar(Node):
    """Outputs ``ping`` (SonarPing), ``pose`` (Pose3D), ``truth`` (PointCloud); see the module docstring."""

    Config = Config
    outputs = {"ping": SonarPing, "pose": Pose3D, "truth": PointCloud}

    def setup(self) -> None:
        cfg: Config = self.config
        self.scene = load_scene(cfg.scene)
        self.rng = np.random.default_rng(cfg.seed)
        self.fake = FakeOculus(cfg, self.log)
        self.port_bound = self.fake.port
        self.own_fire = FireSettings.make(range_m=cfg.range_m, gain_percent=cfg.gain_percent,
                                          gamma=cfg.gamma_correction, ping_rate=PING_RATES[cfg.ping_rate],
                                          frequency=cfg.frequency, bits=cfg.bits, beams=cfg.beams, row_gain=False)
        self.ping_id = 0
        self.render_ms: list[float] = []
        self._t0_ns: int | None = None

    def run(self) -> None:
        cfg: Config = self.config
        self._t0_ns = self.now_ns() // 1000 * 1000
        next_status = next_ping = next_dummy = time.monotonic()
        while not self.stopping.is_set():
            deadline = min(next_status, next_ping) if cfg.status_rate_hz > 0 else next_ping
            self.fake.poll(min(max(0.0, deadline - time.monotonic()), 0.05))
            now = time.monotonic()
            if cfg.status_rate_hz > 0 and now >= next_status:
                self.fake.broadcast_status()
                next_status = now + 1.0 / cfg.status_rate_hz
            fire, version = self.fake.fire, self.fake.fire_version
            if fire is None and self.fake.client is None and cfg.self_fire:
                fire, version = self.own_fire, 2
            if fire is None or fire.ping_rate == STANDBY:
                if self.fake.client is not None and now >= next_dummy:
                    self.fake.send(Header(MSG_DUMMY, 0, src=cfg.serial).pack())
                    next_dummy = now + 1.0
                next_ping = now + 0.02
                continue
            if fire.flags & FLAG_NETWORK_TRIGGER:
                if not self.fake.triggers:
                    next_ping = now + 0.01
                    continue
                self.fake.triggers -= 1
            elif now < next_ping:
                continue
            self._ping(fire, version)
            settings = settings_from_fire(fire, self.scene)
            rate = min(PING_RATE_HZ.get(fire.ping_rate, 10.0) or 10.0, self.scene.sonar.sound_speed_mps / (2 * settings.range_m))
            next_ping = max(next_ping + 1.0 / rate, time.monotonic())

    def _ping(self, fire: FireSettings, version: int) -> None:
        cfg: Config = self.config
        begin = time.perf_counter()
        stamp_ns = self.now_ns() // 1000 * 1000
        pose = self.scene.sonar_pose((stamp_ns - (self._t0_ns or 0)) / 1e9 + cfg.time_offset_s)
        r = render_ping(self.scene, pose, settings_from_fire(fire, self.scene, cfg.elevation_rays, cfg.row_gain_db_per_m),
                        rng=self.rng)
        self.ping_id += 1
        echo = replace(fire, range=r.range_m, flags=fire.flags | FLAG_RANGE_METRES, ext_flags=0)
        data = encode_ping(r.intensities, r.bearings_cdeg, fire=echo, version=2 if version == 2 else 0,
                           ping_id=self.ping_id, range_resolution_m=r.range_resolution_m, frequency_hz=r.frequency_hz,
                           sound_speed_mps=self.scene.sonar.sound_speed_mps,
                           ping_start_time=stamp_ns / 1e9 if version == 2 else (stamp_ns // 1000) & 0xFFFFFFFF,
                           row_gains=r.row_gains if fire.row_gain else None,
                           gain_encoding=cfg.row_gain_encoding, image_align=cfg.image_align, src=cfg.serial)
        self.fake.send(data)
        self.render_ms.append((time.perf_counter() - begin) * 1e3)
        keep = r.hit_labels > 0 if cfg.truth_structures_only else slice(None)
        self.publish("pose", Pose3D.from_matrix(pose, stamp_ns=stamp_ns, frame_id="world"))
        self.publish("truth", PointCloud(stamp_ns=stamp_ns, frame_id="world", points_m=r.hits_m[keep].astype(np.float32),
                                         intensity=r.hit_echo[keep].astype(np.float32)))
        self.publish("ping", sonar_ping_from(decode_ping(data, gain_encoding=cfg.row_gain_encoding), stamp_ns=stamp_ns,
                                             vertical_aperture_rad=r.vertical_aperture_rad))

    def teardown(self) -> None:
        self.fake.close()
        if self.render_ms:
            ms = np.asarray(self.render_ms)
            self.log.info("fls simulator: %d pings to %d clients, render+encode median %.1f ms (max %.1f)",
                          ms.size, self.fake.clients, float(np.median(ms)), float(ms.max()))
