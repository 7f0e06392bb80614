"""Issue 21 §1: no message kills a node. Untrusted headers, malformed frames, oversize frames,
byte-bounded queues, sink statistics and losses across a restart; the last test sends seeded
extremes of every registered message type through a live two-process graph."""
from __future__ import annotations

import importlib
import itertools
import pkgutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import msgpack
import msgspec
import numpy as np
import pytest
import zmq

from conftest import REPO
from msgs.sensor import Image
from msgs.std import Bytes, Float64, NodeStats
from tether import Input, Node
from tether.codec import Codec
from tether.inputs import I64_MAX, U64_MAX, InputState
from tether.message import Message, registered_types
from tether.runtime import NodeRuntime, RunSpec, Source
from tether.transport import ipc_endpoint

EXTREME_SEQ = [0, 1, 1 << 63, U64_MAX, 1, 2, 1 << 63, U64_MAX, 1]


class Take(Node):
    inputs = {"value": Input(Float64, depth=4), "blob": Input(Bytes, depth=64, max_queue_bytes=3 << 20),
              "image": Input(Image, depth=4)}

    def setup(self) -> None:
        self.seen: list[Message] = []

    def on_value(self, msg: Float64) -> None:
        self.seen.append(msg)

    def on_blob(self, msg: Bytes) -> None:
        self.seen.append(msg)

    def on_image(self, msg: Image) -> None:
        self.seen.append(msg)


def _runtime(**spec: Any) -> NodeRuntime:
    ep = ipc_endpoint("f", "src", "x")
    rt = NodeRuntime(RunSpec(graph="f", node_id="take", node="tests:Take",
                             inputs={"value": Source(topic="a/value", endpoint=ep),
                                     "blob": Source(topic="a/blob", endpoint=ep),
                                     "image": Source(topic="a/image", endpoint=ep)}, **spec), Take)
    rt.node.setup()
    return rt


def _frames(msg: Message) -> list[bytes]:
    return [bytes(f) for f in Codec().encode(msg)]


def test_absurd_seq_jumps_are_counted_resets_and_statistics_stay_encodable(runtime_env: dict) -> None:
    rt = _runtime()
    value = rt.inputs["value"]
    for i, seq in enumerate(EXTREME_SEQ):
        rt._accept(value, _frames(Float64(data=float(i), seq=seq, stamp_ns=[-1, 0, I64_MAX][i % 3])), i)
        rt._handle_pending()
    assert len(rt.node.seen) == len(EXTREME_SEQ)          # every valid message is handled, whatever its header
    assert value.stats["dropped_seq_gap"] == 0            # 1 -> 2 is the only plausible step, and it loses nothing
    assert value.stats["seq_resets"] == 7                 # 0, the jumps to 2^63 and 2^64-1, and back to 1
    stats = Codec().decode(NodeStats, Codec().encode(rt.stats()))   # what _publish_stats sends, round-tripped
    assert stats.inputs[0].seq_resets == 7
    rt.close()


def test_counters_saturate_instead_of_overflowing_the_wire_format(runtime_env: dict) -> None:
    rt = _runtime()
    rt.inputs["value"].stats["dropped_seq_gap"] = 1 << 70  # however it got there, it must still publish
    rt._published["x"] = 1 << 80
    stats = Codec().decode(NodeStats, Codec().encode(rt.stats()))
    assert stats.inputs[0].dropped_seq_gap == I64_MAX and stats.published["x"] == I64_MAX
    rt.close()


def test_a_failure_while_publishing_statistics_is_counted_not_fatal(runtime_env: dict) -> None:
    rt = NodeRuntime(RunSpec(graph="f", node_id="take", node="tests:Take", binds=[ipc_endpoint("f", "take", "y")]),
                     Take)
    rt._codec.encode = lambda msg: (_ for _ in ()).throw(OverflowError("boom"))   # type: ignore[method-assign]
    rt._publish_stats()
    rt._publish_stats()
    assert rt._stats_errors == 2 and rt.stats().stats_errors == 2
    rt.close()


