"""The ``tether`` command line: launch, run, check, graph, record, replay, topic, node, import, log, export."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
import uuid
from typing import Any, Sequence

from tether.errors import ConfigError, TetherError
from tether.runner import LOG_FORMAT

log = logging.getLogger("tether")


class _Progress:
    """One status line: rewritten in place on a terminal, every few seconds otherwise."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.tty = sys.stderr.isatty()
        self.period_s = period_s if self.tty else max(period_s, 5.0)
        self._last = 0.0

    def __call__(self, text: str, *, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < self.period_s:
            return
        self._last = now
        sys.stderr.write(f"\r{text}\033[K" if self.tty else f"{text}\n")
        sys.stderr.flush()

    def done(self) -> None:
        if self.tty:
            sys.stderr.write("\n")


def _params(items: Sequence[str] | None) -> dict[str, Any]:
    from tether.launch import parse_value

    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--param {item!r}: expected KEY=VALUE")
        out[key] = parse_value(value)
    return out


def _pairs(items: Sequence[str] | None, flag: str) -> dict[str, str]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise ConfigError(f"{flag} {item!r}: expected NAME=TOPIC")
        out[key] = value
    return out


# -- launch / check / graph / run -------------------------------------------------------
def cmd_launch(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, parse_overrides
    from tether.supervisor import Supervisor

    launch = load_launch(args.file, parse_overrides(args.param))
    sup = Supervisor(launch, machine=args.machine, record=args.record, keys=args.keys)
    names = ", ".join(c.id for c in sup.children)
    log.info("launching %s (%s)%s", launch.name, names, f" for {args.duration:g} s" if args.duration else "")
    return sup.run(args.duration)


def cmd_check(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, parse_overrides

    for path in args.files:
        launch = load_launch(path, parse_overrides(args.param))
        unconnected = [f"{n.id}.{name}" for n in launch.nodes for name in n.ports.inputs
                       if name not in n.inputs and name not in n.ports.timers]
        print(f"{path}: ok ({len(launch.nodes)} nodes, {len(launch.edges())} connections"
              + (f"; unconnected inputs: {', '.join(unconnected)}" if unconnected else "") + ")")
    return 0


def cmd_graph(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, to_dot, to_text

    launch = load_launch(args.file)
    print(to_dot(launch) if args.format == "dot" else to_text(launch))
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from tether import registry
    from tether.runner import load_node_class
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    cls = load_node_class(args.node)
    node_id = args.id or cls.__name__.lower()
    inputs = {}
    for name, topic in _pairs(args.input, "--input").items():
        if topic.startswith("timer/"):
            from tether.launch import timer_period_ns
            inputs[name] = Source(timer_ns=timer_period_ns(topic))
        else:
            inputs[name] = Source(topic=topic, endpoint=registry.find_topic(topic).endpoint)
    endpoint = ipc_endpoint("run", node_id, uuid.uuid4().hex[:8])
    spec = RunSpec(graph=f"run-{node_id}", node_id=node_id, node=args.node, params=_params(args.param),
                   binds=[endpoint], inputs=inputs)
    runtime = NodeRuntime(spec, cls)
    topics = {f"{node_id}/{o}": {"type": t.type_name(), "endpoint": endpoint} for o, t in runtime.node.ports.outputs.items()}
    topics[f"{node_id}/_stats"] = {"type": "std.NodeStats", "endpoint": endpoint}
    entry = registry.register({"name": f"run-{node_id}", "machine": "", "topics": topics,
                               "nodes": {node_id: {"class": args.node, "pid": 0}}})
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: runtime.stop())
    if args.duration:
        timer = threading.Timer(args.duration, runtime.stop)
        timer.daemon = True          # a node stopped by a signal must not wait out its duration
        timer.start()
    try:
        return runtime.serve()
    finally:
        registry.unregister(entry)


# -- record / replay ------------------------------------------------------------------------
def cmd_record(args: argparse.Namespace) -> int:
    import json

    from tether import registry
    from tether.record import Recorder
    from tether.transport import CurveKeys

    available = registry.topics()
    wanted = args.topics or [t for t in available if not t.endswith("/_stats")]
    missing = [t for t in wanted if t not in available]
    if missing or not wanted:
        raise TetherError(f"not published by any running graph: {', '.join(missing) or '(no topics at all)'}")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    curves = {json.dumps(available[t].curve, sort_keys=True) for t in wanted if available[t].curve}
    if len(curves) > 1:
        raise TetherError("the topics belong to graphs with different CurveZMQ keys: record them separately")
    curve = CurveKeys.from_json(json.loads(curves.pop())) if curves else None
    rec = Recorder(args.output, {t: available[t].endpoint for t in wanted}, curve=curve,
                   secure={t for t in wanted if available[t].curve}).start()
    progress = _Progress()
    rec.run_until(stop, args.duration, lambda text: progress(text, force=True))
    progress.done()
    print(f"recorded {rec.count} messages ({rec.bytes / 1e6:.1f} MB) on {len(wanted)} topics to {args.output}"
          + (f"; {rec.errors} malformed dropped" if rec.errors else ""))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from tether.log import LogReader
    from tether.replay import Window, play, replay_into

    window = Window(args.start, args.end, args.topics, args.rate, args.loop)
    if args.into:
        from tether.runner import load_node_class

        if not args.record:
            raise ConfigError("--into needs --record OUT (where the node's outputs go)")
        if args.loop:
            raise ConfigError("--loop does not apply to --into (a node is run once over the log)")
        progress = _Progress()
        n = replay_into(args.file, load_node_class(args.into), _pairs(args.map, "--map"), args.record,
                        params=_params(args.param), window=window, lockstep=args.lockstep,
                        progress=lambda k, total: progress(f"replay {k}/{total} messages"))
        progress.done()
        print(f"fed {n} messages into {args.into}; outputs in {args.record}")
        return 0
    return _replay_publish(args, window, LogReader(args.file), play)


def _replay_publish(args: argparse.Namespace, window: Any, reader: Any, play: Any) -> int:
    import zmq

    from tether import registry
    from tether.transport import ipc_endpoint

    info = reader.info()
    topics = {t: tp for t, tp in info.topics.items() if not args.topics or t in args.topics}
    endpoint = ipc_endpoint("replay", "log", uuid.uuid4().hex[:8])
    sock = zmq.Context.instance().socket(zmq.PUB)
    sock.sndhwm = 10000
    sock.bind(endpoint)
    entry = registry.register({"name": f"replay-{reader.path.stem}", "machine": "", "nodes": {},
                               "topics": {t: {"type": tp, "endpoint": endpoint} for t, tp in topics.items()}})
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    total = sum(info.counts.get(t, 0) for t in topics)
    progress = _Progress()
    try:
        stop.wait(args.delay)   # subscribers that attach within this time miss nothing
        n = play(reader, sock, window, stop,
                 lambda k, rec: progress(f"replay {k}/{total}  t={(rec.log_time_ns - info.start_ns) / 1e9:7.2f} s"))
    finally:
        registry.unregister(entry)
        sock.close(linger=1000)
    progress.done()
    print(f"replayed {n} messages from {args.file}")
    return 0


# -- topic / node ---------------------------------------------------------------------------
def _subscribe(topic: str) -> Any:
    import zmq

    from tether import registry
    from tether.transport import make_sub

    from tether.transport import CurveKeys, connect_sub

    info = registry.find_topic(topic)
    sock = make_sub(zmq.Context.instance())
    sock.rcvhwm = 100000
    connect_sub(sock, info.endpoint, CurveKeys.from_json(info.curve) if info.curve else None)
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


def _echo(args: argparse.Namespace) -> int:
    import msgpack

    from tether.codec import Codec
    from tether.message import message_type

    info, sock = _subscribe(args.topic)
    codec, tp = Codec(), message_type(info.type_name)
    shown = 0
    while args.count is None or shown < args.count:
        frames = sock.recv_multipart(copy=False)
        if frames[0].bytes != args.topic.encode():
            continue
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
    """hz/bw from the publisher's seq and stamps, so a slow terminal never under-reports."""
    import msgspec

    class Head(msgspec.Struct):
        stamp_ns: int = 0
        seq: int = 0

    head_decoder = msgspec.msgpack.Decoder(Head)
    info, sock = _subscribe(args.topic)
    samples: list[tuple[float, int, int, int]] = []   # (receive time, stamp, seq, bytes)
    t_end = time.monotonic() + args.duration if args.duration else None
    next_report = time.monotonic() + 1.0
    while t_end is None or time.monotonic() < t_end:
        if sock.poll(200):
            frames = sock.recv_multipart(copy=False)
            if frames[0].bytes == args.topic.encode():
                h = head_decoder.decode(frames[1].buffer)
                samples.append((time.monotonic(), h.stamp_ns, h.seq, sum(len(f.buffer) for f in frames)))
        now = time.monotonic()
        if now >= next_report:
            next_report = now + 1.0
            samples = [s for s in samples if now - s[0] <= args.window]
            print(_rate_line(args.action, samples), flush=True)
    return 0


def _rate_line(action: str, samples: list[tuple[float, int, int, int]]) -> str:
    if len(samples) < 2:
        return "no messages yet"
    (_, s0, q0, _), (_, s1, q1, _) = samples[0], samples[-1]
    published = q1 - q0
    span_s = (s1 - s0) / 1e9
    rate = published / span_s if span_s > 0 and published > 0 else float("nan")
    seen = len(samples) - 1
    size = sum(s[3] for s in samples) / len(samples)
    lost = f", {published - seen} not seen here" if published > seen else ""
    if action == "hz":
        return f"rate {rate:9.2f} Hz  (from stamps and seq over {len(samples)} msgs{lost})"
    return f"bw {rate * size / 1e6:9.2f} MB/s  mean {size / 1e3:.1f} kB x {rate:.2f} Hz"


def cmd_node(args: argparse.Namespace) -> int:
    from tether import registry

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
    from msgs.std import NodeStats

    _, sock = _subscribe(f"{args.id}/_stats")
    if not sock.poll(3000):
        raise TetherError(f"node {args.id!r} published no statistics within 3 s")
    frames = sock.recv_multipart(copy=False)
    st = Codec().decode(NodeStats, frames[1:])
    print(f"{st.node_id}  [{st.node_class}]  pid {st.pid}  up {st.uptime_s:.1f} s  errors {st.errors}")
    for i in st.inputs:
        print(f"  <- {i.name:12s} {i.topic:28s} recv {i.received:8d} handled {i.handled:8d} "
              f"gap-drops {i.dropped_seq_gap:6d} queue-drops {i.dropped_queue:6d} decode-err {i.decode_errors:4d} "
              f"handler-err {i.handler_errors:4d} {i.handler_ms_mean:7.3f} ms mean {i.handler_ms_max:7.2f} ms max")
    for out, n in sorted(st.published.items()):
        print(f"  -> {out:12s} published {n:8d}  subscribers {st.subscribers.get(f'{st.node_id}/{out}', 0)}")
    return 0


# -- logs -----------------------------------------------------------------------------------
def cmd_log(args: argparse.Namespace) -> int:
    from tether.log import LogReader

    info = LogReader(args.file).info()
    print(f"{info.path}: {sum(info.counts.values())} messages, {info.duration_s:.2f} s"
          + ("  (recovered: the file was not closed cleanly)" if info.recovered else ""))
    for topic in sorted(info.topics):
        print(f"  {topic:40s} {info.topics[topic]:28s} {info.counts.get(topic, 0):8d}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from tether.imports import IMPORTERS

    n = IMPORTERS[args.kind](args.file, args.output, topic=args.topic)
    print(f"imported {n} messages from {args.file} into {args.output}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from tether.export import export_foxglove

    n = export_foxglove(args.file, args.output)
    print(f"exported {n} messages to {args.output} (json channels, viewable in Foxglove)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="tether", description="ROS-free robotics middleware")
    ap.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("launch", help="run a pipeline file")
    p.add_argument("file")
    p.add_argument("--duration", type=float, help="stop after S seconds")
    p.add_argument("--param", action="append", metavar="NODE.KEY=VALUE", help="override a node parameter")
    p.add_argument("--record", metavar="FILE", help="record every topic to an MCAP log")
    p.add_argument("--machine", help="start only this machine's nodes")
    p.add_argument("--keys", help="CurveZMQ key file of the graph (default ~/.config/tether/keys/NAME.json)")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("check", help="validate pipeline files without starting anything")
    p.add_argument("files", nargs="+")
    p.add_argument("--param", action="append", metavar="NODE.KEY=VALUE")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("graph", help="print a pipeline's graph (text or Graphviz dot)")
    p.add_argument("file")
    p.add_argument("--format", choices=("text", "dot"), default="text")
    p.set_defaults(func=cmd_graph)

    p = sub.add_parser("run", help="run one node alone")
    p.add_argument("node", metavar="MODULE:Class")
    p.add_argument("--id")
    p.add_argument("--param", action="append", metavar="KEY=VALUE")
    p.add_argument("--input", action="append", metavar="NAME=TOPIC", help="connect an input to a running topic or timer/hz/N")
    p.add_argument("--duration", type=float)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("record", help="record running topics to an MCAP log")
    p.add_argument("topics", nargs="*")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--duration", type=float)
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("replay", help="publish a log, or run a node on it (--into)")
    p.add_argument("file")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (0 = as fast as possible)")
    p.add_argument("--start", type=float, default=0.0, help="seconds from the log's start")
    p.add_argument("--end", type=float, help="seconds from the log's start")
    p.add_argument("--loop", action="store_true")
    p.add_argument("--topics", nargs="+")
    p.add_argument("--delay", type=float, default=0.5, help="seconds to let subscribers attach before playing")
    p.add_argument("--into", metavar="MODULE:Class", help="run this node on the log")
    p.add_argument("--map", action="append", metavar="INPUT=TOPIC")
    p.add_argument("--param", action="append", metavar="KEY=VALUE")
    p.add_argument("--record", metavar="OUT", help="with --into: where the node's outputs go")
    p.add_argument("--lockstep", action="store_true", help="with --into: deterministic, as fast as the node goes")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("topic", help="list / echo / hz / bw")
    p.add_argument("action", choices=("list", "echo", "hz", "bw"))
    p.add_argument("topic", nargs="?")
    p.add_argument("-n", "--count", type=int, help="echo: stop after N messages")
    p.add_argument("--raw", action="store_true", help="echo: plain msgpack")
    p.add_argument("--all", action="store_true", help="list: include _stats topics")
    p.add_argument("--window", type=float, default=5.0, help="hz/bw: seconds averaged")
    p.add_argument("--duration", type=float, help="hz/bw: stop after S seconds")
    p.set_defaults(func=cmd_topic)

    p = sub.add_parser("node", help="list running nodes / show one node's counters")
    p.add_argument("action", choices=("list", "info"))
    p.add_argument("id", nargs="?")
    p.set_defaults(func=cmd_node)

    p = sub.add_parser("log", help="what a log holds")
    p.add_argument("file")
    p.set_defaults(func=cmd_log)

    p = sub.add_parser("import", help="convert a foreign log (oculus, candump) to a tether log")
    p.add_argument("kind", choices=("oculus", "candump"))
    p.add_argument("file")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--topic", help="topic to write (default sonar/ping or can/frame)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("export", help="export a log for other tools")
    p.add_argument("format", choices=("foxglove",))
    p.add_argument("file")
    p.add_argument("-o", "--output", required=True)
    p.set_defaults(func=cmd_export)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.INFO, format=LOG_FORMAT)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (TetherError, FileNotFoundError, KeyError, ValueError) as exc:
        if args.debug:
            raise
        text = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"tether: error: {text}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
