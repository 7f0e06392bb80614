"""Foxglove sinks: the live WebSocket view of running graphs (``tether foxglove``) and the
channel bookkeeping ``tether export foxglove`` shares with it.

Both feed Tether messages through :func:`tether.foxglove_convert.convert` into the
channels of one ``foxglove.Context``; the context's sink is a WebSocket server (live) or
an MCAP writer (export). The live view finds topics in the registry every second (graphs
started later appear, graphs that stop are unadvertised), subscribes to them like
``tether record`` does (CurveZMQ keys from the keystore for secured topics), and converts
on one thread. It keeps up rather than queues: per round it converts every message of a
topic up to 256 KiB and only the newest of larger ones (images, clouds), counting the
ones it skipped; a topic no Foxglove client subscribes to is converted once, to advertise
its channels, and then only received. Undecodable messages are counted and logged (at most
one line per 5 s), never raised.
"""
from __future__ import annotations

import fnmatch
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Iterable

import msgspec
import zmq

from tether.codec import Codec, wire_to_inline
from tether.errors import TetherError
from tether.foxglove_convert import convert, foxglove, json_schema

log = logging.getLogger("tether.foxglove")

ERROR_LOG_PERIOD_S = 5.0
LATEST_ONLY_BYTES = 256 << 10       # messages larger than this are sampled (newest per round), not queued
REGISTRY_PERIOD_S = 1.0
#: Messages the server queues per client before dropping its oldest (the SDK's default, 1024, is counted
#: in messages: 1024 RGB-D frames for a stalled browser tab would be gigabytes).
CLIENT_BACKLOG = 128


@dataclass
class Counters:
    received: int = 0
    converted: int = 0             # Tether messages turned into Foxglove messages
    logged: int = 0                # Foxglove messages written (a message may give several)
    skipped: int = 0               # large messages superseded by a newer one before conversion
    errors: int = 0                # undecodable or unconvertible messages, dropped
    by_topic: dict[str, int] = field(default_factory=dict)


class FoxgloveSink:
    """Channels of one ``foxglove.Context``, made on first use: a typed channel per Foxglove
    schema, a JSON channel (with the message type's JSON schema) otherwise."""

    def __init__(self, context: foxglove.Context) -> None:
        self.context = context
        self.counters = Counters()
        self._channels: dict[str, tuple[str, Any]] = {}      # Foxglove topic -> (kind, channel)
        self._sources: dict[str, set[str]] = {}              # Tether topic -> its Foxglove topics
        self._last_error_log = 0.0

    def _channel(self, topic: str, out: Any, tp: type | None, type_name: str) -> tuple[str, Any]:
        kind = "json" if isinstance(out, dict) else type(out).__name__
        have = self._channels.get(topic)
        if have is not None:
            if have[0] != kind:
                raise TypeError(f"{topic} carried {have[0]} and now {kind}: the topic changed type")
            return have
        if kind == "json":
            schema = foxglove.Schema(name=type_name or "json", encoding="jsonschema", data=json_schema(tp))
            channel = foxglove.Channel(topic, schema=schema, message_encoding="json", context=self.context,
                                       metadata={"tether_source_type": type_name})
        else:
            channel = getattr(foxglove.channels, f"{kind}Channel")(topic, context=self.context,
                                                                    metadata={"tether_source_type": type_name})
        self._channels[topic] = (kind, channel)
        return kind, channel

    def log(self, topic: str, type_name: str, msg: Any, log_time_ns: int) -> int:
        """Convert and log one message (typed, or a plain dict); returns the Foxglove messages written.
        Content no schema can hold is counted and logged (rate-limited), never raised."""
        try:
            outputs = convert(type_name, msg)
            tp = type(msg) if isinstance(msg, msgspec.Struct) else None
            for suffix, out in outputs:
                kind, channel = self._channel(topic + suffix, out, tp, type_name)
                self._sources.setdefault(topic, set()).add(topic + suffix)
                if kind == "json":
                    channel.log(json.dumps(out, allow_nan=False).encode(), log_time=log_time_ns)
                else:
                    channel.log(out, log_time=log_time_ns)
        except (ValueError, TypeError, OverflowError) as exc:
            self.error(f"dropped a message on {topic} ({type_name}): {type(exc).__name__}: {exc}")
            return 0
        self.counters.converted += 1
        self.counters.logged += len(outputs)
        return len(outputs)

    def error(self, text: str) -> None:
        self.counters.errors += 1
        if time.monotonic() - self._last_error_log >= ERROR_LOG_PERIOD_S:
            self._last_error_log = time.monotonic()
            log.error("%s (%d dropped so far)", text, self.counters.errors)

    def watched(self, topic: str) -> bool:
        """Whether anyone subscribes to a channel made from ``topic`` (True before its first message:
        the channels only exist, and are advertised, once it has been converted)."""
        names = self._sources.get(topic)
        return not names or any(self._channels[n][1].has_sinks() for n in names)

    def close_topic(self, topic: str) -> None:
        """Unadvertise the channels made from ``topic`` (its graph stopped)."""
        for name in self._sources.pop(topic, set()):
            _, channel = self._channels.pop(name)
            channel.close()

    @property
    def topics(self) -> list[str]:
        return sorted(self._channels)


