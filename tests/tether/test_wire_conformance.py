"""docs/wire.md conformance: peers written without Tether join a running graph.

docs/examples/wire_client.py (plain pyzmq + msgpack, run as its own process) and
docs/examples/wire_client.c (libzmq and hand-written msgpack, compiled here when gcc and
zmq.h are available) each publish std.Float64 on a topic they register, and subscribe to
the outputs of a Tether node started in-process that consumes it: a relay that answers
every value with ``3 * value`` and a 4 x 8 uint8 image (its buffer in a frame of its own).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Iterator

import msgspec
import numpy as np
import pytest

from conftest import REPO
from msgs.sensor import Image
from msgs.std import Float64
from tether import Node, registry
from tether.runtime import NodeRuntime, RunSpec, Source
from tether.transport import ipc_endpoint

EXAMPLES = REPO / "docs" / "examples"


def pattern(k: int) -> np.ndarray:
    return ((np.arange(32) + k) % 256).astype(np.uint8).reshape(4, 8)


class Relay(Node):
    """value -> 3 * value, and an image that says which value it answers."""

    inputs = {"value": Float64}
    outputs = {"value": Float64, "image": Image}

    def on_value(self, msg: Float64) -> dict[str, msgspec.Struct]:
        return {"value": Float64(data=3 * msg.data, stamp_ns=msg.stamp_ns),
                "image": Image(data=pattern(int(msg.data)), stamp_ns=msg.stamp_ns)}


def wait_for_topic(topic: str, proc: subprocess.Popen, timeout_s: float = 20.0) -> registry.TopicInfo:
    deadline = time.monotonic() + timeout_s
    while topic not in registry.topics():
        assert proc.poll() is None, f"the client exited: {proc.communicate()}"
        assert time.monotonic() < deadline, f"{topic} was never registered"
        time.sleep(0.05)
    return registry.topics()[topic]


class RunningRelay:
    """The relay node on real sockets in a thread, registered like ``tether run`` registers."""

    def __init__(self, input_topic: str, endpoint: str, bind: str = "") -> None:
        self.endpoint = bind or ipc_endpoint("relay", "relay", uuid.uuid4().hex[:8])
        spec = RunSpec(graph="relay", node_id="relay", node="test_wire_conformance:Relay", binds=[self.endpoint],
                       inputs={"value": Source(topic=input_topic, endpoint=endpoint)})
        self.runtime = NodeRuntime(spec, Relay)
        self.entry = registry.register({"name": "relay", "machine": "", "nodes": {}, "topics": {
            "relay/value": {"type": "std.Float64", "endpoint": self.endpoint},
            "relay/image": {"type": "sensor.Image", "endpoint": self.endpoint}}})
        self.thread = threading.Thread(target=self.runtime.serve, daemon=True)
        self.thread.start()

    def stop(self) -> dict:
        stats = msgspec.to_builtins(self.runtime.stats())
        self.runtime.stop()
        self.thread.join(10)
        registry.unregister(self.entry)
        return stats


def check_lines(out: str, count: int) -> None:
    """What the client printed: the relay's answers, decoded by the client, consistent and in order."""
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    values = [d for d in lines if d["topic"] == "relay/value"]
    images = [d for d in lines if d["topic"] == "relay/image"]
    assert len(values) >= count and len(images) >= count, out[-2000:]
    for d in values:
        assert d["type"] == "std.Float64" and d["data"] % 3 == 0 and d["stamp_ns"] > 0 and d["frames"] == 2
    for d in images:
        assert d["type"] == "sensor.Image" and d["frames"] == 3          # topic, body, the array's buffer
        assert (d["data"]["dtype"], d["data"]["shape"]) == ("|u1", [4, 8])
        k = bytes.fromhex(d["data"]["hex"])[0]
        assert bytes.fromhex(d["data"]["hex"]) == pattern(k).tobytes()
    seqs = [d["seq"] for d in values]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))               # numbered 1, 2, ... with no gap


def check_relay(stats: dict) -> None:
    (inp,) = stats["inputs"]
    assert inp["received"] > 0 and inp["handled"] > 0
    assert (inp["decode_errors"], inp["handler_errors"], inp["seq_resets"], inp["dropped_seq_gap"]) == (0, 0, 0, 0)


def run_client_against_relay(client: subprocess.Popen, topic: str, bind: str = "") -> None:
    """Relay ``topic`` (the client's) back to it as relay/value and relay/image; check both sides."""
    relay = None
    try:
        source = wait_for_topic(topic, client)
        assert source.type_name == "std.Float64"
        relay = RunningRelay(topic, source.endpoint, bind=bind)
        out, err = client.communicate(timeout=60)
    finally:
        if client.poll() is None:
            client.kill()
        stats = relay.stop() if relay is not None else {}
    assert client.returncode == 0, err
    check_lines(out, 5)
    check_relay(stats)


