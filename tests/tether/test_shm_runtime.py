"""Shared memory through the live runtime: nodes unchanged, fan-out, fallbacks to frames, graphs side by side."""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import msgpack
import msgspec
import numpy as np
import pytest
import zmq

from msgs.sensor import Image
from tether import Input, Node, shm
from tether.codec import wire_to_inline
from tether.runtime import NodeRuntime, RunSpec, Source

from conftest import free_port

pytestmark = pytest.mark.skipif(not shm.Settings.from_env().enabled, reason="no /dev/shm or OFD locks here")

MIB = 1 << 20


class CamConfig(msgspec.Struct, frozen=True, kw_only=True):
    count: int = 5
    first: int = 1              # message i is filled with first + i (mod 256)
    loan: bool = False


class Cam(Node):
    """Publishes ``count`` 1 MiB images, each filled with one value, then idles."""

    Config = CamConfig
    outputs = {"image": Image}

    def run(self) -> None:
        for i in range(self.config.count):
            if self.stopping.is_set():
                return
            value = (self.config.first + i) % 256
            if self.config.loan:
                data = self.loan("image", (512, 2048))
                data[:] = value
            else:
                data = np.full((512, 2048), value, np.uint8)
            self.publish("image", Image(data=data))
        self.stopping.wait()


class Keeper(Node):
    """Keeps every image it handles (so a rewritten buffer would show)."""

    inputs = {"image": Input(Image, depth=1000, max_queue_bytes=1 << 31)}

    def setup(self) -> None:
        self.kept: list[Image] = []

    def on_image(self, msg: Image) -> None:
        self.kept.append(msg)


class LatestKeeper(Keeper):
    inputs = {"image": Input(Image, latest=True)}


def _until(done: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


@contextmanager
def _running(*runtimes: NodeRuntime) -> Iterator[None]:
    """Serve each runtime on its own thread, from when every node's setup has run (a test's checks
    read what setup creates: before, a check could run first, 'Taker' object has no attribute 'values')."""
    ready = []
    for rt in runtimes:
        done, setup = threading.Event(), rt.node.setup

        def setup_then_say(setup=setup, done=done) -> None:
            try:
                setup()
            finally:
                done.set()

        rt.node.setup = setup_then_say
        ready.append(done)
    threads = [threading.Thread(target=rt.serve, daemon=True) for rt in runtimes]
    for t in threads:
        t.start()
    for done in ready:
        done.wait(30)
    try:
        yield
    finally:
        for rt in runtimes:
            rt.stop()
        for t in threads:
            t.join(30)


def _cam(endpoint: str, subscribers: int, *, graph: str = "g", **params) -> NodeRuntime:
    spec = RunSpec(graph=graph, node_id="cam", node="test:Cam", binds=[endpoint], params=params,
                   expect_subscribers={"cam/image": subscribers}, wait_subscribers_s=30)
    return NodeRuntime(spec, Cam)


def _keeper(endpoint: str, node_id: str = "keep", cls: type[Keeper] = Keeper, graph: str = "g") -> NodeRuntime:
    spec = RunSpec(graph=graph, node_id=node_id, node="test:Keeper",
                   inputs={"image": Source(topic="cam/image", endpoint=endpoint)})
    return NodeRuntime(spec, cls)


def _values(rt: NodeRuntime) -> list[int]:
    """Each kept image's value, checked to be uniform (a rewritten or torn buffer would not be)."""
    out = []
    for msg in rt.node.kept:
        data = msg.data
        assert data.shape == (512, 2048) and data.min() == data.max(), "an array changed under its holder"
        out.append(int(data[0, 0]))
    return out


def test_same_host_subscribers_share_one_copy_and_nodes_see_the_same_arrays(tmp_path: Path) -> None:
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 4, count=6)
    keepers = [_keeper(endpoint, f"keep{i}") for i in range(4)]
    with _running(*keepers, cam):
        _until(lambda: all(len(k.node.kept) == 6 for k in keepers), "all six images at every keeper")
        for keeper in keepers:
            assert _values(keeper) == [1, 2, 3, 4, 5, 6]
            assert not keeper.node.kept[0].data.flags.writeable
            assert [m.seq for m in keeper.node.kept] == [1, 2, 3, 4, 5, 6]
        counters = cam.shm_counters()
        assert counters["placed"] == 6 and counters["fallbacks"] == 0    # one copy per message, not per subscriber


