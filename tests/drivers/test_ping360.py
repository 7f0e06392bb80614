"""Ping360: the protocol and its parser, the driver end to end against the simulated head on a
pseudo-terminal, the scanning image, the imager node and the importer."""
from __future__ import annotations

import math
import os
import struct
import threading
import time

import numpy as np
import pytest

from drivers import ping_protocol as pp
from drivers.ping360 import Ping360
from drivers.ping360_file import iter_ping360_stream
from msgs.sonar import SonarPing
from nodes.sonar.scan import ScanImage
from nodes.sonar.scan_imager import ScanImager
from sim.ping360_device import Ping360Device
from tether.errors import ConfigError
from tether.testing import Harness

S = pp.Settings(number_of_samples=200)


def wait_for(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def _beam(angle, n=200):
    return pp.encode_device_data(S, angle, (np.arange(n) % 256).astype(np.uint8))


def test_frames_round_trip_and_checksum():
    frame = _beam(123)
    assert frame[:2] == b"BR" and struct.unpack("<H", frame[-2:])[0] == sum(frame[:-2]) & 0xFFFF
    (f,) = pp.PingParser().feed(frame)
    beam = pp.decode_beam(f.message_id, f.payload)
    assert beam.angle == 123 and beam.settings == S and np.array_equal(beam.samples, np.arange(200) % 256)
    settings, angle, transmit = pp.decode_transducer(pp.encode_transducer(S, 399)[8:-2])
    assert (settings, angle, transmit) == (S, 399, True)
    assert pp.Settings.for_range(20.0).range_m() == pytest.approx(20.0, rel=0.01)


def test_parser_resyncs_after_garbage_bad_checksums_and_impossible_lengths():
    p = pp.PingParser()
    bad_sum = bytearray(_beam(2))
    bad_sum[20] ^= 0xFF
    huge = b"BR" + struct.pack("<HHBB", 60000, 2300, 1, 0)                  # a length no Ping360 sends
    stream = b"\x00garbageBR\xffB" + _beam(1) + bytes(bad_sum) + huge + _beam(3) + b"xx" + _beam(4)
    frames = []
    for i in range(0, len(stream), 7):                                       # split anywhere
        frames += p.feed(stream[i:i + 7])
    angles = [pp.decode_beam(f.message_id, f.payload).angle for f in frames]
    assert angles == [1, 3, 4]
    assert p.checksum_errors == 1 and p.skipped_bytes > 10
    assert p.bad_lengths == 2                    # the huge one, and the garbage's own "BR\xffB" (length 0x42ff)


def test_replies_that_cannot_be_beams_raise():
    head = struct.pack("<BBHHHHHH", 1, 0, 12, 32, 80, 740, 200, 200)
    with pytest.raises(pp.PingProtocolError, match="shorter"):
        pp.decode_beam(pp.DEVICE_DATA, head[:10])
    with pytest.raises(pp.PingProtocolError, match="carries"):
        pp.decode_beam(pp.DEVICE_DATA, head + bytes(50))                      # short payload
    bad_angle = struct.pack("<BBHHHHHH", 1, 0, 400, 32, 80, 740, 200, 4) + bytes(4)
    with pytest.raises(pp.PingProtocolError, match="0-399"):
        pp.decode_beam(pp.DEVICE_DATA, bad_angle)
    with pytest.raises(pp.PingProtocolError):
        pp.Settings(number_of_samples=5000)


@pytest.fixture
def head():
    made = []

    def make(**kw):
        dev = Ping360Device(None, baudrate=kw.pop("baudrate", 4_000_000), seed=kw.pop("seed", 0), **kw).start()
        made.append(dev)
        return dev

    yield make
    for d in made:
        d.close()


@pytest.fixture
def driver():
    started = []

    def start(**params):
        h = Harness(Ping360, params={"number_of_samples": 200, "backoff_initial_s": 0.05, "backoff_max_s": 0.2,
                                     "data_timeout_s": 0.5, **params}, node_id="sonar")
        t = threading.Thread(target=h.node.run, daemon=True)
        t.start()
        started.append((h, t))
        return h

    yield start
    for h, t in started:
        h.node.stopping.set()
        t.join(timeout=5)
        h.close()


def test_auto_transmit_scan_gives_400_beams_a_turn_and_motor_off_on_stop(head, driver):
    dev = head()
    h = driver(port=dev.port, mode="auto")
    wait_for(lambda: h.node.counters["beams"] >= 420)
    h.node.stopping.set()
    wait_for(lambda: dev.motor_offs == 1, 5)
    pings = h.of("ping")
    angles = [round(p.bearings_rad[0] / (2 * math.pi) * 400) % 400 for p in pings[:400]]
    assert sorted(angles) == list(range(400)) and h.node.counters["checksum_errors"] == 0
    assert pings[0].intensities.shape == (200, 1) and pings[0].range_m == pytest.approx(20.0, rel=0.01)
    assert h.node.device_type == pp.DEVICE_TYPE_PING360


def test_per_angle_requests_sweep_a_sector_back_and_forth(head, driver):
    dev = head()
    h = driver(port=dev.port, mode="request", sector_start_grad=100, sector_stop_grad=110, step_grad=2)
    wait_for(lambda: h.node.counters["beams"] >= 15)
    angles = [round(p.bearings_rad[0] / (2 * math.pi) * 400) for p in h.of("ping")[:15]]
    assert set(angles) <= set(range(100, 111, 2)) and angles[:7] == [100, 102, 104, 106, 108, 110, 108]


def test_a_noisy_line_loses_only_the_damaged_frames(head, driver):
    dev = head(garbage_rate=0.1, corrupt_rate=0.05, seed=3)
    h = driver(port=dev.port)
    wait_for(lambda: dev.beams_sent >= 300)
    dev.hold()                                     # the head falls silent: beams_sent is final
    c = h.node.counters
    # every beam sent is read, as a beam or a checksum error: waited for (a loaded driver reads
    # behind), then exact -- no longer "within 2 in flight at the stop"
    wait_for(lambda: c["beams"] + c["checksum_errors"] >= dev.beams_sent)
    time.sleep(0.1)                                # nothing more arrives to overshoot
    h.node.stopping.set()
    assert c["checksum_errors"] > 0 and c["bytes_skipped"] > 0
    assert c["beams"] + c["checksum_errors"] == dev.beams_sent


def test_a_port_that_disappears_mid_scan_is_reopened(head, driver, tmp_path):
    first = head()
    link = tmp_path / "ping360"
    os.symlink(first.port, link)
    h = driver(port=str(link))
    wait_for(lambda: h.node.counters["beams"] >= 50)
    first.close()                                                              # the cable is pulled
    second = head()
    link.unlink()
    os.symlink(second.port, link)
    before = h.node.counters["beams"]
    wait_for(lambda: h.node.counters["beams"] >= before + 50)
    assert h.node.counters["reconnects"] >= 1


def test_config_is_checked():
    for bad in ({"mode": "sideways"}, {"sector_start_grad": 400}, {"number_of_samples": 50}, {"gain_setting": 3}):
        with pytest.raises(ConfigError):
            Ping360.make_config(bad)


def test_scan_image_puts_a_target_where_the_beam_points():
    scan = ScanImage(n_angles=400, n_samples=100)
    for a in range(400):
        row = np.zeros(100)
        if a == 100:                                                           # 90 degrees to starboard
            row[49:51] = 255
        turned = scan.add(2 * math.pi * a / 400, row, 10.0)
        assert not turned
    assert scan.coverage == 1.0 and scan.turns == 0
    assert scan.add(0.0, np.zeros(100), 10.0) is True and scan.turns == 1     # back at angle 0: a turn
    img = scan.cartesian(200)
    y, x = np.unravel_index(np.nanargmax(img), img.shape)
    assert abs(y - 99.5) <= 2 and 140 <= x <= 160                               # right of centre, half way out
    assert np.isnan(img[0, 0])
    with pytest.raises(ValueError):
        scan.add(float("nan"), np.zeros(10), 10.0)


def test_imager_node_writes_the_png_each_turn_and_skips_non_beams(tmp_path):
    png = tmp_path / "scan.png"
    with Harness(ScanImager, params=dict(png=str(png), sector_beams=100, size_px=128)) as h:
        events = []
        for k in range(801):
            a = k % 400
            events.append((k * 0.01, "ping", SonarPing(intensities=np.full((50, 1), a % 256, np.uint8),
                                                        bearings_rad=np.array([2 * math.pi * a / 400], np.float32),
                                                        range_m=20.0)))
        events.append((9.0, "ping", SonarPing(intensities=np.zeros((50, 3), np.uint8), bearings_rad=np.zeros(3, np.float32),
                                               range_m=20.0)))
        h.feed(events)
    assert png.exists() and h.node.written >= 2 and h.node.bad == 1
    grids = h.of("image")
    assert len(grids) == 8 and grids[-1].data.shape == (128, 128)
    assert grids[-1].resolution_m == pytest.approx(40.0 / 128)


def test_importer_reads_beams_from_a_raw_byte_stream(tmp_path):
    path = tmp_path / "scan.bin"
    bad = bytearray(_beam(7))
    bad[-1] ^= 1
    path.write_bytes(b"noise" + b"".join(_beam(a) for a in range(5)) + bytes(bad) + b"\xff" * 9 + _beam(9))
    skipped = []
    pings = list(iter_ping360_stream(path, on_skip=lambda off, why: skipped.append(why)))
    assert [round(p.bearings_rad[0] / (2 * math.pi) * 400) for p in pings] == [0, 1, 2, 3, 4, 9]
    assert len(skipped) == 1 and pings[1].stamp_ns > pings[0].stamp_ns


def test_simulator_node_renders_the_scene_behind_its_link(tmp_path, driver):
    from sim.ping360_sim import Ping360Sim

    link = tmp_path / "ping360.pty"
    sim = Harness(Ping360Sim, params=dict(link=str(link), baudrate=4_000_000))
    try:
        assert link.is_symlink()
        h = driver(port=str(link), number_of_samples=300, range_m=20.0)
        wait_for(lambda: h.node.counters["beams"] >= 60, 20)
        ahead = [p for p in h.of("ping") if round(p.bearings_rad[0] / (2 * math.pi) * 400) % 400 < 30]
        assert ahead and max(int(p.intensities.max()) for p in ahead) > 100      # the tripod's echoes ahead
        sim.advance_to(1.5)
        assert sim.of("pose") and sim.of("pose")[0].qw != 0
    finally:
        sim.close()
    assert not link.exists()
