"""The live node runtime: one XPUB, SUB sockets, timers, queues and the handler loop.

Receive, decode, handle and publish all happen on one thread, so a message crosses a
node with no thread hand-off. Source nodes' :meth:`Node.run` loops get a thread of their
own; publishing is serialised by a lock.
"""
from __future__ import annotations

import collections
import itertools
import logging
import os
import stat
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import zmq

from tether import shm
from tether.codec import Codec
from tether.errors import ConfigError, DecodeError, TetherError
from tether.inputs import InputState, SeqStore, saturate
from tether.link import LinkModel
from tether.message import Message
from tether.node import Context, Node, Tick, iter_outputs
from tether.stats import NodeStats
from tether.transport import (HWM_MAX, PUB_QUEUE_BYTES, CurveKeys, LinkWatch, Subscriptions, hwm_for, make_pub,
                              start_authenticator)

log = logging.getLogger("tether.runtime")

STATS_PERIOD_NS = 1_000_000_000
LINK_CHECK_NS = 100_000_000
ERROR_LOG_PERIOD_NS = 5_000_000_000
SUBSCRIPTIONS_PERIOD_NS = 20_000_000      # how stale a publisher's view of who subscribes (plain or @shm/) may be
READ_AHEAD = 16
RETIRE_NS = 2_000_000_000                   # longest a replaced SUB socket keeps receiving beside its successor
FINISH_IDLE_NS = 200_000_000       # a stopping node whose publishers are connected but silent this long is done
FINISH_MAX_NS = 2_000_000_000      # longest a stopping node handles what still reaches its inputs
#: a launched node's last output line: its :meth:`NodeRuntime.stop_report` (JSON), taken by the launcher
STOP_REPORT_TEXT = "tether-stop-report "
# Plain ints: pyzmq's flag enums cost an enum construction per operation on the hot path.
_SNDMORE, _NOBLOCK, _RCVMORE, _EVENTS, _POLLIN = (int(zmq.SNDMORE), int(zmq.NOBLOCK), int(zmq.RCVMORE),
                                                   int(zmq.EVENTS), int(zmq.POLLIN))


@dataclass
class Source:
    """Where an input comes from: a topic at an endpoint, or a timer."""

    topic: str = ""
    endpoint: str = ""
    timer_ns: int = 0
    secure: bool = False      # the publisher is a CurveZMQ server (it has a tcp endpoint)
    server_key: str = ""      # its machine's public key (z85), when secure
    link: dict[str, Any] | None = None   # a LinkModel (to_json) the messages cross, from the launch file
    #: a stopping node waits for this publisher to close (or fall silent) first. The launcher says
    #: True for a publisher it stops before this node (an earlier stage), False for another machine's
    #: or one of the same stage; a node run alone (``tether run``, ``replay --into``) stops no
    #: publisher first, so it handles what its sockets hold and stops (a live stream never closes:
    #: waiting for it held Ctrl-C of ``tether run`` on a 200 Hz topic 2 s, with a warning)
    await_on_stop: bool = False


@dataclass
class RunSpec:
    """Everything a node process needs to run one node in a graph (the launcher writes it)."""

    graph: str
    node_id: str
    node: str
    params: dict[str, Any] = field(default_factory=dict)
    binds: list[str] = field(default_factory=list)
    inputs: dict[str, Source] = field(default_factory=dict)
    expect_subscribers: dict[str, int] = field(default_factory=dict)
    wait_subscribers_s: float = 5.0
    curve: dict[str, Any] | None = None     # this machine's CurveKeys (to_json); never on a command line
    parent_pid: int = 0       # the launcher: the node stops when it goes away (0: not watched)
    incarnation: int = 0          # how many times the launcher restarted this node before this run
    state_file: str = ""          # where the node keeps its seq numbers across restarts ("": nowhere)
    rt_priority: int = 0          # SCHED_FIFO priority asked for the node's process (0: normal scheduling)


def fifo_priority() -> int:
    """The SCHED_FIFO priority this thread runs at (0: another policy, or no POSIX scheduling here)."""
    if not hasattr(os, "sched_getscheduler"):
        return 0
    return os.sched_getparam(0).sched_priority if os.sched_getscheduler(0) == os.SCHED_FIFO else 0


class LogThrottle:
    """At most one log line per key (an input, an endpoint, ...) per ``period_ns``; counts the lines held back."""

    def __init__(self, period_ns: int = ERROR_LOG_PERIOD_NS) -> None:
        self.period_ns = period_ns
        self._last: dict[str, tuple[int, int]] = {}     # key -> (last logged ns, lines held back since)

    def admit(self, key: str, now_ns: int) -> int | None:
        """None: hold this line back (counted); else log it, and this many were held back since the last."""
        logged_ns, held = self._last.get(key, (now_ns - self.period_ns, 0))
        if now_ns - logged_ns < self.period_ns:
            self._last[key] = (logged_ns, held + 1)
            return None
        self._last[key] = (now_ns, 0)
        return held


