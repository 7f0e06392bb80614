"""The ``tether`` command line: launch, run, check, graph, record, replay, topic, node, import, log, export, foxglove."""
from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
import time
import uuid
from glob import escape as glob_escape
from pathlib import Path
from typing import Any, Sequence

from tether.errors import ConfigError, TetherError
from tether.paths import check_writable, not_regular
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
    from tether.launch import parse_assignments

    return parse_assignments(list(items or []), "--param")


def _pairs(items: Sequence[str] | None, flag: str) -> dict[str, str]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise ConfigError(f"{flag} {item!r}: expected NAME=TOPIC")
        if key in out:
            raise ConfigError(f"{flag} {key} is given twice")
        out[key] = value
    return out


def _regular_input(path: str, what: str) -> None:
    """Refuse an input that is not a regular file before opening it: a FIFO without a writer blocks
    the open for ever, /dev/zero is read for ever (as :class:`tether.log.LogReader` refuses them)."""
    kind = not_regular(path)
    if kind:
        raise ConfigError(f"{path}: {kind}, not {what}")


def _check_output(output: str | None, *inputs: str, flag: str = "-o", log: bool = False,
                  overwrite: bool = False, split: bool = False) -> None:
    """Before any work: refuse an output that cannot be written (:func:`tether.paths.check_writable`:
    found at the end of the work otherwise), or that is one of the inputs (opening it for writing
    would empty the input first). ``log``: the output is an MCAP log; an existing file that is not
    one (a launch file, an image: a mistyped -o) is never written over, an existing log only with
    ``overwrite`` (--overwrite; as ``ros2 bag record`` refuses an existing output). ``split``: the
    recording may go on into ``OUT_1.mcap``, ``OUT_2.mcap``, ...: an existing one is refused too."""
    if not output:
        return
    check_writable(output, flag)
    at = f"{flag} {output}" if flag else output
    if log and split and not overwrite:
        path = Path(output)
        old = sorted(path.parent.glob(f"{glob_escape(path.stem)}_[0-9]*{glob_escape(path.suffix)}"))
        if old:
            raise ConfigError(f"{at}: the recording would go on into {old[0].name}, which exists (an older "
                              "recording's part); --overwrite to replace it, or give another name")
    if not Path(output).is_file():
        return
    for src in inputs:
        if Path(src).exists() and Path(output).samefile(src):
            raise ConfigError(f"{at} is the input {src}: writing it would destroy the input; give another output file")
    if log and Path(output).stat().st_size:
        from tether.logcheck import MAGIC

        with open(output, "rb") as fh:
            if not MAGIC.startswith(fh.read(len(MAGIC))):       # a shorter head: a log cut early
                raise ConfigError(f"{at}: an existing file that is not an MCAP log; writing the log would destroy "
                                  "it (remove it first, or give another name)")
        if not overwrite:
            raise ConfigError(f"{at}: a log exists there ({Path(output).stat().st_size / 1e6:.1f} MB); "
                              f"--overwrite to replace it, or give a new name (e.g. {_fresh_name(output)})")


def _fresh_name(output: str) -> str:
    """``run.mcap`` -> ``run-2.mcap`` (or the first of -3, -4, ... that does not exist)."""
    path = Path(output)
    k = 2
    while path.with_name(f"{path.stem}-{k}{path.suffix}").exists():
        k += 1
    return str(path.with_name(f"{path.stem}-{k}{path.suffix}"))