def test_plain_zeromq_clients_and_recorders_get_ordinary_frames(tmp_path: Path) -> None:
    """A client that knows nothing of shared memory subscribes to the topic and gets [topic, body, buffer]."""
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 1, count=3)
    keeper = _keeper(endpoint)
    ctx = zmq.Context.instance()
    plain = ctx.socket(zmq.SUB)
    plain.connect(endpoint)
    plain.setsockopt(zmq.SUBSCRIBE, b"")                   # everything: it must still be able to tell
    plain.rcvtimeo = 30_000
    try:
        with _running(keeper, cam):
            got = []
            while len(got) < 3:
                frames = plain.recv_multipart()
                if frames[0].startswith(shm.TOPIC_PREFIX):
                    continue                                # slot tables for shared-memory subscribers only
                if frames[0] == b"cam/image":
                    got.append(frames)
            _until(lambda: len(keeper.node.kept) == 3, "the keeper's images")
        for i, frames in enumerate(got):
            body = msgpack.unpackb(frames[1])
            assert body["data"]["frame"] == 0 and "shm" not in body["data"] and len(frames[2]) == MIB
            assert frames[2][0] == i + 1
            record = msgpack.unpackb(wire_to_inline(frames[1:]))    # what a recorder writes: the bytes inline
            assert len(record["data"]["data"]) == MIB
        assert _values(keeper) == [1, 2, 3] and cam.shm_counters()["placed"] == 3, cam.shm_counters()
    finally:
        plain.close(linger=0)


def test_a_subscriber_on_another_machine_gets_frames(tmp_path: Path) -> None:
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    cam = _cam(endpoint, 1, count=3)
    keeper = _keeper(endpoint)
    with _running(keeper, cam):
        _until(lambda: len(keeper.node.kept) == 3, "three images over tcp")
    assert _values(keeper) == [1, 2, 3] and cam.shm_counters()["placed"] == 0


def test_a_curve_publisher_serves_its_same_host_subscribers_through_shared_memory(tmp_path: Path) -> None:
    """A node that also publishes to another machine is a CurveZMQ server on its ipc endpoint too:
    a same-host subscriber asks for slot tables over the secured socket, not a plain one whose
    handshake fails at every redial (a dslam monitor logged ~300 such redials in 9 s)."""
    from tether.transport import CurveKeys

    keys = CurveKeys.generate(("here",))
    ipc, tcp = f"ipc://{tmp_path}/cam", f"tcp://127.0.0.1:{free_port()}"
    cam = NodeRuntime(RunSpec(graph="g", node_id="cam", node="test:Cam", binds=[ipc, tcp], params={"count": 3},
                              expect_subscribers={"cam/image": 1}, wait_subscribers_s=30, curve=keys.to_json()), Cam)
    keeper = NodeRuntime(RunSpec(graph="g", node_id="keep", node="test:Keeper", curve=keys.to_json(),
                                 inputs={"image": Source(topic="cam/image", endpoint=ipc, secure=True,
                                                         server_key=keys.public.decode())}), Keeper)
    with _running(keeper, cam):
        _until(lambda: len(keeper.node.kept) == 3, "three images from a Curve publisher over ipc")
        time.sleep(0.6)                             # a few link checks: a failing handshake would have shown
    assert _values(keeper) == [1, 2, 3]
    assert cam.shm_counters()["placed"] == 3, "the images went as frames: the slot-table subscription never arrived"
    assert keeper.stats().inputs[0].link_resets == 0


