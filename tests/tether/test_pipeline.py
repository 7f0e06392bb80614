"""End to end with real processes: a 3-node pipeline, restart, recording, replay, lockstep."""
from __future__ import annotations

import os
import re
import textwrap
from pathlib import Path

import numpy as np

from conftest import launch_until, recording_for, tether
from tether.log import LogReader


def _values(path: Path, topic: str) -> list[tuple[int, float]]:
    reader = LogReader(path)
    return [(m.seq, m.data) for m in (reader.decode(r) for r in reader.messages([topic]))]


def _printed_max(stdout: str) -> float:
    """The largest value the printer logged so far (-1 before any)."""
    return max((float(v) for v in re.findall(r"\[printer\] .* value (-?[0-9.]+) \(seq", stdout)), default=-1.0)


def test_three_node_pipeline_end_to_end(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "run.mcap"
    res = launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=20", "--param", "scale.gain=3",
                        "--record", str(log)], runtime_env, lambda out, err: _printed_max(out) >= 60.0)
    assert res.returncode == 0, res.stderr + res.stdout
    counter = _values(log, "counter/value")
    scaled = _values(log, "scale/value")
    assert len(counter) >= 21          # the printer saw 3 * 20: counter values 0 .. 20 were recorded
    assert [s for s, _ in counter] == list(range(1, len(counter) + 1))      # nothing lost from the first message
    assert [v for _, v in counter] == [float(i) for i in range(len(counter))]
    # the launch stops from the source: every value it sent went through scale and reached the printer
    assert [v for _, v in scaled] == [3.0 * v for _, v in counter]
    assert "[printer] INFO tether.printer: value 0.0 (seq 1)" in res.stdout   # log lines prefixed with node id
    assert f"[printer] INFO tether.printer: saw {len(counter)} values" in res.stdout   # teardown ran on shutdown


def test_handler_failure_is_counted_and_node_keeps_running(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "run.mcap"
    res = launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=20", "--param", "scale.fail_on=3.0",
                        "--record", str(log)], runtime_env,
                       lambda out, err: "injected failure on 3.0" in out and _printed_max(out) >= 12.0)
    assert res.returncode == 0, res.stdout + res.stderr
    scaled = [v for _, v in _values(log, "scale/value")]
    assert 6.0 not in scaled and 4.0 in scaled and 8.0 in scaled             # 3.0 dropped, neighbours fine
    assert res.stdout.count("injected failure on 3.0") == 1                   # one clear line
    assert "stamp_ns=" in res.stdout and "counter/value" in res.stdout


def test_crashed_node_is_restarted_per_policy(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "run.mcap"
    res = launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=20", "--param", "scale.exit_on=5.0",
                        "--record", str(log)], runtime_env,
                       lambda out, err: "restarting scale (1/3)" in err and _printed_max(out) > 20.0)
    assert "scale exited with code 3; restart in 0.5 s" in res.stderr
    assert "restarting scale (1/3)" in res.stderr
    scaled = [v for _, v in _values(log, "scale/value")]
    assert 8.0 in scaled and max(scaled) > 20.0           # values flowed before and after the restart
    assert res.returncode == 0                            # recovered within its restart budget


def test_failed_node_without_restart_makes_launch_exit_nonzero(tmp_path: Path, runtime_env: dict) -> None:
    path = tmp_path / "g.yaml"
    path.write_text(textwrap.dedent("""
        name: failing
        nodes:
          - {id: counter, node: nodes.std.demo:Counter, params: {rate_hz: 20}}
          - {id: scale, node: nodes.std.demo:Scale, params: {exit_on: 2.0}, inputs: {value: counter/value}}
    """))
    res = tether("launch", str(path), "--duration", "3", env=runtime_env)
    assert res.returncode == 1 and "failed: scale" in res.stderr


def test_record_then_replay_into_node_lockstep_is_deterministic(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "in.mcap"
    assert launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=30", "--record", str(log)], runtime_env,
                        lambda out, err: _printed_max(out) >= 20.0).returncode == 0     # 10 values through
    outs = []
    for i in range(2):
        out = tmp_path / f"out{i}.mcap"
        res = tether("replay", str(log), "--into", "nodes.std.demo:Scale", "--map", "value=counter/value",
                     "--param", "gain=5", "--record", str(out), "--lockstep", env=runtime_env)
        assert res.returncode == 0, res.stderr
        outs.append([(r.topic, r.log_time_ns, r.data) for r in LogReader(out).messages()])
    assert outs[0] == outs[1]                                         # byte-identical, same log times
    counter = [v for _, v in _values(log, "counter/value")]
    replayed = [v for _, v in _values(tmp_path / "out0.mcap", "scale/value")]
    assert len(counter) >= 11 and replayed == [5.0 * v for v in counter]     # every message handled, in order


def test_replay_into_live_node_handles_every_message(tmp_path: Path, runtime_env: dict) -> None:
    from tether.log import LogWriter
    from msgs.std import Float64

    log = tmp_path / "in.mcap"
    with LogWriter(log) as w:
        for i in range(50):
            w.write("counter/value", Float64(data=float(i), stamp_ns=1_000 + i), log_time_ns=10**9 + i * 10**6)
    out = tmp_path / "out.mcap"
    res = tether("replay", str(log), "--into", "nodes.std.demo:Scale", "--map", "value=counter/value",
                 "--record", str(out), "--rate", "1", "--start", "0.01", env=runtime_env)
    assert res.returncode == 0, res.stderr
    got = [v for _, v in _values(out, "scale/value")]
    assert got == [2.0 * i for i in range(10, 50)]                    # --start skips the first 10 ms