# -- launch / check / graph / run -------------------------------------------------------
def cmd_launch(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, parse_launch_args, parse_overrides
    from tether.supervisor import Supervisor

    if not args.record:                  # they were ignored: the run went unrecorded
        given = [flag for flag, value in (("--record-topics", args.record_topics), ("--record-exclude",
                 args.record_exclude), ("--record-max-size", args.record_max_size),
                 ("--record-max-duration", args.record_max_duration), ("--overwrite", args.overwrite)) if value]
        if given:
            raise ConfigError(f"{', '.join(given)} without --record FILE: nothing would be recorded")
    launch = load_launch(args.file, parse_overrides(args.param), args=parse_launch_args(args.arg))
    _check_output(args.record, args.file, flag="--record", log=True, overwrite=args.overwrite,   # not over the launch file
                  split=bool(args.record_max_size or args.record_max_duration))
    if args.keys and not launch.machines:     # ignored: a graph on one machine talks over ipc, without keys
        raise ConfigError(f"{args.file}: --keys {args.keys}: the file declares no machines (keys secure the "
                          "links between machines)")
    sup = Supervisor(launch, machine=args.machine, record=args.record,
                     record_topics=_flat(args.record_topics), record_exclude=_flat(args.record_exclude), keys=args.keys,
                     record_max_bytes=args.record_max_size or 0, record_max_duration_s=args.record_max_duration or 0.0)
    for warning in launch.warnings:
        log.warning("%s", warning)
    from tether import registry

    registry.check_free([f"{c.id}/{out}" for c in sup.children for out in [*launch.node(c.id).ports.outputs, "_stats"]],
                        f"graph {launch.name!r}")
    names = ", ".join(c.id for c in sup.children)
    log.info("launching %s (%s)%s", launch.name, names, f" for {args.duration:g} s" if args.duration else "")
    return sup.run(args.duration)


def cmd_check(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, parse_launch_args, parse_overrides

    files: list[str] = []
    for item in args.files:
        if Path(item).is_dir():
            found = sorted(str(f) for f in Path(item).glob("*.yaml"))
            if not found:
                raise ConfigError(f"{item}: a directory with no .yaml launch file in it")
            files += found
        else:
            files.append(item)
    warned, failed = 0, 0
    overrides, launch_args = parse_overrides(args.param), parse_launch_args(args.arg)
    for path in files:
        try:
            launch = load_launch(path, overrides, args=launch_args)
        except ConfigError as exc:            # one line per bad file: the others are still checked
            if len(files) == 1:
                raise
            print(f"tether: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        for warning in launch.warnings:
            print(f"tether: warning: {warning}", file=sys.stderr)
        warned += len(launch.warnings)
        unconnected = [f"{n.id}.{name}" for n in launch.nodes for name in n.ports.inputs
                       if name not in n.inputs and name not in n.ports.timers]
        print(f"{path}: ok ({len(launch.nodes)} nodes, {len(launch.edges())} connections"
              + (f"; unconnected inputs: {', '.join(unconnected)}" if unconnected else "")
              + (f"; {len(launch.warnings)} warning(s)" if launch.warnings else "") + ")")
    if failed:
        print(f"tether: error: {failed} of {len(files)} files failed", file=sys.stderr)
        return 2
    if warned and args.strict:
        print(f"tether: error: {warned} warning(s) with --strict", file=sys.stderr)
        return 1
    return 0


def cmd_graph(args: argparse.Namespace) -> int:
    from tether.launch import load_launch, parse_launch_args, to_dot, to_text

    launch = load_launch(args.file, args=parse_launch_args(args.arg))
    print(to_dot(launch) if args.format == "dot" else to_text(launch))
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from tether import registry
    from tether.runner import load_node_class
    from tether.runtime import NodeRuntime, RunSpec, Source
    from tether.transport import ipc_endpoint

    from tether.launch import NODE_ID_RE
    from tether.node import Tick

    cls = load_node_class(args.node)
    node_id = cls.__name__.lower() if args.id is None else args.id
    if not NODE_ID_RE.match(node_id):
        raise ConfigError(f"--id {node_id!r}: an id starts with a letter and uses letters, digits, '-' or '_'")
    try:
        ports = cls.resolve_ports(cls.make_config(_params(args.param)))
    except TetherError:
        raise
    except Exception as exc:  # noqa: BLE001 - a Config or port declaration saying what is wrong (as tether check)
        raise ConfigError(f"{args.node}: params: {type(exc).__name__}: {exc}") from exc
    inputs = {}
    for name, topic in _pairs(args.input, "--input").items():
        if name not in ports.inputs:
            raise ConfigError(f"--input {name}={topic}: {args.node} has no input {name!r} "
                              f"(inputs: {', '.join(sorted(ports.inputs)) or 'none'})")
        want = ports.inputs[name].type.type_name()
        if topic.startswith("timer/"):
            from tether.launch import timer_period_ns
            if ports.inputs[name].type is not Tick:
                raise ConfigError(f"--input {name}={topic}: input {name!r} takes {want}, not a timer")
            inputs[name] = Source(timer_ns=timer_period_ns(topic))
        else:
            found = registry.find_topic(topic)
            if found.type_name != want:
                raise ConfigError(f"--input {name}={topic}: input {name!r} takes {want} but {topic} "
                                  f"publishes {found.type_name}")
            inputs[name] = Source(topic=topic, endpoint=found.endpoint)
    registry.check_free([f"{node_id}/{o}" for o in [*ports.outputs, "_stats"]], f"--id {node_id}")
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
    from tether import registry
    from tether.record import Recorder

    import fnmatch

    _check_output(args.output, log=True, overwrite=args.overwrite, split=bool(args.max_size or args.max_duration))
    available = registry.topics()
    wanted = args.topics or [t for t in available if not t.endswith("/_stats")]
    missing = [t for t in wanted if t not in available]
    if missing or not wanted:
        raise TetherError(f"not published by any running graph: {', '.join(missing) or '(no topics at all)'}")
    include, exclude = _flat(args.include), _flat(args.exclude)
    wanted = [t for t in wanted if (not include or any(fnmatch.fnmatchcase(t, p) for p in include))
              and not any(fnmatch.fnmatchcase(t, p) for p in exclude or [])]
    if not wanted:
        raise ConfigError(f"--include/--exclude leave no topic of: {', '.join(sorted(available))}")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    keys = {t: available[t].client_keys() for t in wanted if available[t].secure}
    stores = {(available[t].keystore, available[t].machine) for t in keys}
    if len(stores) > 1:
        raise TetherError("the topics belong to graphs with different CurveZMQ keystores: record them separately")
    curve = next(iter(keys.values()))[0] if keys else None
    rec = Recorder(args.output, {t: available[t].endpoint for t in wanted}, curve=curve,
                   secure={t: server_key for t, (_, server_key) in keys.items()},
                   max_bytes=args.max_size or 0, max_duration_s=args.max_duration or 0.0).start()
    progress = _Progress()
    rec.run_until(stop, args.duration, lambda text: progress(text, force=True))
    progress.done()
    if rec.failed:
        raise TetherError(f"recording stopped: {rec.failed}; {rec.count} messages written to {args.output} "
                          f"stay readable")
    files = ", ".join(str(p) for p in rec.segments) if len(rec.segments) > 1 else str(args.output)
    print(f"recorded {rec.count} messages ({rec.bytes / 1e6:.1f} MB) on {len(wanted)} topics to {files}"
          + (f"; {rec.errors} malformed dropped" if rec.errors else ""))
    return _nothing_done(rec.count, args, f"nothing was received on {', '.join(wanted)}")


def cmd_replay(args: argparse.Namespace) -> int:
    from tether.log import LogReader
    from tether.replay import Window, play, replay_into

    window = Window(args.start, args.end, args.topics, args.rate, args.loop)
    ignored = [flag for flag, value in (("--record", args.record), ("--map", args.map), ("--param", args.param),
                                        ("--lockstep", args.lockstep), ("--overwrite", args.overwrite)) if value]
    if ignored and not args.into:        # they were ignored: the log was published, nothing recorded
        raise ConfigError(f"{', '.join(ignored)} without --into MODULE:Class: they apply to a node run on the log")
    if args.into:
        from tether.runner import load_node_class

        if not args.record:
            raise ConfigError("--into needs --record OUT (where the node's outputs go)")
        if args.loop:
            raise ConfigError("--loop does not apply to --into (a node is run once over the log)")
        _check_output(args.record, args.file, flag="--record", log=True, overwrite=args.overwrite)
        progress = _Progress()
        reader = LogReader(args.file)
        n = replay_into(reader, load_node_class(args.into), _pairs(args.map, "--map"), args.record,
                        params=_params(args.param), window=window, lockstep=args.lockstep,
                        progress=lambda k, total: progress(f"replay {k}/{total} messages"))
        progress.done()
        print(f"fed {n} messages into {args.into}; outputs in {args.record}")
        return _damaged([reader], args, f"{args.into} was fed and {args.record} written") or _nothing_done(
            n, args, f"no message of {args.file} reached {args.into}: check --map, --topics, --start/--end")
    return _replay_publish(args, window, LogReader(args.file), play)


def _wait_subscribers(sock: Any, topics: Any, n: int, timeout_s: float, stop: threading.Event) -> int:
    """Read an XPUB's subscriptions until ``n`` cover every topic, or for ``timeout_s``; the least count.

    A subscription covers a topic it is a prefix of (a recorder of everything subscribes to
    ``""``); Tether's own markers (``@shm/``, ``@dual/``) stand beside a plain subscription and
    are not counted."""
    counts = {t.encode(): 0 for t in topics}
    deadline = time.monotonic() + timeout_s
    while counts and min(counts.values()) < n and not stop.is_set():
        left = deadline - time.monotonic()
        if left <= 0:
            break
        if not sock.poll(min(left, 0.1) * 1000):
            continue
        event = sock.recv()
        if event[:1] not in (b"\x00", b"\x01") or event[1:2] == b"@":
            continue
        change = 1 if event[0] == 1 else -1
        for topic in counts:
            if topic.startswith(event[1:]):
                counts[topic] += change
    return min(counts.values()) if counts else n


def _nothing_done(count: int, args: argparse.Namespace, why: str) -> int:
    """Zero work is not success: one warning and exit 1, unless --allow-empty."""
    if count > 0 or getattr(args, "allow_empty", False):
        return 0
    print(f"tether: warning: {why} (--allow-empty to accept)", file=sys.stderr)
    return 1


def _damaged(readers: Sequence[Any], args: argparse.Namespace, done: str = "") -> int:
    """An output written from damaged inputs lacks their messages: one error line and exit 1, unless --skip-bad.
    Read after the readers' last pass (their ``damaged`` chunks and ``truncated_at``); ``done`` says what
    went without them (default: ``-o OUT was written``)."""
    damage = [f"{r.path}: " + ", ".join(
        ([f"{len(r.damaged)} damaged chunk(s)"] if r.damaged else [])
        + ([f"unreadable from byte {r.truncated_at}"] if r.truncated_at >= 0 else []))
        for r in readers if r.damaged or r.truncated_at >= 0]
    if not damage or args.skip_bad:
        return 0
    print(f"tether: error: {'; '.join(damage)}: {done or f'{args.output} was written'} without their messages "
          "(--skip-bad to accept)", file=sys.stderr)
    return 1


class _PassDamage:
    """The damage a replay met: a reader's ``damaged``/``truncated_at`` describe its last pass only,
    and with --loop the last pass may have been stopped before the damaged chunk."""

    def __init__(self, reader: Any) -> None:
        self.reader = reader
        self.full: Any = None

    def keep(self) -> None:
        """After each complete pass (every pass of a window meets the same chunks)."""
        r = self.reader
        self.full = argparse.Namespace(path=r.path, damaged=list(r.damaged), truncated_at=r.truncated_at)

    def worst(self) -> Any:
        return self.full if self.full is not None else self.reader


def _replay_publish(args: argparse.Namespace, window: Any, reader: Any, play: Any) -> int:
    import zmq

    from tether import registry
    from tether.transport import ipc_endpoint

    from tether.replay import select_topics

    info = reader.info()
    topics = {t: info.topics[t] for t in select_topics(info.topics, args.topics)}
    endpoint = ipc_endpoint("replay", "log", uuid.uuid4().hex[:8])
    if args.wait_subscribers < 0:
        raise ConfigError(f"--wait-subscribers {args.wait_subscribers}: give a count >= 0")
    sock = zmq.Context.instance().socket(zmq.XPUB if args.wait_subscribers else zmq.PUB)
    sock.sndhwm = 10000
    if args.wait_subscribers:
        sock.xpub_verbose = True      # every subscriber's subscription, not only a topic's first
    sock.bind(endpoint)
    entry = registry.register({"name": f"replay-{reader.path.stem}", "machine": "", "nodes": {},
                               "topics": {t: {"type": tp, "endpoint": endpoint} for t, tp in topics.items()}})
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    total = sum(info.counts.get(t, 0) for t in topics)
    progress = _Progress()
    try:
        if args.wait_subscribers:
            delay = 30.0 if args.delay is None else args.delay
            least = _wait_subscribers(sock, topics, args.wait_subscribers, delay, stop)
            if least < args.wait_subscribers and not stop.is_set():
                print(f"tether: warning: {least} of {args.wait_subscribers} subscribers on every topic after "
                      f"{delay:g} s: playing anyway", file=sys.stderr)
        else:
            stop.wait(0.5 if args.delay is None else args.delay)   # who attaches within this time misses nothing
        def show(k: int, rec: Any) -> None:
            lap = f"loop {(k - 1) // total + 1}, " if args.loop and total else ""
            shown = (k - 1) % total + 1 if args.loop and total else k
            progress(f"replay {lap}{shown}/{total}  t={(rec.log_time_ns - info.start_ns) / 1e9:7.2f} s")

        damage = _PassDamage(reader)
        n = play(reader, sock, window, stop, show, on_pass=damage.keep)
    finally:
        registry.unregister(entry)
        sock.close(linger=1000)
        Path(endpoint[len("ipc://"):]).unlink(missing_ok=True)      # ZeroMQ leaves the file behind
    progress.done()
    print(f"replayed {n} messages from {args.file}")
    return _damaged([damage.worst()], args, "replayed") or _nothing_done(n, args, f"nothing replayed from {args.file}: its topics are {sorted(info.topics)}, "
                                  f"{(info.end_ns - info.start_ns) / 1e9:.1f} s long")


# -- topic / node (tether/introspect.py) ------------------------------------------------------
def cmd_topic(args: argparse.Namespace) -> int:
    from tether.introspect import cmd_topic as run

    return run(args)


def cmd_node(args: argparse.Namespace) -> int:
    from tether.introspect import cmd_node as run

    return run(args)


# -- logs -----------------------------------------------------------------------------------
def cmd_log(args: argparse.Namespace) -> int:
    from tether.log import LogReader, recover_log
    from tether.logcheck import LogCheck, chunk_refs

    if args.file in ("cut", "merge"):
        return _log_cut_merge(args)
    if args.more:
        raise ConfigError(f"tether log takes one log (or 'cut IN' / 'merge IN ...'), got {args.more}")
    if args.overwrite and not args.output:
        raise ConfigError("--overwrite without -o OUT (with --recover, cut or merge): nothing would be written")
    if args.recover:
        if not args.output:
            raise ConfigError("tether log --recover IN needs -o OUT")
        _check_output(args.output, args.file, log=True, overwrite=args.overwrite)
        written, damaged, lost = recover_log(args.file, args.output)
        print(f"recovered {written} messages from {args.file} into {args.output}; {len(damaged)} damaged chunk(s)"
              + (f", {lost} messages lost" if lost >= 0 else " (the source had no statistics: losses unknown)"))
        return 0 if written else 1
    reader = LogReader(args.file)
    size = Path(args.file).stat().st_size
    compression = ", ".join(sorted({c.compression or "none" for c in reader._summary.chunk_indexes})) \
        if reader._summary is not None and reader._summary.chunk_indexes else "unknown (no summary)"
    recovered = "  (recovered: the file was not closed cleanly)" if reader.recovered else ""
    if args.no_check:
        info = reader.info()
        print(f"{info.path}: {sum(info.counts.values())} messages, {info.duration_s:.2f} s, {size / 1e6:.2f} MB, "
              f"compression {compression}{recovered}")
        for topic in sorted(info.topics):
            print(f"  {topic:40s} {info.topics[topic]:28s} {info.counts.get(topic, 0):8d}")
        return 0
    # One pass reads (and CRC-checks) every chunk: the per-topic figures and the damage both come from it.
    stats: dict[str, list] = {}                    # topic -> [type, count, bytes, first log ns, last log ns]
    for rec in reader.messages():
        row = stats.setdefault(rec.topic, [rec.type_name, 0, 0, rec.log_time_ns, rec.log_time_ns])
        row[1] += 1
        row[2] += len(rec.data)
        row[4] = rec.log_time_ns
    start = min((r[3] for r in stats.values()), default=0)
    end = max((r[4] for r in stats.values()), default=0)
    if reader._summary is not None:                 # channels without a message are listed too (cheap: the summary)
        for topic, type_name in reader.info().topics.items():
            stats.setdefault(topic, [type_name, 0, 0, start, start])
    print(f"{reader.path}: {sum(r[1] for r in stats.values())} messages, {(end - start) / 1e9:.2f} s, "
          f"{size / 1e6:.2f} MB, compression {compression}{recovered}")
    print(f"  {'topic':36s} {'type':24s} {'count':>8s} {'rate Hz':>9s} {'MB':>9s} {'first s':>9s} {'last s':>9s}")
    for topic in sorted(stats):
        type_name, count, nbytes, first, last = stats[topic]
        rate = (count - 1) / ((last - first) / 1e9) if count > 1 and last > first else 0.0
        print(f"  {topic:36s} {type_name:24s} {count:8d} {rate:9.2f} {nbytes / 1e6:9.3f} "
              f"{(first - start) / 1e9:9.2f} {(last - start) / 1e9:9.2f}")
    with open(args.file, "rb") as fh:               # where the chunks are (the index, or a walk): no decompression
        refs, indexed, truncated_at = chunk_refs(fh)
    check = LogCheck(str(args.file), chunks=len(refs), damaged=reader.damaged, indexed=indexed,
                     truncated_at=truncated_at)
    for bad in check.damaged:
        print(f"  DAMAGED {bad.describe()}")
    if check.truncated_at >= 0:
        print(f"  DAMAGED: unreadable from byte {check.truncated_at} on")
    if not check.ok:
        print(f"{args.file}: {len(check.damaged)} of {check.chunks} chunks damaged; "
              f"'tether log --recover {args.file} -o OUT' keeps the rest")
        return 1
    print(f"  {check.chunks} chunks, CRCs ok")
    return 0


def _log_cut_merge(args: argparse.Namespace) -> int:
    """``tether log cut IN -o OUT [--start S] [--end S] [--topics ...]`` and ``tether log merge IN ... -o OUT``."""
    import heapq

    from tether.log import LogReader, LogWriter
    from tether.replay import Window, records, select_topics

    if not args.output or not args.more:
        raise ConfigError(f"tether log {args.file} needs the input log(s) and -o OUT")
    if args.file == "cut" and len(args.more) != 1:
        raise ConfigError("tether log cut takes one input log")
    for k, path in enumerate(args.more):       # a glob overlapping a name: every message written twice
        twin = next((other for other in args.more[:k] if Path(other).exists() and Path(path).exists()
                     and Path(other).samefile(path)), None)
        if twin is not None:
            raise ConfigError(f"{path} is given twice" + (f" (as {twin})" if twin != path else "")
                              + ": each message would be written twice")
    _check_output(args.output, *args.more, log=True, overwrite=args.overwrite)
    readers = [LogReader(path) for path in args.more]
    types: dict[str, str] = {}
    for reader in readers:
        for topic, type_name in reader.info().topics.items():
            if types.setdefault(topic, type_name) != type_name:
                raise ConfigError(f"topic {topic} is {types[topic]} in one log and {type_name} in another: "
                                  "they cannot share a channel")
    if args.file == "cut":
        info = readers[0].info()
        window = Window(args.start, args.end, select_topics(info.topics, args.topics) if args.topics else None)
        streams = [records(readers[0], window)]
    else:
        streams = [reader.messages() for reader in readers]
    written = 0
    with LogWriter(args.output, metadata={f"{args.file}_of": " ".join(args.more)}) as writer:
        for rec in heapq.merge(*streams, key=lambda r: r.log_time_ns):
            writer.write_encoded(rec.topic, rec.type_name, rec.data, log_time_ns=rec.log_time_ns,
                                 publish_time_ns=rec.publish_time_ns, sequence=rec.sequence)
            written += 1
    print(f"wrote {written} messages to {args.output}")
    return _damaged(readers, args) or _nothing_done(written, args, f"the {args.file} selected no message")


def _name(text: str) -> str:
    """A machine's name: not empty (--machine '' was taken as no --machine: every node started)."""
    if not text:
        raise argparse.ArgumentTypeError("'': give a machine name from the launch file")
    return text


def _path(text: str) -> str:
    """A file or folder named on the command line: not empty (Path('') is the current folder)."""
    if not text:
        raise argparse.ArgumentTypeError("'': give a path")
    return text


def _topic(text: str) -> str:
    """A topic to write: NODE/OUTPUT as a graph's (an import with --topic '' wrote a log no graph could name)."""
    from tether.launch import TOPIC_RE

    if not TOPIC_RE.match(text):
        raise argparse.ArgumentTypeError(f"{text!r}: a topic is NODE/OUTPUT, e.g. sonar/ping (letters, digits, "
                                         "'-' or '_')")
    return text


def _patterns(text: str) -> list[str]:
    """``'a/*,b/c'`` -> ['a/*', 'b/c'] (an option value that cannot swallow the next argument)."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"{text!r}: give topic names or patterns, comma-separated")
    return items


def _flat(groups: list[list[str]] | None) -> list[str] | None:
    return [t for group in groups for t in group] if groups else None


def _size(text: str) -> int:
    """``65536``, ``64K``, ``64M``, ``1G`` -> bytes."""
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
    scale = units.get(text[-1:].upper(), 1)
    try:
        value = int(float(text[:-1] if scale > 1 else text) * scale)
    except (ValueError, OverflowError):              # int(float('inf')) overflows
        raise argparse.ArgumentTypeError(f"{text!r} is not a size like 65536, 64K or 64M") from None
    if not 1 <= value <= 1 << 40:
        raise argparse.ArgumentTypeError(f"{text!r}: a size between 1 B and 1 TiB")
    return value


#: the longest time an option takes (about 31 years): 1e308 s overflowed timers, time_t and
#: nanosecond log times (OverflowError tracebacks from run --duration, replay --start/--delay)
MAX_SECONDS = 1e9


def _number(text: str, *, low: float = -math.inf, strict: bool = False, high: float = math.inf,
            what: str = "a finite number") -> float:
    """An option's number: finite (argparse's float takes 'nan' and 'inf'), above ``low``, at most ``high``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value < low or (strict and value == low) or value > high:
        raise argparse.ArgumentTypeError(f"{text!r}: give {what}")
    return value


def _finite(text: str) -> float:
    return _number(text)


def _seconds(text: str) -> float:
    """A duration or window: seconds in (0, MAX_SECONDS]."""
    return _number(text, low=0.0, strict=True, high=MAX_SECONDS, what=f"a number of seconds > 0 (at most {MAX_SECONDS:g})")


def _offset(text: str) -> float:
    """A time from a log's start, or a delay: seconds in [0, MAX_SECONDS]."""
    return _number(text, low=0.0, high=MAX_SECONDS, what=f"a number of seconds >= 0 (at most {MAX_SECONDS:g})")


def _positive(text: str) -> float:
    return _number(text, low=0.0, strict=True, what="a number > 0")


def _at_least_zero(text: str) -> float:
    """A rate factor or a tolerance: >= 0."""
    return _number(text, low=0.0, what="a number >= 0")


def _whole(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"{text!r}: give a whole number >= {low}")
    return value


def _port(text: str) -> int:
    """A TCP port, 0 for a free one."""
    value = _whole(text, 0)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: a port is at most 65535")
    return value


def _board(text: str) -> tuple[int, int]:
    """``9x6`` -> (9, 6): a chessboard's inner corners, at least 3 each way (OpenCV's minimum)."""
    cols, sep, rows = text.lower().partition("x")
    if not (sep and cols.isdigit() and rows.isdigit() and int(cols) >= 3 and int(rows) >= 3):
        raise argparse.ArgumentTypeError(f"{text!r}: give the inner corners as COLSxROWS, each at least 3 (e.g. 9x6)")
    return int(cols), int(rows)


def _positive_int(text: str) -> int:
    """A count of messages, states, iterations, episodes, instances: >= 1."""
    return _whole(text, 1)


def _seed(text: str) -> int:
    """A seed: a whole number in [0, 2**32) (gymnasium refuses a negative one, numpy a huge one)."""
    value = _whole(text, 0)
    if value >= 1 << 32:
        raise argparse.ArgumentTypeError(f"{text!r}: a seed is below 2**32")
    return value


def _rate_window(text: str) -> int:
    """hz/bw -w N: 0 (off) or at least 2 messages (a rate needs two; -w 1 said 'no messages yet' for ever)."""
    value = _whole(text, 0)
    if value == 1:
        raise argparse.ArgumentTypeError("'1': a rate needs at least 2 messages (0: average over --window seconds)")
    return value


def _natural(text: str) -> int:
    """A count that may be 0 (0: off, or none)."""
    return _whole(text, 0)


def cmd_import(args: argparse.Namespace) -> int:
    from tether.imports import importer

    run = importer(args.kind)
    _regular_input(args.file, "a log file")
    _check_output(args.output, args.file, log=True, overwrite=args.overwrite)
    try:
        result = run(args.file, args.output, topic=args.topic, max_bytes=args.max_bytes, skip_bad=args.skip_bad)
    except OSError as exc:                  # unreadable input, unwritable output: one line, not a traceback
        raise ConfigError(f"{exc.filename or args.file}: {exc.strerror or exc}") from None
    print(result.summary(args.file, args.output))
    if result.imported == 0:
        Path(args.output).unlink(missing_ok=True)
        print(f"tether: error: nothing could be imported from {args.file}; no log written", file=sys.stderr)
        return 1
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from tether.export import export_foxglove
    from tether.log import LogReader

    _check_output(args.output, args.file, log=True, overwrite=args.overwrite)
    progress = _Progress()
    reader = LogReader(args.file)
    n = export_foxglove(reader, args.output, lambda k, total: progress(f"export {k}/{total} messages"))
    progress.done()
    print(f"exported {n.converted} messages to {args.output} as {n.logged} Foxglove messages (images, clouds, "
          f"poses, grids in Foxglove's schemas; the rest JSON)" + (f"; {n.errors} dropped" if n.errors else ""))
    return _damaged([reader], args) or _nothing_done(n.converted, args, f"nothing exported from {args.file}")


def cmd_foxglove(args: argparse.Namespace) -> int:
    from tether.foxglove_bridge import LiveView

    view = LiveView(host=args.host, port=args.port, patterns=_flat(args.include) or (),
                    exclude=_flat(args.exclude) or ()).start()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"serving running graphs to Foxglove at ws://{args.host}:{view.port} (Open connection -> Foxglove "
          f"WebSocket, or open {view.server.app_url()}); Ctrl-C stops", flush=True)
    progress = _Progress()
    t_end = time.monotonic() + args.duration if args.duration else None
    while not stop.wait(1.0) and (t_end is None or time.monotonic() < t_end):
        n = view.sink.counters
        progress(f"foxglove: {len(view.sink.topics)} channels, {n.converted} messages, {n.skipped} sampled out, "
                 f"{n.errors} dropped")
    view.stop()
    progress.done()
    return 0


def cmd_verify(args: argparse.Namespace) -> int:
    from nodes.verify.graph_model import default_properties, focus_of, spec_from_launch, verify_spec
    from nodes.verify.kripke import StateBoundExceeded
    from tether.launch import load_launch

    if args.focus and not args.ctl:           # it was ignored: the default properties choose their own topics
        raise ConfigError("--focus applies to --ctl formulas (the default properties track every subscribed topic)")
    spec = spec_from_launch(load_launch(args.file))
    checks = ([(args.focus if args.focus else focus_of(spec, f), f) for f in args.ctl] if args.ctl
              else default_properties(spec))
    try:
        results = verify_spec(spec, checks, faults=args.faults, max_states=args.max_states)
    except StateBoundExceeded as exc:
        print(f"tether: verify stopped: {exc} (explored {exc.explored} states)", file=sys.stderr)
        return 3
    failed = [r for r in results if not r.holds]
    for r in results:
        if not r.holds or args.ctl or args.verbose:
            print(r.explain())
    print(f"{args.file}: {len(results) - len(failed)} of {len(results)} properties hold "
          f"(faults per node: {args.faults}; {max(r.states for r in results)} states at most, "
          f"{sum(r.seconds for r in results) * 1e3:.0f} ms)")
    return 1 if failed else 0


#: the widest robust kernel slam optimize takes, in Mahalanobis units (gnc: its gate, a squared
#: error): 1e308 overflowed width**2 (Cauchy stopped at the start with a NaN cost, exit 0)
MAX_KERNEL_WIDTH = {"huber": 1e6, "cauchy": 1e6, "gnc": 1e12}


def cmd_slam_optimize(args: argparse.Namespace) -> int:
    from nodes.slam.graph_io import read_graph, write_graph
    from nodes.slam.pose_graph import GraphError, check_graph, chi2, optimize

    _check_output(args.output, args.file)
    if args.kernel_width is not None:
        if not args.robust:                   # it was ignored: plain least squares
            raise ConfigError("--kernel-width applies to a --robust kernel (huber, cauchy or gnc)")
        most = MAX_KERNEL_WIDTH[args.robust]
        if args.kernel_width > most:          # width**2 overflowed: a numpy warning and a NaN cost, exit 0
            raise ConfigError(f"--kernel-width {args.kernel_width:g}: a {args.robust} "
                              + ("chi2 gate" if args.robust == "gnc" else "width") + f" is at most {most:g} "
                              "(a kernel wider than every error is plain least squares: leave out --robust)")
    try:
        graph = read_graph(args.file)
        found = check_graph(graph)
        print(f"{args.file}: {graph.n} poses, {len(graph.edges)} edges"
              + (f", {found.duplicates} duplicate edges (kept)" if found.duplicates else ""))

        def progress(iteration: int, cost: float, lam: float) -> None:
            print(f"  iteration {iteration:3d}  cost {cost:.6g}  lambda {lam:.2g}", file=sys.stderr, flush=True)

        result = optimize(graph, initial=args.initial, method=args.method, robust=args.robust,
                          kernel_width=args.kernel_width, anchor=args.anchor, max_iterations=args.max_iterations,
                          rel_tol=args.rel_tol, progress=progress)
    except GraphError as exc:
        raise ConfigError(str(exc)) from None
    print(f"chi2 {result.chi2_initial:.6f} -> {result.chi2:.6f} (g2o convention; GTSAM's: "
          f"{chi2(graph, result.poses, convention='gtsam'):.6f}), {result.iterations} iterations, "
          f"{result.time_s:.3f} s CPU, {result.message}")
    if args.robust == "gnc":
        print(f"rejected {len(result.outliers)} edges: "
              + ", ".join(f"{graph.ids[graph.edges[k, 0]]}->{graph.ids[graph.edges[k, 1]]}" for k in result.outliers[:20]))
    if args.output:
        write_graph(args.output, graph, result.poses)
        print(f"wrote {args.output}")
    return 0 if result.converged else 1


def cmd_selfcal(args: argparse.Namespace) -> int:
    """A camera's intrinsics from its images alone (Kruppa / rotation / planar self-calibration)."""
    import json

    import numpy as np

    from nodes.vision.selfcal_images import calibrate_chessboard, calibrate_images, read_images

    for path in args.images:
        _regular_input(path, "an image")
    images = read_images(sorted(args.images))
    if args.chessboard:
        cols, rows = args.chessboard
        cal, extra = calibrate_chessboard(images, (cols, rows), distortion=not args.no_distortion)
    else:
        pp = tuple(args.principal_point) if args.principal_point else None
        cal, pairs = calibrate_images(images, features=args.features, gap=args.gap, principal_point=pp)
        extra = {"pairs": pairs}
    K, s = cal.K, cal.sigma_px
    out = {"fx_px": K[0, 0], "fy_px": K[1, 1], "cx_px": K[0, 2], "cy_px": K[1, 2], "fx_sigma_px": s[0],
           "fy_sigma_px": s[1], "cx_sigma_px": s[2], "cy_sigma_px": s[3], "method": cal.method,
           "degenerate": cal.degenerate, "reasons": cal.reasons, "images": len(images), **extra}
    if args.json:
        print(json.dumps({k: (float(v) if isinstance(v, np.floating) else v) for k, v in out.items()}, default=str))
    else:
        print(f"{len(images)} images, {cal.method}: fx {K[0, 0]:.1f} +- {s[0]:.1f}, fy {K[1, 1]:.1f} +- {s[1]:.1f}, "
              f"cx {K[0, 2]:.1f} +- {s[2]:.1f}, cy {K[1, 2]:.1f} +- {s[3]:.1f} px")
        for r in cal.reasons:
            print(f"  {r}")
        if cal.degenerate:
            print("DEGENERATE: these numbers are not determined by the images")
    return 2 if cal.degenerate else 0


def _learn_params(items: list[str] | None) -> dict[str, Any]:
    from tether.launch import parse_value

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--param {item!r}: give KEY=VALUE")
        out[key] = parse_value(value)
    return out


_POSITIVE = ("a value > 0", lambda v: v > 0)
_AT_LEAST_0 = ("a value >= 0", lambda v: v >= 0)
_FRACTION = ("a value in [0, 1]", lambda v: 0 <= v <= 1)
#: PPO settings' ranges (what PPO itself would take without complaint but cannot learn with:
#: lr=-1 climbs the loss, gamma=2 discounts nothing away, n_steps=0 divides by zero)
PPO_RANGES: dict[str, tuple[str, Any]] = {
    "n_steps": _POSITIVE, "epochs": _POSITIVE, "minibatches": _POSITIVE, "clip": _POSITIVE, "lr": _POSITIVE,
    "max_grad_norm": _POSITIVE, "obs_clip": _POSITIVE, "gamma": _FRACTION, "gae_lambda": _FRACTION,
    "ent_coef": _AT_LEAST_0, "vf_coef": _AT_LEAST_0, "target_kl": ("a value >= 0 (0: off)", lambda v: v >= 0),
    "squash": ("'clip' or 'tanh'", lambda v: v in ("clip", "tanh")),
    # [100000, 100000] asked JAX for 40 GB and died in a traceback
    "hidden": ("1 to 8 layer widths, each at most 4096", lambda v: len(v) <= 8 and max(v) <= 4096),
}


def _ppo_config(items: list[str] | None) -> Any:
    """``--ppo KEY=VALUE`` settings checked against PPOConfig's field types and :data:`PPO_RANGES`."""
    import dataclasses

    from nodes.learn.ppo import PPOConfig

    fields = {f.name: f.type for f in dataclasses.fields(PPOConfig)}
    overrides = _learn_params(items)
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ConfigError(f"unknown PPO setting(s) {unknown}; known: {', '.join(fields)}")
    for key, value in overrides.items():      # PPOConfig does not check: 'lr=abc' trained with lr 'abc'
        kind = fields[key] if isinstance(fields[key], str) else getattr(fields[key], "__name__", "")
        if kind == "float" and isinstance(value, str):     # YAML 1.1 reads 1e-3 (no dot) as text
            try:
                value = overrides[key] = float(value)
            except ValueError:
                pass
        number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        ok = {"int": isinstance(value, int) and number, "float": number, "bool": isinstance(value, bool),
              "str": isinstance(value, str)}.get(kind, isinstance(value, list) and all(
                  isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value) and bool(value))
        if not ok:
            want = {"int": "a whole number", "float": "a finite number", "bool": "true or false", "str": "text"}
            raise ConfigError(f"--ppo {key}={value!r}: give {want.get(kind, 'a list of layer widths like [64, 64]')}")
        if key in PPO_RANGES and not PPO_RANGES[key][1](value):
            raise ConfigError(f"--ppo {key}={value!r}: give {PPO_RANGES[key][0]}")
    if "hidden" in overrides:
        overrides["hidden"] = tuple(overrides["hidden"])
    return PPOConfig(**overrides)


def cmd_learn(args: argparse.Namespace) -> int:
    """Train, evaluate, export or replay PPO policies on Tether simulators (``nodes.learn``)."""
    from nodes.learn.bus_env import replay_log
    from nodes.learn.ppo import PPO
    from nodes.learn.train import evaluate, export, report_json, train

    logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)   # "no TPU" is not news on a CPU

    if args.learn_cmd == "train":
        _check_output(args.out)                  # with --resume, -o is read and written again: allowed
        if args.resume:
            _regular_input(args.out, "a checkpoint")
        elif Path(args.out).is_file() and not args.overwrite:     # the first checkpoint replaced an older training
            raise ConfigError(f"-o {args.out}: a checkpoint exists there; --resume to go on training it, --overwrite "
                              f"to start over, or give a new name")
        config = _ppo_config(args.ppo)
        rollout = config.n_steps * args.n_envs     # PPO updates on whole rollouts: fewer steps train nothing
        if args.steps < rollout:
            raise ConfigError(f"--steps {args.steps:g} is less than one PPO rollout (n_steps {config.n_steps} x "
                              f"--n-envs {args.n_envs} = {rollout} env steps): give --steps {rollout} or more, "
                              "or a smaller --n-envs / --ppo n_steps")
        agent = train(args.env, args.out, steps=int(args.steps), n_envs=args.n_envs, params=_learn_params(args.param),
                      config=config, seed=args.seed, mode=args.mode, shards=args.shards,
                      resume=args.resume, checkpoint_every=int(args.checkpoint_every), progress=print)
        short = (f": --steps {args.steps:g} rounded down to whole rollouts of {rollout}"
                 if agent.steps_done < args.steps else "")
        print(f"wrote {args.out} ({agent.steps_done} steps{short}) and {Path(args.out).with_suffix('.png')}")
        return 0
    if args.learn_cmd == "eval":
        if args.overwrite and not args.record:
            raise ConfigError("--overwrite without --record FILE: nothing would be written")
        _regular_input(args.checkpoint, "a checkpoint")
        _check_output(args.record, args.checkpoint, flag="--record", log=True, overwrite=args.overwrite)
        agent = PPO.load(args.checkpoint)
        report = evaluate(agent, args.env, episodes=args.episodes, seed=args.seed, params=_learn_params(args.param),
                          record=args.record)
        print(report_json(report))
        return 0
    if args.learn_cmd == "export":
        _regular_input(args.checkpoint, "a checkpoint")
        _check_output(args.out, args.checkpoint, flag="")
        size = export(args.checkpoint, args.out)
        print(f"wrote {args.out} ({size} bytes: policy and normaliser, no optimiser state)")
        return 0
    result = replay_log(args.log)
    print(f"{args.log}: {result['replies']} replies from {result['instances']} instances replayed bit-identically")
    return 0


