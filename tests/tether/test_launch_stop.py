"""Stopping a launch: sources first, each node handles its inputs' last messages, bounded by one timeout."""
from __future__ import annotations

import re
import textwrap
import time
from pathlib import Path

import pytest

from conftest import REPO, launch_until
from tether.launch import load_launch
from tether.log import LogReader
from tether.supervisor import Supervisor, stop_stages


def _values(path: Path, topic: str) -> list[float]:
    reader = LogReader(path)
    return [m.data for m in (reader.decode(r) for r in reader.messages([topic]))]


def _saw(stdout: str, node: str) -> int:
    """What ``node`` (a demo Printer) says it saw at teardown; -1 when it never said (killed)."""
    found = re.findall(rf"\[{re.escape(node)}\] .*saw (\d+) values", stdout)
    return int(found[0]) if found else -1


def test_stop_stages_go_from_the_sources_with_a_cycle_as_one_stage(tmp_path: Path, runtime_env: dict,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(REPO))                   # tests.tether.stop_nodes, as the launched nodes see it
    path = tmp_path / "g.yaml"
    path.write_text(textwrap.dedent("""
        name: stages
        nodes:
          - {id: sink, node: nodes.std.demo:Printer, inputs: {value: d/value}}
          - {id: d, node: tests.tether.stop_nodes:Add, inputs: {a: c/value, b: e/value}}
          - {id: c, node: tests.tether.stop_nodes:Add, inputs: {a: b/value, b: e/value}}
          - {id: b, node: tests.tether.stop_nodes:Add, inputs: {a: a/value, b: c/value}}
          - {id: a, node: nodes.std.demo:Scale, inputs: {value: src/value}}
          - {id: src, node: nodes.std.demo:Counter}
          - {id: e, node: nodes.std.demo:Counter}
          - {id: self, node: nodes.std.demo:Scale, inputs: {value: self/value}}
    """))
    launch = load_launch(path)
    assert stop_stages(launch) == [["src", "e", "self"], ["a"], ["c", "b"], ["d"], ["sink"]]
    assert stop_stages(launch, ["sink", "a", "src"]) == [["src"], ["a"], ["sink"]]   # one machine's share
    b = Supervisor(launch).all_specs["b"].inputs
    assert b["a"].await_on_stop and not b["b"].await_on_stop      # its cycle stops with it: not waited for


def test_a_node_on_another_machine_still_orders_the_local_ones(tmp_path: Path, runtime_env: dict) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(textwrap.dedent("""
        name: machines
        machines:
          boat:  {host: 127.0.0.1, port_base: 47100}
          shore: {host: 127.0.0.1, port_base: 47110}
        nodes:
          - {id: counter, node: nodes.std.demo:Counter, machine: boat}
          - {id: relay, node: nodes.std.demo:Scale, inputs: {value: counter/value}, machine: shore}
          - {id: printer, node: nodes.std.demo:Printer, inputs: {value: relay/value}, machine: boat}
          - {id: other, node: nodes.std.demo:Counter, machine: boat}
    """))
    launch = load_launch(path)
    assert stop_stages(launch, ["counter", "printer", "other"]) == [["counter", "other"], ["printer"]]
    assert stop_stages(launch, ["relay"]) == [["relay"]]
    # a stopping node waits only for the publishers its own launcher stopped before it
    boat = Supervisor(launch, machine="boat")
    assert boat.stop_stages == [["counter", "other"], ["printer"]]
    assert not boat.all_specs["printer"].inputs["value"].await_on_stop            # relay: the shore's
    shore = Supervisor(launch, machine="shore")
    assert not shore.all_specs["relay"].inputs["value"].await_on_stop             # counter: the boat's
    local = load_launch(REPO / "launch" / "counter.yaml")
    specs = Supervisor(local).all_specs
    assert specs["scale"].inputs["value"].await_on_stop and specs["printer"].inputs["value"].await_on_stop


