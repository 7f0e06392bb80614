"""Replay: publish a log's topics, or run one node on a log (lockstep or paced).

- :func:`play` publishes records under their original topics (``tether replay FILE``).
- :class:`Player` is a node publishing a log inside a launch file.
- :func:`replay_into` runs a node on a log and records its outputs
  (``tether replay FILE --into MODULE:Class --map INPUT=TOPIC --record OUT``). With
  ``lockstep`` it runs in-process on the log's clock: every message is handled before the
  next is given, so outputs are identical on every run and come as fast as the node goes.
"""
from __future__ import annotations

import fnmatch
import logging
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import msgspec
import zmq

from tether.errors import ConfigError, DecodeError, TetherError
from tether.log import LogReader, LogRecord, LogWriter
from tether.message import Message, message_type
from tether.node import Node
from tether.testing import Harness

log = logging.getLogger("tether.replay")


@dataclass
class Window:
    """Which part of a log to play: seconds from the log's start, topics, rate, looping."""

    start_s: float = 0.0
    end_s: float | None = None
    topics: list[str] | None = None
    rate: float = 1.0
    loop: bool = False

    def __post_init__(self) -> None:
        if self.rate < 0:
            raise ConfigError("--rate must be >= 0 (0 means as fast as possible)")
        if self.end_s is not None and self.end_s <= self.start_s:
            raise ConfigError(f"--end ({self.end_s}) must be after --start ({self.start_s})")


def select_topics(topics: Iterable[str], patterns: Sequence[str] | None, *, what: str = "--topics") -> list[str]:
    """The topics named by ``patterns`` (exact names or globs like ``sonar/*``); all when none.

    One filter for the ``replay`` verb, ``replay --into`` and the Player node alike; a
    filter that selects nothing is an error listing what the log has, and so is an exact
    name the log lacks (a typo beside a good name was dropped silently).
    """
    names = sorted(topics)
    if not patterns:
        return names
    chosen = [t for t in names if any(fnmatch.fnmatchcase(t, p) for p in patterns)]
    if not chosen:
        raise ConfigError(f"{what} {' '.join(patterns)} selects none of the log's topics: {', '.join(names) or 'none'}")
    missing = [p for p in patterns if not any(c in p for c in "*?[") and p not in names]
    if missing:
        raise ConfigError(f"{what}: the log has no topic {', '.join(missing)} (its topics: {', '.join(names)})")
    return chosen


def records(reader: LogReader, window: Window) -> Iterator[LogRecord]:
    """The records of one pass through the window."""
    info = reader.info()
    if not info.counts:
        return
    start = info.start_ns + int(window.start_s * 1e9)
    end = None if window.end_s is None else info.start_ns + int(window.end_s * 1e9)
    topics = select_topics(info.topics, window.topics) if window.topics else None
    yield from reader.messages(topics, start_ns=start, end_ns=end)


def paced(reader: LogReader, window: Window, stop: threading.Event,
          on_pass: Callable[[], None] | None = None) -> Iterator[LogRecord]:
    """Records at their log-time spacing divided by ``rate`` (0 = no waiting), looping if asked.

    ``on_pass`` is called after each complete pass (the reader's ``damaged`` then tells that pass's damage)."""
    while not stop.is_set():
        t_log0: int | None = None
        t_wall0 = time.monotonic()
        any_record = False
        for rec in records(reader, window):
            any_record = True
            if t_log0 is None:
                t_log0 = rec.log_time_ns
            if window.rate > 0:
                due = t_wall0 + (rec.log_time_ns - t_log0) / 1e9 / window.rate
                delay = due - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    return
            if stop.is_set():
                return
            yield rec
        if on_pass is not None:
            on_pass()
        if not window.loop or not any_record:
            return


def play(reader: LogReader, sock: zmq.Socket, window: Window, stop: threading.Event,
         progress: Callable[[int, LogRecord], None] | None = None, *,
         on_pass: Callable[[], None] | None = None) -> int:
    """Publish records on ``sock`` under their original topics; returns how many were sent."""
    sent = 0
    for rec in paced(reader, window, stop, on_pass):
        # A log body has its arrays inline; every tether decoder reads that form too.
        sock.send_multipart([rec.topic.encode(), rec.data])
        sent += 1
        if progress is not None:
            progress(sent, rec)
    return sent