class LiveView:
    """Serve running graphs' topics (``patterns``: fnmatch globs, default all but ``*/_stats``) on a
    Foxglove WebSocket server at ``host:port`` (port 0: a free one, see :attr:`port`)."""

    def __init__(self, *, host: str = "127.0.0.1", port: int = 8765, patterns: Iterable[str] = (),
                 exclude: Iterable[str] = (), ctx: zmq.Context | None = None) -> None:
        self.patterns, self.exclude = list(patterns), list(exclude)
        self.context = foxglove.Context()
        self.sink = FoxgloveSink(self.context)
        # Clients coming and going are logged once each (foxglove.websocket.server); the per-client errors
        # after a tab closes or a client resets come once per message still queued for it: not shown.
        logging.getLogger("foxglove.websocket.connected_client").setLevel(logging.CRITICAL)
        try:
            self.server = foxglove.start_server(name="tether", host=host, port=port, context=self.context,
                                                message_backlog_size=CLIENT_BACKLOG)
        except RuntimeError as exc:            # the SDK's error for a port in use, an unknown host, ...
            raise TetherError(f"cannot serve Foxglove on {host}:{port}: {str(exc).removeprefix('FoxgloveError: ')}"
                              f"; choose another --port (0: any free one)") from None
        self.port = self.server.port
        self.ctx = ctx or zmq.Context.instance()
        self._codec = Codec()
        self._subs: dict[tuple[str, str], Any] = {}          # (keystore, machine) -> Subscriptions
        self._poller = zmq.Poller()
        self._types: dict[str, str] = {}                     # topic -> type tag, as registered
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def wanted(self, topic: str) -> bool:
        if self.patterns:
            keep = any(fnmatch.fnmatchcase(topic, p) for p in self.patterns)
        else:
            keep = not topic.endswith("/_stats")
        return keep and not any(fnmatch.fnmatchcase(topic, p) for p in self.exclude)

    def refresh(self) -> None:
        """Subscribe to topics that appeared in the registry; unadvertise those that went away."""
        from tether import registry
        from tether.transport import Subscriptions

        found = {t: info for t, info in registry.topics().items() if self.wanted(t)}
        for topic, info in found.items():
            if self._types.get(topic) == info.type_name + "@" + info.endpoint:
                continue
            key = (info.keystore, info.machine) if info.secure else ("", "")
            subs = self._subs.get(key)
            if subs is None:
                curve = info.client_keys()[0] if info.secure else None
                subs = self._subs[key] = Subscriptions(self.ctx, curve)
            before = set(subs.sockets)
            sock = subs.add(topic, info.endpoint, secure=info.secure, server_key=info.client_keys()[1])
            if sock not in before:
                sock.setsockopt(zmq.RCVHWM, 1000)
                self._poller.register(sock, zmq.POLLIN)
            self._types[topic] = info.type_name + "@" + info.endpoint
            log.info("serving %s (%s)", topic, info.type_name)
        for topic in [t for t in self._types if t not in found]:
            del self._types[topic]
            self.sink.close_topic(topic)

    def step(self, timeout_ms: int = 100) -> int:
        """Receive what is waiting (up to ``timeout_ms``), convert and log it; returns messages converted."""
        batch: list[tuple[str, list[Any]]] = []
        latest: dict[str, int] = {}
        for sock, _ in self._poller.poll(timeout_ms):
            while len(batch) < 4096:
                try:
                    frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
                except zmq.Again:
                    break
                topic = frames[0].bytes.decode(errors="replace")
                if topic not in self._types:
                    continue                   # another topic sharing our prefix
                self.sink.counters.received += 1
                if len(frames) < 2:
                    self.sink.error(f"dropped a message on {topic} with no body (1 frame)")
                    continue
                if sum(len(f.buffer) for f in frames[1:]) > LATEST_ONLY_BYTES:
                    if topic in latest:
                        batch[latest[topic]] = ("", [])
                        self.sink.counters.skipped += 1
                    latest[topic] = len(batch)
                batch.append((topic, frames[1:]))
        done = 0
        for topic, frames in batch:
            if topic and self.sink.watched(topic):
                done += self._log(topic, frames)
        return done

    def _log(self, topic: str, frames: list[Any]) -> int:
        from tether.message import message_type

        type_name = self._types[topic].split("@", 1)[0]
        try:
            try:
                msg: Any = self._codec.decode(message_type(type_name), frames)
            except KeyError:                   # a type this process does not know: plain msgpack
                import msgpack

                msg = msgpack.unpackb(wire_to_inline(frames), raw=False, strict_map_key=False)
        except Exception as exc:  # noqa: BLE001 - whatever a malformed frame makes a decoder raise
            self.sink.error(f"dropped an undecodable message on {topic}: {type(exc).__name__}: {exc}")
            return 0
        self.sink.counters.by_topic[topic] = self.sink.counters.by_topic.get(topic, 0) + 1
        return 1 if self.sink.log(topic, type_name, msg, time.time_ns()) else 0

    def run(self) -> None:
        """Serve until :meth:`stop`."""
        next_refresh = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_refresh:
                try:
                    self.refresh()
                except Exception as exc:  # noqa: BLE001 - a bad registry entry must not stop the view
                    self.sink.error(f"cannot read the registry: {type(exc).__name__}: {exc}")
                next_refresh = time.monotonic() + REGISTRY_PERIOD_S
            self.step(100)

    def start(self) -> "LiveView":
        self._thread = threading.Thread(target=self.run, name="foxglove", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close sockets and server; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        for subs in self._subs.values():
            for sock in subs.sockets:
                sock.close(linger=0)
        self._subs.clear()
        if self.server is not None:
            self.server.stop()
            self.server = None