def test_a_stopped_pipeline_handles_every_message_its_source_sent(tmp_path: Path, runtime_env: dict) -> None:
    """A middle node slower than its source has a backlog when Ctrl-C comes: the source stops first,
    the middle node handles its backlog, then the sink stops, having seen all of it. Before, every
    node got SIGTERM at once and the backlog was lost (the middle node stopped at its next message)."""
    path = tmp_path / "slow.yaml"
    path.write_text(textwrap.dedent("""
        name: slow
        nodes:
          - {id: counter, node: nodes.std.demo:Counter, params: {rate_hz: 200, count: 40}}
          - {id: scale, node: tests.tether.stop_nodes:SlowScale, params: {gain: 3, delay_ms: 10},
             inputs: {value: counter/value}}
          - {id: printer, node: nodes.std.demo:Printer, inputs: {value: scale/value}}
    """))
    log = tmp_path / "run.mcap"
    res = launch_until([str(path), "--record", str(log)], runtime_env,
                       lambda out, err: "[printer] INFO tether.printer: value 0.0" in out)
    assert res.running_at_stop and res.returncode == 0, res.stderr[-2000:]
    counter = _values(log, "counter/value")
    assert counter == [float(i) for i in range(len(counter))] and len(counter) >= 1
    assert _values(log, "scale/value") == [3.0 * v for v in counter]
    assert _saw(res.stdout, "printer") == len(counter), res.stdout[-3000:]


def test_a_node_hung_in_its_stop_holds_the_later_stages_for_half_the_timeout_only(tmp_path: Path,
                                                                                  runtime_env: dict) -> None:
    """Two stages in a row that cannot stop: the sink after them is still stopped (after T / 2, not
    after each of them in turn), and the whole stop ends at T plus the stack dumps, not 2 T."""
    path = tmp_path / "stuck.yaml"
    path.write_text(textwrap.dedent("""
        name: stuck
        nodes:
          - {id: counter, node: nodes.std.demo:Counter, params: {rate_hz: 20}}
          - {id: stuck1, node: tests.tether.stop_nodes:SlowScale, params: {delay_ms: 0, hang_on_stop: true},
             inputs: {value: counter/value}}
          - {id: stuck2, node: tests.tether.stop_nodes:SlowScale, params: {delay_ms: 0, hang_on_stop: true, gain: 1},
             inputs: {value: stuck1/value}}
          - {id: printer, node: nodes.std.demo:Printer, inputs: {value: stuck2/value}}
    """))
    timeout_s = 4.0
    log = tmp_path / "run.mcap"
    res = launch_until([str(path), "--record", str(log)], {**runtime_env, "TETHER_STOP_TIMEOUT_S": str(timeout_s)},
                       lambda out, err: "[printer] INFO tether.printer: value 4.0" in out)
    stop_s = res.stop_s
    assert res.running_at_stop and res.returncode == 1, res.stderr[-2000:]
    assert "failed: stuck1, stuck2" in res.stderr, res.stderr[-2000:]
    assert "stuck1 still stopping after 2 s: stopping stuck2, printer without waiting" in res.stderr
    for node in ("stuck1", "stuck2"):
        assert f"node {node} did not stop within 4 s: its stacks follow, then it is killed" in res.stderr
        assert f"[{node}] INFO tether.{node}: hanging in teardown" in res.stdout
    counter = _values(log, "counter/value")
    assert _values(log, "stuck2/value") == [2.0 * v for v in counter]      # each handled all it got first
    assert _saw(res.stdout, "printer") == len(counter)                     # and the sink stopped by itself
    # T, then up to 2 s for the stacks, plus the launcher's own exit (4.4-4.8 s measured, load 3); one T plus its 2 s
    # of stacks per hung stage, in turn, would be 12 s: the bound leaves a loaded machine 3 s more
    assert stop_s < 2 * timeout_s, stop_s


def test_a_stopped_publishers_last_messages_are_read_before_its_link_is_redialled(runtime_env: dict) -> None:
    """A publisher that stops leaves its last messages in its subscriber's ZeroMQ queue; redialling
    its endpoint (``zmq_disconnect``) would discard them, so the redial waits until they are read.
    Before, a node behind by more than one read-ahead lost the rest when its upstream stopped."""
    import itertools

    import zmq

    from msgs.std import Float64
    from nodes.std.chaos import QuietSink
    from tether.codec import Codec
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    ep = ipc_endpoint("drain", "src", "x")
    rt = NodeRuntime(RunSpec(graph="drain", node_id="sink", node="nodes.std.chaos:QuietSink",
                             inputs={"value": Source(topic="a/value", endpoint=ep)}), QuietSink)
    rt.node.setup()
    state = rt.inputs["value"]
    pub = zmq.Context.instance().socket(zmq.PUB)
    pub.bind(ep)
    codec, order, seq = Codec(), itertools.count(), itertools.count(1)

    def send() -> None:
        pub.send_multipart([b"a/value", *(bytes(f) for f in codec.encode(Float64(data=1.0, seq=next(seq))))])

    try:
        deadline = time.monotonic() + 30
        while not state.stats["handled"]:                  # subscribed: messages flow
            assert time.monotonic() < deadline
            send()
            rt._receive(20, order)
            rt._handle_pending()
        while rt._receive(0, order) or state.queue:       # nothing of the probes left behind
            rt._handle_pending()
        before = state.stats["handled"]
        for _ in range(200):
            send()
        pub.close(linger=5000)                             # the publisher stops: its connection drops
        for _ in range(30):                                # the node checks its links meanwhile, busy elsewhere
            rt._check_links()
            time.sleep(0.01)
        deadline = time.monotonic() + 10
        while state.stats["handled"] < before + 200 and time.monotonic() < deadline:
            rt._receive(20, order)
            rt._handle_pending()
        assert state.stats["handled"] - before == 200
        deadline = time.monotonic() + 10
        while not state.stats["link_resets"] and time.monotonic() < deadline:
            rt._check_links()                              # read empty: now redialled
            time.sleep(0.01)
        assert state.stats["link_resets"] == 1
    finally:
        pub.close(linger=0)
        rt.close()


