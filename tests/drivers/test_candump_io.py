"""drivers.candump: candump -L / python-can .log import and export; the real shared log
imports, round-trips through python-can's own reader/writer, and replays onto a bus."""
from __future__ import annotations

import io
import time

import can
import numpy as np
import canopen
import pytest

from drivers import candump
from drivers import cia402 as p
from drivers.can_bus import frame_from_message, open_bus
from drivers.candump import CandumpPlayer, format_line, iter_frames, parse_line, read_candump, replay, write_candump
from msgs.can import CanFrame
from tether.testing import Harness

REAL = "can/ros2_canopen_issue225_candump.log"


def test_real_log_imports(shared_data):
    frames = read_candump(shared_data / REAL)
    assert len(frames) == 31
    assert frames[0].stamp_ns == 1699584944_440580_000 and frames[0].channel == "can0"
    assert (frames[1].arbitration_id, frames[1].data) == (0x000, b"\x82\x00")          # NMT reset comm
    assert [f.arbitration_id for f in frames[2:5]] == [0x704, 0x703, 0x702]              # boot-ups
    sdo = p.parse_sdo_response(frames[6].data)
    assert (frames[6].arbitration_id, sdo.index, sdo.value()) == (0x582, 0x1000, 0x00020192)
    syncs = [f for f in frames if f.arbitration_id == p.SYNC]
    assert len(syncs) == 20 and all(f.data == b"" for f in syncs)
    gaps_ms = [(b.stamp_ns - a.stamp_ns) / 1e6 for a, b in zip(syncs, syncs[1:])]
    assert all(9.5 < g < 10.5 for g in gaps_ms)                                          # SYNC every 10 ms


def test_real_log_round_trips_through_python_can(shared_data, tmp_path):
    frames = read_candump(shared_data / REAL)
    for pylog in (False, True):
        out = tmp_path / f"copy{int(pylog)}.log"
        write_candump(frames, out, pylog=pylog)
        theirs = list(can.CanutilsLogReader(out))
        assert [(m.arbitration_id, bytes(m.data), m.timestamp) for m in theirs] == \
               [(f.arbitration_id, f.data, pytest.approx(f.stamp_ns * 1e-9, abs=1e-6)) for f in frames]
        assert read_candump(out) == frames
    # and what python-can writes, we read
    pyfile = tmp_path / "python_can.log"
    with can.CanutilsLogWriter(pyfile, channel="vcan0") as w:
        for f in frames:
            w.on_message_received(can.Message(timestamp=f.stamp_ns * 1e-9, arbitration_id=f.arbitration_id,
                                              data=f.data, is_extended_id=False, is_rx=False, channel="vcan0"))
    back = read_candump(pyfile)
    assert [(f.arbitration_id, f.data, f.is_rx) for f in back] == [(f.arbitration_id, f.data, False) for f in frames]


@pytest.mark.parametrize("line, check", [
    ("(1.000000) can0 12345678#DEADBEEF", lambda f: f.is_extended_id and f.arbitration_id == 0x12345678),
    ("(1.000000) can0 123#R", lambda f: f.is_remote_frame and f.dlc == 0),
    ("(1.000000) can0 123#R4", lambda f: f.is_remote_frame and f.dlc == 4),
    ("(1.000000) can0 123##1" + "00" * 12, lambda f: f.is_fd and len(f.data) == 12),
    ("(1.000000) can0 20000080#0000000000000000", lambda f: f.is_error_frame),
    ("(1.000000) can0 123#1122334455667788_E", lambda f: f.data == bytes.fromhex("1122334455667788")),
    ("(1.5) vcan0 701#7F T", lambda f: not f.is_rx and f.stamp_ns == 1_500_000_000),
])
def test_line_forms(line, check):
    f = parse_line(line)
    assert check(f)
    if not f.is_error_frame:
        again = parse_line(format_line(f, direction=True))
        assert (again.arbitration_id, again.data, again.is_remote_frame, again.is_fd, again.dlc) == \
               (f.arbitration_id, f.data, f.is_remote_frame, f.is_fd, f.dlc)


