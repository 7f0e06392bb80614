"""A simulated Ping360 that speaks the Ping protocol on a byte channel (a pseudo-terminal).

The head turns over an FLS scene (:mod:`sim.fls_scene`): each beam is rendered by
:func:`sim.fls_render.render_ping` with the Ping360's own beam (2 degrees wide, 25 tall) at
the head angle, ``number_of_samples`` samples out to the range the sample period sets. It
answers ``general_request`` (device information, protocol version), ``transducer``
(one beam at the asked angle, as ``device_data``), ``auto_transmit`` (beams stream as
``auto_device_data`` from start to stop and back until ``motor_off``), ``reset`` and
``motor_off`` (ack); anything else gets a nack. Writes are paced at ``baudrate`` (10 bits a
byte), as the serial line would; ``garbage_rate`` / ``corrupt_rate`` inject junk bytes between
frames and wrong checksums, for the driver's tests.

Only what the scene needs: no motor dynamics beyond the line's pace, no temperature drift.
"""
from __future__ import annotations

import dataclasses
import math
import os
import select
import struct
import threading
import time
import tty

import numpy as np

from drivers import ping_protocol as pp

BEAM_WIDTH_DEG = 2.0
BEAM_HEIGHT_DEG = 25.0


class BeamRenderer:
    """Beams of a Ping360 at ``pose`` (4x4, head frame at angle 0 -> world) over ``scene``."""

    def __init__(self, scene, pose: np.ndarray, *, seed: int = 0, sound_speed_mps: float = 1500.0) -> None:
        from sim.fls_render import PingSettings

        modes = {k: dict(m, horizontal_aperture_deg=BEAM_WIDTH_DEG, vertical_aperture_deg=BEAM_HEIGHT_DEG,
                         max_range_m=max(m.get("max_range_m", 50.0), 100.0)) for k, m in scene.sonar.modes.items()}
        self.scene = dataclasses.replace(scene, sonar=dataclasses.replace(scene.sonar, modes=modes))
        self.pose = np.asarray(pose, float)
        self.rng = np.random.default_rng(seed)
        self.sound_speed_mps = sound_speed_mps
        self._settings = PingSettings

    def beam(self, angle: int, settings: pp.Settings) -> np.ndarray:
        from sim.fls_render import render_ping

        a = 2 * math.pi * angle / pp.GRADIANS
        turn = np.eye(4)
        turn[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
        rendered = render_ping(self.scene, self.pose @ turn,
                               self._settings(n_beams=2, range_m=settings.range_m(self.sound_speed_mps),
                                              n_ranges=settings.number_of_samples, gain_percent=50.0 + 25.0 * settings.gain_setting,
                                              bits=8),
                               rng=self.rng)
        return rendered.intensities.astype(np.float32).mean(axis=1).astype(np.uint8)


class Ping360Device:
    """The device behind a pseudo-terminal: ``port`` is the path a driver opens."""

    def __init__(self, renderer: BeamRenderer | None, *, baudrate: int = 115200, garbage_rate: float = 0.0,
                 corrupt_rate: float = 0.0, seed: int = 0) -> None:
        self.renderer = renderer
        self.baudrate = baudrate
        self.garbage_rate, self.corrupt_rate = garbage_rate, corrupt_rate
        self.rng = np.random.default_rng(seed)
        self.master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(self.master, False)      # a driver that stops reading must not hang the device
        self.port = os.ttyname(slave)
        self._slave = slave                       # kept open so the pty lives while drivers come and go
        self._stop = threading.Event()
        self._hold = threading.Event()            # asked to fall silent (hold())
        self._held = threading.Event()            # ... and it has: nothing more is written
        self._auto: tuple[pp.Settings, int, int, int] | None = None
        self._auto_angle, self._auto_dir = 0, 1
        self.beams_sent = 0
        self.requests = 0
        self.motor_offs = 0
        self.parser = pp.PingParser()
        self._thread = threading.Thread(target=self._run, name="ping360-sim", daemon=True)

    def start(self) -> "Ping360Device":
        self._thread.start()
        return self

    def hold(self, timeout_s: float = 5.0) -> None:
        """Fall silent: no more beams nor replies (requests are left unread). Returns once the device
        thread has stopped writing, so :attr:`beams_sent` is final: a test can then wait for a driver
        to read what is on the line instead of guessing how much was in flight."""
        self._hold.set()
        if not self._held.wait(timeout_s):
            raise TimeoutError(f"the simulated Ping360 did not fall silent within {timeout_s} s")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    # -- the line --------------------------------------------------------------------------------
    def _write(self, frame: bytes) -> None:
        if self.garbage_rate and self.rng.random() < self.garbage_rate:
            frame = bytes(self.rng.integers(0, 256, int(self.rng.integers(1, 40)), dtype=np.uint8)) + frame
        if self.corrupt_rate and self.rng.random() < self.corrupt_rate:
            frame = frame[:-1] + bytes([frame[-1] ^ 0x5A])
        t_end = time.monotonic() + len(frame) * 10 / self.baudrate
        view = memoryview(frame)
        while view and not self._stop.is_set():
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                select.select([], [self.master], [], 0.05)          # the line is full: wait, then look at stop
                continue
            except (OSError, ValueError):
                return
            view = view[n:]
        delay = t_end - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._hold.is_set():
                self._held.set()
                self._stop.wait(0.05)
                continue
            timeout = 0.0 if self._auto else 0.05
            try:
                ready, _, _ = select.select([self.master], [], [], timeout)
            except (OSError, ValueError):                          # closed under us: the device is gone
                return
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    data = b""
                for f in self.parser.feed(data):
                    self._handle(f)
            if self._auto:
                self._auto_step()

    def _handle(self, f: pp.Frame) -> None:
        self.requests += 1
        try:
            if f.message_id == pp.GENERAL_REQUEST:
                (wanted,) = struct.unpack("<H", f.payload[:2])
                if wanted == pp.DEVICE_INFORMATION:
                    self._write(pp.encode(pp.DEVICE_INFORMATION, bytes([pp.DEVICE_TYPE_PING360, 1, 3, 3, 0, 0]), src=1))
                elif wanted == pp.PROTOCOL_VERSION:
                    self._write(pp.encode(pp.PROTOCOL_VERSION, bytes([1, 0, 0, 0]), src=1))
                else:
                    self._nack(f.message_id, "unsupported request")
            elif f.message_id == pp.TRANSDUCER:
                self._auto = None
                settings, angle, transmit = pp.decode_transducer(f.payload)
                samples = self._render(angle, settings) if transmit else np.zeros(0, np.uint8)
                self._write(pp.encode_device_data(settings, angle, samples))
                self.beams_sent += bool(transmit)
            elif f.message_id == pp.AUTO_TRANSMIT:
                settings, start, stop, steps, delay = pp.decode_auto_transmit(f.payload)
                self._auto = (settings, start, stop, max(1, steps), delay)
                self._auto_angle, self._auto_dir = start, 1
            elif f.message_id in (pp.MOTOR_OFF, pp.RESET):
                self._auto = None
                self.motor_offs += f.message_id == pp.MOTOR_OFF
                self._write(pp.encode(pp.ACK, struct.pack("<H", f.message_id), src=1))
            else:
                self._nack(f.message_id, "unknown message")
        except pp.PingProtocolError as e:
            self._nack(f.message_id, str(e))

    def _nack(self, mid: int, text: str) -> None:
        self._write(pp.encode(pp.NACK, struct.pack("<H", mid) + text.encode()[:60] + b"\0", src=1))

    def _render(self, angle: int, settings: pp.Settings) -> np.ndarray:
        if self.renderer is None:
            n = settings.number_of_samples
            return ((np.arange(n) * 7 + angle * 3) % 251).astype(np.uint8)   # a known pattern for tests
        return self.renderer.beam(angle, settings)

    def _auto_step(self) -> None:
        settings, start, stop, steps, delay = self._auto
        angle = self._auto_angle
        self._write(pp.encode_auto_device_data(settings, angle, self._render(angle, settings), start, stop, steps, delay))
        self.beams_sent += 1
        if start <= stop and (start, stop) != (0, pp.GRADIANS - 1):         # a sector: sweep back and forth
            nxt = angle + self._auto_dir * steps
            if not start <= nxt <= stop:
                self._auto_dir = -self._auto_dir
                nxt = angle + self._auto_dir * steps
            self._auto_angle = min(max(nxt, start), stop)
        else:                                                                  # the whole circle: keep turning
            self._auto_angle = (angle + steps) % pp.GRADIANS
