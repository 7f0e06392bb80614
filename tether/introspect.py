"""Introspection of running graphs: ``tether topic list/echo/hz/bw`` and ``tether node list/info``."""
from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from tether.errors import ConfigError, TetherError

WAIT_NOTICE_S = 3.0          # topic echo/hz/bw: how long a silent topic waits before it is said to be silent


def subscribe(topic: str) -> Any:
    """``(TopicInfo, SUB socket)`` for a topic of a running graph (found in the registry)."""
    import zmq

    from tether import registry
    from tether.transport import make_sub

    from tether.transport import connect_sub

    info = registry.find_topic(topic)
    sock = make_sub(zmq.Context.instance())
    sock.rcvhwm = 100000
    connect_sub(sock, info.endpoint, *info.client_keys())
    sock.subscribe(topic.encode())
    return info, sock


def _describe(value: Any, indent: str = "") -> str:
    import numpy as np
    import msgspec

    if isinstance(value, np.ndarray):
        preview = np.array2string(value.reshape(-1)[:6], precision=4, separator=", ")
        return f"<array {value.dtype} {'x'.join(map(str, value.shape)) or 'scalar'} {preview}{'...' if value.size > 6 else ''}>"
    if isinstance(value, msgspec.Struct):
        lines = [f"{type(value).__name__}"]
        for name in value.__struct_fields__:
            lines.append(f"{indent}  {name}: {_describe(getattr(value, name), indent + '  ')}")
        return "\n".join(lines)
    if isinstance(value, (bytes, bytearray)):
        return f"<{len(value)} bytes {bytes(value[:16]).hex()}{'...' if len(value) > 16 else ''}>"
    return repr(value)


def cmd_topic(args: argparse.Namespace) -> int:
    from tether import registry

    if args.action == "list":
        if args.topic:                       # 'tether topic list a/b' listed every topic, as if filtered
            raise ConfigError(f"tether topic list takes no TOPIC (got {args.topic!r}); 'tether topic echo "
                              f"{args.topic}' shows one")
        found = registry.topics()
        if not found:
            print("no graph is running")
        for topic, info in sorted(found.items()):
            if args.all or not topic.endswith("/_stats"):
                print(f"{topic:40s} {info.type_name:28s} {info.graph}")
        return 0
    if not args.topic:
        raise ConfigError(f"tether topic {args.action} needs a TOPIC")
    if args.action == "echo":
        return _echo(args)
    return _rate(args)


class _Silence:
    """A subscriber's watch over a silent topic: says once, after :data:`WAIT_NOTICE_S`, that
    nothing came yet, and sees (every :data:`WAIT_NOTICE_S` of silence) whether the graph
    publishing it has stopped, so that echo, hz and bw do not wait for ever on a dead topic."""

    def __init__(self, topic: str, info: Any) -> None:
        self.topic, self.info = topic, info
        self.heard = False
        self._told = False
        self._next = time.monotonic() + WAIT_NOTICE_S

    def quiet(self) -> bool:
        """Called when a poll found nothing: False once the topic's graph has stopped (said on stderr)."""
        from tether import registry

        if time.monotonic() < self._next:
            return True
        self._next = time.monotonic() + WAIT_NOTICE_S
        if self.topic not in registry.topics():
            print(f"tether: error: {self.topic}: its graph {self.info.graph!r} stopped", file=sys.stderr)
            return False
        if not self.heard and not self._told:
            print(f"tether: waiting for {self.topic} ({self.info.type_name}, graph {self.info.graph!r}): nothing "
                  "published yet (Ctrl-C to stop)", file=sys.stderr, flush=True)
            self._told = True
        return True


