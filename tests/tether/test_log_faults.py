"""Issue 21 §3: the recorder never dies on content, a full disk is a clear error, damaged chunks
are found, skipped on replay and left behind by recovery."""
from __future__ import annotations

import errno
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from conftest import tether
from msgs.std import Float64
from tether.codec import Codec
from tether.log import LogReader, LogWriter, recover_log
from tether.logcheck import check_log
from tether.record import Recorder
from tether.transport import ipc_endpoint

U64_MAX = (1 << 64) - 1


def _publisher(ctx: zmq.Context) -> tuple[zmq.Socket, str]:
    endpoint = ipc_endpoint("logf", "pub", f"{time.monotonic_ns() % 10**6}")
    pub = ctx.socket(zmq.XPUB)
    pub.bind(endpoint)
    return pub, endpoint


def _send(pub: zmq.Socket, msg: Float64) -> None:
    pub.send_multipart([b"p/value", *[bytes(f) for f in Codec().encode(msg)]])


def test_the_recorder_writes_absurd_stamps_and_survives_malformed_bodies(tmp_path: Path, runtime_env: dict) -> None:
    ctx = zmq.Context()
    pub, endpoint = _publisher(ctx)
    rec = Recorder(tmp_path / "r.mcap", {"p/value": endpoint}, ctx=ctx).start()
    assert pub.poll(5000) and pub.recv()[0] == 1                  # the recorder subscribed
    stamps = [-1, 0, (1 << 63) - 1, U64_MAX, -(1 << 63)]
    for i, stamp in enumerate(stamps):
        _send(pub, Float64(data=float(i), stamp_ns=stamp, seq=[1, U64_MAX, 0, 5, 6][i]))
        pub.send_multipart([b"p/value", msgpack.packb([1, 2, 3])])  # valid msgpack, not a message
        pub.send_multipart([b"p/value"])                            # no body at all
    _send(pub, Float64(data=99.0, seq=7))
    deadline = time.monotonic() + 10
    while rec.count < len(stamps) + 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    rec.stop()
    ctx.destroy(linger=0)
    assert not rec.failed and rec.errors == 2 * len(stamps)
    reader = LogReader(tmp_path / "r.mcap")
    assert not reader.recovered                                       # a complete file, footer and all
    got = [reader.decode(r) for r in reader.messages()]
    assert [m.data for m in got] == [0.0, 1.0, 2.0, 3.0, 4.0, 99.0]
    assert [m.stamp_ns for m in got[:5]] == stamps                    # kept exactly, in the body


class _FullDisk:
    """A file that accepts ``room`` bytes and then fails like a full disk."""

    def __init__(self, fh, room: int) -> None:
        self._fh, self.room = fh, room

    def write(self, data) -> int:
        if self.room < len(data):
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= len(data)
        return self._fh.write(data)

    def __getattr__(self, name: str):
        return getattr(self._fh, name)