def test_a_node_run_alone_on_a_live_stream_stops_at_once_on_ctrl_c(runtime_env: dict) -> None:
    """``tether run`` attached to another graph's topic: that publisher never closes (nobody stops it
    first), so the node handles what it holds and stops; before, it waited for the stream to end or
    fall silent and took the 2 s bound with a warning at every Ctrl-C."""
    import signal
    import subprocess
    import sys

    from conftest import wait_for_topic

    graph = subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml",
                              "--param", "counter.rate_hz=200"], cwd=REPO, env=runtime_env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_topic("scale/value", runtime_env)
        res = launch_until(["nodes.std.demo:Printer", "--id", "alone", "--input", "value=scale/value"], runtime_env,
                           lambda out, err: "tether.alone: value" in out + err, verb="run")
        said = res.stdout + res.stderr
        assert res.running_at_stop and res.returncode == 0, said[-2000:]
        assert "saw" in said and "still arriving" not in said, said[-2000:]
    finally:
        graph.send_signal(signal.SIGINT)
        graph.wait(timeout=60)


def test_messages_lost_in_flight_on_a_cycle_at_the_stop_are_counted_in_one_line(tmp_path: Path,
                                                                                 runtime_env: dict) -> None:
    """The nodes of a cycle stop together (one stage): each returns once its sockets are read empty, so
    the ping or pong in flight between a Pinger and its Echo was dropped without a word. Now the
    launcher compares each publisher's last seq with what its subscriber last received (stop reports)
    and says so in one line; an acyclic graph, stopped from its sources, loses nothing and says nothing."""
    import subprocess
    import sys

    path = tmp_path / "ping.yaml"
    path.write_text(textwrap.dedent("""
        name: pingpong
        nodes:
          - {id: pinger, node: nodes.std.perf:Pinger, params: {count: 1000000000}, inputs: {pong: echo/pong}}
          - {id: echo, node: nodes.std.perf:Echo, inputs: {ping: pinger/ping}}
    """))
    res = subprocess.run([sys.executable, "-m", "tether.cli", "launch", str(path), "--duration", "2.5"], cwd=REPO,
                         env=runtime_env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = [line for line in res.stderr.splitlines() if "stop: " in line]
    assert len(lines) == 1, res.stderr
    found = re.search(r"stop: (\d+) message\(s\) published were never handled .*: "
                      r"(pinger/ping -> echo\.ping|echo/pong -> pinger\.pong) (\d+)$", lines[0])
    assert found and 1 <= int(found.group(1)) == int(found.group(3)) <= 3, lines[0]   # one in flight (+ a timer's)
    assert "tether-stop-report" not in res.stdout + res.stderr                         # taken, not printed
    res = subprocess.run([sys.executable, "-m", "tether.cli", "launch", "launch/counter.yaml", "--param",
                          "counter.rate_hz=50", "--duration", "2.5"], cwd=REPO, env=runtime_env, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0 and "saw " in res.stdout and "stop: " not in res.stderr, res.stderr


def test_stop_losses_count_the_tail_after_the_last_message_received() -> None:
    from tether.supervisor import stop_losses

    reports = {"a": {"published": {"a/value": 40}, "received": {}},
               "b": {"published": {}, "received": {"v": ["a/value", 37], "w": ["far/value", 5]}},
               "c": {"published": {}, "received": {"v": ["a/value", 0]}}}
    # b missed 38..40; 'far' did not report (another machine, or killed): not counted; c never received
    # anything (not connected, or every message dropped): no tail to speak of
    assert stop_losses(reports) == {"a/value -> b.v": 3}
    reports["b"]["received"]["v"] = ["a/value", 40]
    assert stop_losses(reports) == {}