def _echo(args: argparse.Namespace) -> int:
    import msgpack

    from tether.codec import Codec
    from tether.message import message_type

    info, sock = subscribe(args.topic)
    codec, tp = Codec(), message_type(info.type_name)
    shown, silence = 0, _Silence(args.topic, info)
    t_end = time.monotonic() + args.duration if args.duration else None
    while args.count is None or shown < args.count:
        if t_end is not None and time.monotonic() >= t_end:
            break
        if not sock.poll(200):
            if not silence.quiet():
                return 1
            continue
        frames = sock.recv_multipart(copy=False)
        if frames[0].bytes != args.topic.encode():
            continue
        silence.heard = True
        if args.raw:
            print(msgpack.unpackb(frames[1].bytes, raw=False, strict_map_key=False))
        else:
            try:
                print(_describe(codec.decode(tp, frames[1:])))
            except TetherError as exc:
                print(f"<undecodable: {exc}>")
        print("---", flush=True)
        shown += 1
    return 0


def _rate(args: argparse.Namespace) -> int:
    """hz/bw from the publisher's seq and stamps, so a slow terminal never under-reports.

    A report line each second once a message has come (before, a silent topic is said to be
    waited for, once); ends when the topic's graph stops (exit 1) or after ``--duration``."""
    import msgspec

    class Head(msgspec.Struct):
        stamp_ns: int = 0
        seq: int = 0

    head_decoder = msgspec.msgpack.Decoder(Head)
    info, sock = subscribe(args.topic)
    silence = _Silence(args.topic, info)
    samples: list[tuple[float, int, int, int]] = []   # (receive time, stamp, seq, bytes)
    received = 0
    t_end = time.monotonic() + args.duration if args.duration else None
    next_report = time.monotonic() + 1.0
    while t_end is None or time.monotonic() < t_end:
        if sock.poll(200):
            frames = sock.recv_multipart(copy=False)
            if frames[0].bytes == args.topic.encode():
                h = head_decoder.decode(frames[1].buffer)
                samples.append((time.monotonic(), h.stamp_ns, h.seq, sum(len(f.buffer) for f in frames)))
                received += 1
                silence.heard = True
        elif not silence.quiet():
            return 1
        now = time.monotonic()
        if now >= next_report:
            next_report = now + 1.0
            samples = [s for s in samples if now - s[0] <= args.window][-args.window_msgs:] if args.window_msgs \
                else [s for s in samples if now - s[0] <= args.window]
            if silence.heard:
                print(rate_line(args.action, samples, window_s=args.window, received=received), flush=True)
    return 0


def rate_line(action: str, samples: list[tuple[float, int, int, int]], *, window_s: float | None = None,
              received: int = 0) -> str:
    """One report line from (arrival s, stamp ns, seq, bytes) samples (those of the last ``window_s``
    seconds; ``received``: how many came since the start).

    ``hz`` gives both rates, labelled: arrival (what ``ros2 topic hz`` shows: when messages
    reached this terminal, with the period's min / max / std) and stamps (what the publisher
    produced, from its stamps and seq, so a slow terminal never under-reports it).
    """
    if len(samples) < 2:
        if not received:
            return "no messages yet"
        # --window 0.001 on a 50 Hz topic said 'no messages yet' every second while messages came
        return (f"{len(samples)} message(s) in the last {window_s:g} s of {received} received: a rate needs 2; "
                "give a --window longer than the topic's period")
    (a0, s0, q0, _), (a1, s1, q1, _) = samples[0], samples[-1]
    published = q1 - q0
    span_s = (s1 - s0) / 1e9
    rate = published / span_s if span_s > 0 and published > 0 else float("nan")
    seen = len(samples) - 1
    size = sum(s[3] for s in samples) / len(samples)
    if action == "hz":
        periods = [b[0] - a[0] for a, b in zip(samples, samples[1:])]
        arrival = seen / (a1 - a0) if a1 > a0 else float("nan")
        mean = sum(periods) / len(periods)
        std = (sum((p - mean) ** 2 for p in periods) / len(periods)) ** 0.5
        lost = f"; {published - seen} published but not seen here" if published > seen else ""
        return (f"rate (arrival) {arrival:9.2f} Hz  min {min(periods) * 1e3:.1f} ms max {max(periods) * 1e3:.1f} ms "
                f"std {std * 1e3:.1f} ms  |  rate (stamps) {rate:9.2f} Hz  window {len(samples)} msgs{lost}")
    # a 100-byte topic at 50 Hz read 'bw 0.00 MB/s  mean 0.1 kB': the unit follows the size
    return f"bw {_bytes(rate * size, '/s', 9)}  mean {_bytes(size)} x {rate:.2f} Hz"


