"""Every ``tether import`` kind under seeded mutation: any input is a clear one-line error or a
counted skip, never a traceback; ``--skip-bad`` imports the rest of a log with one bad line.

Each importer runs in-process on a few hundred mutants (byte flips, truncation, insertion,
duplication, extreme numbers) of a sample the test builds itself, and of the shared real
samples when ../shared/data is there.
"""
from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path
from typing import Callable

import can
import numpy as np
import pytest

from drivers import ping_protocol as pp
from drivers.candump import format_line, import_candump
from drivers.oculus_file import import_oculus, write_rmlog
from drivers.oculus_protocol import FireSettings, encode_ping
from drivers.ping360_file import import_ping360
from msgs.can import CanFrame
from tether.errors import DecodeError
from tether.imports import ImportResult
from tether.log import LogReader

REPO = Path(__file__).resolve().parents[2]
REAL_CAN = "can/ros2_canopen_issue225_candump.log"
REAL_OCULUS = "sonar/oculus-m1200d/one_ping_8bit.raw"
EXTREMES = [b"99999999999999999999", b"9223372036.999999999", b"-1e30", b"1e308", b"nan", b"inf",
            b"\xff" * 8, b"\x00" * 8, b"\xf0\xff\xff\xff", b"FFFFFFFF", b"#", b"\n", b"\r\n(", b")"]


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One seeded mutant: flips, a cut, an insertion, a duplicated span, or extreme values dropped in."""
    out = bytearray(data)
    op = rng.randrange(5)
    if op == 0:
        for _ in range(rng.randint(1, 16)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
    elif op == 1:
        del out[rng.randrange(len(out)):]
    elif op == 2:
        at = rng.randrange(len(out) + 1)
        out[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
    elif op == 3:
        a = rng.randrange(len(out))
        b = min(len(out), a + rng.randint(1, 4096))
        out[b:b] = out[a:b]
    else:
        for _ in range(rng.randint(1, 4)):
            at, value = rng.randrange(len(out)), rng.choice(EXTREMES)
            out[at:at + len(value)] = value
    return bytes(out)


def one_line(exc: BaseException) -> bool:
    text = str(exc)
    return bool(text) and "\n" not in text and "Traceback" not in text


def run_mutants(importer: Callable[..., ImportResult], sample: bytes, tmp_path: Path, *, suffix: str,
                cases: int, seed: int) -> dict[str, int]:
    """Both modes on each mutant: strict is a result with no skips or one DecodeError/ValueError line
    naming the file, leaving no log; ``skip_bad`` is a result (or a whole-file ValueError line) whose
    log holds exactly the messages it counts."""
    rng = random.Random(seed)
    src, dst = tmp_path / f"mutant{suffix}", tmp_path / "out.mcap"
    tally = {"clean": 0, "refused": 0, "skipped": 0, "whole_file": 0}
    for case in range(cases):
        src.write_bytes(mutate(sample, rng))
        try:
            strict = importer(src, dst)
            assert strict.skipped == 0
            tally["clean"] += 1
        except (DecodeError, ValueError) as exc:
            assert one_line(exc) and str(src) in str(exc), (case, exc)
            assert not dst.exists()
            tally["refused"] += 1
        try:
            lenient = importer(src, dst, skip_bad=True)
        except ValueError as exc:                     # the file as a whole is not this format
            assert one_line(exc) and not dst.exists(), (case, exc)
            tally["whole_file"] += 1
            continue
        tally["skipped"] += lenient.skipped > 0
        if case % 10 == 0:                             # the log holds what the result counts
            assert sum(1 for _ in LogReader(dst).messages()) == lenient.imported
    return tally


# -- samples the test builds itself --------------------------------------------------------
def _oculus_pings(n: int) -> list[bytes]:
    rng = np.random.default_rng(3)
    fire = FireSettings.make(range_m=5.0, frequency="low", beams=256)
    return [encode_ping(rng.integers(0, 255, size=(12, 256), dtype=np.uint8), np.linspace(-6500, 6500, 256).astype(np.int16),
                        fire=fire, version=1 + k % 2, ping_id=k, range_resolution_m=0.2, ping_start_time=1.0 + k)
            for k in range(n)]


def _candump_text(n: int = 40) -> bytes:
    rng = np.random.default_rng(5)
    lines = ["# generated"]
    for k in range(n):
        ext = k % 7 == 0
        frame = CanFrame(stamp_ns=1_700_000_000_000_000_000 + k * 1_000_123, arbitration_id=int(rng.integers(0x1FFFFFFF if ext else 0x7FF)),
                         data=rng.bytes(int(rng.integers(0, 9))), is_extended_id=ext, channel="can0")
        lines.append(format_line(frame, direction=bool(k % 2)))
    return ("\n".join(lines) + "\n").encode()


def _python_can_log(path: Path, writer: type) -> bytes:
    with writer(path) as w:
        for k in range(30):
            w.on_message_received(can.Message(timestamp=1_700_000_000.0 + k * 0.01, arbitration_id=0x180 + k,
                                              data=bytes([k, 2 * k % 256, 3]), is_extended_id=False, channel="can0"))
    return path.read_bytes()


def _ping360_stream(n: int = 12) -> bytes:
    s = pp.Settings(number_of_samples=200)
    return b"".join(pp.encode_device_data(s, (k * 7) % pp.GRADIANS, (np.arange(200) * k % 256).astype(np.uint8))
                    for k in range(n))


# -- the mutation suites -------------------------------------------------------------------
def test_candump_text_mutants(tmp_path):
    tally = run_mutants(import_candump, _candump_text(), tmp_path, suffix=".log", cases=300, seed=1)
    assert tally["refused"] > 100 and tally["skipped"] > 100       # the mutants did reach the parser


@pytest.mark.parametrize("suffix, writer", [(".asc", can.ASCWriter), (".blf", can.BLFWriter),
                                            (".trc", can.TRCWriter), (".csv", can.CSVWriter)])
def test_python_can_format_mutants(tmp_path, suffix, writer):
    sample = _python_can_log(tmp_path / f"sample{suffix}", writer)
    tally = run_mutants(import_candump, sample, tmp_path, suffix=suffix, cases=100, seed=2)
    assert tally["clean"] + tally["refused"] == 100 and tally["refused"] > 10


def test_oculus_raw_stream_mutants(tmp_path):
    tally = run_mutants(import_oculus, b"".join(_oculus_pings(4)), tmp_path, suffix=".raw", cases=300, seed=3)
    assert tally["refused"] > 100


@pytest.mark.parametrize("compress", [False, True])
def test_oculus_viewpoint_log_mutants(tmp_path, compress):
    path = tmp_path / "sample.oculus"
    write_rmlog(path, [(1_700_000_000.0 + k, p) for k, p in enumerate(_oculus_pings(4))], compress=compress)
    tally = run_mutants(import_oculus, path.read_bytes(), tmp_path, suffix=".oculus", cases=150, seed=4)
    assert tally["refused"] > 50


def test_ping360_stream_mutants(tmp_path):
    tally = run_mutants(import_ping360, _ping360_stream(), tmp_path, suffix=".bin", cases=300, seed=5)
    assert tally["refused"] > 50


def test_shared_candump_log_mutants(tmp_path, shared_data):
    tally = run_mutants(import_candump, (shared_data / REAL_CAN).read_bytes(), tmp_path, suffix=".log",
                        cases=300, seed=6)
    assert tally["refused"] > 100


def test_shared_oculus_ping_mutants(tmp_path, shared_data):
    tally = run_mutants(import_oculus, (shared_data / REAL_OCULUS).read_bytes(), tmp_path, suffix=".raw",
                        cases=150, seed=7)
    assert tally["refused"] > 50


# -- the known failures, pinned ------------------------------------------------------------
def test_out_of_range_python_can_times_are_counted_skips_not_overflow(tmp_path):
    """An out-of-range stamp used to reach the log writer: ``OverflowError: can't serialize ints < -2**63``."""
    src = tmp_path / "times.csv"
    src.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n"
                   "-1e30,0x123,0,0,0,2,AQI=\n1e30,0x123,0,0,0,2,AQI=\nnan,0x123,0,0,0,2,AQI=\n1.5,0x124,0,0,0,2,AQI=\n")
    result = import_candump(src, tmp_path / "o.mcap", skip_bad=True)
    assert (result.imported, result.skipped) == (1, 3)
    with pytest.raises(DecodeError, match=r"times.csv: message 1: time -1e\+30 s is not a time"):
        import_candump(src, tmp_path / "o.mcap")


