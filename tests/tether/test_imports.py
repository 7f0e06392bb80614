"""`tether import` on the shared real logs, then a lockstep replay of real pings into a node."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from conftest import tether
from tether.log import LogReader


def test_import_real_oculus_pings_and_replay_them_into_the_imager(tmp_path: Path, runtime_env: dict,
                                                                   shared_data: Path) -> None:
    raw = shared_data / "sonar" / "oculus-m1200d" / "three_pings_8bit.raw"
    log, out = tmp_path / "pings.mcap", tmp_path / "fans.mcap"
    res = tether("import", "oculus", str(raw), "-o", str(log), env=runtime_env)
    assert res.returncode == 0 and "imported 3 messages" in res.stdout, res.stderr
    reader = LogReader(log)
    pings = [reader.decode(r) for r in reader.messages(["sonar/ping"])]
    assert len(pings) == 3 and all(p.intensities.dtype == np.uint8 for p in pings)
    assert [p.ping_id for p in pings] == sorted(p.ping_id for p in pings)
    res = tether("replay", str(log), "--into", "nodes.sonar.polar_imager:PolarImager", "--map", "ping=sonar/ping",
                 "--param", "width_px=256", "--record", str(out), "--lockstep", env=runtime_env)
    assert res.returncode == 0, res.stderr
    fans = [LogReader(out).decode(r) for r in LogReader(out).messages()]
    assert len(fans) == 3 and all(f.image.shape[1] == 256 and f.mask.any() for f in fans)
    assert [f.ping_id for f in fans] == [p.ping_id for p in pings]


def test_import_real_candump_log(tmp_path: Path, runtime_env: dict, shared_data: Path) -> None:
    log = tmp_path / "can.mcap"
    res = tether("import", "candump", str(shared_data / "can" / "ros2_canopen_issue225_candump.log"), "-o", str(log),
                 env=runtime_env)
    assert res.returncode == 0, res.stderr
    frames = [LogReader(log).decode(r) for r in LogReader(log).messages(["can/frame"])]
    assert (frames[0].arbitration_id, frames[0].data) == (0x701, b"\x00")               # node 1 boot-up
    assert (frames[1].arbitration_id, frames[1].data) == (0x000, bytes.fromhex("8200"))  # NMT reset-comm
    boot_ups = {f.arbitration_id - 0x700 for f in frames if 0x700 < f.arbitration_id < 0x780 and f.data == b"\x00"}
    assert {2, 3, 4} <= boot_ups
    stamps = [f.stamp_ns for f in frames]
    assert stamps == sorted(stamps) and stamps[0] > 0


def test_import_skips_and_counts_bad_lines_and_fails_when_nothing_is_left(tmp_path, runtime_env):
    good = tmp_path / "mixed.log"
    good.write_text("(1.0) can0 701#00\n(99999999999999999999.0) can0 701#00\n(1.0) can0 123#RFFFF\n(2.0) can0 702#05\n")
    res = tether("import", "candump", str(good), "-o", str(tmp_path / "m.mcap"), env=runtime_env)
    assert res.returncode == 2 and f"{good}: line 2: " in res.stderr and "--skip-bad" in res.stderr
    assert res.stderr.strip().count("\n") == 0 and not (tmp_path / "m.mcap").exists()
    res = tether("import", "candump", str(good), "-o", str(tmp_path / "m.mcap"), "--skip-bad", env=runtime_env)
    assert res.returncode == 0 and "imported 2 messages" in res.stdout and "skipped 2 bad records" in res.stdout
    assert "line 2:" in res.stderr and "line 3:" in res.stderr and "Traceback" not in res.stderr
    bad = tmp_path / "bad.log"
    bad.write_text("(99999999999999999999.0) can0 701#00\n")
    res = tether("import", "candump", str(bad), "-o", str(tmp_path / "b.mcap"), "--skip-bad", env=runtime_env)
    assert res.returncode == 1 and "nothing could be imported" in res.stderr and not (tmp_path / "b.mcap").exists()