def _bytes(n: float, per: str = "", width: int = 0) -> str:
    """``5100.0`` -> ``'5.10 kB'``: B, kB or MB (decimal), two decimals."""
    scale, unit = next(((s, u) for s, u in ((1e6, "MB"), (1e3, "kB")) if abs(n) >= s), (1.0, "B"))
    return f"{n / scale:{width}.2f} {unit}{per}"


def cmd_node(args: argparse.Namespace) -> int:
    from tether import registry

    if args.action == "list" and args.id:          # 'tether node list counter' listed every node
        raise ConfigError(f"tether node list takes no ID (got {args.id!r}); 'tether node info {args.id}' shows one")
    graphs = registry.running()
    if args.action == "list":
        for g in graphs:
            for node_id, n in g.get("nodes", {}).items():
                print(f"{node_id:20s} {n.get('class', ''):50s} pid {n.get('pid', 0):<8d} graph {g['name']}")
        if not graphs:
            print("no graph is running")
        return 0
    if not args.id:
        raise ConfigError("tether node info needs a node ID")
    from tether.codec import Codec
    from tether.stats import NodeStats

    wait_s = float(getattr(args, "wait", 3.0))
    if not wait_s > 0:
        raise ConfigError(f"tether node info --wait must be > 0 s (got {wait_s}): statistics come once a second")
    _, sock = subscribe(f"{args.id}/_stats")
    if not sock.poll(int(wait_s * 1000)):
        raise TetherError(f"node {args.id!r} published no statistics within {wait_s:g} s (is it running? a busy "
                          f"machine may need a longer --wait)")
    frames = sock.recv_multipart(copy=False)
    st = Codec().decode(NodeStats, frames[1:])
    print(f"{st.node_id}  [{st.node_class}]  pid {st.pid}  up {st.uptime_s:.1f} s  errors {st.errors}  "
          f"restarts {st.restarts}" + (f"  stats-errors {st.stats_errors}" if st.stats_errors else ""))
    for i in st.inputs:
        print(f"  <- {i.name:12s} {i.topic:28s} recv {i.received:8d} handled {i.handled:8d} "
              f"gap-drops {i.dropped_seq_gap:6d} queue-drops {i.dropped_queue:6d} decode-err {i.decode_errors:4d} "
              f"handler-err {i.handler_errors:4d} {i.handler_ms_mean:7.3f} ms mean {i.handler_ms_max:7.2f} ms max"
              + (f" {i.received_bytes / 1e6:9.3f} MB in" if i.received_bytes else "")
              + (f" link-drops {i.dropped_link}" if i.dropped_link else ""))
        if st.restarts or i.dropped_restart or i.seq_resets or i.link_resets:
            print(f"     {'':12s} lost while this node restarted {i.dropped_restart}  publisher seq resets "
                  f"{i.seq_resets}  connections redialled {i.link_resets}")
    for out, n in sorted(st.published.items()):
        sent = st.published_bytes.get(out, 0)
        print(f"  -> {out:12s} published {n:8d}  subscribers {st.subscribers.get(f'{st.node_id}/{out}', 0)}"
              + (f"  {sent / 1e6:.3f} MB sent" if sent else ""))
    if st.shm_placed or st.shm_fallbacks or st.shm_oversize or st.shm_stale:
        print(f"  shared memory: placed {st.shm_placed} (loaned, no copy: {st.shm_loaned})  fallbacks to frames "
              f"{st.shm_fallbacks} (pool busy) + {st.shm_oversize} (oversize)  stale tables {st.shm_stale}")
    if st.rt_priority:
        print(f"  scheduling: SCHED_FIFO priority {st.rt_priority}")
    return 0

