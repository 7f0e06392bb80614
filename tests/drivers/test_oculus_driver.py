"""OculusSonar over real sockets on 127.0.0.1: resync, reconnect, discovery, standby on stop."""
from __future__ import annotations

import socket
import threading
import time
from typing import Callable

import numpy as np
import pytest

from drivers.oculus import OculusSonar
from drivers.oculus_protocol import MSG_FIRE, FireSettings, StatusInfo, decode_fire, encode_ping, encode_status
from drivers.oculus_stream import Frame, StreamParser
from tether.testing import Harness


def wait_for(cond: Callable[[], bool], timeout: float = 5.0) -> None:
    """Bounded poll: return as soon as ``cond()`` holds, fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def make_ping(ping_id: int, *, version: int = 2, bits: int = 8, gains: bool = False, descending: bool = False,
              beams: int = 256) -> bytes:
    rng = np.random.default_rng(ping_id)
    dtype = np.uint16 if bits == 16 else np.uint8
    image = rng.integers(0, np.iinfo(dtype).max, size=(30, beams), dtype=dtype)
    bearings = np.round(np.linspace(-6500, 6500, beams) ** 3 / 6500 ** 2 * 0.3 + np.linspace(-6500, 6500, beams) * 0.7)
    bearings = bearings[::-1] if descending else bearings
    fire = FireSettings.make(range_m=10.0, bits=bits, row_gain=gains, beams=512 if beams == 512 else 256)
    return encode_ping(image, bearings.astype(np.int16), fire=fire, version=version, ping_id=ping_id,
                       range_resolution_m=0.05, row_gains=np.full(30, 2.0) if gains else None,
                       image_align=2048, ping_start_time=100.0 + ping_id / 10, src=4242)


class ScriptedSonar:
    """A TCP server on 127.0.0.1 that plays ``script(conn, index)`` to each client and records fires."""

    def __init__(self, script: Callable[[socket.socket, int], None]) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.server.settimeout(0.05)
        self.port = self.server.getsockname()[1]
        self.script = script
        self.fires: list[FireSettings] = []
        self.connections = 0
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._serve, daemon=True)]
        self._threads[0].start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except (socket.timeout, OSError):
                continue
            self.connections += 1
            t = threading.Thread(target=self._client, args=(conn, self.connections - 1), daemon=True)
            self._threads.append(t)
            t.start()

    def _client(self, conn: socket.socket, index: int) -> None:
        reader = threading.Thread(target=self._read_fires, args=(conn,), daemon=True)
        reader.start()
        try:
            self.script(conn, index)
        except OSError:
            pass

    def _read_fires(self, conn: socket.socket) -> None:
        parser = StreamParser(accept=(MSG_FIRE,))
        try:
            conn.settimeout(0.05)
        except OSError:                                          # already closed by the script
            return
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            if not data:
                return
            self.fires += [decode_fire(f.data) for f in parser.feed(data) if isinstance(f, Frame)]

    def hold(self, conn: socket.socket) -> None:
        """Keep a connection open until the test ends."""
        self._stop.wait()
        conn.close()

    def close(self) -> None:
        self._stop.set()
        self.server.close()


@pytest.fixture
def run_driver():
    started: list[tuple[Harness, threading.Thread]] = []

    def start(**params) -> Harness:
        base = dict(address="127.0.0.1", status_port=0, status_bind="127.0.0.1", backoff_initial_s=0.05,
                    backoff_max_s=0.2, connect_timeout_s=1.0, refire_s=0.0)
        h = Harness(OculusSonar, params={**base, **params}, node_id="sonar")
        t = threading.Thread(target=h.node.run, daemon=True)
        t.start()
        started.append((h, t))
        return h

    yield start
    for h, t in started:
        h.node.stopping.set()
        t.join(timeout=5)
        h.close()


def test_garbage_truncation_and_corruption_are_skipped_and_counted(run_driver):
    v2_16 = make_ping(1, bits=16, gains=True, beams=512)
    corrupt = bytearray(make_ping(2))
    corrupt[198:202] = b"\x07\0\0\0"                              # V2 messageSize wrong

    def script(conn: socket.socket, index: int) -> None:
        conn.sendall(b"\x00garbage" * 50 + v2_16 + bytes(corrupt) + make_ping(3)[:3000]
                     + make_ping(4, version=0, descending=True) + b"SO" + bytes(40) + make_ping(5))
        sonar.hold(conn)

    sonar = ScriptedSonar(script)
    h = run_driver(port=sonar.port, bits=16, beams=512, fire_version=2)
    wait_for(lambda: len(h.of("ping")) >= 3)
    pings = h.of("ping")
    assert [p.ping_id for p in pings] == [1, 4, 5]
    first, v1 = pings[0], pings[1]
    assert first.intensities.dtype == np.uint16 and first.intensities.shape == (30, 512)
    np.testing.assert_array_equal(first.row_gains, np.full(30, 2.0, np.float32))
    assert first.device_stamp_ns == 100_100_000_000 and first.device_id == 4242
    assert v1.device_stamp_ns == 0 and np.all(np.diff(v1.bearings_rad) < 0)
    c = h.node.counters
    assert c["resyncs"] >= 2 and c["bad_messages"] >= 2 and c["bytes_skipped"] > 400
    fire = sonar.fires[0]
    assert fire.bits == 16 and fire.beams == 512 and fire.row_gain and fire.ping_rate == 1
    sonar.close()


def test_standby_is_sent_on_stop(run_driver):
    sonar = ScriptedSonar(lambda conn, i: (conn.sendall(make_ping(1, version=1)), sonar.hold(conn)))
    h = run_driver(port=sonar.port, fire_version=1, range_m=7.5, gain_percent=33)
    wait_for(lambda: len(h.of("ping")) == 1 and len(sonar.fires) >= 1)
    h.node.stopping.set()
    wait_for(lambda: any(f.ping_rate == 5 for f in sonar.fires))
    standby = [f for f in sonar.fires if f.ping_rate == 5][0]
    assert standby.range == 7.5 and standby.gain_percent == 33
    sonar.close()


def test_sonar_vanishing_mid_stream_triggers_reconnect(run_driver):
    def script(conn: socket.socket, index: int) -> None:
        if index == 0:
            conn.sendall(make_ping(10) + make_ping(11)[:5000])   # dies mid-message
            conn.close()
        else:
            conn.sendall(make_ping(20 + index))
            sonar.hold(conn)

    sonar = ScriptedSonar(script)
    h = run_driver(port=sonar.port)
    wait_for(lambda: len(h.of("ping")) >= 2)
    assert [p.ping_id for p in h.of("ping")][:2] == [10, 21]
    assert h.node.counters["reconnects"] >= 1 and sonar.connections >= 2
    sonar.close()


def test_silent_data_stream_times_out_and_reconnects(run_driver):
    sonar = ScriptedSonar(lambda conn, i: sonar.hold(conn))     # accepts, never sends
    h = run_driver(port=sonar.port, data_timeout_s=0.2)
    wait_for(lambda: sonar.connections >= 2)
    assert h.node.counters["reconnects"] >= 1 and not h.of("ping")
    sonar.close()


def test_unreachable_sonar_backs_off_without_crashing(run_driver):
    from tether.transport import free_port_base

    # below the ephemeral range: a port bind(0) handed out can be taken by an outgoing connection,
    # the driver's own included (a TCP self-connect "succeeds" on Linux)
    port = free_port_base(1)                                     # nothing listens there
    h = run_driver(port=port)
    wait_for(lambda: h.node.counters["reconnects"] >= 3)
    assert not h.of("ping")


def test_discovery_from_status_broadcast_on_loopback(run_driver):
    sonar = ScriptedSonar(lambda conn, i: (conn.sendall(make_ping(42)), sonar.hold(conn)))
    h = run_driver(address="", port=sonar.port, discovery_timeout_s=0.2, status_timeout_s=0.0)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    status = encode_status(StatusInfo(device_id=4242, ip_address="127.0.0.1"))
    try:
        wait_for(lambda: (udp.sendto(status, ("127.0.0.1", h.node.status_port_bound)) and False)
                 or len(h.of("ping")) >= 1)
    finally:
        udp.close()
    assert h.of("ping")[0].ping_id == 42 and h.node.counters["status"] >= 1
    sonar.close()


def test_bad_status_datagram_is_counted_and_ignored(run_driver):
    h = run_driver(address="", port=1, discovery_timeout_s=0.1)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        wait_for(lambda: (udp.sendto(b"SO" + bytes(60), ("127.0.0.1", h.node.status_port_bound)) and False)
                 or h.node.counters["bad_status"] >= 1)
    finally:
        udp.close()
    assert h.node.counters["reconnects"] == 0 and not h.of("ping")


def test_status_going_silent_drops_the_connection(run_driver):
    sonar = ScriptedSonar(lambda conn, i: (conn.sendall(make_ping(i)), sonar.hold(conn)))
    h = run_driver(port=sonar.port, status_timeout_s=0.2, data_timeout_s=30.0)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    status = encode_status(StatusInfo(device_id=4242, ip_address="127.0.0.1"))
    try:
        wait_for(lambda: (udp.sendto(status, ("127.0.0.1", h.node.status_port_bound)) and False)
                 or h.node.counters["status"] >= 1)
    finally:
        udp.close()
    wait_for(lambda: sonar.connections >= 2)                    # status stopped: reconnect
    assert h.node.counters["reconnects"] >= 1
    sonar.close()


def test_config_rejects_bad_values():
    from tether.errors import ConfigError

    with pytest.raises(ConfigError, match="ping_rate"):
        OculusSonar.make_config({"ping_rate": "fast"})
    with pytest.raises(ConfigError, match="stamp"):
        OculusSonar.make_config({"stamp": "gps"})


def test_a_ping_whose_time_is_not_a_time_is_counted_and_skipped(run_driver):
    def ping(ping_id: int, start: float) -> bytes:
        fire = FireSettings.make(range_m=10.0, bits=8, beams=256)
        image = np.zeros((30, 256), np.uint8)
        return encode_ping(image, np.linspace(-6500, 6500, 256).astype(np.int16), fire=fire, version=2,
                           ping_id=ping_id, range_resolution_m=0.05, ping_start_time=start)

    def script(conn: socket.socket, index: int) -> None:
        conn.sendall(ping(1, float("inf")) + ping(2, -1.0) + ping(3, float("nan")) + ping(4, 1e300) + ping(5, 12.5))
        sonar.hold(conn)

    sonar = ScriptedSonar(script)
    h = run_driver(port=sonar.port, fire_version=2)
    wait_for(lambda: len(h.of("ping")) >= 1)
    assert [p.ping_id for p in h.of("ping")] == [5] and h.of("ping")[0].device_stamp_ns == 12_500_000_000
    assert h.node.counters["bad_times"] == 4
    sonar.close()