def test_python_client_without_tether_publishes_into_and_subscribes_from_a_graph(runtime_env: dict) -> None:
    client = subprocess.Popen([sys.executable, str(EXAMPLES / "wire_client.py"), "--publish", "wirepy/value",
                               "--subscribe", "relay/value", "--subscribe", "relay/image", "-n", "5"],
                              cwd=EXAMPLES, env=runtime_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run_client_against_relay(client, "wirepy/value")
    assert "wirepy/value" not in registry.topics()           # the client removed its entry


def test_the_client_imports_nothing_of_tether() -> None:
    import ast

    tree = ast.parse((EXAMPLES / "wire_client.py").read_text())
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported <= {"__future__", "argparse", "json", "os", "sys", "tempfile", "time", "pathlib", "msgpack", "zmq"}


@pytest.fixture(scope="module")
def c_client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """docs/examples/wire_client.c compiled against libzmq (skipped without gcc or zmq.h)."""
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler")
    probe = subprocess.run([gcc, "-x", "c", "-E", "-"], input="#include <zmq.h>\n", capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip("zmq.h not found (install libzmq3-dev / zeromq-devel)")
    exe = tmp_path_factory.mktemp("c") / "wire_client"
    build = subprocess.run([gcc, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
                            str(EXAMPLES / "wire_client.c"), "-lzmq"], capture_output=True, text=True)
    if build.returncode != 0 and "cannot find -lzmq" in build.stderr:
        pytest.skip("libzmq not found by the linker")
    assert build.returncode == 0, build.stderr
    yield exe


def test_c_client_publishes_into_and_subscribes_from_a_graph(runtime_env: dict, c_client: Path) -> None:
    relay_topics = ["relay/value", "relay/image"]
    # The C client reads no JSON: it registers its own topic but is told the relay's endpoint,
    # which is known before the relay binds (ZeroMQ connects to an endpoint before it exists).
    endpoint = ipc_endpoint("relay", "relay", uuid.uuid4().hex[:8])
    client = subprocess.Popen([str(c_client), "wirec/value", endpoint, *relay_topics, "5"], env=runtime_env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run_client_against_relay(client, "wirec/value", bind=endpoint)


class Collect(Node):
    """Keeps what it receives."""

    inputs = {"image": Image}

    def setup(self) -> None:
        self.got: list[Image] = []

    def on_image(self, msg: Image) -> None:
        self.got.append(msg)


def test_a_tether_subscriber_reads_what_the_spec_allows_and_counts_what_it_forbids(runtime_env: dict) -> None:
    """docs/wire.md 3-5, 7, from raw frames: inline arrays and a missing tag are accepted; a wrong
    tag, a size mismatch and a one-frame message are decode errors; seq jumps are counted."""
    import msgpack
    import zmq

    endpoint = ipc_endpoint("raw", "peer", uuid.uuid4().hex[:8])
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.bind(endpoint)
    runtime = NodeRuntime(RunSpec(graph="raw", node_id="collect", node="test_wire_conformance:Collect",
                                  inputs={"image": Source(topic="peer/image", endpoint=endpoint)}), Collect)
    thread = threading.Thread(target=runtime.serve, daemon=True)
    thread.start()
    try:
        seen: list[bytes] = []                                     # subscriptions: 0x01 + the topic
        while b"\x01peer/image" not in seen:
            assert pub.poll(10_000), f"the node never subscribed to peer/image (it sent {seen})"
            seen.append(pub.recv())

        def body(seq: int, **fields) -> bytes:
            return msgpack.packb({"type": "sensor.Image", "stamp_ns": 5, "frame_id": "cam", "seq": seq,
                                  "encoding": "mono8", **fields})

        pixels = bytes(range(6))
        sent = [
            [body(1, data={"dtype": "|u1", "shape": [2, 3], "frame": 0}), pixels],     # frame form
            [body(2, data={"dtype": "|u1", "shape": [2, 3], "data": pixels})],         # inline form
            [msgpack.packb({"data": {"dtype": "<u2", "shape": [3], "frame": 0}, "seq": 5}), pixels],  # no tag; 2 lost
            [body(6, type="sensor.DepthImage")],                                     # wrong tag
            [body(7, data={"dtype": "|u1", "shape": [4, 3], "frame": 0}), pixels],     # 12 bytes announced, 6 sent
            [],                                                                        # the topic frame alone
            [body(3, data={"dtype": "|u1", "shape": [1], "frame": 0}), b"\x09"],       # seq went back: a reset
        ]
        for frames in sent:
            pub.send_multipart([b"peer/image", *frames])
            pub.send_multipart([b"peer/image_raw", *frames])           # a longer topic: must not be delivered
        deadline = time.monotonic() + 20
        while runtime.stats().inputs[0].received < 7:
            assert time.monotonic() < deadline, runtime.stats()
            time.sleep(0.02)
        deadline = time.monotonic() + 20
        while len(runtime.node.got) < 4 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        runtime.stop()
        thread.join(10)
        pub.close(linger=0)
    got = runtime.node.got
    assert [m.seq for m in got] == [1, 2, 5, 3]
    np.testing.assert_array_equal(got[0].data, np.arange(6, dtype=np.uint8).reshape(2, 3))
    np.testing.assert_array_equal(got[1].data, got[0].data)
    assert got[2].data.dtype == np.dtype("<u2") and got[2].frame_id == "" and got[0].frame_id == "cam"
    (inp,) = msgspec.to_builtins(runtime.stats())["inputs"]
    assert (inp["received"], inp["decode_errors"], inp["dropped_seq_gap"], inp["seq_resets"]) == (7, 3, 2, 1)
