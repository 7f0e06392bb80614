"""Queue policies and drop accounting on the live runtime's receive path (no sockets needed)."""
from __future__ import annotations

from msgs.std import Float64
from tether import Input, Node
from tether.codec import Codec
from tether.runtime import NodeRuntime, RunSpec, Source
from tether.transport import ipc_endpoint


class Recorder(Node):
    inputs = {"deep": Input(Float64, depth=3), "latest": Input(Float64, latest=True)}

    def setup(self) -> None:
        self.seen: list[tuple[str, float]] = []

    def on_deep(self, msg: Float64) -> None:
        self.seen.append(("deep", msg.data))

    def on_latest(self, msg: Float64) -> None:
        self.seen.append(("latest", msg.data))


def _runtime(runtime_env: dict) -> NodeRuntime:
    ep = ipc_endpoint("q", "src", "x")
    spec = RunSpec(graph="q", node_id="rec", node="tests:Recorder",
                   inputs={"deep": Source(topic="a/x", endpoint=ep), "latest": Source(topic="b/y", endpoint=ep)})
    rt = NodeRuntime(spec, Recorder)
    rt.node.setup()          # serve() would call it; these tests drive the receive path directly
    return rt


def _frames(value: float, seq: int) -> list[bytes]:
    return [bytes(f) for f in Codec().encode(Float64(data=value, seq=seq))]


def test_depth_keeps_the_newest_n_and_latest_keeps_one(runtime_env: dict) -> None:
    rt = _runtime(runtime_env)
    deep, latest = rt.inputs["deep"], rt.inputs["latest"]
    order = iter(range(100))
    for i in range(1, 6):                       # a burst arrives before the node gets to run
        rt._accept(deep, _frames(float(i), i), next(order))
        rt._accept(latest, _frames(10.0 + i, i), next(order))
    rt._handle_pending()
    assert rt.node.seen == [("deep", 3.0), ("deep", 4.0), ("deep", 5.0), ("latest", 15.0)]
    assert deep.stats["dropped_queue"] == 2 and latest.stats["dropped_queue"] == 4
    assert deep.stats["dropped_seq_gap"] == 0 and deep.stats["handled"] == 3
    rt.close()


def test_sequence_gaps_count_transport_drops_and_a_restarted_publisher_is_not_a_drop(runtime_env: dict) -> None:
    rt = _runtime(runtime_env)
    deep = rt.inputs["deep"]
    for i, seq in enumerate([1, 2, 5, 6, 10]):   # 3, 4 and 7, 8, 9 were lost on the way
        rt._accept(deep, _frames(0.0, seq), i)
        rt._handle_pending()
    assert deep.stats["dropped_seq_gap"] == 5
    rt._accept(deep, _frames(0.0, 1), 99)        # the publisher restarted: seq starts over
    rt._accept(deep, _frames(0.0, 2), 100)
    assert deep.stats["dropped_seq_gap"] == 5 and deep.stats["received"] == 7
    stats = rt.stats().inputs
    assert {s.name: s.dropped_seq_gap for s in stats}["deep"] == 5
    rt.close()


def test_handling_order_follows_arrival_across_inputs(runtime_env: dict) -> None:
    rt = _runtime(runtime_env)
    rt._accept(rt.inputs["latest"], _frames(1.0, 1), 0)
    rt._accept(rt.inputs["deep"], _frames(2.0, 1), 1)
    rt._accept(rt.inputs["deep"], _frames(3.0, 2), 2)
    rt._handle_pending()
    assert rt.node.seen == [("latest", 1.0), ("deep", 2.0), ("deep", 3.0)]
    rt.close()
