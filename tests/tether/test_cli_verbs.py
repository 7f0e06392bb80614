"""CLI verbs say what happened (issue 23 §1): unknown parameters are errors with a suggestion,
zero work is not success, topic patterns cannot swallow a positional argument, directories
are checked file by file, and there is a --version."""
from __future__ import annotations

from pathlib import Path

from conftest import REPO, launch_until, recording_for, tether
from msgs.std import Float64
from tether.log import LogWriter


def _log(path: Path, n: int = 5) -> Path:
    with LogWriter(path) as w:
        for i in range(n):
            w.write("a/value", Float64(data=float(i), seq=i + 1, stamp_ns=1_000_000_000 + i * 10_000_000),
                    log_time_ns=1_000_000_000 + i * 10_000_000)
    return path


def test_a_mistyped_parameter_is_an_error_naming_the_key_and_the_closest(tmp_path: Path, runtime_env: dict) -> None:
    res = tether("launch", "launch/counter.yaml", "--duration", "1", "--param", "scale.gian=3", env=runtime_env)
    assert res.returncode == 2 and "unknown key 'gian' (did you mean 'gain'?)" in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr
    res = tether("run", "nodes.std.demo:Counter", "--param", "rate_hx=5", "--duration", "1", env=runtime_env)
    assert res.returncode == 2 and "did you mean 'rate_hz'" in res.stderr
    res = tether("replay", str(_log(tmp_path / "a.mcap")), "--into", "nodes.std.demo:Scale", "--map", "value=a/value",
                 "--param", "gian=2", "--record", str(tmp_path / "o.mcap"), "--lockstep", env=runtime_env)
    assert res.returncode == 2 and "did you mean 'gain'" in res.stderr


def test_replaying_nothing_is_not_success(tmp_path: Path, runtime_env: dict) -> None:
    log = _log(tmp_path / "a.mcap")
    res = tether("replay", str(log), "--rate", "0", "--delay", "0", "--start", "100", env=runtime_env)
    assert res.returncode == 1 and "nothing replayed" in res.stderr and "a/value" in res.stderr
    res = tether("replay", str(log), "--rate", "0", "--delay", "0", "--start", "100", "--allow-empty", env=runtime_env)
    assert res.returncode == 0
    res = tether("replay", str(log), "--rate", "0", "--delay", "0", env=runtime_env)
    assert res.returncode == 0 and "replayed 5 messages" in res.stdout
    res = tether("replay", str(log), "--into", "nodes.std.demo:Scale", "--map", "value=a/other",
                 "--record", str(tmp_path / "o.mcap"), "--lockstep", env=runtime_env)
    assert res.returncode != 0


