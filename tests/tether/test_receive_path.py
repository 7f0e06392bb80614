"""The live receive path over a real socket (``NodeRuntime._take``, its inline common case and the
general route), and the codec's per-call state: what a fast path must not change.

Per input: received, handled, received_bytes, decode errors (logged once per throttle period),
seq gaps; a body-only message, one with array buffers, a topic-only frame, a longer topic sharing
the prefix, and two inputs on one socket.
"""
from __future__ import annotations

import logging
import time

import numpy as np
import pytest
import zmq

from msgs.sensor import Image
from msgs.std import Float64
from tether import Input, Node
from tether.codec import Codec
from tether.errors import DecodeError
from tether.inputs import U64_MAX, InputState
from tether.runtime import NodeRuntime, RunSpec, Source
from tether.transport import ipc_endpoint


class Taker(Node):
    inputs = {"value": Input(Float64, depth=64), "latest": Input(Float64, latest=True), "image": Image}

    def setup(self) -> None:
        self.seen: list[tuple[str, object]] = []

    def on_value(self, msg: Float64) -> None:
        self.seen.append(("value", msg.data))

    def on_latest(self, msg: Float64) -> None:
        self.seen.append(("latest", msg.data))

    def on_image(self, msg: Image) -> None:
        self.seen.append(("image", msg.data.copy()))


@pytest.fixture
def wired(runtime_env: dict):
    """A runtime subscribed to three topics of one raw publisher (an XPUB, to see it subscribe)."""
    ep = ipc_endpoint("rp", "src", "x")
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.XPUB)
    pub.bind(ep)
    spec = RunSpec(graph="rp", node_id="taker", node="tests:Taker",
                   inputs={"value": Source(topic="src/value", endpoint=ep),
                           "latest": Source(topic="src/latest", endpoint=ep),
                           "image": Source(topic="src/image", endpoint=ep)})
    rt = NodeRuntime(spec, Taker)
    rt.node.setup()
    want = {b"\x01src/value", b"\x01src/latest", b"\x01src/image"}
    deadline = time.monotonic() + 10
    while want:
        assert time.monotonic() < deadline, f"never subscribed: {want}"
        if pub.poll(100):
            want.discard(pub.recv())
    try:
        yield rt, pub
    finally:
        rt.close()
        pub.close(linger=0)


def _pump(rt: NodeRuntime, until, timeout_s: float = 10.0) -> None:
    """Run the receive-and-handle steps of serve() until ``until()`` holds."""
    import itertools

    order = itertools.count()
    deadline = time.monotonic() + timeout_s
    while not until():
        assert time.monotonic() < deadline, "messages never arrived"
        rt._receive(20, order)
        rt._handle_pending()


def _body(msg) -> bytes:
    frames = Codec().encode(msg)
    assert len(frames) == 1
    return frames[0]


def test_body_only_messages_are_counted_per_input_and_gaps_still_count(wired) -> None:
    rt, pub = wired
    bodies = [_body(Float64(data=float(i), seq=seq)) for i, seq in enumerate([1, 2, 3, 6, 7])]
    for b in bodies:
        pub.send_multipart([b"src/value", b])
    pub.send_multipart([b"src/valueX", bodies[0]])          # a longer topic sharing the prefix: not ours
    pub.send_multipart([b"src/latest", _body(Float64(data=9.0, seq=1))])
    value, latest = rt.inputs["value"], rt.inputs["latest"]
    _pump(rt, lambda: value.stats["handled"] == 5 and latest.stats["handled"] == 1)
    assert [v for k, v in rt.node.seen if k == "value"] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert value.stats["received"] == 5 and value.stats["received_bytes"] == sum(map(len, bodies))
    assert value.stats["dropped_seq_gap"] == 2 and value.stats["seq_resets"] == 0
    assert value.last_seq == 7
    assert latest.stats["received"] == 1 and ("latest", 9.0) in rt.node.seen
    assert value.handler_ns > 0 and value.handler_max_ns > 0
    stats = {s.name: s for s in rt.stats().inputs}
    assert stats["value"].handled == 5 and stats["latest"].handled == 1 and stats["image"].received == 0


def test_malformed_frames_are_counted_and_logged_once(wired, caplog: pytest.LogCaptureFixture) -> None:
    rt, pub = wired
    caplog.set_level(logging.ERROR)
    pub.send_multipart([b"src/value", b"\xc1not msgpack"])        # a bad body
    pub.send(b"src/value")                                        # a topic and nothing else
    pub.send_multipart([b"src/value", _body(Float64(data=1.0, seq=1))])
    value = rt.inputs["value"]
    _pump(rt, lambda: value.stats["handled"] == 1)
    assert value.stats["received"] == 3 and value.stats["decode_errors"] == 2
    assert rt.node.seen == [("value", 1.0)]
    lines = [r for r in caplog.records if "undecodable" in r.getMessage()]
    assert len(lines) == 1 and "src/value" in lines[0].getMessage()


def test_array_buffers_take_the_general_path(wired) -> None:
    rt, pub = wired
    arr = np.arange(24, dtype=np.uint16).reshape(4, 6)
    frames = Codec().encode(Image(data=arr, encoding="mono16", seq=1))
    assert len(frames) == 2
    pub.send_multipart([b"src/image", *frames])
    image = rt.inputs["image"]
    _pump(rt, lambda: image.stats["handled"] == 1)
    (kind, got), = rt.node.seen
    np.testing.assert_array_equal(got, arr)
    assert image.stats["received_bytes"] == len(frames[0]) + arr.nbytes


def test_a_latest_only_input_sees_the_newest_of_a_burst(wired) -> None:
    rt, pub = wired
    for i in range(5):
        pub.send_multipart([b"src/latest", _body(Float64(data=float(i), seq=i + 1))])
    latest = rt.inputs["latest"]
    time.sleep(0.3)                                   # the whole burst waits in the socket
    _pump(rt, lambda: latest.stats["received"] == 5)
    assert rt.node.seen == [("latest", 4.0)] and latest.stats["dropped_queue"] == 4


def test_codec_state_does_not_leak_between_calls() -> None:
    codec = Codec()
    with pytest.raises(TypeError):
        codec.encode(Image(data=np.array(["a"], dtype=object)))
    assert codec.encode(Float64(data=1.0)) == [_body(Float64(data=1.0))]   # no buffer left from the failure
    frames = codec.encode(Image(data=np.ones(3, np.uint8)))
    assert len(frames) == 2 and len(codec.encode(Float64(data=2.0))) == 1
    codec.decode(Image, [bytes(frames[0]), bytes(frames[1])])
    with pytest.raises(DecodeError, match="frame 0"):
        codec.decode(Image, [bytes(frames[0])])          # the previous message's buffer is not reused


def test_track_seq_next_in_line_and_the_u64_edge() -> None:
    st = InputState("v", "a/v", Float64, 4)
    for seq in (1, 2, 3):
        st.track_seq(seq)
    assert st.last_seq == 3 and st.stats["dropped_seq_gap"] == 0 and st.stats["seq_resets"] == 0
    st.last_seq = U64_MAX
    st.track_seq(U64_MAX + 1)                              # past the encodable range: a reset
    assert st.stats["seq_resets"] == 1 and st.last_seq == 0
    st.restart_seq = 10
    st.track_seq(1)                                        # the first after a restart is not "next in line"
    assert st.stats["seq_resets"] == 2 and st.last_seq == 1