BAD_FRAMES: dict[str, Callable[[], list[Any]]] = {
    "no body": lambda: [],
    "0-byte body": lambda: [b""],
    "random bytes": lambda: [np.random.default_rng(3).bytes(40)],
    "not a map": lambda: [msgpack.packb([1, 2, 3])],
    "wrong type": lambda: [msgpack.packb({"type": "std.String", "data": "x"})],
    "huge declared length": lambda: [b"\xc6\xff\xff\xff\xf0" + bytes(8)],
    "truncated": lambda: [_frames(Float64(data=1.0, seq=5))[0][:7]],
}


@pytest.mark.parametrize("case", sorted(BAD_FRAMES))
def test_malformed_frames_are_counted_decode_errors(case: str, runtime_env: dict) -> None:
    rt = _runtime()
    value = rt.inputs["value"]
    rt._accept(value, BAD_FRAMES[case](), 0)
    rt._accept(value, _frames(Float64(data=2.0, seq=1)), 1)   # and the input goes on
    rt._handle_pending()
    assert value.stats["decode_errors"] == 1 and [m.data for m in rt.node.seen] == [2.0]
    rt.close()


@pytest.mark.parametrize("shape,buffer", [([64, 64], 100), ([1 << 40, 1 << 40], 16), ([U64_MAX], 16),
                                          ([-4, 4], 16), ([4, 4], 0)])
def test_an_array_whose_shape_disagrees_with_its_buffer_is_a_decode_error(shape: list[int], buffer: int,
                                                                           runtime_env: dict) -> None:
    rt = _runtime()
    image = rt.inputs["image"]
    body = msgpack.packb({"type": "sensor.Image", "seq": 1, "encoding": "mono8",
                          "data": {"dtype": "|u1", "shape": shape, "frame": 0}})
    rt._accept(image, [body, bytes(buffer)], 0)             # [2^64-1]: an OverflowError inside numpy, once fatal
    rt._handle_pending()
    assert image.stats["decode_errors"] == 1 and not rt.node.seen
    rt.close()


def test_queues_are_bounded_in_bytes_and_zeromq_queues_follow_the_message_size(runtime_env: dict) -> None:
    rt = _runtime()
    blob = rt.inputs["blob"]
    one_mib = _frames(Bytes(data=bytes(1 << 20), seq=1))
    for i in range(10):
        rt._accept(blob, one_mib, i)
    assert len(blob.queue) == 2 and blob.stats["dropped_queue"] == 8   # 3 MiB bound: two 1 MiB messages (+ header)
    assert blob.queued_bytes <= 3 << 20
    assert rt._resubscribe_due                                         # never set on a live socket: replaced
    rt._resubscribe()
    assert rt._socket_of["blob"].getsockopt(zmq.RCVHWM) <= 64          # 64 MiB / 1 MiB on the shared socket
    rt._handle_pending()
    assert blob.queued_bytes == 0 and blob.stats["handled"] == 2
    rt.close()


def _pump(rt: NodeRuntime, done: Callable[[], bool], timeout_s: float = 5.0) -> None:
    """Run the runtime's receive-and-handle step until ``done()`` (or the time is up)."""
    order = itertools.count()
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        rt._receive(20, order)
        rt._handle_pending()


def test_a_message_sent_while_the_receive_queue_is_replaced_is_not_lost(runtime_env: dict) -> None:
    """The last message of a finished publisher, sent while its subscriber swaps its SUB socket (to a
    smaller receive queue), arrives: the old socket is read until the new one is proven (CI: a
    latest-only input never saw a camera's last image; before, the old socket was closed at once)."""
    rt = _runtime()
    pub = zmq.Context.instance().socket(zmq.PUB)
    pub.bind(rt.spec.inputs["value"].endpoint)
    try:
        sent = itertools.count(1)
        def first_seen() -> bool:
            pub.send_multipart([b"a/value", *_frames(Float64(data=0.0, seq=next(sent)))])
            return bool(rt.node.seen)
        _pump(rt, first_seen)                                          # subscribed: messages flow
        assert rt.node.seen
        rt._resubscribe()                                              # e.g. the first large message shrank the queue
        last = next(sent)
        pub.send_multipart([b"a/value", *_frames(Float64(data=1.0, seq=last))])   # the publisher's last
        _pump(rt, lambda: rt.node.seen[-1].seq == last)
        value = rt.inputs["value"]
        assert rt.node.seen[-1].seq == last and value.stats["dropped_seq_gap"] == 0
        assert [m.seq for m in rt.node.seen] == sorted({m.seq for m in rt.node.seen})   # no copy handled twice
        following = [next(sent) for _ in range(3)]                     # both sockets get these: each handled once
        for seq in following:
            pub.send_multipart([b"a/value", *_frames(Float64(data=2.0, seq=seq))])
        _pump(rt, lambda: rt.node.seen[-1].seq == following[-1] and not rt._retiring)
        assert [m.seq for m in rt.node.seen][-4:] == [last, *following]
        assert value.stats["received"] == value.stats["handled"] == len(rt.node.seen)
        assert not rt._retiring                                        # the old socket closed once proven
    finally:
        pub.close(linger=0)
        rt.close()