def test_the_last_nanosecond_an_int64_holds_is_the_limit(tmp_path):
    src = tmp_path / "edge.log"
    src.write_text("(9223372036.854775807) can0 701#00\n(9223372036.854775808) can0 701#00\n")
    result = import_candump(src, tmp_path / "o.mcap", skip_bad=True)
    assert (result.imported, result.skipped) == (1, 1)
    stamps = [r.log_time_ns for r in LogReader(tmp_path / "o.mcap").messages()]
    assert stamps == [(1 << 63) - 1]


def test_a_reader_that_fails_in_an_unexpected_way_is_one_line_or_a_counted_skip(tmp_path):
    from tether.imports import write_messages

    def broken():
        yield CanFrame(stamp_ns=5, arbitration_id=1)
        raise IndexError("a parser bug")

    with pytest.raises(DecodeError, match=r"x.log: message 2: the reader stopped: IndexError: a parser bug"):
        write_messages(broken(), tmp_path / "o.mcap", "can/frame", ImportResult(source="x.log"))
    assert not (tmp_path / "o.mcap").exists()
    result = write_messages(broken(), tmp_path / "o.mcap", "can/frame", ImportResult(skip_bad=True))
    assert (result.imported, result.skipped) == (1, 1)


# -- --skip-bad on the command line ---------------------------------------------------------
def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tether.cli", "import", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=120)