def test_a_full_disk_stops_recording_with_a_clear_error_and_the_log_stays_readable(
        tmp_path: Path, runtime_env: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    import tether.record

    writers = []

    class SmallDiskWriter(LogWriter):
        def __init__(self, path, **kw) -> None:
            super().__init__(path, chunk_size=2048, **kw)
            writers.append(self)
            self._fh = _FullDisk(self._fh, 40_000)
            self._writer._Writer__stream = self._fh     # mcap keeps its stream name-mangled

    monkeypatch.setattr(tether.record, "LogWriter", SmallDiskWriter)
    ctx = zmq.Context()
    pub, endpoint = _publisher(ctx)
    rec = Recorder(tmp_path / "full.mcap", {"p/value": endpoint}, ctx=ctx).start()
    assert pub.poll(5000) and pub.recv()[0] == 1
    for i in range(5000):
        _send(pub, Float64(data=float(i), seq=i + 1))
        if rec.failed:
            break
        time.sleep(0.0002)
    deadline = time.monotonic() + 10
    while not rec.failed and time.monotonic() < deadline:
        time.sleep(0.02)
    rec.stop()
    ctx.destroy(linger=0)
    assert "No space left" in rec.failed
    assert writers and all(w._fh.closed for w in writers)             # the failed log's file is not left open
    values = [LogReader(tmp_path / "full.mcap").decode(r).data for r in LogReader(tmp_path / "full.mcap").messages()]
    assert len(values) > 100 and values == sorted(values)             # what was written before is all there


def _log_with_chunks(path: Path, n: int = 600) -> None:
    rng = np.random.default_rng(5)
    with LogWriter(path, chunk_size=4096) as log:
        for i in range(n):
            log.write("a/value", Float64(data=float(rng.normal()), seq=i + 1, stamp_ns=1000 + i),
                      log_time_ns=1_000_000 + i)


def _flip(path: Path, fractions: list[float]) -> None:
    data = bytearray(path.read_bytes())
    for f in fractions:
        data[int(len(data) * f)] ^= 0x40
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("complete", [True, False])
def test_bit_flips_are_found_skipped_and_recovery_keeps_the_rest(tmp_path: Path, runtime_env: dict,
                                                                  complete: bool) -> None:
    path = tmp_path / "flip.mcap"
    _log_with_chunks(path)
    if not complete:                       # a recorder killed mid-write: no summary, found by walking
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * 0.8)])
    clean = check_log(path)
    assert not clean.damaged and clean.chunks > 10 and clean.indexed == complete
    _flip(path, [0.2, 0.45])
    check = check_log(path)
    assert 1 <= len(check.damaged) <= 2
    reader = LogReader(path)
    values = [reader.decode(r).seq for r in reader.messages()]      # no zstd traceback: the rest still comes
    assert len(reader.damaged) == len(check.damaged) and 300 < len(values) < 600
    assert values == sorted(values)
    out = tether("log", str(path), env=runtime_env)
    assert out.returncode == 1 and "DAMAGED chunk" in out.stdout and "Traceback" not in out.stderr
    written, damaged, lost = recover_log(path, tmp_path / "clean.mcap")
    assert written == len(values) and len(damaged) == len(check.damaged)
    assert lost == (600 - written if complete else -1)
    assert check_log(tmp_path / "clean.mcap").ok and not LogReader(tmp_path / "clean.mcap").recovered
    cli = tether("log", "--recover", str(path), "-o", str(tmp_path / "again.mcap"), env=runtime_env)
    assert cli.returncode == 0 and f"recovered {written} messages" in cli.stdout
    replay = tether("replay", str(path), "--rate", "0", "--delay", "0", env=runtime_env)   # damaged: exit 1 unless --skip-bad
    assert replay.returncode == 1 and "skipping damaged chunk" in replay.stderr and "Traceback" not in replay.stderr
    assert f"replayed {len(values)} messages" in replay.stdout and "(--skip-bad to accept)" in replay.stderr
    replay = tether("replay", str(path), "--rate", "0", "--delay", "0", "--skip-bad", env=runtime_env)
    assert replay.returncode == 0 and f"replayed {len(values)} messages" in replay.stdout


def test_recording_splits_by_size_and_warns_before_the_disk_fills(tmp_path: Path, runtime_env: dict,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil as _shutil

    ctx = zmq.Context()
    pub, endpoint = _publisher(ctx)
    rec = Recorder(tmp_path / "split.mcap", {"p/value": endpoint}, ctx=ctx, max_bytes=2000).start()
    assert pub.poll(5000) and pub.recv()[0] == 1
    for i in range(300):
        _send(pub, Float64(data=float(i), seq=i + 1))
        time.sleep(0.002)
    time.sleep(0.5)
    rec.stop()
    ctx.destroy(linger=0)
    assert len(rec.segments) >= 3 and rec.segments[1].name == "split_1.mcap"
    values = [LogReader(p).decode(r).data for p in rec.segments for r in LogReader(p).messages()]
    assert values == sorted(values) and len(values) == rec.count               # every file complete, nothing lost
    monkeypatch.setattr(_shutil, "disk_usage", lambda p: _shutil._ntuple_diskusage(10 ** 10, 10 ** 10 - 10 ** 8, 10 ** 8))
    assert "is full in" in rec.check_disk(1e6)                                  # 100 MB free at 1 MB/s
    assert rec.check_disk(1e3) == ""
