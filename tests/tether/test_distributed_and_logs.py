"""Two launchers over CurveZMQ tcp; crash-safe recording; schema evolution; CLI attach; hz honesty."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path


from conftest import REPO, free_port, tether, two_machines, wait_for_topic
from tether.log import LogReader, LogWriter


def test_two_machines_talk_over_curve_tcp(tmp_path: Path, runtime_env: dict) -> None:
    path = two_machines(tmp_path, "twomachines")
    log = tmp_path / "shore.mcap"
    cmd = [sys.executable, "-m", "tether.cli", "launch", str(path), "--duration", "4"]
    boat = subprocess.Popen([*cmd, "--machine", "boat"], cwd=REPO, env=runtime_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    shore = subprocess.run([*cmd, "--machine", "shore", "--record", str(log)], cwd=REPO, env=runtime_env,
                           capture_output=True, text=True, timeout=60)
    boat_out = boat.communicate(timeout=60)[0]
    assert shore.returncode == 0 and boat.returncode == 0, shore.stderr + boat_out
    values = [LogReader(log).decode(r).data for r in LogReader(log).messages(["scale/value"])]
    assert len(values) >= 20 and all(v % 2 == 0 for v in values)   # counter values crossed tcp and were doubled
    store = Path(runtime_env["TETHER_KEYS_DIR"]) / "twomachines"          # one key pair per machine
    peers = json.loads((store / "peers.json").read_text())
    assert set(peers) == {"boat", "shore"} and peers["boat"] != peers["shore"]
    for machine in ("boat", "shore"):
        key = json.loads((store / f"{machine}.key").read_text())
        assert key["public"] == peers[machine] and oct(os.stat(store / f"{machine}.key").st_mode & 0o777) == "0o600"


def test_a_port_held_by_another_process_is_one_clear_line(tmp_path: Path, runtime_env: dict) -> None:
    import re
    import socket

    path = two_machines(tmp_path, "heldport")
    base = int(re.search(r"boat:\s+\{host: 127.0.0.1, port_base: (\d+)\}", path.read_text()).group(1))
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", base))                       # the counter's port
        holder.listen()
        boat = subprocess.run([sys.executable, "-m", "tether.cli", "launch", str(path), "--duration", "3",
                               "--machine", "boat"], cwd=REPO, env=runtime_env, capture_output=True, text=True,
                              timeout=60)
    out = boat.stdout + boat.stderr
    assert boat.returncode != 0 and "Traceback" not in out, out
    assert f"cannot bind tcp://127.0.0.1:{base}: the address is in use by another process" in out, out


def test_curve_rejects_a_subscriber_without_the_graph_keys(runtime_env: dict) -> None:
    import threading

    import zmq

    from nodes.std.demo import Counter
    from tether.runtime import NodeRuntime, RunSpec
    from tether.transport import CurveKeys

    port = free_port()
    (boat_pub, boat_sec), (shore_pub, shore_sec) = zmq.curve_keypair(), zmq.curve_keypair()
    keys = CurveKeys(boat_pub, boat_sec, {"boat": boat_pub, "shore": shore_pub})   # the publisher is on boat
    spec = RunSpec(graph="c", node_id="counter", node="nodes.std.demo:Counter", params={"rate_hz": 50},
                   binds=[f"tcp://127.0.0.1:{port}"], curve=keys.to_json())
    ctx = zmq.Context()
    runtime = NodeRuntime(spec, Counter, ctx)
    thread = threading.Thread(target=runtime.serve, daemon=True)
    thread.start()
    try:
        intruder = ctx.socket(zmq.SUB)
        stranger = zmq.curve_keypair()           # encrypts, knows the server key, but is not on the allow-list
        intruder.curve_serverkey, intruder.curve_publickey, intruder.curve_secretkey = (boat_pub, *stranger)
        intruder.connect(f"tcp://127.0.0.1:{port}")
        intruder.subscribe(b"counter/value")
        plain = ctx.socket(zmq.SUB)              # no encryption at all
        plain.connect(f"tcp://127.0.0.1:{port}")
        plain.subscribe(b"counter/value")
        friend = ctx.socket(zmq.SUB)
        friend.curve_serverkey, friend.curve_publickey, friend.curve_secretkey = (boat_pub, shore_pub, shore_sec)
        friend.connect(f"tcp://127.0.0.1:{port}")
        friend.subscribe(b"counter/value")
        assert friend.poll(5000)                 # another machine of the graph gets data ...
        assert not intruder.poll(500) and not plain.poll(100)   # ... the others get nothing
    finally:
        runtime.stop()
        thread.join(5)
        ctx.destroy(linger=0)


def test_recorder_killed_with_sigkill_leaves_a_readable_log(tmp_path: Path, runtime_env: dict) -> None:
    log = tmp_path / "killed.mcap"
    launch = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml",
                               "--param", "counter.rate_hz=50"], cwd=REPO, env=runtime_env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_topic("scale/value", runtime_env, alive=launch)
        rec = subprocess.Popen([sys.executable, "-m", "tether.cli", "record", "-o", str(log)], cwd=REPO,
                               env=runtime_env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(3.5)                          # > 3 flush periods of recording at 50 Hz
        rec.send_signal(signal.SIGKILL)
        rec.wait(10)
    finally:
        launch.send_signal(signal.SIGINT)
        _, err = launch.communicate(timeout=30)      # (once, in a loaded full run: did not exit in 30 s)
    assert launch.returncode == 0, err[-3000:]
    reader = LogReader(log)
    assert reader.recovered                      # no footer: read by streaming
    msgs = [reader.decode(r) for r in reader.messages(["counter/value"])]
    assert len(msgs) >= 50                       # at least the chunks flushed each second
    seqs = [m.seq for m in msgs]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))   # complete chunks hold contiguous messages


def test_old_log_still_decodes_after_a_field_is_appended(tmp_path: Path) -> None:
    log = tmp_path / "old.mcap"
    old = textwrap.dedent(f"""
        from tether.message import Message
        from tether.log import LogWriter
        class Reading(Message, tag="evolve.Reading"):
            value: float = 0.0
        with LogWriter({str(log)!r}) as w:
            w.write("s/r", Reading(value=1.5, stamp_ns=7))
    """)
    new = textwrap.dedent(f"""
        from tether.message import Message
        from tether.log import LogReader
        class Reading(Message, tag="evolve.Reading"):
            value: float = 0.0
            unit: str = "m"          # appended with a default, per the schema policy
        import tether.message as tm
        r = LogReader({str(log)!r})
        m = r.decode_as(Reading, next(r.messages()))
        assert (m.value, m.unit, m.stamp_ns) == (1.5, "m", 7), m
        print("ok")
    """)
    for code in (old, new):
        res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"
    schema = json.loads(LogReader(log).schemas()["evolve.Reading"])   # the log carries its schema
    assert schema["$defs"]["Reading"]["properties"]["value"]["type"] == "number"


def test_log_is_readable_with_the_mcap_package_and_plain_msgpack(tmp_path: Path) -> None:
    import msgpack
    import numpy as np
    from mcap.reader import make_reader

    from msgs.sensor import Image
    log = tmp_path / "a.mcap"
    with LogWriter(log) as w:
        w.write("cam/image", Image(data=np.arange(6, dtype=np.uint8).reshape(2, 3)), log_time_ns=5)
    with open(log, "rb") as fh:
        reader = make_reader(fh)
        schema, channel, message = next(reader.iter_messages())
        assert channel.message_encoding == "msgpack" and schema.encoding == "jsonschema"
        assert reader.get_summary().chunk_indexes[0].compression == "zstd"
        doc = msgpack.unpackb(message.data)
    assert doc["data"]["shape"] == [2, 3] and doc["data"]["data"] == bytes(range(6))


def test_foxglove_export_writes_foxglove_schemas(tmp_path: Path, runtime_env: dict) -> None:
    """Images export as Foxglove RawImage (protobuf), the rest as JSON (tests/tether/test_foxglove_convert.py)."""
    import numpy as np
    from mcap.reader import make_reader

    from msgs.sensor import Image
    log, out = tmp_path / "a.mcap", tmp_path / "fox.mcap"
    with LogWriter(log) as w:
        w.write("cam/image", Image(data=np.zeros((2, 2), np.uint8)), log_time_ns=5)
    res = tether("export", "foxglove", str(log), "-o", str(out), env=runtime_env)
    assert res.returncode == 0, res.stderr
    with open(out, "rb") as fh:
        schema, channel, message = next(make_reader(fh).iter_messages())
    assert (schema.name, channel.message_encoding, message.log_time) == ("foxglove.RawImage", "protobuf", 5)


def test_cli_attaches_echo_hz_and_node_info_to_a_running_graph(runtime_env: dict) -> None:
    launch = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml",
                               "--param", "counter.rate_hz=40"], cwd=REPO, env=runtime_env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_topic("scale/value", runtime_env)
        echo = tether("topic", "echo", "scale/value", "-n", "2", env=runtime_env)
        assert echo.returncode == 0 and echo.stdout.count("Float64") == 2
        hz = tether("topic", "hz", "counter/value", "--duration", "3", env=runtime_env)
        rates = [float(line.split("rate (stamps)")[1].split()[0]) for line in hz.stdout.splitlines()
                 if "rate (stamps)" in line]
        arrivals = [float(line.split()[2]) for line in hz.stdout.splitlines() if line.startswith("rate (arrival)")]
        assert rates and abs(rates[-1] - 40.0) < 4.0 and arrivals and abs(arrivals[-1] - 40.0) < 8.0
        info = tether("node", "info", "scale", "--wait", "20", env=runtime_env)
        assert info.returncode == 0 and "<- value" in info.stdout and "-> value" in info.stdout
        nodes = tether("node", "list", env=runtime_env).stdout
        assert "scale" in nodes and "nodes.std.demo:Scale" in nodes
        missing = tether("topic", "echo", "nobody/here", "-n", "1", env=runtime_env)
        assert missing.returncode == 2 and "no running graph publishes 'nobody/here'" in missing.stderr
        assert "Traceback" not in missing.stderr
    finally:
        launch.send_signal(signal.SIGINT)
        _, err = launch.communicate(timeout=30)        # (once, in a loaded full run: exit 1; say which node)
        assert launch.returncode == 0, err[-3000:]


def test_hz_is_computed_from_publisher_seq_and_stamps_not_from_what_arrived() -> None:
    from tether.introspect import rate_line

    # 1000 Hz publisher, but the slow terminal only saw every 10th message.
    samples = [(i * 0.01, i * 10 * 1_000_000, 1 + i * 10, 1 << 20) for i in range(100)]
    line = rate_line("hz", samples)
    assert "rate (stamps)   1000.00 Hz" in line and "rate (arrival)    100.00 Hz" in line and "not seen here" in line
    bw = rate_line("bw", samples)
    assert f"{1000 * (1 << 20) / 1e6:9.2f} MB/s" in bw


def test_replay_then_record_gives_the_same_messages(tmp_path: Path, runtime_env: dict) -> None:
    import numpy as np

    from msgs.sensor import Image
    from msgs.std import String
    src, dst = tmp_path / "src.mcap", tmp_path / "dst.mcap"
    with LogWriter(src) as w:
        for i in range(40):
            w.write("cam/image", Image(data=np.full((64, 32), i, np.uint8), stamp_ns=10**9 + i, seq=i + 1),
                    log_time_ns=10**9 + i * 10**7)
            w.write("cam/name", String(data=f"frame {i}", stamp_ns=10**9 + i, seq=i + 1), log_time_ns=10**9 + i * 10**7)
    replay = subprocess.Popen([sys.executable, "-m", "tether.cli", "replay", str(src), "--wait-subscribers", "1",
                               "--delay", "60"], cwd=REPO,
                              env=runtime_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rec = None
    try:
        wait_for_topic("cam/name", runtime_env, alive=replay)
        rec = subprocess.Popen([sys.executable, "-m", "tether.cli", "record", "-o", str(dst)], cwd=REPO,
                               env=runtime_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _, replay_err = replay.communicate(timeout=90)   # starts once the recorder subscribes, ends by itself
        assert replay.returncode == 0, replay_err[-2000:]
        rec.send_signal(signal.SIGINT)              # at once: a stopped recorder writes what is still in flight
        _, rec_err = rec.communicate(timeout=30)
        assert rec.returncode == 0, rec_err[-2000:]
    finally:
        for proc in (replay, rec):
            if proc is not None and proc.poll() is None:     # a failure above: no process left behind
                proc.kill()
                proc.communicate()
    a = [(r.topic, r.data) for r in LogReader(src).messages()]
    b = [(r.topic, r.data) for r in LogReader(dst).messages()]
    assert sorted(a) == sorted(b) and len(b) == 80
    alone = tether("replay", str(src), "--wait-subscribers", "2", "--delay", "0.3", env=runtime_env)
    assert alone.returncode == 0 and "0 of 2 subscribers on every topic after 0.3 s: playing anyway" in alone.stderr
    assert "replayed 80 messages" in alone.stdout


def test_random_frames_on_the_live_accept_path_never_raise(runtime_env: dict) -> None:
    from hypothesis import given, settings, strategies as st

    from nodes.std.demo import Scale
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    spec = RunSpec(graph="h", node_id="scale", node="nodes.std.demo:Scale", binds=[],
                   inputs={"value": Source(topic="c/value", endpoint=ipc_endpoint("h", "c", "z"))})
    runtime = NodeRuntime(spec, Scale)
    state = runtime.inputs["value"]

    @settings(max_examples=300, deadline=None)
    @given(st.lists(st.binary(max_size=48), min_size=0, max_size=3))
    def feed(frames: list[bytes]) -> None:
        runtime._accept(state, frames, 0)
        runtime._handle_pending()

    feed()
    assert state.stats["received"] == state.stats["decode_errors"] + state.stats["handled"] + len(state.queue)
    runtime.close()


def test_run_attaches_one_node_to_a_running_graph(runtime_env: dict) -> None:
    launch = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml",
                               "--param", "counter.rate_hz=20"], cwd=REPO, env=runtime_env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_topic("counter/value", runtime_env)
        res = tether("run", "nodes.std.demo:Printer", "--id", "lone", "--input", "value=counter/value",
                     "--duration", "2", env=runtime_env)
        assert res.returncode == 0, res.stderr
        seen = [line for line in res.stderr.splitlines() if "tether.lone: value" in line]
        assert len(seen) >= 20                                  # ~20 Hz for 2 s
        values = [float(line.split("value ")[1].split()[0]) for line in seen]
        assert values == sorted(values) and all(b - a == 1.0 for a, b in zip(values, values[1:]))
        # a node stopped by SIGTERM exits promptly, whatever its --duration
        lone = subprocess.Popen([sys.executable, "-m", "tether.cli", "run", "nodes.std.demo:Printer", "--id", "lone2",
                                 "--input", "value=counter/value", "--duration", "60"], cwd=REPO, env=runtime_env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_for_topic("lone2/_stats", runtime_env)
        lone.terminate()
        assert lone.wait(20) == 0          # stopped by the signal, long before its 60 s duration
    finally:
        launch.send_signal(signal.SIGINT)
        launch.wait(30)