def cmd_doctor(args: argparse.Namespace) -> int:
    """Check the runtime directory and keystores; clean what crashed runs left (stale registry
    entries, ipc sockets nobody listens on, seq-state files of graphs no longer running)."""
    from tether import keystore, registry
    from tether.transport import check_private_dir, runtime_dir, sweep_stale_sockets

    problems = 0
    folder = runtime_dir()
    try:
        check_private_dir(folder)
        print(f"runtime directory {folder}: private (0700, yours)")
    except TetherError as exc:
        problems += 1
        print(f"runtime directory: PROBLEM: {exc}")
    entries = sorted((folder / "graphs").glob("*.json")) if (folder / "graphs").is_dir() else []
    live = registry.running()
    print(f"graphs running: {len(live)} ({', '.join(sorted(g['name'] for g in live)) or 'none'}); "
          f"stale registry entries removed: {len(entries) - len(live)}")
    print(f"stale ipc sockets removed: {sweep_stale_sockets()}")
    names = {g["name"] for g in live}
    stale_state = [f for f in (folder / "state").glob("*.seq") if f.name.split(".", 1)[0] not in names] \
        if (folder / "state").is_dir() else []
    for f in stale_state:
        f.unlink(missing_ok=True)
    print(f"seq-state files of stopped graphs removed: {len(stale_state)}")
    root = keystore.keys_root()
    stores = sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    for store in stores:
        for key in sorted(store.glob("*.key")):
            try:
                keystore.check_private(key)
            except TetherError as exc:
                problems += 1
                print(f"keystore {store.name}: UNSAFE: {exc}")
    print(f"keystores under {root}: {len(stores)}" + ("" if problems else "; every key file private"))
    return 1 if problems else 0