def test_replay_window_and_player_node(tmp_path: Path) -> None:
    from tether.log import LogWriter
    from tether.replay import Player, Window, records
    from msgs.std import Float64, String

    log = tmp_path / "in.mcap"
    with LogWriter(log) as w:
        for i in range(20):
            w.write("a/x", Float64(data=float(i)), log_time_ns=10**9 + i * 10**8)
            w.write("b/y", String(data=str(i)), log_time_ns=10**9 + i * 10**8)
    got = [r.topic for r in records(LogReader(log), Window(start_s=0.5, end_s=1.0, topics=["a/x"]))]
    assert got == ["a/x"] * 5
    ports = Player.resolve_ports(Player.make_config({"log": str(log)}))
    assert dict(ports.outputs) == {"x": Float64, "y": String}


def test_malformed_frames_into_a_live_node_are_counted_not_fatal(runtime_env: dict) -> None:
    import threading
    import time

    import msgpack
    import zmq

    from msgs.std import Float64
    from nodes.std.demo import Scale
    from tether.codec import Codec
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    ctx = zmq.Context()
    src_ep, out_ep = ipc_endpoint("t", "src", "a"), ipc_endpoint("t", "scale", "b")
    pub = ctx.socket(zmq.XPUB)
    pub.bind(src_ep)
    spec = RunSpec(graph="t", node_id="scale", node="nodes.std.demo:Scale", binds=[out_ep],
                   inputs={"value": Source(topic="c/value", endpoint=src_ep)},
                   expect_subscribers={"scale/value": 1}, wait_subscribers_s=30.0)
    runtime = NodeRuntime(spec, Scale, ctx)
    sub = ctx.socket(zmq.SUB)
    sub.connect(out_ep)
    sub.subscribe(b"scale/value")
    thread = threading.Thread(target=runtime.serve, daemon=True)
    thread.start()
    assert pub.poll(30000)                                  # the node subscribed
    deadline = time.monotonic() + 30
    while runtime._subscribers.get("scale/value", 0) < 1:   # ... and saw our subscription
        assert time.monotonic() < deadline
        time.sleep(0.01)
    rng = np.random.default_rng(3)
    codec = Codec()
    good = codec.encode(Float64(data=21.0, seq=1))
    garbage = [[b"c/value"], [b"c/value", b"\xc1"], [b"c/value", rng.bytes(40)],
               [b"c/value", msgpack.packb({"type": "std.String", "data": "x"})],
               [b"c/value", msgpack.packb({"type": "std.Float64", "data": "NaN?"})],
               [b"c/value_long", good[0]]]                   # prefix-sharing topic: not delivered at all
    for frames in garbage * 5:
        pub.send_multipart(frames)
    pub.send_multipart([b"c/value", *good])
    assert sub.poll(5000), "the node stopped answering after garbage"
    topic, body = sub.recv_multipart()
    assert topic == b"scale/value" and codec.decode(Float64, [body]).data == 42.0
    deadline = time.monotonic() + 10      # the handler publishes before its call is counted
    while runtime.stats().inputs[0].handled < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    stats = runtime.stats().inputs[0]
    assert stats.decode_errors == 25 and stats.handled == 1 and stats.received == 26
    runtime.stop()
    thread.join(5)
    assert not thread.is_alive()
    ctx.destroy(linger=0)


def test_launch_records_only_the_selected_topics(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "sel.mcap"
    res = launch_until(["launch/counter.yaml", "--param", "counter.rate_hz=20", "--record", str(log),
                        "--record-exclude", "scale/*"], runtime_env, recording_for(1.0))
    assert res.returncode == 0, res.stderr
    assert set(LogReader(log).info().topics) == {"counter/value"}
    assert "[record]" in res.stdout and "recorded" in res.stdout        # the recorder is its own process
    bad = tether("launch", "launch/counter.yaml", "--duration", "1", "--record", str(log), "--overwrite",
                 "--record-topics", "nothing/*", env=runtime_env)
    assert bad.returncode == 2 and "no topic matches" in bad.stderr


def test_a_launch_stopped_while_its_recorder_starts_leaves_a_complete_log(tmp_path: Path, runtime_env: dict) -> None:
    """A short run on a loaded (or small) machine can end before the recorder process has finished
    importing: the launcher lets it start, then stops it; a complete log, and no failure."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text("import sys, time\n"
                                           "if 'tether.record' in sys.orig_argv:\n"
                                           "    time.sleep(2.0)              # a recorder slow to start\n")
    env = {**runtime_env, "PYTHONPATH": os.pathsep.join(p for p in (str(site), runtime_env.get("PYTHONPATH")) if p)}
    log = tmp_path / "run.mcap"
    res = tether("launch", "launch/counter.yaml", "--duration", "0.5", "--record", str(log), env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "recorder" not in res.stderr, res.stderr            # no 'the recorder exited with code -15'
    reader = LogReader(log)
    assert not reader.recovered                                 # closed properly: footer and summary