def _one_corrupt_line(text: str, line: int) -> str:
    lines = text.splitlines()
    lines[line - 1] = lines[line - 1].replace("#", "#Z", 1)          # 'Z' is not hex
    return "\n".join(lines) + "\n"


def test_skip_bad_imports_the_rest_of_a_log_with_one_corrupt_line(tmp_path):
    src, dst = tmp_path / "one_bad.log", tmp_path / "o.mcap"
    src.write_text(_one_corrupt_line(_candump_text(40).decode(), 8))
    res = _cli("can", str(src), "-o", str(dst))
    assert res.returncode == 2 and not dst.exists() and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and f"{src}: line 8: " in res.stderr and "--skip-bad" in res.stderr
    res = _cli("can", str(src), "-o", str(dst), "--skip-bad")
    assert res.returncode == 0, res.stderr
    assert "imported 39 messages" in res.stdout and "skipped 1 bad records" in res.stdout
    assert sum(1 for _ in LogReader(dst).messages()) == 39


def test_skip_bad_on_the_real_candump_log(tmp_path, shared_data):
    src, dst = tmp_path / "real_one_bad.log", tmp_path / "o.mcap"
    src.write_text(_one_corrupt_line((shared_data / REAL_CAN).read_text(), 12))
    assert _cli("can", str(src), "-o", str(dst)).returncode == 2 and not dst.exists()
    res = _cli("can", str(src), "-o", str(dst), "--skip-bad")
    assert res.returncode == 0 and "imported 30 messages" in res.stdout and "skipped 1 bad records" in res.stdout


def test_unreadable_input_or_unwritable_output_is_one_line(tmp_path):
    res = _cli("can", str(tmp_path), "-o", str(tmp_path / "o.mcap"))
    assert res.returncode == 2 and "a directory" in res.stderr and "Traceback" not in res.stderr
    src = tmp_path / "ok.log"
    src.write_bytes(_candump_text(3))
    res = _cli("can", str(src), "-o", str(src / "o.mcap"))            # a file where a folder should be
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