def cmd_keys(args: argparse.Namespace) -> int:
    from tether import keystore

    folder = keystore.keystore_dir(args.graph, args.keys)
    if args.action == "init":
        machines = (args.machines or "").split(",") if args.machines else []
        if "" in machines or len(set(machines)) < len(machines):    # 'a,,b' and 'a,a' were taken as 'a,b', 'a'
            raise ConfigError(f"--machines {args.machines!r}: give distinct names separated by single commas")
        created = keystore.init(folder, machines)
        print(f"keystore {folder}: created keys for {', '.join(created) or 'no new machine'}")
        print("copy peers.json to every machine's keystore, and <machine>.key to that machine only (mode 0600)")
        return 0
    if args.machines:                        # ignored: list shows every machine of the keystore
        raise ConfigError("--machines applies to 'tether keys init' (list shows every machine)")
    if not (folder / keystore.PEERS).exists():
        raise ConfigError(f"no keystore for graph {args.graph!r} in {folder} ('tether keys init {args.graph} "
                          "--machines A,B' creates one; --keys FOLDER names another)")
    peers = keystore.read_peers(folder)
    for machine, public in sorted(peers.items()):
        path = folder / f"{machine}.key"
        if path.exists():
            try:
                keystore.check_private(path)
                state = "secret key here"
            except TetherError as exc:
                state = f"UNSAFE: {exc}"
        else:
            state = "public only"
        print(f"{machine:16s} {public}  {state}")
    return 0


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tether")
    except PackageNotFoundError:
        return "(not installed)"