def test_bad_lines_name_the_line_or_are_skipped(caplog):
    text = "(1.0) can0 701#00\nthis is not a frame\n(2.0) can0 800#00\n(3.0) can0 123#123\n# comment\n(4.0) can0 702#05\n"
    with pytest.raises(ValueError, match="line 2"):
        read_candump(io.StringIO(text))
    frames = read_candump(io.StringIO(text), errors="skip")
    assert [f.arbitration_id for f in frames] == [0x701, 0x702]
    assert sum("skipped line" in r.getMessage() for r in caplog.records) == 3


class VirtualClock:
    """Stands in for the ``time`` module inside drivers.candump: sleeping advances the clock."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_real_log_replays_onto_a_bus_into_a_canopen_master(shared_data, monkeypatch):
    frames = read_candump(shared_data / REAL)
    clock = VirtualClock()
    monkeypatch.setattr(candump, "time", clock)
    channel = "candump-replay"
    src, dst = open_bus("virtual", channel), open_bus("virtual", channel)
    network = canopen.Network(dst)
    nodes = {n: network.add_node(n, canopen.ObjectDictionary()) for n in (2, 3, 4)}
    seen: list[can.Message] = []
    network.listeners.append(seen.append)
    network.connect()
    try:
        assert replay(frames, src, speed=2.0) == 31
        deadline = time.monotonic() + 2.0
        while len(seen) < 31 and time.monotonic() < deadline:
            time.sleep(0.01)
        span_s = (frames[-1].stamp_ns - frames[0].stamp_ns) * 1e-9     # the log spans 193 ms: kept its pace at 2x
        assert clock.now == pytest.approx(span_s / 2, abs=1e-9) and span_s > 0.19
        assert [m.arbitration_id for m in seen] == [f.arbitration_id for f in frames]
        assert all(nodes[n].nmt.state == "PRE-OPERATIONAL" for n in (2, 3, 4))   # boot-ups were seen
    finally:
        network.disconnect()
        src.shutdown()


def test_candump_player_node_publishes_the_log(shared_data):
    h = Harness(CandumpPlayer, params={"path": str(shared_data / REAL), "speed": 50.0})
    h.node.run()
    frames = h.of("frames")
    assert [f.arbitration_id for f in frames] == [f.arbitration_id for f in read_candump(shared_data / REAL)]
    assert all(isinstance(f, CanFrame) for f in frames)
    h.close()


def test_frame_message_conversion_keeps_fields():
    m = can.Message(timestamp=12.5, arbitration_id=0x1ABCDEF0, data=b"\x01\x02", is_extended_id=True, channel="can1")
    f = frame_from_message(m)
    assert (f.stamp_ns, f.arbitration_id, f.data, f.is_extended_id, f.channel, f.dlc) == \
           (12_500_000_000, 0x1ABCDEF0, b"\x01\x02", True, "can1", 2)


@pytest.mark.parametrize("line, why", [
    ("(99999999999999999999999.000000) can0 701#00", "past what a nanosecond stamp holds"),
    ("(9223372037.000000) can0 701#00", "past what a nanosecond stamp holds"),
    ("(1.0) can0 123#R" + "F" * 40, "one hex digit"),
    ("(1.0) can0 123#" + "AB" * 9, "9 data bytes in a classic CAN frame"),
    ("(1.0) can0 123##0" + "AB" * 65, "65 data bytes in a CAN FD frame"),
    ("(1.0) can0 701#" + "0" * 600, "a line of"),
])
def test_hostile_lines_are_refused_with_a_reason(line, why):
    with pytest.raises(ValueError, match=why):
        list(iter_frames([line]))


def test_an_error_frame_with_a_long_payload_keeps_eight_bytes():
    f = parse_line("(1.0) can0 20000080#" + "AB" * 100)
    assert f.is_error_frame and f.data == b"\xab" * 8 and f.dlc == 8


def test_mutated_real_log_imports_without_a_traceback(tmp_path, shared_data):
    from drivers.candump import import_candump

    lines = (shared_data / REAL).read_text().splitlines()
    rng = np.random.default_rng(9)
    hostile = ["(99999999999999999999999.000000) can0 701#00", "(1.0) can0 123#R" + "F" * 20,
               "(1.0) can0 2" + "0" * 7 + "#" + "AB" * 300, "\x00\xff garbage"]
    for trial in range(20):
        mutated = list(lines)
        for _ in range(5):
            i = int(rng.integers(len(mutated)))
            if rng.random() < 0.5:
                mutated[i] = hostile[int(rng.integers(len(hostile)))]
            else:
                j = int(rng.integers(len(mutated[i]) or 1))
                mutated[i] = mutated[i][:j] + chr(int(rng.integers(32, 127))) + mutated[i][j + 1:]
        src = tmp_path / f"m{trial}.log"
        src.write_text("\n".join(mutated) + "\n")
        result = import_candump(src, tmp_path / "m.mcap", skip_bad=True)
        assert len(lines) - 5 <= result.imported <= len(lines) and result.skipped <= 5


# -- tether import can: every format python-can reads, and candump text through our parser ------

def _sample_messages():
    return [can.Message(timestamp=1700000000.0 + k * 0.01, arbitration_id=0x180 + k, data=bytes([k, 2 * k, 3]),
                        is_extended_id=False, channel="can0") for k in range(20)]


@pytest.mark.parametrize("suffix,writer", [(".asc", can.ASCWriter), (".blf", can.BLFWriter), (".trc", can.TRCWriter),
                                            (".csv", can.CSVWriter)])
def test_python_can_formats_import_through_its_readers(tmp_path, suffix, writer):
    path = tmp_path / f"log{suffix}"
    with writer(path) as w:
        for m in _sample_messages():
            w.on_message_received(m)
    frames = list(candump.iter_can_log(path))
    assert [(f.arbitration_id, bytes(f.data)) for f in frames] == [(m.arbitration_id, bytes(m.data)) for m in _sample_messages()]


def test_a_truncated_blf_keeps_what_was_read_and_counts_the_failure(tmp_path):
    path = tmp_path / "log.blf"
    with can.BLFWriter(path) as w:
        for _ in range(50):
            for m in _sample_messages():
                w.on_message_received(m)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])
    skips = []
    frames = list(candump.iter_can_log(path, on_skip=lambda n, why: skips.append(why)))
    assert len(frames) < 1000 and (skips or len(frames) > 0)


def test_unknown_suffix_says_so(tmp_path):
    path = tmp_path / "log.xyz"
    path.write_text("nothing")
    with pytest.raises(ValueError, match="no reader"):
        list(candump.iter_can_log(path))


def test_our_candump_parser_keeps_what_python_cans_reader_loses(tmp_path):
    text = "# a comment from the capture tool\n(1699584944.440580123) can0 701#00\n(1699584944.440590000) can0 123#1122334455667788_9\n"
    ours = list(iter_frames(io.StringIO(text)))
    assert ours[0].stamp_ns == 1699584944_440580123                       # the nanoseconds survive
    assert ours[1].data == bytes.fromhex("1122334455667788")                # the _X DLC extension kept out
    with pytest.raises(ValueError):                                       # python-can: the comment line breaks it
        list(can.CanutilsLogReader(io.StringIO(text)))
    with pytest.raises(ValueError):                                       # ... and so does the DLC extension
        list(can.CanutilsLogReader(io.StringIO(text.split("\n")[2] + "\n")))
    theirs = list(can.CanutilsLogReader(io.StringIO(text.split("\n", 1)[1].split("\n")[0] + "\n")))
    assert int(round(theirs[0].timestamp * 1e9)) != 1699584944_440580123  # a float cannot hold them