# -- a node that plays a log inside a launch file --------------------------------------------
class PlayerConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    log: str
    topics: list[str] = []
    rate: float = 1.0
    start_s: float = 0.0
    end_s: float | None = None
    loop: bool = False


def output_names(topics: Mapping[str, str]) -> dict[str, str]:
    """Output name per topic: the part after the node id when unique, else the topic with '/' -> '.'."""
    tails: dict[str, int] = {}
    for topic in topics:
        tail = topic.split("/", 1)[-1]
        tails[tail] = tails.get(tail, 0) + 1
    return {topic: (tail if tails[tail] == 1 else topic.replace("/", "."))
            for topic in topics for tail in [topic.split("/", 1)[-1]]}


class Player(Node):
    """Publishes a recorded log; outputs are the log's topics (``sonar/ping`` -> output ``ping``)."""

    Config = PlayerConfig

    @classmethod
    def ports_for(cls, config: PlayerConfig) -> tuple[Mapping[str, Any], Mapping[str, type[Message]], Mapping[str, Any]]:
        try:
            info = LogReader(config.log).info()
        except FileNotFoundError as exc:
            raise ConfigError(str(exc)) from None
        topics = {t: info.topics[t] for t in select_topics(info.topics, config.topics, what="topics")}
        try:
            return {}, {name: message_type(topics[t]) for t, name in output_names(topics).items()}, {}
        except KeyError as exc:
            raise ConfigError(f"log {config.log}: {exc}") from None

    def run(self) -> None:
        reader = LogReader(self.config.log)
        window = Window(self.config.start_s, self.config.end_s, self.config.topics or None,
                        self.config.rate, self.config.loop)
        info = reader.info()
        names = output_names({t: info.topics[t] for t in select_topics(info.topics, self.config.topics, what="topics")})
        for rec in paced(reader, window, self.stopping):
            name = names.get(rec.topic)
            if name is None or name not in self.ports.outputs:
                continue
            try:
                self.publish(name, reader.decode(rec))
            except DecodeError as exc:
                self.log.error("skipped a malformed record on %s: %s", rec.topic, exc)


# -- one node on a log --------------------------------------------------------------------
def replay_into(log_path: str | Path | LogReader, node_cls: type[Node], mapping: Mapping[str, str], out_path: str | Path, *,
                params: Mapping[str, Any] | None = None, window: Window | None = None, lockstep: bool = True,
                node_id: str | None = None, progress: Callable[[int, int], None] | None = None) -> int:
    """Run ``node_cls`` on the log's ``mapping`` ({input: topic}); record its outputs to ``out_path``.

    Returns the number of messages fed. Lockstep runs in-process on the log's clock
    (deterministic); otherwise the node runs on real sockets fed at ``window.rate``. Given an
    open reader, its ``damaged`` and ``truncated_at`` then tell what the node was not fed.
    """
    window = window or Window()
    reader = log_path if isinstance(log_path, LogReader) else LogReader(log_path)
    info = reader.info()
    try:
        config = node_cls.make_config(params)
        ports = node_cls.resolve_ports(config)
    except TetherError:
        raise
    except Exception as exc:  # noqa: BLE001 - a Config or port declaration saying what is wrong (as tether check)
        raise ConfigError(f"{node_cls.__module__}:{node_cls.__name__}: params: {type(exc).__name__}: {exc}") from exc
    if not mapping:
        raise ConfigError(f"--into needs --map INPUT=TOPIC ({node_cls.__name__}'s inputs: "
                          f"{', '.join(sorted(ports.inputs)) or 'none'}; the log's topics: {', '.join(sorted(info.topics))})")
    for name, topic in mapping.items():
        if name not in ports.inputs:
            raise ConfigError(f"--map {name}={topic}: {node_cls.__name__} has no input {name!r} "
                              f"(inputs: {sorted(ports.inputs)})")
        if topic not in info.topics:
            raise ConfigError(f"--map {name}={topic}: the log has no topic {topic!r} (topics: {sorted(info.topics)})")
        want = ports.inputs[name].type.type_name()
        if info.topics[topic] != want:
            raise ConfigError(f"--map {name}={topic}: input takes {want}, the log has {info.topics[topic]}")
    node_id = node_id or node_cls.__name__.lower()
    allowed = set(select_topics(info.topics, window.topics)) if window.topics else set(info.topics)
    by_topic: dict[str, list[str]] = {}
    for name, topic in mapping.items():
        if topic in allowed:
            by_topic.setdefault(topic, []).append(name)
    if not by_topic:
        raise ConfigError(f"--topics {' '.join(window.topics or [])} leaves none of the --map topics "
                          f"({', '.join(sorted(set(mapping.values())))})")
    window = Window(window.start_s, window.end_s, sorted(by_topic), window.rate, window.loop)
    total = sum(info.counts.get(t, 0) for t in by_topic)
    if lockstep:
        return _lockstep(reader, info.start_ns, node_cls, config, node_id, by_topic, window, out_path, total, progress)
    return _live(reader, node_cls, params or {}, node_id, mapping, window, out_path, total, progress)