def test_a_publisher_bounds_its_send_queue_in_bytes(runtime_env: dict) -> None:
    from nodes.std.perf import BlobSource

    rt = NodeRuntime(RunSpec(graph="f", node_id="blob", node="nodes.std.perf:BlobSource",
                             binds=[ipc_endpoint("f", "blob", "z")], params={"count": 1}), BlobSource)
    assert rt.pub.getsockopt(zmq.SNDHWM) == 1000
    rt.node.publish("image", Image(data=np.zeros((1024, 4096), np.uint8)))
    assert rt.pub.getsockopt(zmq.SNDHWM) == 15   # 64 MiB of 4 MiB messages (plus headers)
    rt.close()


def test_input_state_queue_drops_oldest_by_bytes() -> None:
    state = InputState("x", "a/x", Float64, maxlen=100, max_bytes=250)
    for i in range(5):
        state.push(i, Float64(seq=i + 1), 100)
    assert [m.seq for _, m, _ in state.queue] == [4, 5] and state.stats["dropped_queue"] == 3
    state.push(9, Float64(seq=9), 1000)                                  # larger than the bound: kept alone
    assert [m.seq for _, m, _ in state.queue] == [9] and state.queued_bytes == 1000


def test_a_restarted_node_counts_what_it_missed_and_its_outputs_continue(runtime_env: dict,
                                                                         tmp_path: Path) -> None:
    from nodes.std.demo import Scale

    ep = ipc_endpoint("r", "src", "x")

    def start(incarnation: int) -> NodeRuntime:
        spec = RunSpec(graph="r", node_id="scale", node="nodes.std.demo:Scale", binds=[ipc_endpoint("r", "sc", "y")],
                       inputs={"value": Source(topic="c/value", endpoint=ep)}, incarnation=incarnation,
                       state_file=str(tmp_path / "scale.seq"))
        return NodeRuntime(spec, Scale)

    first = start(0)
    for seq in range(1, 6):
        first._accept(first.inputs["value"], _frames(Float64(data=1.0, seq=seq)), seq)
    first._handle_pending()
    assert first._seq["value"] == 5
    first.close()    # the seq numbers live in the mapped file's pages: they would outlast a SIGKILL too
    second = start(1)
    second._accept(second.inputs["value"], _frames(Float64(data=1.0, seq=9)), 0)   # 6, 7, 8 came while it was down
    second._handle_pending()
    value = second.stats().inputs[0]
    assert value.dropped_restart == 3 and value.dropped_seq_gap == 0 and second.stats().restarts == 1
    assert second._seq["value"] == 6                                     # its own numbering went on
    second.close()
    fresh = start(0)                                                     # a new launch starts from nothing
    fresh._accept(fresh.inputs["value"], _frames(Float64(data=1.0, seq=40)), 0)
    assert fresh.stats().inputs[0].dropped_restart == 0 and fresh._seq.get("value", 0) == 0
    fresh.close()