class NodeRuntime(Context):
    """Runs one node on real sockets until stopped; :meth:`serve` returns the exit code."""

    def __init__(self, spec: RunSpec, node_cls: type[Node], ctx: zmq.Context | None = None) -> None:
        self.spec = spec
        self.ctx = ctx or zmq.Context.instance()
        self.stop_event = threading.Event()
        self.curve = CurveKeys.from_json(spec.curve) if spec.curve else None
        self._socket_of: dict[str, zmq.Socket] = {}
        secure_pub = self.curve is not None and any(b.startswith("tcp://") for b in spec.binds)
        self._auth = start_authenticator(self.ctx, self.curve) if secure_pub else None
        self._codec = Codec()
        self._pub_lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._published: dict[str, int] = collections.Counter()
        self._published_bytes: dict[str, int] = collections.Counter()
        self._subscribers: dict[str, int] = collections.Counter()
        self._started_ns = time.monotonic_ns()
        self._stats_errors = 0
        self._stats_seq = 0
        self._log_throttle = LogThrottle()      # input errors, statistics, dropped links
        self._largest_sent = 0
        self._sndhwm = HWM_MAX
        self._shm = shm.Settings.from_env()
        self._pools: dict[str, shm.Pool] = {}
        self._reader = shm.Reader() if self._shm.enabled else None
        self._shm_refused: set[str] = set()       # topics whose segments we cannot map: ordinary frames
        self._shm_seen: set[bytes] = set()        # @shm/ topics a message arrived on (a Tether publisher)
        self._shm_dupes: set[bytes] = set()       # their plain topics: what arrives there is a copy for others
        self._shm_resolved: set[bytes] = set()    # @shm/ topics whose slot tables resolved at least once
        self._sub_topics: dict[bytes, int] = collections.Counter()   # subscriptions (as asked for) -> subscribers
        self._sub_routes: dict[bytes, tuple[bool, bool]] = {}
        self._subs_read_ns = 0
        config = node_cls.make_config(spec.params)
        self.node = node_cls(config, node_id=spec.node_id, context=self)
        self._topics = {name: f"{spec.node_id}/{name}".encode() for name in self.node.ports.outputs}
        self._stats_topic = f"{spec.node_id}/_stats".encode()
        self._shm_topics = {t: shm.shm_topic(t) for t in [*self._topics.values(), self._stats_topic]}
        try:
            self.pub = make_pub(self.ctx, spec.binds, self.curve if secure_pub else None) if spec.binds else None
        except ConfigError:
            if self._auth is not None:
                self._auth.stop()           # its thread would keep the process from exiting
            raise
        self._build_inputs()
        self._open_seq_store()

    # -- wiring -----------------------------------------------------------------------
    def _build_inputs(self) -> None:
        ports = self.node.ports
        self.inputs: dict[str, InputState] = {}
        self.routes: dict[bytes, list[InputState]] = {}
        self.timers: dict[str, int] = dict(ports.timers)
        for name, port in ports.inputs.items():
            src = self.spec.inputs.get(name)
            if src is not None and src.timer_ns:
                self.timers[name] = src.timer_ns
            if name in self.timers:
                self.inputs[name] = InputState(name, f"timer/{name}", Tick, 1)
                continue
            if src is None or not src.topic:
                continue  # unconnected input: it simply never fires
            state = InputState(name, src.topic, port.type, port.maxlen, port.max_queue_bytes)
            if src.link:
                state.link = LinkModel.from_json(src.link)
            self.inputs[name] = state
            states = self.routes.setdefault(src.topic.encode(), [])
            states.append(state)
            self.routes[shm.shm_topic(src.topic.encode())] = states
        self.subs: list[zmq.Socket] = []
        self._links: LinkWatch | None = None
        self._resubscribe_due = False
        self._largest_in: dict[str, int] = {}
        self._retiring: list[zmq.Socket] = []     # replaced SUB sockets, still read until their successors overlap
        self._retire_by_ns = 0
        self._overlapped: set[str] = set()         # inputs whose new socket delivered a message the old one did
        # the queues the read-ahead bound counts (latest-only inputs keep one message: not counted)
        self._deep_queues = [st.queue for st in self.inputs.values() if st.maxlen > 1]
        self._subscribe({})

    def _subscribe(self, rcvhwm: dict[bool, int], *, retire: bool = False) -> None:
        """(Re)make the SUB sockets -- receive high-water marks ``rcvhwm`` by kind (secure or not),
        set before they connect -- for every input that has a topic; close the old ones, or with
        ``retire`` keep reading them until the new ones are proven to receive (:meth:`_resubscribe`)."""
        subs = Subscriptions(self.ctx, self.curve, rcvhwm=rcvhwm)
        for name in self.inputs:
            src = self.spec.inputs.get(name)
            if src is not None and src.topic and name not in self.timers:
                wants = self._wants_shm(src)
                # every subscription to one publisher rides the same socket: a publisher that also
                # serves another machine is a Curve server on its ipc endpoint too, and a plain
                # socket's handshake with it fails at every redial (a dslam monitor logged ~300)
                via = {"secure": src.secure, "server_key": src.server_key}
                if wants:
                    sock = subs.add(shm.shm_topic(src.topic.encode()).decode(), src.endpoint, **via)
                if not wants or src.topic.encode() not in self._shm_dupes:
                    if wants:   # also plain, for publishers that are not Tether nodes; the marker says why
                        subs.add((shm.DUAL_PREFIX + src.topic.encode()).decode(), src.endpoint, **via)
                    sock = subs.add(src.topic, src.endpoint, **via)
                self._socket_of[name] = sock
        old = self.subs
        if self._links is not None:
            self._links.close()
        self.subs = subs.sockets
        self._links = LinkWatch(self.subs, subs.endpoints) if self.subs else None
        self._rcvhwm = {sock: subs.rcvhwm_of(sock) for sock in self.subs}
        self._poll_lists: dict[zmq.Socket, list[tuple[zmq.Socket, int]]] = {}
        self._rcvtimeo = -1
        self._poller: zmq.Poller | None = None
        if retire:
            self._retiring.extend(old)
            self._retire_by_ns = time.monotonic_ns() + RETIRE_NS
            self._overlapped = set()
            return
        for sock in old:
            sock.close(linger=0)

    def _wants_shm(self, src: Source) -> bool:
        """Same host (ipc) and shared memory usable: subscribe to ``@shm/<topic>`` (slot tables)."""
        return self._reader is not None and src.endpoint.startswith("ipc://") and src.topic not in self._shm_refused

    def _open_seq_store(self) -> None:
        """Seq numbers kept across restarts: what this node missed while down is counted on return."""
        self._seq_store: SeqStore | None = None
        if not self.spec.state_file:
            return
        routed = [st for st in self.inputs.values() if st.topic in self.spec_topics()]
        names = [f"in:{st.name}" for st in routed] + [f"out:{out}" for out in self._topics]
        try:
            store = SeqStore(Path(self.spec.state_file), names, fresh=self.spec.incarnation == 0)
        except OSError as exc:
            self.node.log.warning("cannot keep seq numbers across restarts in %s: %s", self.spec.state_file, exc)
            return
        for st in routed:
            st.slot = store.slots[f"in:{st.name}"]
            st.restart_seq = store.previous[f"in:{st.name}"]
        for out in self._topics:
            self._seq[out] = store.previous[f"out:{out}"]   # outputs continue their numbering
        self._out_slots = {out: store.slots[f"out:{out}"] for out in self._topics}
        self._seq_store = store

    def spec_topics(self) -> set[str]:
        return {src.topic for src in self.spec.inputs.values() if src.topic}

    # -- Context ----------------------------------------------------------------------
    def now_ns(self) -> int:
        return time.time_ns()

    def publish(self, node: Node, output: str, msg: Message) -> None:
        expected = node.ports.outputs[output]
        if not isinstance(msg, expected):
            raise TypeError(f"{type(node).__name__} published {type(msg).__name__} on {output!r}, declared {expected.__name__}")
        with self._pub_lock:
            seq = self._seq.get(output, 0) + 1
            self._seq[output] = seq
            msg = msgspec.structs.replace(msg, seq=seq, stamp_ns=msg.stamp_ns or time.time_ns())
            frames = self._codec.encode(msg)
            if self.pub is not None:
                nbytes = len(frames[0]) if len(frames) == 1 else sum(map(len, frames))
                topic = self._topics[output]
                plain, to_shm = self._routes_of(topic)
                placed = self._place(output, frames) if to_shm and len(frames) > 1 else None
                wire = nbytes if placed is None or plain else nbytes - placed[2] + len(placed[0])
                if wire > self._largest_sent:
                    self._largest_sent = wire
                    hwm = hwm_for(PUB_QUEUE_BYTES, wire)
                    if hwm != self._sndhwm:
                        # Changing a live socket's HWM races ZeroMQ's I/O thread (see make_sub): only when
                        # the value changes -- messages over 64 KiB, so in practice once, at the first large one.
                        self._sndhwm = hwm
                        self.pub.setsockopt(zmq.SNDHWM, hwm)
                if to_shm:
                    _send(self.pub, self._shm_topics[topic], frames if placed is None else [placed[0], *placed[1]])
                if plain or not to_shm:
                    if placed is not None and self._pools[output].last_loaned:
                        # the loaned slot is reused once shared-memory readers let go; a plain
                        # subscriber's queue may still hold these frames then: it gets a copy
                        frames = [frames[0], *(bytes(f) if shm._nbytes(f) >= self._shm.min_bytes else f for f in frames[1:])]
                    _send(self.pub, topic, frames)
                self._published_bytes[output] += nbytes + len(topic)
            self._published[output] += 1
            if self._seq_store is not None:
                self._seq_store.set(self._out_slots[output], seq)

    def _place(self, output: str, frames: list[Any]) -> tuple[bytes, list[Any], int] | None:
        """Large buffers of ``frames`` into ``output``'s shared-memory pool, or None (send frames)."""
        if not self._shm.enabled:
            return None
        pool = self._pools.get(output)
        if pool is None:
            pool = self._pools[output] = shm.Pool(f"{self.spec.graph}.{self.spec.node_id}.{output}", self._shm)
        if time.monotonic_ns() - self._subs_read_ns > 1_000_000:
            self._read_subscriptions()          # a subscriber that just joined must be known before a slot is reused
        try:
            return pool.place(frames, self._sub_topics.get(self._shm_topics[self._topics[output]], 0))
        except OSError as exc:          # /dev/shm full or gone: this output sends frames from now on
            self._shm = shm.Settings(enabled=False)
            self.node.log.error("shared memory unusable (%s): sending ordinary frames", exc)
            return None

    def loan(self, node: Node, output: str, shape: tuple[int, ...], dtype: Any) -> Any:
        """An array in ``output``'s pool when subscribers on this host take slot tables, else a plain one."""
        with self._pub_lock:
            topic = self._topics[output]
            array = None
            if self.pub is not None and self._shm.enabled and self._routes_of(topic)[1]:
                pool = self._pools.get(output)
                if pool is None:
                    pool = self._pools[output] = shm.Pool(f"{self.spec.graph}.{self.spec.node_id}.{output}", self._shm)
                try:
                    array = pool.loan(shape, np.dtype(dtype), self._sub_topics.get(self._shm_topics[topic], 0))
                except OSError:
                    array = None
        return array if array is not None else super().loan(node, output, shape, dtype)

    def _routes_of(self, topic: bytes) -> tuple[bool, bool]:
        """Whether ``topic`` has plain subscribers (ordinary frames) and ``@shm/`` ones (slot tables)."""
        if time.monotonic_ns() - self._subs_read_ns > SUBSCRIPTIONS_PERIOD_NS:
            self._read_subscriptions()
        routes = self._sub_routes.get(topic)
        if routes is None:
            wide = self._shm_topics.get(topic) or shm.shm_topic(topic)
            plain = sum(n for s, n in self._sub_topics.items() if not s.startswith(b"@") and topic.startswith(s))
            plain -= self._sub_topics.get(shm.DUAL_PREFIX + topic, 0)   # Tether subscribers that take tables
            to_shm = any(wide.startswith(s) for s in self._sub_topics if s.startswith(shm.TOPIC_PREFIX))
            plain = plain > 0
            routes = self._sub_routes[topic] = (plain, to_shm)
        return routes

    def shm_counters(self) -> dict[str, int]:
        """Shared-memory counters of this node: placed, fallbacks (pool busy), oversize, stale (subscriber side)."""
        out = {"placed": sum(p.placed for p in self._pools.values()),
               "fallbacks": sum(p.fallbacks for p in self._pools.values()),
               "oversize": sum(p.oversize for p in self._pools.values()),
               "loaned": sum(p.loaned for p in self._pools.values()),
               "stale": self._reader.stale if self._reader is not None else 0}
        return out

    # -- receiving --------------------------------------------------------------------
    def _take(self, sock: zmq.Socket, flags: int, order: itertools.count) -> None:
        """Receive one message from ``sock`` and queue it (:meth:`_route`): the topic, then the body
        and array buffers as zero-copy frames; the common case -- a plain topic, one input, no link
        model, a body without buffers -- is routed inline.

        The C-level recv with positional arguments, and ``Frame.more`` instead of
        ``getsockopt(RCVMORE)``: pyzmq builds an enum per getsockopt, which doubled the cost of a
        small message. A multipart message arrives whole, so the loop never blocks mid-message.
        """
        frame = _recv_frame(sock, flags, False)
        if frame.more:
            topic = frame.bytes
            frame = _recv_frame(sock, 0, False)
            if not frame.more:
                body = frame.bytes
                states = self.routes.get(topic)
                if states is not None and len(states) == 1 and topic[0] != 64 and states[0].link is None \
                        and topic not in self._shm_dupes:
                    nbytes = len(body)
                    self._accept(states[0], [body], next(order), nbytes, nbytes)
                else:
                    self._route(topic, [body], len(body), order)
                return
            body = frame.bytes
            frames: list[Any] = [body]
            nbytes = len(body)
            while frame.more:
                frame = _recv_frame(sock, 0, False)
                frames.append(frame)          # array buffers stay zero-copy
                nbytes += len(frame)
            self._route(topic, frames, nbytes, order)
            return
        self._route(frame.bytes, [], 0, order)

    def _route(self, topic: bytes, frames: list[Any], nbytes: int, order: itertools.count) -> None:
        states = self.routes.get(topic)
        if not states:
            return  # a longer topic sharing our prefix: not ours
        if topic[0] != 64:          # not b"@" (a routed topic is never empty)
            if topic in self._shm_dupes:
                return    # its publisher sends us slot tables on @shm/: this copy is for plain subscribers
        elif topic not in self._shm_seen:
            self._shm_started(topic)
        if topic[0] == 64 and frames and frames[0][:1] and frames[0][0] in shm.TABLE_MARKERS:
            resolved = self._resolve_shm(topic, states, frames)
            if resolved is None:
                for state in states:
                    if not state.last_seq:
                        state.stats["dropped_seq_gap"] += 1   # no seq before it: no later gap would count it
                return
            frames, held = resolved
            wire, nbytes = nbytes, nbytes + held
        else:
            wire = nbytes
        for state in states:
            if state.link is not None:
                lost = state.link.admit(nbytes, time.time_ns())
                if lost:
                    state.stats["dropped_link"] += 1       # the scenario's network, not a fault: not logged
                    continue
            self._accept(state, frames, next(order), nbytes, wire)

    def _resolve_shm(self, topic: bytes, states: list[InputState],
                     frames: list[Any]) -> tuple[list[Any], int] | None:
        """``[table, body, *frames]`` to ``[body, *buffers]`` viewing the publisher's slot; None if lost.

        A slot already reused is a lost message, counted where every loss is (the next seq gap);
        a segment this process may not map switches the topic to ordinary frames."""
        try:
            if self._reader is None:
                raise DecodeError("a shared-memory slot table arrived but shared memory is off here")
            body = frames[1]
            resolved = self._reader.resolve(frames[0], [getattr(body, "bytes", body), *frames[2:]])
        except Exception as exc:  # noqa: BLE001 - whatever a crafted table makes the resolver raise
            for state in states:
                state.stats["decode_errors"] += 1
                self._log_error(state, f"dropped message on {state.topic}: {exc}")
            if isinstance(exc, shm.ShmUnavailable) and not (exc.missing and topic in self._shm_resolved):
                self._refuse_shm(topic)
            return None
        self._shm_resolved.add(topic)
        return resolved

    def _shm_started(self, topic: bytes) -> None:
        """The publisher of ``@shm/<topic>`` speaks shared memory: drop our plain subscription to it.

        Subscribers ask for both at first, since a publisher that is not a Tether node (a plain
        ZeroMQ client, a replayed log) sends on the plain topic only."""
        plain = topic[len(shm.TOPIC_PREFIX):]
        self._shm_seen.add(topic)
        self._shm_dupes.add(plain)
        for name, state in self.inputs.items():
            sock = self._socket_of.get(name)
            if state.topic.encode() == plain and sock is not None:
                sock.setsockopt(zmq.UNSUBSCRIBE, plain)
                sock.setsockopt(zmq.UNSUBSCRIBE, shm.DUAL_PREFIX + plain)

    def _refuse_shm(self, topic: bytes) -> None:
        """Subscribe to ``topic``'s ordinary frames instead of its slot tables (segments we cannot map)."""
        plain = topic[len(shm.TOPIC_PREFIX):]
        if plain.decode() in self._shm_refused:
            return
        self._shm_refused.add(plain.decode())
        self.node.log.warning("cannot map %s's shared memory: receiving it as ordinary frames", plain.decode())
        was_dupe = plain in self._shm_dupes
        self._shm_dupes.discard(plain)
        for name, state in self.inputs.items():
            sock = self._socket_of.get(name)
            if state.topic.encode() == plain and sock is not None:
                if was_dupe:
                    sock.setsockopt(zmq.SUBSCRIBE, plain)
                else:
                    sock.setsockopt(zmq.UNSUBSCRIBE, shm.DUAL_PREFIX + plain)
                sock.setsockopt(zmq.UNSUBSCRIBE, topic)

    def _drain(self, sock: zmq.Socket, order: itertools.count) -> None:
        # Bounded read-ahead: holding hundreds of large received frames at once costs more (cold
        # memory, allocator churn) than handling as we go; ZeroMQ's own queue holds the rest.
        # Latest-only inputs keep at most one message, so they still see the newest.
        ready = self._poll_lists.get(sock)
        if ready is None:
            ready = self._poll_lists[sock] = [(sock, _POLLIN)]
        deep = self._deep_queues
        while _zmq_poll(ready, 0):   # cheaper than getsockopt(EVENTS), which builds an enum per call
            self._take(sock, _NOBLOCK, order)
            if sum(map(len, deep)) >= READ_AHEAD:
                return

    def _receive(self, timeout_ms: int, order: itertools.count) -> None:
        """Wait up to ``timeout_ms`` for messages and queue what arrived (replaced sockets first)."""
        if self._retiring:
            self._read_retiring(order, timeout_ms)
            return
        if self._poller is None:
            self._poller = self._poller_over(self.subs)
        self._wait_and_drain(timeout_ms, self._poller, order)

    @staticmethod
    def _poller_over(socks: list[zmq.Socket]) -> zmq.Poller:
        poller = zmq.Poller()
        for sock in socks:
            poller.register(sock, zmq.POLLIN)
        return poller

    def _wait_and_drain(self, timeout_ms: int, poller: zmq.Poller, order: itertools.count) -> None:
        if len(self.subs) == 1:
            # One socket: a blocking recv with a timeout beats a Python-level poll per message.
            sock = self.subs[0]
            if timeout_ms != self._rcvtimeo:
                sock.setsockopt(zmq.RCVTIMEO, timeout_ms)
                self._rcvtimeo = timeout_ms
            try:
                self._take(sock, 0, order)
            except zmq.Again:
                return
            self._drain(sock, order)
            return
        for sock, _ in poller.poll(timeout_ms):
            self._drain(sock, order)

    def _accept(self, state: InputState, frames: list[Any], index: int, nbytes: int = -1, wire: int = -1) -> None:
        """Decode one received message into ``state``'s queue; ``nbytes`` is its size (-1: measure it),
        ``wire`` what of it ZeroMQ carried (less when its buffers lie in shared memory; -1: all)."""
        stats = state.stats
        stats["received"] += 1
        if nbytes < 0:
            nbytes = sum(map(len, frames))
        stats["received_bytes"] += nbytes
        try:
            msg = self._codec.decode(state.type, frames)
        except Exception as exc:  # noqa: BLE001 - whatever a crafted frame makes the decoder raise
            state.stats["decode_errors"] += 1
            self._log_error(state, f"dropped undecodable message on {state.topic} ({nbytes} bytes): "
                                   f"{type(exc).__name__}: {exc}")
            return
        if self._retiring and 0 < msg.seq <= state.last_seq:
            state.stats["received"] -= 1          # the same message on the replaced socket and its successor
            state.stats["received_bytes"] -= nbytes
            self._overlapped.add(state.name)
            return
        state.track_seq(msg.seq)
        # ZeroMQ's receive queue holds what came through it: a slot table, not the slot (the
        # publisher's pool bounds those), so a shared-memory stream does not shrink it
        wire = nbytes if wire < 0 else wire
        if wire > self._largest_in.get(state.name, 0):
            self._fit_receive_queue(state, wire)
        state.push(index, msg, nbytes)

    def _fit_receive_queue(self, state: InputState, nbytes: int) -> None:
        """Size ZeroMQ's receive queue from the largest message seen, so it too holds ~max_queue_bytes.

        A high-water mark cannot safely change on a connected socket (see ``make_sub``), so a
        socket whose mark should fall to half or less is replaced, between handling rounds, by
        one made with the new mark (:meth:`_resubscribe`); what its queue held is lost and
        counted as a seq gap -- except that the old socket is read until the new one has
        delivered what it did (:meth:`_resubscribe`). The largest message only grows, so this
        happens a few times per run at most."""
        self._largest_in[state.name] = nbytes
        sock = self._socket_of[state.name]
        hwm = min(hwm_for(st.max_bytes, self._largest_in.get(st.name, 0)) for st in self.inputs.values()
                  if self._socket_of.get(st.name) is sock)
        if hwm <= self._rcvhwm.get(sock, HWM_MAX) // 2 or (hwm == 2 and self._rcvhwm.get(sock, HWM_MAX) > 2):
            self._resubscribe_due = True

    def _wanted_rcvhwm(self) -> dict[bool, int]:
        """The receive high-water mark each kind of socket (secure or not) should have now."""
        out: dict[bool, int] = {}
        for name, st in self.inputs.items():
            src = self.spec.inputs.get(name)
            if src is None or not src.topic or name in self.timers:
                continue
            kind = Subscriptions.kind(self.curve, src.secure)
            out[kind] = min(out.get(kind, HWM_MAX), hwm_for(st.max_bytes, self._largest_in.get(name, 0)))
        return out

    def _resubscribe(self) -> None:
        """Replace the SUB sockets by ones made with the wanted receive high-water marks, make before break.

        A new SUB socket receives only what its publisher sends once the subscription has
        reached it, and closing the old one drops what its queue holds: a publisher that
        sent its last messages in between would never be heard again, and no later seq gap
        would count them (CI: a latest-only input never saw a finished camera's last image).
        So the old sockets stay open and are read first; a message that arrives twice
        (``seq`` not above the input's last) is dropped uncounted, which also proves the new
        socket receives. The old ones close once every input has had such an overlap, or
        after :data:`RETIRE_NS`. Publishers keep their numbering across restarts
        (:class:`tether.inputs.SeqStore`), so a repeated ``seq`` is a copy, not a restart."""
        self._resubscribe_due = False
        self._subscribe(self._wanted_rcvhwm(), retire=True)

    def _read_retiring(self, order: itertools.count, timeout_ms: int) -> None:
        """Wait on the replaced sockets and their successors together, reading the replaced ones
        first (what only they hold was sent before anything the new ones have); close them once
        every input has overlapped or their time is up."""
        if time.monotonic_ns() >= self._retire_by_ns or self._overlapped.issuperset(self._socket_of):
            for sock in self._retiring:
                while _zmq_poll([(sock, _POLLIN)], 0):
                    self._take(sock, _NOBLOCK, order)
                sock.close(linger=0)
            self._retiring = []
            self._poller = None
            return
        socks = [*self._retiring, *self.subs]
        if self._poller is None:
            self._poller = self._poller_over(socks)
        ready = dict(self._poller.poll(timeout_ms))
        for sock in socks:                             # the poller's answer is unordered
            if sock in ready:
                self._drain(sock, order)

    def _log_error(self, state: InputState, text: str) -> None:
        held = self._log_throttle.admit("input:" + state.name, time.monotonic_ns())
        if held is None:
            return
        extra = f" (+{held} similar since last report)" if held else ""
        try:
            self.node.log.error(text + extra)
        except Exception:  # noqa: BLE001 - a failing log handler must not take the node with it
            self._stats_errors += 1

    # -- handling ---------------------------------------------------------------------
    def _handle_pending(self) -> bool:
        """Handle queued messages oldest-first across inputs; True if any was handled."""
        handled = False
        states = self.inputs.values()
        while True:
            best: InputState | None = None
            first = 0
            for state in states:
                queue = state.queue
                if queue and (best is None or queue[0][0] < first):
                    best, first = state, queue[0][0]
            if best is None:
                return handled
            msg = best.pop()
            self._call(best, msg)
            if best.slot >= 0:
                self._seq_store.set(best.slot, msg.seq)   # after the handler: what it published is done
            handled = True
            if self.stop_event.is_set():
                return handled

    def _call(self, state: InputState, msg: Message) -> None:
        t0 = time.perf_counter_ns()
        try:
            handler = state.handler
            if handler is None:
                handler = state.handler = self.node.handler(state.name)
            result = handler(msg)
            if result is not None:
                for output, out in iter_outputs(result):
                    self.node.publish(output, out)
        except Exception as exc:  # noqa: BLE001 - a failing handler never kills the node
            state.stats["handler_errors"] += 1
            self._log_error(state, f"handler on_{state.name} failed on {state.topic} stamp_ns={msg.stamp_ns} "
                                   f"seq={msg.seq}: {type(exc).__name__}: {exc}")
            log.debug("handler traceback", exc_info=True)
        dt = time.perf_counter_ns() - t0
        state.stats["handled"] += 1
        state.handler_ns += dt
        if dt > state.handler_max_ns:
            state.handler_max_ns = dt

    # -- timers and stats -------------------------------------------------------------
    def _fire_timers(self, due: dict[str, int], order: itertools.count) -> None:
        now = time.monotonic_ns()
        for name, when in due.items():
            if when <= now:
                period = self.timers[name]
                state = self.inputs[name]
                late = (now - when) // period
                if late:
                    state.stats["dropped_queue"] += late  # missed ticks of a slow node, counted
                due[name] = when + (late + 1) * period
                state.stats["received"] += 1
                state.queue.clear()
                state.queue.append((next(order), Tick(stamp_ns=time.time_ns(), period_ns=period), 0))

    def stats(self) -> NodeStats:
        errors = sum(s.stats["handler_errors"] + s.stats["decode_errors"] for s in self.inputs.values())
        return NodeStats(node_id=self.spec.node_id, node_class=self.spec.node, pid=os.getpid(),
                         uptime_s=(time.monotonic_ns() - self._started_ns) / 1e9,
                         inputs=[state.to_stats() for state in self.inputs.values()],
                         published={k: saturate(v) for k, v in self._published.items()},
                         subscribers={k: saturate(v) for k, v in self._subscribers.items()},
                         errors=saturate(errors), restarts=saturate(self.spec.incarnation),
                         stats_errors=saturate(self._stats_errors),
                         published_bytes={k: saturate(v) for k, v in self._published_bytes.items()},
                         **{f"shm_{k}": saturate(v) for k, v in self.shm_counters().items()},
                         rt_priority=fifo_priority(), stamp_ns=time.time_ns())

    def _publish_stats(self) -> None:
        """Publish :meth:`stats`; a failure here is counted and logged (rate-limited), never fatal."""
        if self.pub is None:
            return
        try:
            with self._pub_lock:
                self._read_subscriptions()
                self._stats_seq += 1              # numbered like any output, so a subscriber sees losses and restarts
                msg = msgspec.structs.replace(self.stats(), seq=self._stats_seq)
                frames = self._codec.encode(msg)
                plain, to_shm = self._routes_of(self._stats_topic)
                if to_shm:
                    _send(self.pub, self._shm_topics[self._stats_topic], frames)
                if plain or not to_shm:
                    _send(self.pub, self._stats_topic, frames)
        except Exception as exc:  # noqa: BLE001 - statistics must never be what kills a node
            self._stats_errors += 1
            if self._log_throttle.admit("stats", time.monotonic_ns()) is not None:
                try:
                    self.node.log.error("publishing statistics failed (%d so far): %s: %s", self._stats_errors,
                                        type(exc).__name__, exc)
                except Exception:  # noqa: BLE001
                    pass

    def _check_links(self) -> None:
        """Redial publishers whose connection ZeroMQ dropped (an oversize frame, a dead publisher, a
        failed security handshake); each endpoint is logged at most once per :data:`ERROR_LOG_PERIOD_NS`."""
        now = time.monotonic_ns()
        for endpoint, refused in self._links.poll():
            hit = [st for name, st in self.inputs.items()
                   if (src := self.spec.inputs.get(name)) is not None and src.endpoint == endpoint]
            for st in hit:
                st.stats["link_resets"] += 1
            if not refused and endpoint.startswith("ipc://") and not os.path.lexists(endpoint[6:]):
                log.debug("the publisher at %s stopped (its socket is gone); redialled", endpoint)
                continue       # a node stopping (a launch stops from its sources): not a fault
            held = self._log_throttle.admit("link:" + endpoint, now)
            if held is None:
                continue
            why = ("failed its security handshake (a plain subscriber dialling a CurveZMQ publisher, or keys "
                   "from another keystore)" if refused else
                   "dropped: a frame over the receive limit or the publisher went away")
            extra = f" (+{held} more since the last report)" if held else ""
            self.node.log.warning("connection to %s (%s) %s; redialled%s", endpoint,
                                  ", ".join(st.topic for st in hit) or "?", why, extra)

    def _read_subscriptions(self) -> None:
        """Take in (un)subscriptions (``XPUB_VERBOSER``: one event per subscriber) and count subscribers.

        A Tether subscriber on this host asks for ``@shm/<t>`` and, until its first slot table
        arrives, also for ``<t>`` and the marker ``@dual/<t>`` (see :mod:`tether.shm`): each
        subscriber counts once, and only plain subscribers make :meth:`publish` send plain frames."""
        self._subs_read_ns = time.monotonic_ns()
        ready = [(self.pub, _POLLIN)]
        while _zmq_poll(ready, 0):
            event = self.pub.recv()
            if not event:
                continue
            raw, step = event[1:], (1 if event[0] == 1 else -1)
            count = self._sub_topics[raw] + step
            if count > 0:
                self._sub_topics[raw] = count
            else:
                del self._sub_topics[raw]
            self._sub_routes.clear()
            logical = raw
            if raw.startswith(shm.TOPIC_PREFIX):
                logical = raw[len(shm.TOPIC_PREFIX):]
            elif raw.startswith(shm.DUAL_PREFIX):
                logical, step = raw[len(shm.DUAL_PREFIX):], -step
            self._subscribers[logical.decode(errors="replace")] += step

    def _wait_for_subscribers(self) -> None:
        """Hold a node's first publication until its known subscribers have joined (bounded)."""
        want = {t: n for t, n in self.spec.expect_subscribers.items() if n > 0}
        if not want or self.pub is None:
            return
        deadline = time.monotonic() + self.spec.wait_subscribers_s
        while not self.stop_event.is_set():
            self._read_subscriptions()
            if all(self._subscribers.get(t, 0) >= n for t, n in want.items()):
                return
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                missing = {t: n - self._subscribers.get(t, 0) for t, n in want.items() if self._subscribers.get(t, 0) < n}
                self.node.log.warning("starting without all subscribers after %.1f s (missing %s)",
                                      self.spec.wait_subscribers_s, missing)
                return
            self.pub.poll(min(50, int(remaining * 1000) + 1), zmq.POLLIN)

    # -- main loop --------------------------------------------------------------------
    def serve(self) -> int:
        """Run until :attr:`stop_event` is set (or a source finishes); return 0, or 1 if the node failed."""
        node = self.node
        failed = threading.Event()
        try:
            node.setup()
        except (ValueError, OSError, TetherError) as exc:
            # A parameter or a file the node cannot use (a missing checkpoint, a scene it does not
            # know): its message says what to do, in one line; a traceback would bury it.
            node.log.error("setup failed: %s: %s", type(exc).__name__, exc)
            self.close()
            return 1
        except Exception:
            node.log.exception("setup failed")            # a fault in the node's code: where it is
            self.close()
            return 1
        self._wait_for_subscribers()
        thread = None
        if type(node).is_source():
            def loop() -> None:
                try:
                    node.run()
                except Exception:
                    node.log.exception("run() failed")
                    failed.set()
                finally:
                    if not self.inputs:
                        self.stop_event.set()
            thread = threading.Thread(target=loop, name=f"{self.spec.node_id}.run", daemon=True)
            thread.start()
        order = itertools.count()
        now = time.monotonic_ns()
        due = {name: now for name in self.timers}
        next_stats = next_link_check = now
        try:
            while not self.stop_event.is_set() and not failed.is_set():
                now = time.monotonic_ns()
                if now >= next_stats:
                    self._publish_stats()
                    next_stats = now + STATS_PERIOD_NS
                if self._links is not None and now >= next_link_check:
                    self._check_links()
                    next_link_check = now + LINK_CHECK_NS
                wake = min(next_stats, min(due.values())) if due else next_stats
                timeout_ms = max(0, min(100, (wake - now) // 1_000_000 + (1 if wake > now else 0)))
                if self.subs:
                    self._receive(timeout_ms, order)
                elif timeout_ms:
                    self.stop_event.wait(timeout_ms / 1000)
                if due:
                    self._fire_timers(due, order)
                self._handle_pending()
                if self._resubscribe_due:
                    self._resubscribe()
        except KeyboardInterrupt:
            pass
        finally:
            node.stopping.set()
            if thread is not None:
                thread.join(timeout=5.0)
                if thread.is_alive():
                    node.log.error("run() did not stop within 5 s of shutdown")
            if self.stop_event.is_set() and not failed.is_set():
                try:
                    self._finish_inputs(order)
                except Exception:  # noqa: BLE001 - stopping goes on: teardown, statistics, sockets
                    node.log.exception("handling the inputs' last messages failed")
            try:
                node.teardown()
            except Exception:
                node.log.exception("teardown failed")
                failed.set()
            self._publish_stats()
            self.close()
        return 1 if failed.is_set() else 0

    def stop(self) -> None:
        """Ask the node to stop (a signal handler may call this): :meth:`serve` ends its loop, lets
        ``run()`` return, handles what reached its inputs (:meth:`_finish_inputs`), then tears down."""
        self.stop_event.set()
        self.node.stopping.set()

    def _finish_inputs(self, order: itertools.count) -> None:
        """Handle, before the node stops, what its publishers sent before they stopped.

        Timers fire no more (they are the node's own sources). Received messages are handled
        in order until every input queue and socket is empty and every publisher it waits for
        has gone (its connection closed: ZeroMQ delivers a connection's last messages before
        its close, so nothing it sent is left in flight), or, while one is still
        connected (a replay, a node hung in its stop), once nothing arrived for
        :data:`FINISH_IDLE_NS`; at most :data:`FINISH_MAX_NS` in all. The launcher stops a
        graph from its sources (:class:`tether.supervisor.Supervisor`), so a node's upstream
        is gone when it is asked to stop, and the node stops as soon as it has handled the
        last message; publishers the launcher does not stop first (``Source.await_on_stop``
        False: another machine's, the node's own cycle) are not waited for: what they sent
        is handled until the sockets are read empty."""
        for name in self.timers:
            self.inputs[name].queue.clear()
        socks = [*self._retiring, *self.subs]
        ready = [(sock, _POLLIN) for sock in socks]
        awaited = {self.spec.inputs[name].endpoint for name in self._socket_of
                   if self.spec.inputs[name].await_on_stop}
        start = heard = time.monotonic_ns()
        handled = 0
        while True:
            now = time.monotonic_ns()
            if now - start >= FINISH_MAX_NS:
                self.node.log.warning("stopping with input still arriving after %.1f s (%d messages handled "
                                      "meanwhile): what comes later is not handled", FINISH_MAX_NS / 1e9, handled)
                return
            queued = any(st.queue for st in self.inputs.values())
            if queued:
                self._handle_pending()                 # one message: the stop event is set
                handled += 1
            if self._read_ready(ready, 0, order):
                heard = time.monotonic_ns()
                continue
            if queued:
                continue
            if self._links is not None:
                self._links.poll(redial=False)         # a redial would discard what a dropped link delivered
            if awaited <= (self._links.gone if self._links is not None else set()):
                if not self._read_ready(ready, 0, order):   # its close came after its last message: all read
                    return
            elif now - heard >= FINISH_IDLE_NS:
                return
            elif self._read_ready(ready, 10, order):
                heard = time.monotonic_ns()

    def stop_report(self) -> dict[str, Any]:
        """This node's last seq published per topic and last seq received per input, for the launcher
        to count at the stop what was published but never reached its subscriber
        (:func:`tether.supervisor.stop_losses`): a node of a cycle stops beside its peers, so what
        one publishes while the other has just stopped is lost, and no later seq reveals the gap."""
        return {"published": {self._topics[out].decode(): seq for out, seq in self._seq.items()},
                "received": {name: [st.topic, st.last_seq] for name, st in self.inputs.items()
                             if name not in self.timers}}

    def _read_ready(self, ready: list[tuple[zmq.Socket, int]], timeout_ms: int, order: itertools.count) -> bool:
        """Queue what the sockets of ``ready`` hold, waiting up to ``timeout_ms`` for some; whether any did."""
        hits = _zmq_poll(ready, timeout_ms) if ready else []
        for sock, _ in hits:
            self._drain(sock, order)
        return bool(hits)

    def close(self) -> None:
        if self._links is not None:
            self._links.close()
            self._links = None
        if self._seq_store is not None:
            self._seq_store.close()
            self._seq_store = None
        for sock in [*self.subs, *self._retiring]:
            sock.close(linger=0)
        self.subs, self._retiring = [], []
        if self.pub is not None:
            # ZeroMQ unlinks ipc files lazily, or not at exit. Before the close: a subscriber that sees
            # the connection drop finds the file gone, so it knows the publisher stopped (_check_links).
            for endpoint in self.spec.binds:
                if endpoint.startswith("ipc://"):
                    try:
                        if stat.S_ISSOCK(os.lstat(endpoint[6:]).st_mode):
                            os.unlink(endpoint[6:])
                    except OSError:
                        pass
            self.pub.close()
            self.pub = None
        if self._auth is not None:
            self._auth.stop()
            self._auth = None
        for pool in self._pools.values():      # closed, kept for their counters
            pool.close()
        if self._reader is not None:
            self._reader.close()


_zmq_poll = zmq.backend.zmq_poll
_recv_frame = zmq.backend.Socket.recv   # (sock, flags, copy): the C-level recv, without keyword parsing
_send_frame = zmq.backend.Socket.send   # pyzmq's C-level send: the Python wrapper only adds routing_id/group


def _send(sock: zmq.Socket, topic: bytes, frames: list[Any]) -> None:
    """Topic and body are copied (small); array buffers go zero-copy (ZeroMQ holds a reference)."""
    _send_frame(sock, topic, _SNDMORE)
    last = len(frames) - 1
    _send_frame(sock, frames[0], _SNDMORE if last else 0)
    for i in range(1, last + 1):
        _send_frame(sock, frames[i], _SNDMORE if i < last else 0, copy=False)
