"""FlsSonar as a fake Oculus on 127.0.0.1: the real driver runs unchanged against it; ground truth outputs."""
from __future__ import annotations

import socket
import threading
import time
from typing import Callable

import numpy as np
import pytest

from drivers.oculus import OculusSonar
from drivers.oculus_protocol import FLAG_NETWORK_TRIGGER, MSG_DUMMY, MSG_PING, FireSettings, decode_ping, encode_fire
from drivers.oculus_stream import Frame, StreamParser
from sim.fls import FlsSonar
from tether.testing import Harness

START_NS = 1_700_000_000_123_456_789          # the harness clock stands still here


def wait_for(cond: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


@pytest.fixture
def running():
    started: list[tuple[Harness, threading.Thread]] = []

    def start(node_cls, node_id: str, **params) -> Harness:
        h = Harness(node_cls, params=params, node_id=node_id, start_ns=START_NS)
        t = threading.Thread(target=h.node.run, daemon=True)
        t.start()
        started.append((h, t))
        return h

    yield start
    for h, t in reversed(started):
        h.node.stopping.set()
        t.join(timeout=5)
        h.close()


SIM = dict(port=0, status_port=9, elevation_rays=24, time_offset_s=14.0)   # status to the discard port


def test_driver_runs_unchanged_against_the_simulator(running):
    sim = running(FlsSonar, "sim", **SIM)
    drv = running(OculusSonar, "sonar", address="127.0.0.1", port=sim.node.port_bound, status_port=0,
                  status_bind="127.0.0.1", stamp="device", ping_rate="highest", beams=512, range_m=20.0)
    wait_for(lambda: len(drv.of("ping")) >= 3)
    got = drv.of("ping")[0]
    sent = next(p for p in sim.of("ping") if p.ping_id == got.ping_id)
    np.testing.assert_array_equal(got.intensities, sent.intensities)          # bit-exact through TCP
    assert got.intensities.shape == (1024, 512) and got.master_mode == 1 and got.device_id == 4242
    assert got.bearings_rad.max() == pytest.approx(np.radians(65.0), abs=1e-3)
    step = np.diff(got.bearings_rad)
    assert step[:10].mean() > 1.1 * step[250:260].mean()                     # non-uniform: denser at the centre
    stamp = START_NS // 1000 * 1000
    assert got.stamp_ns == stamp                                              # device stamp == truth stamp
    pose, truth = sim.of("pose")[0], sim.of("truth")[0]
    assert pose.stamp_ns == truth.stamp_ns == stamp and pose.frame_id == truth.frame_id == "world"
    expected = sim.node.scene.sonar_pose(14.0)
    np.testing.assert_allclose(pose.matrix(), expected, atol=1e-9)
    assert len(truth.points_m) > 1000 and truth.points_m[:, 2].max() > -5.5   # the tripod is in view
    assert drv.node.counters["bad_messages"] == 0 and drv.node.counters["resyncs"] == 0


def test_driver_discovers_the_simulator_from_its_status_broadcast(running):
    drv_params = dict(address="", status_port=0, status_bind="127.0.0.1", discovery_timeout_s=0.2,
                      range_m=5.0, beams=256)
    # the driver binds its status port in setup(); the simulator is then told where to broadcast
    drv_h = Harness(OculusSonar, params={**drv_params, "port": 1}, node_id="probe")
    port = drv_h.node.status_port_bound
    drv_h.close()
    sim = running(FlsSonar, "sim", **{**SIM, "status_port": port, "status_rate_hz": 20.0})
    drv = running(OculusSonar, "sonar", **{**drv_params, "status_port": port, "port": sim.node.port_bound})
    wait_for(lambda: len(drv.of("ping")) >= 1)
    assert drv.node.counters["status"] >= 1 and drv.of("ping")[0].intensities.shape[1] == 256


class RawClient:
    """A bare TCP client speaking the protocol (to drive the simulator's less common paths)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.sock.settimeout(0.05)
        self.parser = StreamParser()
        self.frames: list[Frame] = []

    def pump(self) -> int:
        try:
            data = self.sock.recv(1 << 20)
        except socket.timeout:
            return len(self.frames)
        self.frames += [f for f in self.parser.feed(data) if isinstance(f, Frame)]
        return len(self.frames)

    def wait_frames(self, kind: int, n: int) -> list[Frame]:
        wait_for(lambda: self.pump() >= 0 and sum(f.header.msg_id == kind for f in self.frames) >= n)
        return [f for f in self.frames if f.header.msg_id == kind]


def test_v1_fire_16bit_256_beams_with_row_gains(running):
    sim = running(FlsSonar, "sim", **SIM)
    client = RawClient(sim.node.port_bound)
    fire = FireSettings.make(range_m=8.0, bits=16, beams=256, row_gain=True, frequency="high", ping_rate=2)
    client.sock.sendall(encode_fire(fire, version=1))
    frame = client.wait_frames(MSG_PING, 1)[0]
    ping = decode_ping(frame.data)
    assert frame.header.version == 0 and ping.version == 1                    # V1, as real V1 pings say
    assert ping.image.dtype == np.uint16 and ping.image.shape[1] == 256 and ping.image_offset == 2048
    np.testing.assert_array_equal(ping.row_gains, np.ones(ping.n_ranges))
    assert ping.fire.master_mode == 2 and ping.fire.range == 8.0
    client.sock.close()


def test_network_trigger_gives_one_ping_per_request_and_standby_sends_dummies(running):
    sim = running(FlsSonar, "sim", **SIM)
    client = RawClient(sim.node.port_bound)
    trigger = FireSettings.make(range_m=5.0, beams=256, ping_rate=0, network_trigger=True)
    assert trigger.flags & FLAG_NETWORK_TRIGGER
    for k in (1, 2):
        client.sock.sendall(encode_fire(trigger))
        pings = client.wait_frames(MSG_PING, k)
        assert [decode_ping(f.data).ping_id for f in pings] == list(range(1, k + 1))
    client.sock.sendall(encode_fire(trigger.standby()))
    client.wait_frames(MSG_DUMMY, 1)
    assert sim.node.ping_id == 2                                              # no ping without a request
    client.sock.close()


def test_self_fire_publishes_without_a_client(running):
    sim = running(FlsSonar, "sim", **SIM, self_fire=True, beams=256, range_m=10.0, truth_structures_only=True)
    wait_for(lambda: len(sim.of("ping")) >= 2)
    ping, truth = sim.of("ping")[0], sim.of("truth")[0]
    assert ping.intensities.shape[1] == 256 and ping.range_m == pytest.approx(10.0)
    assert len(truth.points_m) > 0 and truth.points_m[:, 2].min() > -6.0 + 1e-6   # structures only


def test_config_rejects_bad_values():
    from tether.errors import ConfigError

    with pytest.raises(ConfigError, match="row_gain_encoding"):
        FlsSonar.make_config({"row_gain_encoding": "bcd"})
    with pytest.raises(ConfigError):
        FlsSonar.make_config({"no_such_param": 1})


def test_a_client_gone_between_two_polls_is_dropped_when_status_is_broadcast() -> None:
    """getpeername on a socket whose peer hung up raises ENOTCONN: the status sender drops the
    client and broadcasts 'not connected' instead of ending the simulator's thread (seen in a suite run)."""
    import logging

    from sim.fls import Config, FakeOculus

    fake = FakeOculus(Config(port=0, status_port=9, status_address="127.0.0.1"), logging.getLogger("fls"))
    try:
        fake.client = socket.socket()                  # never connected: getpeername fails as for a hung-up peer
        fake.broadcast_status()
        assert fake.client is None
    finally:
        fake.close()
