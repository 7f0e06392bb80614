"""The launch file's link model: loss, bandwidth cap and outages, parsed strictly and applied where
messages are received (counted as dropped_link, with bytes counted per input and per output)."""
from __future__ import annotations

import textwrap
import time
from pathlib import Path

import pytest

from msgs.std import Float64, NodeStats
from tether.codec import Codec
from tether.errors import ConfigError
from tether.launch import load_launch, plan
from tether.link import LinkModel
from tether.runtime import NodeRuntime, RunSpec, Source
from tether.transport import ipc_endpoint

from test_runtime_faults import Take  # noqa: E402  (the recording sink node of the runtime tests)


def test_outage_drop_and_bandwidth():
    outage = LinkModel(outages_s=[(1.0, 2.0)], epoch_ns=0)
    assert outage.admit(10, int(0.5e9)) == "" and outage.admit(10, int(1.5e9)) == "outage" and outage.admit(10, int(2e9)) == ""
    lossy = LinkModel(drop=0.25, seed=3)
    lost = sum(lossy.admit(10, k) == "drop" for k in range(4000))
    assert 850 < lost < 1150                                   # a quarter, seeded
    again = LinkModel(drop=0.25, seed=3)
    assert sum(again.admit(10, k) == "drop" for k in range(4000)) == lost   # the same seed, the same losses
    capped = LinkModel(bandwidth_bps=8000.0)                   # 1000 bytes per second, bucket of one second
    t = 0
    got = 0
    for _ in range(100):                                       # 10 s of 100-byte messages every 10 ms
        for _ in range(10):
            t += 10_000_000
            got += capped.admit(100, t) == ""
    assert 9_000 <= got * 100 <= 10_000 + 1_000 + 100             # 1000 B/s for 10 s, plus the first full bucket
    assert LinkModel.from_json(capped.to_json()).bandwidth_bps == 8000.0


def _launch(tmp_path: Path, links: str) -> Path:
    path = tmp_path / "l.yaml"
    path.write_text(textwrap.dedent("""
        name: linked
        nodes:
          - {id: counter, node: nodes.std.demo:Counter, params: {rate_hz: 20}}
          - {id: scale, node: nodes.std.demo:Scale, inputs: {value: counter/value}}
          - {id: other, node: nodes.std.demo:Scale, inputs: {value: counter/value}}
        links:
    """) + textwrap.indent(textwrap.dedent(links).strip() + "\n", "  "))
    return path


def test_links_are_planned_onto_the_right_inputs(tmp_path, runtime_env):
    launch = load_launch(_launch(tmp_path, "- {between: [counter, scale], drop: 0.5, outages_s: [[1, 2]], seed: 4}"))
    specs = plan(launch, token="t", epoch_ns=123)
    link = specs["scale"].inputs["value"].link
    assert link["drop"] == 0.5 and link["outages_s"] == [[1.0, 2.0]] and link["epoch_ns"] == 123
    assert specs["other"].inputs["value"].link is None       # not on that link


@pytest.mark.parametrize("bad,says", [
    ("- {between: [counter], drop: 0.1}", "two different"),
    ("- {between: [counter, nowhere]}", "neither a node id nor a machine"),
    ("- {between: [counter, scale], drop: 1.5}", "drop must be a number in [0, 1]"),
    ("- {between: [counter, scale], outages_s: [[5, 2]]}", "outages_s"),
    ("- {between: [counter, scale], latency: 3}", "unknown link key 'latency'"),
])
def test_bad_links_are_refused_naming_the_key(tmp_path, bad, says):
    with pytest.raises(ConfigError, match=None) as err:
        load_launch(_launch(tmp_path, bad))
    assert says in str(err.value)


def test_the_runtime_drops_and_counts_on_the_link_and_counts_bytes(runtime_env):
    ep = ipc_endpoint("lk", "src", "x")
    spec = RunSpec(graph="lk", node_id="take", node="tests:Take", binds=[ipc_endpoint("lk", "take", "x")],
                   inputs={"value": Source(topic="a/value", endpoint=ep,
                                           link=LinkModel(outages_s=[(0.0, 60.0)], epoch_ns=time.time_ns()).to_json())})
    rt = NodeRuntime(spec, Take)
    rt.node.setup()
    frames = [bytes(f) for f in Codec().encode(Float64(data=1.0, seq=1))]
    rt._route(b"a/value", frames, sum(map(len, frames)), iter(range(100)))
    state = rt.inputs["value"]
    assert state.stats["dropped_link"] == 1 and state.stats["received"] == 0
    state.link = None                                          # the link comes back
    rt._route(b"a/value", frames, sum(map(len, frames)), iter(range(100)))
    assert state.stats["received"] == 1 and state.stats["received_bytes"] == sum(map(len, frames))
    stats = Codec().decode(NodeStats, Codec().encode(rt.stats()))
    assert stats.inputs[0].dropped_link == 1 and stats.inputs[0].received_bytes == sum(map(len, frames))
    rt.close()