def _lockstep(reader: LogReader, start_ns: int, node_cls: type[Node], config: msgspec.Struct, node_id: str,
              by_topic: dict[str, list[str]], window: Window, out_path: str | Path, total: int,
              progress: Callable[[int, int], None] | None) -> int:
    fed = 0
    harness = Harness(node_cls, config=config, node_id=node_id, roundtrip=False, catch_errors=True, start_ns=start_ns)
    with LogWriter(out_path, metadata={"replay_of": str(reader.path), "node": f"{node_cls.__module__}:{node_cls.__name__}"}) as writer:
        def drain() -> None:
            for out in harness.outputs:
                writer.write(f"{node_id}/{out.output}", out.msg, log_time_ns=out.t_ns)
            harness.outputs.clear()

        for rec in records(reader, window):
            try:
                msg = reader.decode(rec)
            except DecodeError as exc:
                log.error("skipped a malformed record on %s: %s", rec.topic, exc)
                continue
            for name in by_topic[rec.topic]:
                harness.feed([((rec.log_time_ns - start_ns) / 1e9, name, msg)])
            drain()
            fed += 1
            if progress is not None:
                progress(fed, total)
        harness.close()
        drain()
    for name, exc in harness.errors:
        log.error("handler on_%s failed: %s: %s", name, type(exc).__name__, exc)
    return fed


def _live(reader: LogReader, node_cls: type[Node], params: Mapping[str, Any], node_id: str,
          mapping: Mapping[str, str], window: Window, out_path: str | Path, total: int,
          progress: Callable[[int, int], None] | None) -> int:
    from tether.record import Recorder
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    token = uuid.uuid4().hex[:8]
    src_ep, out_ep = ipc_endpoint("replay", "src", token), ipc_endpoint("replay", node_id, token)
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.XPUB)
    pub.bind(src_ep)
    spec = RunSpec(graph="replay", node_id=node_id, node=f"{node_cls.__module__}:{node_cls.__name__}",
                   params=dict(params), binds=[out_ep],
                   inputs={name: Source(topic=topic, endpoint=src_ep) for name, topic in mapping.items()},
                   expect_subscribers={f"{node_id}/{o}": 1 for o in node_cls.resolve_ports(node_cls.make_config(params)).outputs})
    runtime = NodeRuntime(spec, node_cls, ctx)
    recorder = Recorder(out_path, {f"{node_id}/{o}": out_ep for o in runtime.node.ports.outputs}, ctx=ctx).start()
    thread = threading.Thread(target=runtime.serve, daemon=True)
    thread.start()
    try:
        if recorder.failed:          # the output could not be opened (a directory, a read-only place)
            raise ConfigError(f"--record {out_path}: {recorder.failed}")
        pub.poll(5000, zmq.POLLIN)   # the node's subscription arrived: nothing is lost to a slow join
        count = play(reader, pub, window, threading.Event(),
                     (lambda n, rec: progress(n, total)) if progress is not None else None)
        deadline = time.monotonic() + 30.0   # bounded: let the node finish what it was sent
        while time.monotonic() < deadline and thread.is_alive():
            seen = sum(st.stats["handled"] + st.stats["dropped_queue"] + st.stats["decode_errors"]
                       for name, st in runtime.inputs.items() if name in mapping)
            if seen >= count * len(mapping) / max(len(set(mapping.values())), 1):
                break
            time.sleep(0.01)
    finally:
        runtime.stop()
        thread.join(10)
        recorder.stop()
        pub.close(linger=0)
    return count