def test_record_topics_take_commas_and_leave_the_file_alone(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "sel.mcap"
    res = launch_until(["--record", str(log), "--record-topics", "counter/*,scale/value", "launch/counter.yaml",
                        "--param", "counter.rate_hz=20"], runtime_env, recording_for(1.0))
    assert res.returncode == 0, res.stderr
    from tether.log import LogReader

    assert set(LogReader(log).info().topics) == {"counter/value", "scale/value"}


def test_check_a_directory_and_version(tmp_path: Path, runtime_env: dict) -> None:
    res = tether("check", "launch", env=runtime_env)
    assert res.returncode == 0 and res.stdout.count(": ok (") == len(list((REPO / "launch").glob("*.yaml")))
    empty = tmp_path / "empty"
    empty.mkdir()
    res = tether("check", str(empty), env=runtime_env)
    assert res.returncode == 2 and "no .yaml launch file" in res.stderr
    res = tether("--version", env=runtime_env)
    assert res.returncode == 0 and res.stdout.startswith("tether ")


def _two_scans(path: Path) -> Path:
    with LogWriter(path) as w:
        for i in range(4):
            for topic in ("a/scan", "b/scan", "c/other"):
                w.write(topic, Float64(data=float(i), seq=i + 1, stamp_ns=1_000_000_000 + i * 10_000_000),
                        log_time_ns=1_000_000_000 + i * 10_000_000)
    return path


def test_one_topic_filter_for_player_verb_and_into(tmp_path: Path, runtime_env: dict) -> None:
    import pytest

    from tether.errors import ConfigError
    from tether.replay import Player, select_topics
    from tether.testing import Harness

    log = _two_scans(tmp_path / "scans.mcap")
    assert select_topics(["a/scan", "b/scan", "c/other"], ["*/scan"]) == ["a/scan", "b/scan"]
    with pytest.raises(ConfigError, match="selects none of the log's topics: a/scan, b/scan, c/other"):
        select_topics(["a/scan", "b/scan", "c/other"], ["x/*"])
    # Two topics sharing their last part: outputs named from the selected topics, and they publish.
    h = Harness(Player, params={"log": str(log), "topics": ["a/scan", "b/scan"], "rate": 0.0})
    assert set(h.node.ports.outputs) == {"a.scan", "b.scan"}
    h.node.run()
    assert len(h.of("a.scan")) == 4 and len(h.of("b.scan")) == 4
    h.close()
    res = tether("replay", str(log), "--rate", "0", "--delay", "0", "--topics", "*/scan", env=runtime_env)
    assert res.returncode == 0 and "replayed 8 messages" in res.stdout
    res = tether("replay", str(log), "--into", "nodes.std.demo:Scale", "--map", "value=a/scan", "--topics", "c/*",
                 "--record", str(tmp_path / "o.mcap"), "--lockstep", env=runtime_env)
    assert res.returncode == 2 and "leaves none of the --map topics" in res.stderr


def test_topic_hz_reports_arrival_and_stamp_rates_labelled() -> None:
    from tether.introspect import rate_line

    # Published at 10 Hz by stamps, arriving in bursts of two every 0.2 s, one message lost.
    samples = [(0.0, 0, 1, 100), (0.001, 100_000_000, 2, 100), (0.2, 200_000_000, 3, 100),
               (0.201, 300_000_000, 4, 100), (0.4, 500_000_000, 6, 100)]
    line = rate_line("hz", samples)
    assert "rate (arrival)     10.00 Hz" in line and "min 1.0 ms max 199.0 ms" in line
    assert "rate (stamps)     10.00 Hz" in line and "1 published but not seen here" in line
    assert rate_line("hz", samples[:1]) == "no messages yet"


def test_doctor_cleans_what_a_crash_left_and_flags_unsafe_keys(tmp_path: Path, runtime_env: dict) -> None:
    import json
    import os
    import socket

    rt = Path(runtime_env["TETHER_RUNTIME_DIR"])
    (rt / "s").mkdir(parents=True, mode=0o700, exist_ok=True)
    os.chmod(rt, 0o700)
    (rt / "graphs").mkdir(mode=0o700, exist_ok=True)
    (rt / "graphs" / "dead.json").write_text(json.dumps({"name": "gone", "pid": 2 ** 22 + 12345, "topics": {}}))
    stale = rt / "s" / "gone.x.sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(stale))                                        # bound, never listened: refuses
    (rt / "state").mkdir(mode=0o700, exist_ok=True)
    (rt / "state" / "gone.node.abc.seq").write_bytes(b"\0" * 16)
    res = tether("doctor", env=runtime_env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "stale registry entries removed: 1" in res.stdout and "stale ipc sockets removed: 1" in res.stdout
    assert "seq-state files of stopped graphs removed: 1" in res.stdout
    assert not stale.exists() and not (rt / "graphs" / "dead.json").exists()
    store = Path(runtime_env["TETHER_KEYS_DIR"]) / "g"
    store.mkdir(parents=True)
    (store / "m.key").write_text("{}")
    os.chmod(store / "m.key", 0o644)
    res = tether("doctor", env=runtime_env)
    assert res.returncode == 1 and "UNSAFE" in res.stdout


def test_a_normal_replay_leaves_no_socket_behind(tmp_path: Path, runtime_env: dict) -> None:
    log = _log(tmp_path / "a.mcap")
    res = tether("replay", str(log), "--rate", "0", "--delay", "0", env=runtime_env)
    assert res.returncode == 0
    sockets = Path(runtime_env["TETHER_RUNTIME_DIR"]) / "s"
    assert not list(sockets.glob("*")) if sockets.exists() else True


def test_every_option_has_help_and_a_parameter_given_twice_is_an_error() -> None:
    import argparse

    import pytest

    from tether.cli import _params, build_parser
    from tether.errors import ConfigError
    from tether.launch import parse_overrides

    missing = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, path + [name])
            elif not action.help:
                missing.append(" ".join(path + [action.dest]))

    parser = build_parser()
    walk(parser, [])
    assert missing == []
    verbs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert all((sub.epilog or "").startswith("example: tether ") for sub in verbs.values())
    with pytest.raises(ConfigError, match="--param scale.gain is given twice"):
        parse_overrides(["scale.gain=2", "scale.gain=3"])
    with pytest.raises(ConfigError, match="--param gain is given twice"):
        _params(["gain=2", "gain=3"])


def test_tether_log_shows_per_topic_rate_size_and_the_file(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "two.mcap"
    with LogWriter(log) as w:
        for i in range(50):
            w.write("a/value", Float64(data=float(i), seq=i + 1), log_time_ns=1_000_000_000 + i * 100_000_000)
            if i % 2:
                w.write("b/other", Float64(data=float(i), seq=i + 1), log_time_ns=1_000_000_000 + i * 100_000_000)
    res = tether("log", str(log), env=runtime_env)
    assert res.returncode == 0 and "75 messages, 4.90 s" in res.stdout and "compression zstd" in res.stdout
    rows = {line.split()[0]: line.split() for line in res.stdout.splitlines() if line.startswith("  a/") or
            line.startswith("  b/")}
    assert rows["a/value"][2:4] == ["50", "10.00"] and rows["b/other"][2:4] == ["25", "5.00"]
    assert rows["b/other"][5] == "0.10" and "1 chunks, CRCs ok" in res.stdout


def test_log_cut_and_merge(tmp_path: Path, runtime_env: dict) -> None:
    from tether.log import LogReader

    a = _log(tmp_path / "a.mcap", n=10)                       # a/value at 1.00, 1.01, ... 1.09 s
    b = tmp_path / "b.mcap"
    with LogWriter(b) as w:
        for i in range(4):
            w.write("b/value", Float64(data=-float(i), seq=i + 1), log_time_ns=1_005_000_000 + i * 10_000_000)
    res = tether("log", "cut", str(a), "-o", str(tmp_path / "cut.mcap"), "--start", "0.03", "--end", "0.07",
                 env=runtime_env)
    assert res.returncode == 0 and "wrote 4 messages" in res.stdout
    values = [LogReader(tmp_path / "cut.mcap").decode(r).data for r in LogReader(tmp_path / "cut.mcap").messages()]
    assert values == [3.0, 4.0, 5.0, 6.0]
    res = tether("log", "merge", str(a), str(b), "-o", str(tmp_path / "m.mcap"), env=runtime_env)
    assert res.returncode == 0 and "wrote 14 messages" in res.stdout
    merged = LogReader(tmp_path / "m.mcap")
    times = [r.log_time_ns for r in merged.messages()]
    assert times == sorted(times) and merged.info().counts == {"a/value": 10, "b/value": 4}
    res = tether("log", "cut", str(a), "-o", str(tmp_path / "none.mcap"), "--topics", "zzz/*", env=runtime_env)
    assert res.returncode == 2 and "selects none of the log's topics" in res.stderr


def test_record_include_exclude_and_split_by_duration(tmp_path: Path, runtime_env: dict) -> None:
    import signal
    import subprocess
    import sys

    from conftest import wait_for_topic
    from tether.log import LogReader

    graph = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml", "--param",
                              "counter.rate_hz=50"], cwd=REPO, env=runtime_env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    try:
        wait_for_topic("scale/value", runtime_env, alive=graph)
        out = tmp_path / "rec.mcap"
        res = tether("record", "-o", str(out), "--exclude", "scale/*", "--max-duration", "1", "--duration", "3.5",
                     env=runtime_env)
        assert res.returncode == 0, res.stderr
        parts = sorted(tmp_path.glob("rec*.mcap"))
        assert len(parts) >= 3 and (tmp_path / "rec_1.mcap") in parts
        assert all(set(LogReader(p).info().topics) <= {"counter/value"} for p in parts)
        res = tether("record", "-o", str(tmp_path / "none.mcap"), "--include", "nothing/*", "--duration", "1",
                     env=runtime_env)
        assert res.returncode == 2 and "leave no topic" in res.stderr
    finally:
        graph.send_signal(signal.SIGINT)
        graph.wait(30)


def test_launch_record_splits_by_duration(tmp_path: Path, runtime_env: dict) -> None:
    from tether.log import LogReader

    log = tmp_path / "run.mcap"
    res = launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=20", "--record", str(log),
                        "--record-max-duration", "1"], runtime_env,
                       lambda out, err: out.count("recording on into") >= 2)      # two segments complete
    assert res.returncode == 0, res.stderr
    parts = sorted(tmp_path.glob("run*.mcap"))
    assert len(parts) >= 3 and (tmp_path / "run_1.mcap") in parts
    counts = [sum(LogReader(p).info().counts.values()) for p in parts]
    assert all(c > 0 for c in counts[:-1])


def test_the_runtime_imports_nothing_above_it() -> None:
    """tether/'s runtime is the bottom layer: none of its modules imports msgs, nodes, drivers or sim
    (issue 23 §5). The command line (cli.py, whose verbs reach the SLAM tools) is the application
    on top, exempt; importers are found by entry point (tether.importers), not imported."""
    import ast

    upward = []
    for path in sorted((REPO / "tether").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            upward += [f"{path.name}: {n}" for n in names if n.split(".")[0] in ("msgs", "nodes", "drivers", "sim")]
    assert [u for u in upward if not u.startswith("cli.py")] == []