def test_two_graphs_with_the_same_topic_names_stay_apart(tmp_path: Path) -> None:
    a, b = f"ipc://{tmp_path}/a", f"ipc://{tmp_path}/b"
    cams = [_cam(a, 1, graph="one", count=3, first=10), _cam(b, 1, graph="two", count=3, first=100)]
    keepers = [_keeper(a, graph="one"), _keeper(b, graph="two")]
    with _running(*keepers, *cams):
        _until(lambda: all(len(k.node.kept) == 3 for k in keepers), "both graphs' images")
    assert _values(keepers[0]) == [10, 11, 12] and _values(keepers[1]) == [100, 101, 102]
    assert cams[0]._pools["image"].stem != cams[1]._pools["image"].stem


def test_slow_and_latest_only_subscribers_never_see_a_buffer_rewritten(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A 4-slot pool, 60 messages, subscribers that keep everything: slots stay pinned, frames take over."""
    monkeypatch.setenv("TETHER_SHM_POOL_BYTES", str(4 * MIB))
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 2, count=60)
    keeper, latest = _keeper(endpoint), _keeper(endpoint, "latest", LatestKeeper)
    with _running(keeper, latest, cam):
        _until(lambda: len(keeper.node.kept) == 60, f"all sixty images at the deep keeper {len(keeper.node.kept)} {keeper.inputs['image'].stats} {cam.shm_counters()} {latest.inputs['image'].stats}", 20)
        _until(lambda: latest.node.kept and latest.node.kept[-1].seq == 60, "the last image at the latest keeper")
    assert _values(keeper) == [(1 + i) % 256 for i in range(60)]
    values = _values(latest)
    assert values == sorted(values) and values[-1] == 60
    counters = cam.shm_counters()
    assert counters["placed"] <= 4 and counters["fallbacks"] >= 56      # the pool pinned: frames, never corruption


def test_a_subscriber_that_cannot_map_the_segment_falls_back_to_frames(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(name: str) -> shm.Segment:
        raise shm.ShmUnavailable(f"shared-memory segment {name} refused (test)")

    monkeypatch.setattr(shm.Segment, "open", staticmethod(refuse))
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 1, count=200)
    keeper = _keeper(endpoint)
    with _running(keeper, cam):
        _until(lambda: len(keeper.node.kept) >= 5, "images as ordinary frames")
    state = keeper.inputs["image"]
    assert state.stats["decode_errors"] >= 1 and "cam/image" in keeper._shm_refused
    assert len(set(_values(keeper))) == len(keeper.node.kept)


def test_a_loaned_array_crosses_without_a_copy(tmp_path: Path) -> None:
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 1, count=4, loan=True)
    keeper = _keeper(endpoint)
    with _running(keeper, cam):
        _until(lambda: len(keeper.node.kept) == 4, "four loaned images")
    assert _values(keeper) == [1, 2, 3, 4]
    assert cam.shm_counters()["placed"] == 4
    # ZeroMQ carried slot tables only: its receive queue is not sized (nor the socket replaced) for 1 MiB
    assert keeper._largest_in["image"] < 4096 and keeper.inputs["image"].stats["received_bytes"] > 4 * MIB


def test_node_statistics_and_node_info_carry_the_shared_memory_counters(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                         capsys: pytest.CaptureFixture) -> None:
    import argparse

    from tether import introspect
    from tether.stats import NodeStats

    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 1, count=3, loan=True)
    keeper = _keeper(endpoint)
    sock = zmq.Context.instance().socket(zmq.SUB)
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (None, sock))
    try:
        with _running(keeper, cam):
            _until(lambda: len(keeper.node.kept) == 3, "three loaned images")
            sock.connect(endpoint)                  # now: the statistics it gets are sent after the images
            sock.setsockopt(zmq.SUBSCRIBE, b"cam/_stats")
            # the next statistics, over the wire; a loaded CI machine gets longer than a user's 3 s default
            introspect.cmd_node(argparse.Namespace(action="info", id="cam", wait=20.0))
            stats = cam.stats()
    finally:
        sock.close(linger=0)
    assert (stats.shm_placed, stats.shm_loaned, stats.shm_fallbacks, stats.shm_oversize) == (3, 3, 0, 0)
    assert keeper.stats().shm_stale == 0 and keeper.stats().shm_placed == 0
    assert "shared memory: placed 3 (loaned, no copy: 3)  fallbacks to frames 0 (pool busy) + 0 (oversize)" \
        in capsys.readouterr().out
    # statistics from a node built before these fields decode with zeros (appended fields only)
    older = msgspec.msgpack.encode({"type": "std.NodeStats", "node_id": "old", "published": {"old/x": 2}})
    decoded = msgspec.msgpack.decode(older, type=NodeStats)
    assert decoded.node_id == "old" and decoded.shm_placed == 0 and decoded.shm_stale == 0


class Taker(Node):
    """Notes each image's value and lets the image go (its slot is free again at once)."""

    inputs = {"image": Input(Image, depth=1000, max_queue_bytes=1 << 31)}

    def setup(self) -> None:
        self.values: list[int] = []

    def on_image(self, msg: Image) -> None:
        assert msg.data.min() == msg.data.max()
        self.values.append(int(msg.data[0, 0]))


def test_a_plain_subscriber_of_loaned_images_never_sees_a_reused_slot(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Loaned slots are reused as soon as the shared-memory reader lets go; a plain subscriber that has
    not read yet (its frames still queued in ZeroMQ) must still get each image as it was published."""
    monkeypatch.setenv("TETHER_SHM_POOL_BYTES", str(2 * MIB))        # two slots: reused every other image
    monkeypatch.setenv("TETHER_SHM_WAIT_MS", "10000")                 # each loan waits for the taker to let go
    endpoint = f"ipc://{tmp_path}/cam"
    cam = _cam(endpoint, 2, count=8, loan=True)
    taker = NodeRuntime(RunSpec(graph="g", node_id="take", node="test:Taker",
                                inputs={"image": Source(topic="cam/image", endpoint=endpoint)}), Taker)
    plain = zmq.Context.instance().socket(zmq.SUB)
    plain.rcvhwm = 100
    plain.connect(endpoint)
    plain.setsockopt(zmq.SUBSCRIBE, b"cam/image")
    plain.rcvtimeo = 30_000
    try:
        with _running(taker, cam):
            _until(lambda: len(taker.node.values) == 8, "eight images through shared memory")
            got = [plain.recv_multipart() for _ in range(8)]            # read only now
        assert taker.node.values == list(range(1, 9)) and cam.shm_counters()["loaned"] >= 4
        assert [(f[2][0], f[2][-1], len(f[2])) for f in got] == [(v, v, MIB) for v in range(1, 9)]
    finally:
        plain.close(linger=0)


def test_node_info_on_a_silent_node_is_one_clear_line_after_its_wait(monkeypatch: pytest.MonkeyPatch) -> None:
    import argparse

    from tether import introspect
    from tether.errors import ConfigError, TetherError

    sock = zmq.Context.instance().socket(zmq.SUB)        # subscribed to nothing that publishes
    monkeypatch.setattr(introspect, "subscribe", lambda topic: (None, sock))
    try:
        with pytest.raises(TetherError, match=r"no statistics within 0.3 s .*longer --wait"):
            introspect.cmd_node(argparse.Namespace(action="info", id="ghost", wait=0.3))
        with pytest.raises(ConfigError, match="--wait must be > 0"):
            introspect.cmd_node(argparse.Namespace(action="info", id="ghost", wait=float("nan")))
    finally:
        sock.close(linger=0)