EXAMPLES = {
    "launch": "tether launch launch/two_sonars.yaml --arg range_m=10 --duration 10 --record run.mcap",
    "keys": "tether keys init sonar-localize --machines boat,shore",
    "check": "tether check launch/",
    "graph": "tether graph launch/sonar_localize.yaml --format dot | dot -Tpng -o graph.png",
    "run": "tether run nodes.std.demo:Scale --input value=counter/value --param gain=3",
    "record": "tether record counter/value scale/value -o run.mcap --duration 10",
    "replay": "tether replay run.mcap --rate 2 --topics 'sonar/*'",
    "topic": "tether topic hz sonar/ping -w 50",
    "node": "tether node info imager",
    "log": "tether log cut run.mcap -o slice.mcap --start 10 --end 20 --topics 'sonar/*'",
    "import": "tether import oculus capture.oculus -o pings.mcap --max-bytes 32M --skip-bad",
    "export": "tether export foxglove run.mcap -o run-foxglove.mcap",
    "foxglove": "tether foxglove --port 8765 --exclude 'sim/*'",
    "doctor": "tether doctor",
    "slam": "tether slam optimize graph.g2o --initial chordal --robust gnc -o optimised.g2o",
    "selfcal": "tether selfcal ../shared/data/camera/opencv-chessboard-stereo/left*.jpg --chessboard 9x6",
    "learn": "tether learn train --env sim.car_env:ReachCar --param step_cost=0 --steps 2e6 -o out/learn/reach.ppo --resume",
}


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="tether", description="ROS-free robotics middleware")
    ap.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    ap.add_argument("--version", action="version", version=f"tether {_version()}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("launch", help="run a pipeline file",
                       description="Run a launch file: its nodes, and those of the files it includes (ids "
                                   "'NS.NODE', topics 'NS.NODE/OUTPUT'). --arg NAME=VALUE sets one of the file's "
                                   "'args' (used as $(arg NAME)); an arg the file does not declare is an error.")
    p.add_argument("file", type=_path, help="the launch file (YAML)")
    p.add_argument("--arg", action="append", metavar="NAME=VALUE",
                   help="set a launch argument declared under 'args' (repeatable; VALUE read as YAML: 20, true, text)")
    p.add_argument("--duration", type=_seconds, help="stop after S seconds")
    p.add_argument("--param", action="append", metavar="NODE.KEY=VALUE",
                   help="override a node parameter (a namespaced node: NS.NODE.KEY=VALUE)")
    p.add_argument("--record", metavar="FILE", type=_path, help="record the graph's topics to an MCAP log")
    p.add_argument("--record-topics", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="with --record: only these (e.g. 'sim/*,nav/pose'; repeatable)")
    p.add_argument("--record-exclude", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="with --record: not these (e.g. '*/rgbd'; repeatable)")
    p.add_argument("--record-max-size", type=_size, metavar="SIZE",
                   help="with --record: start a new file (RUN_1.mcap, ...) past SIZE, e.g. 500M")
    p.add_argument("--record-max-duration", type=_seconds, metavar="S", help="with --record: a new file every S seconds")
    p.add_argument("--overwrite", action="store_true", help="replace --record FILE (and its FILE_1.mcap, ... parts) when it is an existing log (refused without it)")
    p.add_argument("--machine", type=_name, help="start only this machine's nodes")
    p.add_argument("--keys", type=_path, help="CurveZMQ keystore folder of the graph (default ~/.config/tether/keys/NAME/; "
                               "see 'tether keys')")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("keys", help="create or list a graph's CurveZMQ keystore (one key pair per machine)")
    p.add_argument("action", choices=("init", "list"), help="init: create missing key pairs; list: show them")
    p.add_argument("graph", help="the graph's name (its launch file's 'name')")
    p.add_argument("--machines", help="with init: comma-separated machine names, e.g. boat,shore")
    p.add_argument("--keys", type=_path, help="keystore folder (default ~/.config/tether/keys/GRAPH/)")
    p.set_defaults(func=cmd_keys)

    p = sub.add_parser("check", help="validate pipeline files without starting anything")
    p.add_argument("files", nargs="+", type=_path, help="launch files, or directories of them")
    p.add_argument("--param", action="append", metavar="NODE.KEY=VALUE", help="check with this override")
    p.add_argument("--arg", action="append", metavar="NAME=VALUE", help="check with this launch argument")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 on a warning too (an input wired to its own node's output)")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("graph", help="print a pipeline's graph (text or Graphviz dot)")
    p.add_argument("file", type=_path, help="the launch file (YAML)")
    p.add_argument("--format", choices=("text", "dot"), default="text", help="text listing or Graphviz dot")
    p.add_argument("--arg", action="append", metavar="NAME=VALUE", help="a launch argument (see launch --help)")
    p.set_defaults(func=cmd_graph)

    p = sub.add_parser("run", help="run one node alone")
    p.add_argument("node", metavar="MODULE:Class", help="the node class, e.g. nodes.std.demo:Counter")
    p.add_argument("--id", help="its id (topics are ID/OUTPUT; default: the class name in lower case)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="a Config parameter (unknown keys are errors)")
    p.add_argument("--input", action="append", metavar="NAME=TOPIC", help="connect an input to a running topic or timer/hz/N")
    p.add_argument("--duration", type=_seconds, help="stop after S seconds")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("record", help="record running topics to an MCAP log")
    p.add_argument("topics", nargs="*", help="topics to record (default: every running topic but */_stats)")
    p.add_argument("-o", "--output", required=True, type=_path, help="the MCAP file to write")
    p.add_argument("--duration", type=_seconds, help="stop after S seconds")
    p.add_argument("--allow-empty", action="store_true", help="exit 0 even when nothing was received")
    p.add_argument("--include", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="only topics matching these globs (repeatable)")
    p.add_argument("--exclude", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="not topics matching these globs (repeatable)")
    p.add_argument("--max-size", type=_size, metavar="SIZE", help="start a new file (OUT_1.mcap, ...) past SIZE, e.g. 500M")
    p.add_argument("--max-duration", type=_seconds, metavar="S", help="start a new file every S seconds")
    p.add_argument("--overwrite", action="store_true", help="replace -o OUT (and its OUT_1.mcap, ... parts) when it is an existing log (refused without it)")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("replay", help="publish a log, or run a node on it (--into)")
    p.add_argument("file", type=_path, help="the MCAP log")
    p.add_argument("--rate", type=_at_least_zero, default=1.0, help="speed factor (0 = as fast as possible)")
    p.add_argument("--start", type=_offset, default=0.0, help="seconds from the log's start")
    p.add_argument("--end", type=_offset, help="seconds from the log's start")
    p.add_argument("--loop", action="store_true", help="start again at the end (publishing only)")
    p.add_argument("--topics", nargs="+", help="only these topics (names or globs like 'sonar/*')")
    p.add_argument("--delay", type=_offset, help="seconds to let subscribers attach before playing (0.5; "
                   "with --wait-subscribers the most it waits, 30)")
    p.add_argument("--wait-subscribers", type=int, default=0, metavar="N",
                   help="play once N subscribers take every replayed topic (or --delay has passed: a warning)")
    p.add_argument("--into", metavar="MODULE:Class", help="run this node on the log")
    p.add_argument("--map", action="append", metavar="INPUT=TOPIC", help="with --into: feed INPUT from TOPIC")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="with --into: a Config parameter")
    p.add_argument("--allow-empty", action="store_true", help="exit 0 even when nothing was replayed")
    p.add_argument("--skip-bad", action="store_true",
                   help="skip damaged chunks of the log and exit 0 (without it, the rest is replayed and the exit is 1)")
    p.add_argument("--record", metavar="OUT", type=_path, help="with --into: where the node's outputs go")
    p.add_argument("--lockstep", action="store_true", help="with --into: deterministic, as fast as the node goes")
    p.add_argument("--overwrite", action="store_true", help="replace --record OUT when it is an existing log (refused without it)")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("topic", help="list / echo / hz / bw")
    p.add_argument("action", choices=("list", "echo", "hz", "bw"), help="list topics, print messages, rate, bandwidth")
    p.add_argument("topic", nargs="?", help="the topic (not for list)")
    p.add_argument("-n", "--count", type=_positive_int, help="echo: stop after N messages")
    p.add_argument("--raw", action="store_true", help="echo: plain msgpack")
    p.add_argument("--all", action="store_true", help="list: include _stats topics")
    p.add_argument("--window", type=_seconds, default=5.0,
                   help="hz/bw: the last S seconds averaged (default 5; longer than the topic's period: a rate needs 2 messages)")
    p.add_argument("-w", "--window-msgs", type=_rate_window, default=0, metavar="N",
                   help="hz/bw: average over the last N messages instead (like ros2 topic hz -w)")
    p.add_argument("--duration", type=_seconds, help="stop after S seconds")
    p.set_defaults(func=cmd_topic)

    p = sub.add_parser("node", help="list running nodes / show one node's counters")
    p.add_argument("action", choices=("list", "info"), help="list running nodes, or one node's statistics")
    p.add_argument("id", nargs="?", help="with info: the node id")
    p.add_argument("--wait", type=_seconds, default=3.0, metavar="S",
                   help="with info: how long to wait for the node's next statistics (sent once a second; default 3)")
    p.set_defaults(func=cmd_node)

    p = sub.add_parser("log", help="what a log holds, whether every chunk is intact; cut and merge logs")
    p.add_argument("file", type=_path, help="the MCAP log; or 'cut' (then IN) or 'merge' (then IN ...)")
    p.add_argument("more", nargs="*", type=_path, help="with cut: the log to cut; with merge: the logs to merge")
    p.add_argument("--start", type=_offset, default=0.0, help="with cut: seconds from the log's start")
    p.add_argument("--end", type=_offset, help="with cut: seconds from the log's start")
    p.add_argument("--topics", nargs="+", help="with cut: only these topics (names or globs)")
    checks = p.add_mutually_exclusive_group()
    checks.add_argument("--check", action="store_true", help="verify every chunk's CRC (the default; exit 1 on damage)")
    checks.add_argument("--no-check", action="store_true", help="list only, do not read every chunk")
    p.add_argument("--recover", action="store_true", help="copy every readable message into -o OUT")
    p.add_argument("-o", "--output", type=_path, help="with --recover, cut or merge: the new log")
    p.add_argument("--skip-bad", action="store_true",
                   help="with cut or merge: skip damaged chunks of an input and exit 0 (without it, what is "
                        "readable is written and the exit is 1)")
    p.add_argument("--allow-empty", action="store_true", help="with cut or merge: exit 0 even when no message is written")
    p.add_argument("--overwrite", action="store_true", help="replace -o OUT when it is an existing log (refused without it)")
    p.set_defaults(func=cmd_log)

    p = sub.add_parser("import", help="convert a foreign log (oculus, candump, ...) to a tether log")
    p.add_argument("kind", help="the foreign format: an importer registered by entry point (tether.importers); "
                                "this project's: oculus, candump")
    p.add_argument("file", type=_path, help="the foreign log")
    p.add_argument("-o", "--output", required=True, type=_path, help="the tether MCAP log to write")
    p.add_argument("--topic", type=_topic, help="topic to write (default sonar/ping or can/frame)")
    p.add_argument("--max-bytes", type=_size, default=None,
                   help="the most one record may take once decompressed (e.g. 64M; default 64 MiB)")
    p.add_argument("--skip-bad", action="store_true",
                   help="skip bad records (counted; the first 20 logged) and import the rest; "
                        "without it the first bad record stops the import with one line naming it")
    p.add_argument("--overwrite", action="store_true", help="replace -o OUT when it is an existing log (refused without it)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("export", help="export a log for other tools")
    p.add_argument("format", choices=("foxglove",), help="the target tool")
    p.add_argument("file", type=_path, help="the tether MCAP log")
    p.add_argument("-o", "--output", required=True, type=_path, help="the MCAP file to write")
    p.add_argument("--allow-empty", action="store_true", help="exit 0 even when nothing was exported")
    p.add_argument("--skip-bad", action="store_true",
                   help="skip damaged chunks of the log and exit 0 (without it, the rest is exported and the exit is 1)")
    p.add_argument("--overwrite", action="store_true", help="replace -o OUT when it is an existing log (refused without it)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("foxglove", help="serve the running graphs live to Foxglove (WebSocket)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    p.add_argument("--port", type=_port, default=8765, help="WebSocket port (0: a free one)")
    p.add_argument("--include", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="only topics matching these globs (default: all but */_stats; repeatable)")
    p.add_argument("--exclude", action="append", type=_patterns, metavar="PATTERN[,PATTERN]",
                   help="not topics matching these globs (repeatable)")
    p.add_argument("--duration", type=_seconds, help="stop after S seconds")
    p.set_defaults(func=cmd_foxglove)

    p = sub.add_parser("doctor", help="check the runtime directory and keystores; clean what crashed runs left")
    p.set_defaults(func=cmd_doctor)

    p = sub.add_parser("verify", help="model-check a pipeline: messages handled or counted, deadlocks, wiring",
                       description="Builds a Kripke structure from the launch graph (one tracked message, queues, "
                                   "node crashes and restart policies) and checks CTL formulas with fairness. "
                                   "Without --ctl: every subscribed message is handled or counted as dropped, no "
                                   "deadlock, every input has a publisher.",
                       epilog="example: tether verify launch/counter.yaml --ctl "
                              "'AG (published -> AF (handled(scale.value) | counted(scale.value)))'")
    p.add_argument("file", type=_path, help="the launch file")
    p.add_argument("--ctl", action="append", help="a CTL formula (repeatable); propositions: up(NODE), dead(NODE), "
                                                  "published, settled, deadlock, queued/handled/dropped/lost/"
                                                  "counted/has_publisher(NODE.INPUT)")
    p.add_argument("--focus", help="the topic whose message is tracked (default: read from the formula)")
    p.add_argument("--faults", type=_natural, default=1, help="crashes per node the model allows (default 1; 0: none)")
    p.add_argument("--max-states", type=_positive_int, default=1_000_000, help="stop exploring past this many states")
    p.add_argument("-v", "--verbose", action="store_true", help="print every property, not only the failing ones")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("selfcal", help="a camera's intrinsics from its images alone (no calibration target)")
    p.add_argument("images", nargs="+", type=_path, help="images from one camera (sorted by name: the sequence order)")
    p.add_argument("--features", choices=("orb", "sift"), default="sift",
                   help="feature detector (default sift: about 10x more accurate than orb here; SURF is not in pip OpenCV)")
    p.add_argument("--gap", type=_positive_int, default=2, help="match each image with the next N (default 2)")
    p.add_argument("--principal-point", type=_finite, nargs=2, metavar=("CX", "CY"), help="fix the principal point")
    p.add_argument("--chessboard", type=_board, metavar="COLSxROWS", help="use a plane's corners (inner corners, e.g. 9x6) "
                   "as correspondences; its square size is not needed")
    p.add_argument("--no-distortion", action="store_true", help="with --chessboard: do not estimate lens distortion")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_selfcal)

    p = sub.add_parser("learn", help="train, evaluate, export and replay RL policies on Tether simulators")
    learn = p.add_subparsers(dest="learn_cmd", required=True)
    q = learn.add_parser("train", help="PPO on a bus environment (resumable; writes a learning curve PNG)")
    q.add_argument("--env", default="sim.car_env:ReachCar", help="the simulator, module:Class (a VecSim)")
    q.add_argument("--param", action="append", metavar="KEY=VALUE", help="a scenario parameter (repeatable)")
    q.add_argument("--ppo", action="append", metavar="KEY=VALUE", help="a PPO setting, e.g. lr=1e-3 (repeatable)")
    q.add_argument("--steps", type=_positive, default=1e6, help="env steps in all (all instances counted)")
    q.add_argument("--n-envs", type=_positive_int, default=16, help="simulator instances stepped together")
    q.add_argument("--mode", choices=("inproc", "ipc"), default="inproc", help="simulator in this process or in node processes")
    q.add_argument("--shards", type=_positive_int, default=1, help="with --mode ipc: node processes sharing the instances")
    q.add_argument("--seed", type=_seed, default=0, help="seed of the policy and of the first episodes")
    q.add_argument("--checkpoint-every", type=_positive, default=2e5, help="env steps between checkpoints")
    q.add_argument("--resume", action="store_true", help="continue from the checkpoint at -o when it exists")
    q.add_argument("--overwrite", action="store_true", help="start over, replacing the checkpoint at -o (refused without "
                                                             "it or --resume)")
    q.add_argument("-o", "--out", required=True, type=_path, help="checkpoint path (msgpack)")
    q = learn.add_parser("eval", help="one deterministic episode per seed; metrics at the episodes' end")
    q.add_argument("checkpoint", type=_path, help="a checkpoint of tether learn train (or export)")
    q.add_argument("--env", default="sim.car_env:ReachCar", help="the simulator, module:Class (a VecSim)")
    q.add_argument("--param", action="append", metavar="KEY=VALUE", help="a scenario parameter (repeatable)")
    q.add_argument("--episodes", type=_positive_int, default=100, help="episodes, run side by side")
    q.add_argument("--seed", type=_seed, default=10_000, help="first seed (episode i: seed + i)")
    q.add_argument("--record", metavar="FILE", type=_path, help="record the episodes to an MCAP log (tether learn replay FILE)")
    q.add_argument("--overwrite", action="store_true", help="replace --record FILE when it is an existing log (refused without it)")
    q = learn.add_parser("export", help="strip optimiser state and history: a policy to deploy")
    q.add_argument("checkpoint", type=_path, help="a checkpoint of tether learn train")
    q.add_argument("out", type=_path, help="where the policy goes")
    q = learn.add_parser("replay", help="re-run a recorded environment log and check it bit for bit")
    q.add_argument("log", type=_path, help="an MCAP log written by tether learn eval --record (or BusVecEnv(record=...))")
    p.set_defaults(func=cmd_learn)

    p = sub.add_parser("slam", help="pose-graph tools")
    slam = p.add_subparsers(dest="slam_cmd", required=True)
    q = slam.add_parser("optimize", help="optimise a g2o / TORO SE(2) pose graph")
    q.add_argument("file", type=_path, help="input graph (.g2o, or TORO .graph; the format is read from its tags)")
    q.add_argument("-o", "--output", type=_path, help="write the optimised graph here (.graph = TORO, else g2o)")
    q.add_argument("--initial", choices=("given", "odometry", "chordal"),
                   help="start from the file's vertices, the odometry chain, or a chordal relaxation "
                        "(default: given when every vertex has a pose, else odometry)")
    q.add_argument("--method", choices=("lm", "gn"), default="lm", help="Levenberg-Marquardt or Gauss-Newton")
    q.add_argument("--robust", choices=("huber", "cauchy", "gnc"), help="robust kernel, or gnc to reject false loop closures")
    q.add_argument("--kernel-width", type=_positive, help="with --robust: kernel width (Mahalanobis units, at most 1e6; for gnc the chi2 gate, at most 1e12)")
    q.add_argument("--anchor", type=int, help="vertex id held fixed (default: FIX lines, else the first vertex)")
    q.add_argument("--max-iterations", type=_positive_int, default=100, help="stop after N iterations")
    q.add_argument("--rel-tol", type=_at_least_zero, default=1e-10, help="stop when a step lowers chi2 by less than this fraction")
    q.set_defaults(func=cmd_slam_optimize)
    for action in ap._actions:                       # an example at the end of every verb's --help
        if isinstance(action, argparse._SubParsersAction):
            for name, sub_parser in action.choices.items():
                if name in EXAMPLES:
                    sub_parser.epilog = f"example: {EXAMPLES[name]}"
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
    except OSError as exc:       # a file the command was pointed at: a directory, unwritable, a full disk
        if args.debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"tether: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