def _wait(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


class _Graph:
    """A raw XPUB in this process feeding one ``tether.runner`` child; reads the child's statistics."""

    def __init__(self, node: str, params: dict, inputs: dict[str, str], *, max_message_bytes: int = 0) -> None:
        self.ctx = zmq.Context()
        self.endpoint = ipc_endpoint("prop", "fuzz", f"{time.monotonic_ns() % 10**6}")
        self.pub = self.ctx.socket(zmq.XPUB)
        self.pub.bind(self.endpoint)
        stats_ep = ipc_endpoint("prop", "sink", f"s{time.monotonic_ns() % 10**6}")
        spec = RunSpec(graph="prop", node_id="sink", node=node, params=params, binds=[stats_ep],
                       inputs={name: Source(topic=t, endpoint=self.endpoint) for name, t in inputs.items()})
        code = ("import sys, tether.transport as t, tether.runner as r; "
                f"t.MAX_MESSAGE_BYTES = {max_message_bytes} or t.MAX_MESSAGE_BYTES; sys.exit(r.main())")
        self.proc = subprocess.Popen([sys.executable, "-c", code, msgspec.json.encode(spec).decode()], cwd=REPO,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.stats_sub = self.ctx.socket(zmq.SUB)
        self.stats_sub.subscribe(b"sink/_stats")
        self.stats_sub.connect(stats_ep)
        want = len(set(inputs.values()))
        subscribed: set[bytes] = set()
        _wait(lambda: self._subscriptions(subscribed) >= want, 20.0, "the node never subscribed")

    def _subscriptions(self, seen: set[bytes]) -> int:
        while self.pub.poll(10):
            event = self.pub.recv()
            if event[:1] == b"\x01":
                seen.add(event[1:])
        assert self.proc.poll() is None, self.proc.stdout.read() if self.proc.stdout else ""
        return len(seen)

    def send(self, topic: str, frames: list[bytes]) -> None:
        self.pub.send_multipart([topic.encode(), *frames])

    def has_stats(self, wait_s: float) -> bool:
        return bool(self.stats_sub.poll(int(wait_s * 1000)))

    def stats(self, wait_s: float = 5.0) -> NodeStats:
        """The newest statistics the node published (waits up to ``wait_s`` for one)."""
        latest = None
        while latest is None or self.stats_sub.poll(0):
            assert self.stats_sub.poll(int(wait_s * 1000)), "the node stopped publishing statistics"
            latest = self.stats_sub.recv_multipart()
        return Codec().decode(NodeStats, latest[1:])

    def close(self) -> str:
        self.proc.terminate()
        out, _ = self.proc.communicate(timeout=20)
        self.pub.close(0)
        self.stats_sub.close(0)
        self.ctx.term()
        return out


def test_an_oversize_frame_is_counted_and_the_input_keeps_receiving(runtime_env: dict) -> None:
    graph = _Graph("nodes.std.chaos:QuietSink", {}, {"value": "fuzz/value"}, max_message_bytes=4096)
    try:
        seq = 0

        def send(frames: list[bytes] | None = None) -> None:
            nonlocal seq
            seq += 1
            graph.send("fuzz/value", frames or _frames(Float64(data=1.0, seq=seq)))

        for _ in range(3):
            send()
        send([bytes(64 << 10)])                           # over the (lowered) receive limit
        deadline = time.monotonic() + 20.0
        handled = 0
        while handled < 20:                               # keep sending: what follows must get through
            assert time.monotonic() < deadline, "the input stayed cut after an oversize frame"
            for _ in range(5):
                send()
            handled = graph.stats(wait_s=0.1).inputs[0].handled if graph.has_stats(0.1) else handled
        value = graph.stats().inputs[0]
        assert value.link_resets >= 1
        assert graph.proc.poll() is None
    finally:
        out = graph.close()
    assert "dropped" in out and "redialled" in out and "Traceback" not in out


def test_a_failing_security_handshake_is_named_and_logged_once_per_period(runtime_env: dict,
                                                                          caplog: pytest.LogCaptureFixture) -> None:
    """A plain subscriber dialling a CurveZMQ publisher: ZeroMQ retries every ~100 ms and each retry
    fails its handshake; the node says why, once per log period, and counts every redial."""
    rt = _runtime()
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.curve_publickey, pub.curve_secretkey = zmq.curve_keypair()
    pub.curve_server = True
    pub.bind(rt.spec.inputs["value"].endpoint)
    try:
        deadline = time.monotonic() + 1.5
        with caplog.at_level("WARNING"):
            while time.monotonic() < deadline:
                _pump(rt, lambda: False, timeout_s=0.1)
                rt._check_links()
        refused = [r.getMessage() for r in caplog.records if "security handshake" in r.getMessage()]
        assert len(refused) == 1 and "a/value" in refused[0], refused
        assert rt.inputs["value"].stats["link_resets"] >= 3       # every redial counted, not every one logged
        assert not rt.node.seen
    finally:
        pub.close(linger=0)
        rt.close()


def _all_message_types() -> dict[str, type[Message]]:
    import msgs

    for info in pkgutil.iter_modules(msgs.__path__):
        importlib.import_module(f"msgs.{info.name}")
    types = {}
    for tag, tp in registered_types().items():
        try:
            types[tag] = tp()                              # only types with all-default fields can be crafted blind
        except TypeError:
            continue
    return types


def test_header_and_length_extremes_of_every_message_type_through_a_live_graph(runtime_env: dict) -> None:
    from hypothesis import HealthCheck, given, settings, strategies as st

    from nodes.std.chaos import input_name

    types = _all_message_types()
    tags = sorted(types)
    graph = _Graph("nodes.std.chaos:TypedSink", {"types": tags}, {input_name(t): f"fuzz/{t}" for t in tags})
    codec = Codec()
    sent = {"total": 0, "intact": 0}
    header = st.integers(min_value=0, max_value=U64_MAX) | st.sampled_from([0, 1, 1 << 63, U64_MAX])
    stamps = st.integers(min_value=-(1 << 63), max_value=I64_MAX) | st.sampled_from([-1, 0, I64_MAX])
    cut = st.sampled_from(["intact", "intact", "empty", "truncate", "pad", "drop buffers"])

    @settings(max_examples=150, derandomize=True, deadline=None, suppress_health_check=list(HealthCheck))
    @given(tag=st.sampled_from(tags), seq=header, stamp=stamps, how=cut, at=st.integers(0, 1 << 16))
    def send(tag: str, seq: int, stamp: int, how: str, at: int) -> None:
        msg = msgspec.structs.replace(types[tag], seq=seq, stamp_ns=stamp)
        frames = [bytes(f) for f in codec.encode(msg)]
        if how == "empty":
            frames = [b""]
        elif how == "truncate":
            frames[0] = frames[0][: at % len(frames[0])]
        elif how == "pad":
            frames[0] += b"\xc1" * (1 + at % 64)          # 0xc1 is never valid msgpack
        elif how == "drop buffers":
            frames = frames[:1]
        graph.send(f"fuzz/{tag}", frames)
        sent["total"] += 1
        sent["intact"] += how == "intact"

    try:
        send()
        _wait(lambda: sum(i.received for i in graph.stats().inputs) >= sent["total"], 20.0,
              "frames were lost without being counted")
        stats = graph.stats()
        received = sum(i.received for i in stats.inputs)
        handled = sum(i.handled for i in stats.inputs)
        errors = sum(i.decode_errors for i in stats.inputs)
        assert received == sent["total"] and handled + errors == received   # each frame received, and handled or counted
        assert handled >= sent["intact"] and stats.stats_errors == 0
        assert graph.proc.poll() is None
    finally:
        out = graph.close()
    assert "Traceback" not in out


class _BadSetup(Node):
    """Its setup fails the way its Config says (``fault``): a file it cannot open, a value it refuses, a bug."""

    class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
        fault: str = "missing_file"

    def setup(self) -> None:
        if self.config.fault == "missing_file":
            open("/nonexistent/weights.ppo", "rb")
        if self.config.fault == "bad_value":
            raise ValueError("no crowd scene 'nowhere': bundled scenes are ['toward'], or pass a YAML path")
        raise KeyError("a bug")


@pytest.mark.parametrize("fault, one_line", [("missing_file", True), ("bad_value", True), ("bug", False)])
def test_a_setup_failure_is_one_line_unless_it_is_a_bug(fault: str, one_line: bool, runtime_env: dict,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    rt = NodeRuntime(RunSpec(graph="g", node_id="bad", node="test:_BadSetup", params={"fault": fault}), _BadSetup)
    with caplog.at_level("ERROR"):
        assert rt.serve() == 1
    failed = [r for r in caplog.records if r.getMessage().startswith("setup failed")]
    assert len(failed) == 1
    assert (failed[0].exc_info is None) == one_line, failed[0].getMessage()
    if one_line:
        assert ("FileNotFoundError" if fault == "missing_file" else "ValueError: no crowd scene") in failed[0].getMessage()
