"""Launcher supervision: start node processes, prefix their logs, restart per policy, stop cleanly.

A launch stops from its sources (:func:`stop_stages`): a node is asked to stop once every node
it takes input from has exited, so it handles their last messages before it stops
(:meth:`tether.runtime.NodeRuntime._finish_inputs`), and a recording holds everything the
sources published before the stop went through the whole pipeline.
"""
from __future__ import annotations

import fnmatch
import json
import logging
import math
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import msgspec

from tether import forked, keystore, registry
from tether.launch import TIMER_RE, LaunchFile, plan
from tether.paths import check_writable
from tether.record import READY_TEXT
from tether.errors import ConfigError
from tether.runtime import STOP_REPORT_TEXT, RunSpec
from tether.transport import sweep_stale_sockets

log = logging.getLogger("tether.launch")

BACKOFF_START_S = 0.5
BACKOFF_MAX_S = 10.0
STOP_TIMEOUT_S = 10.0
MAX_RECORDER_RESTARTS = 5


def _next_segment(path: str, n: int) -> str:
    p = Path(path)
    return str(p if n == 0 else p.with_name(f"{p.stem}.{n}{p.suffix}"))


@dataclass
class Child:
    id: str
    spec: RunSpec
    restart: str
    max_restarts: int
    env: dict[str, str]
    proc: subprocess.Popen | None = None
    restarts: int = 0
    restart_at: float | None = None
    failed: bool = False
    done: bool = False
    exit_codes: list[int] = field(default_factory=list)


def _stop_timeout() -> float:
    """``TETHER_STOP_TIMEOUT_S``: how long nodes get to stop after SIGTERM before SIGKILL (default 10 s)."""
    text = os.environ.get("TETHER_STOP_TIMEOUT_S", "")
    try:
        value = float(text) if text else STOP_TIMEOUT_S
    except ValueError:
        value = math.nan
    if not 0.1 <= value <= 3600:
        raise ConfigError(f"TETHER_STOP_TIMEOUT_S={text!r}: give seconds between 0.1 and 3600")
    return value


def stop_stages(launch: LaunchFile, ids: list[str] | None = None) -> list[list[str]]:
    """The order the launcher stops the nodes ``ids`` of ``launch`` (default: all) in: stages, sources first.

    A node's stage is one after the last stage of the nodes it takes input from (stage 0: it
    takes none, only timers); the nodes of a cycle (a strongly connected set) share one stage.
    The stages are computed over the whole graph, nodes of other machines included, so that
    ``a -> remote -> c`` still stops ``c`` after ``a``; then restricted to ``ids``, in launch file
    order within a stage, empty stages dropped.
    """
    nodes = [n.id for n in launch.nodes]
    preds = {n.id: {src.partition("/")[0] for src in n.inputs.values() if not TIMER_RE.match(src)}
             for n in launch.nodes}
    succs: dict[str, set[str]] = {v: set() for v in nodes}
    for v, ps in preds.items():
        for u in ps:
            succs[u].add(v)
    reach = {v: _reachable(v, succs) for v in nodes}
    group = {v: frozenset(u for u in reach[v] if v in reach[u]) | {v} for v in nodes}
    stage: dict[frozenset[str], int] = {}
    while len(stage) < len(set(group.values())):          # longest path from a source, group by group
        for g in set(group.values()) - stage.keys():
            before = {group[u] for v in g for u in preds[v]} - {g}
            if before <= stage.keys():
                stage[g] = 1 + max((stage[b] for b in before), default=-1)
    wanted = nodes if ids is None else [v for v in nodes if v in set(ids)]
    out: dict[int, list[str]] = {}
    for v in wanted:
        out.setdefault(stage[group[v]], []).append(v)
    return [out[k] for k in sorted(out)]


def stop_losses(reports: dict[str, dict]) -> dict[str, int]:
    """Messages lost at a stop, per ``'TOPIC -> NODE.INPUT'``: the publisher's last seq minus the last
    seq the subscriber received, from both nodes' stop reports (:meth:`NodeRuntime.stop_report`).

    A gap between two received messages is counted by the subscriber (``dropped_seq_gap``); the
    tail after its last one is not, and at a stop nothing later reveals it. Only edges between two
    nodes that both reported (this machine's, not killed) and that carried a message are counted.
    """
    lost: dict[str, int] = {}
    for node_id, report in reports.items():
        for name, (topic, last) in report.get("received", {}).items():
            publisher = reports.get(topic.partition("/")[0])
            if publisher is None or not last:
                continue
            missing = publisher.get("published", {}).get(topic, 0) - last
            if missing > 0:
                lost[f"{topic} -> {node_id}.{name}"] = missing
    return lost


def _reachable(start: str, succs: dict[str, set[str]]) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for w in succs[todo.pop()] - seen:
            seen.add(w)
            todo.append(w)
    return seen


def _wait_delivered(pid: int, sig: int, timeout_s: float) -> None:
    """Wait (bounded) until ``sig`` is no longer pending for ``pid``: its handler has run (Linux /proc)."""
    bit = 1 << (sig - 1)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            time.sleep(0.3)                  # not Linux, or gone: a fixed pause
            return
        pending = [int(line.split()[1], 16) for line in status.splitlines() if line.startswith(("SigPnd", "ShdPnd"))]
        if pending and not any(p & bit for p in pending):
            time.sleep(0.05)                 # the handler runs once delivered: let it write
            return
        time.sleep(0.02)


def _running(child: Child) -> bool:
    return child.proc is not None and child.proc.poll() is None


def _wait_exit(children: list[Child], until: float) -> list[Child]:
    """Wait until ``children`` have all exited or the monotonic time ``until``; those still running."""
    while True:
        left = [c for c in children if _running(c)]
        if not left or time.monotonic() >= until:
            return left
        time.sleep(0.005)


def signal_node(pid: int, sig: int, *, group: bool = True) -> None:
    """Signal a node's process group (the node and anything it started), or the node alone.

    A node leaves the launcher's group first thing; one that has not yet (just forked) has
    no group of its own and gets the signal directly, instead of none at all."""
    try:
        if group:
            try:
                os.killpg(pid, sig)
                return
            except ProcessLookupError:
                pass
        os.kill(pid, sig)
    except ProcessLookupError:
        pass                     # gone already


def spawn(module: str, spec_json: bytes, *, env: dict[str, str] | None = None) -> subprocess.Popen:
    """Start ``python -m module -`` and hand it ``spec_json`` on its stdin.

    Never on the command line nor in the environment: a spec can hold this machine's
    CurveZMQ secret key, and ``/proc/PID/cmdline`` and ``environ`` are readable by others.
    Its own session (a Ctrl-C in the terminal reaches the launcher only, which stops
    children in order); the child watches its launcher and stops when it dies.
    """
    proc = subprocess.Popen([sys.executable, "-m", module, "-"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env=env, text=True, errors="replace", start_new_session=True)
    try:
        proc.stdin.write(spec_json.decode())
        proc.stdin.close()
    except OSError:
        pass                     # it died at once: its exit code says so, the reaper reports it
    return proc


class Supervisor:
    """Run the nodes of ``launch`` that belong to ``machine`` (all when there are no machines)."""

    def __init__(self, launch: LaunchFile, *, machine: str | None = None, record: str | None = None,
                 record_topics: list[str] | None = None, record_exclude: list[str] | None = None,
                 keys: str | None = None, out: IO[str] | None = None, record_max_bytes: int = 0,
                 record_max_duration_s: float = 0.0) -> None:
        self.launch = launch
        self.record_split = {"max_bytes": int(record_max_bytes), "max_duration_s": float(record_max_duration_s)}
        self.machine = machine or ""
        self.out = out or sys.stdout
        self.stop_event = threading.Event()
        self.stop_timeout_s = _stop_timeout()
        self._write_lock = threading.Lock()
        if self.machine and not launch.machines:       # was ignored: every node started here
            raise ConfigError(f"{launch.path}: --machine {self.machine}: the file declares no machines "
                              "(every node runs on this one)")
        if launch.machines and self.machine not in launch.machines:
            raise ConfigError(f"{launch.path}: --machine must be one of {sorted(launch.machines)}")
        if record:                    # found at the run's end otherwise: every node started and stopped for nothing
            check_writable(record, "--record")
        self.keystore = keystore.keystore_dir(launch.name, keys)
        curve = keystore.ensure(self.keystore, list(launch.machines), self.machine) if launch.machines else None
        self.curve = curve
        specs = plan(launch, token=uuid.uuid4().hex[:8], curve=curve.to_json() if curve else None,
                     epoch_ns=time.time_ns())
        for spec in specs.values():
            spec.parent_pid = os.getpid()
        self.children = [Child(n.id, specs[n.id], n.restart, n.max_restarts, n.env)
                         for n in launch.nodes if not launch.machines or n.machine == self.machine]
        self.all_specs = specs
        self.stop_stages = stop_stages(launch, [c.id for c in self.children])
        stage_of = {node_id: k for k, stage in enumerate(self.stop_stages) for node_id in stage}
        for child in self.children:     # upstream nodes this launcher stops (and sees exit) before this one
            for src in child.spec.inputs.values():
                upstream = src.topic.partition("/")[0]
                src.await_on_stop = stage_of.get(upstream, stage_of[child.id]) < stage_of[child.id]
        self.record_path = record
        self.record_topics = self._recorded(record_topics, record_exclude) if record else {}
        for child in self.children:   # the recorder is one more subscriber those sources wait for
            child.spec.expect_subscribers = {t: n + (t in self.record_topics)
                                             for t, n in child.spec.expect_subscribers.items()}
        self.recorder: subprocess.Popen | None = None
        self._recorder_ready = threading.Event()
        self.recorder_segments: list[str] = []
        self.stop_reports: dict[str, dict] = {}      # node id -> its last NodeRuntime.stop_report()
        self.recorder_failures = 0
        self._registry_path: Path | None = None
        self._pumps: list[threading.Thread] = []

    def _recorded(self, patterns: list[str] | None, exclude: list[str] | None) -> dict[str, str]:
        """Topics of this machine's nodes to record (fnmatch patterns), with their endpoints."""
        topics = {f"{c.id}/{out}": c.spec.binds[0] for c in self.children if c.spec.binds
                  for out in self.launch.node(c.id).ports.outputs}
        keep = {t: ep for t, ep in topics.items()
                if (not patterns or any(fnmatch.fnmatchcase(t, p) for p in patterns))
                and not any(fnmatch.fnmatchcase(t, p) for p in exclude or [])}
        if not keep:
            raise ConfigError(f"--record: no topic matches (topics: {', '.join(sorted(topics))})")
        return keep

    def _start_recorder(self) -> None:
        """Start the recorder into the next file segment (``run.mcap``, then ``run.1.mcap``, ...)."""
        n = len(self.recorder_segments)
        segment = _next_segment(self.record_path, n)
        self.recorder_segments.append(segment)
        spec = {"path": segment, "topics": self.record_topics, "secure": {}, "parent_pid": os.getpid(),
                "curve": self.curve.to_json() if self.curve else None, **self.record_split,
                "metadata": {"launch": str(self.launch.path), "graph": self.launch.name, "segment": n}}
        # Its own process: recording a camera stream costs CPU (the mcap writer copies every byte a
        # few times), which must not slow the supervisor's log pumping or restarts.
        self._recorder_ready = threading.Event()
        self.recorder = spawn("tether.record", json.dumps(spec).encode())
        threading.Thread(target=self._pump, args=("record", self.recorder.stdout, self._recorder_ready),
                         daemon=True).start()

    def _watch_recorder(self) -> None:
        """A dead recorder is an error: say so and record on into a new segment (never run on without a log)."""
        if self.recorder is None or self.recorder.poll() is None:
            return
        self.recorder_failures += 1
        if self.recorder_failures > MAX_RECORDER_RESTARTS:
            log.error("the recorder died again (exit %d): %d restarts, giving up recording", self.recorder.returncode,
                      MAX_RECORDER_RESTARTS)
            self.recorder = None
            return
        log.error("the recorder died (exit %d) writing %s; recording on into %s", self.recorder.returncode,
                  self.recorder_segments[-1], _next_segment(self.record_path, len(self.recorder_segments)))
        self._start_recorder()

    # -- processes --------------------------------------------------------------------
    def _start(self, child: Child) -> None:
        child.spec.incarnation = child.restarts     # a restarted node counts what it missed while down
        env = {**os.environ, **child.env, "PYTHONUNBUFFERED": "1"}
        if forked.can_fork():
            with self._write_lock:      # no launcher thread is writing (holding stream locks) at the fork
                child.proc = forked.ForkedNode(child.spec, env)
        else:
            child.proc = spawn("tether.runner", msgspec.json.encode(child.spec), env=env)
        pump = threading.Thread(target=self._pump, args=(child.id, child.proc.stdout), daemon=True)
        pump.start()
        self._pumps.append(pump)
        self._register()

    def _pump(self, node_id: str, stream: IO[str], ready: threading.Event | None = None) -> None:
        """Copy a child's output lines, prefixed with its id; ``ready`` is set at the recorder's :data:`READY_TEXT`.
        A node's stop report (:data:`STOP_REPORT_TEXT`) is kept for :func:`stop_losses`, not printed."""
        for line in stream:
            if ready is not None and READY_TEXT in line:
                ready.set()
            if line.startswith(STOP_REPORT_TEXT):
                try:
                    self.stop_reports[node_id] = json.loads(line[len(STOP_REPORT_TEXT):])
                except ValueError:
                    pass                 # a cut line (a node killed while writing it): its edges go uncounted
                continue
            with self._write_lock:
                self.out.write(f"[{node_id}] {line}" if line.endswith("\n") else f"[{node_id}] {line}\n")
                self.out.flush()

    def _register(self) -> None:
        topics = {}
        for child in self.children:
            spec = child.spec
            if not spec.binds:
                continue
            entry = self.launch.node(child.id)
            secure = any(b.startswith("tcp://") for b in spec.binds) and self.curve is not None
            for out, tp in [*entry.ports.outputs.items(), ("_stats", None)]:
                topics[f"{child.id}/{out}"] = {"type": tp.type_name() if tp else "std.NodeStats",
                                               "endpoint": spec.binds[0], "secure": secure}
        nodes = {c.id: {"class": c.spec.node, "pid": c.proc.pid if c.proc else 0, "restarts": c.restarts}
                 for c in self.children}
        # Public facts only: tools that need to dial a secured topic load this machine's keys
        # from the keystore themselves (a 0600 file), never from the registry.
        self._registry_path = registry.register({"name": self.launch.name, "machine": self.machine,
                                                 "launch": str(self.launch.path), "topics": topics, "nodes": nodes,
                                                 "keystore": str(self.keystore) if self.curve else None})

    def _terminate_all(self) -> None:
        """Stop this machine's nodes stage by stage (:func:`stop_stages`), all within one stop timeout.

        Each stage's running nodes get SIGTERM, and the next stage is signalled once they have
        all exited, so a node is asked to stop only after its upstream nodes are gone and handles
        their last messages first. Nodes not running (ended, failed, waiting for a restart) are
        skipped; restarts are over once the stop has begun. Bounds, with ``T`` =
        ``TETHER_STOP_TIMEOUT_S``: the stages go in order for ``T / 2``; a stage still running
        then (a node slow or hung in its stop) and every stage after it get SIGTERM together;
        whatever runs at ``T`` has its stacks dumped (SIGUSR1, up to 2 s for all of them) and
        is killed. A stop takes ``T`` + 2 s at most, however many stages or hung nodes.
        """
        start = time.monotonic()
        ordered_until = start + self.stop_timeout_s / 2
        deadline = start + self.stop_timeout_s
        by_id = {c.id: c for c in self.children}
        signalled: list[Child] = []
        for k, stage in enumerate(self.stop_stages):
            live = [by_id[i] for i in stage if _running(by_id[i])]
            for child in live:
                signal_node(child.proc.pid, signal.SIGTERM)
            signalled += live
            slow = _wait_exit(live, ordered_until)
            if slow:
                rest = [by_id[i] for later in self.stop_stages[k + 1:] for i in later if _running(by_id[i])]
                if rest:
                    log.warning("%s still stopping after %g s: stopping %s without waiting",
                                ", ".join(c.id for c in slow), self.stop_timeout_s / 2, ", ".join(c.id for c in rest))
                for child in rest:
                    signal_node(child.proc.pid, signal.SIGTERM)
                signalled += rest
                break
        hung = _wait_exit(signalled, deadline)
        for child in hung:
            # Its stacks first (every node dumps all threads' stacks on SIGUSR1 into its log), then kill.
            log.error("node %s did not stop within %g s: its stacks follow, then it is killed",
                      child.id, self.stop_timeout_s)
            signal_node(child.proc.pid, signal.SIGUSR1, group=False)
        dumped = time.monotonic() + 2.0
        for child in hung:
            _wait_delivered(child.proc.pid, signal.SIGUSR1, max(0.0, dumped - time.monotonic()))
        for child in hung:
            signal_node(child.proc.pid, signal.SIGKILL)
            child.failed = True
        for child in _wait_exit(hung, time.monotonic() + STOP_TIMEOUT_S):
            log.error("node %s (pid %d) survived SIGKILL for %.0f s: left behind", child.id, child.proc.pid,
                      STOP_TIMEOUT_S)

    # -- main loop --------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> int:
        """Run until Ctrl-C/SIGTERM, ``duration_s``, or every node has ended; 0 unless a node failed."""
        previous = {sig: signal.signal(sig, lambda *_: self.stop_event.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            swept = sweep_stale_sockets()
            if swept:
                log.info("removed %d stale ipc socket(s) left by killed nodes", swept)
            if self.record_path:
                self._start_recorder()
            for child in self.children:
                self._start(child)
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while not self.stop_event.wait(0.05):
                self._reap()
                self._watch_recorder()
                if all(c.done or c.failed for c in self.children):
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
        finally:
            self._terminate_all()
            drained = time.monotonic() + 2.0          # the nodes' last lines (and stacks) reach the output
            for pump in self._pumps:
                pump.join(max(0.0, drained - time.monotonic()))
            lost = stop_losses(self.stop_reports)
            if lost:
                log.warning("stop: %d message(s) published were never handled by their subscriber (in flight "
                            "when both stopped, as on a cycle, or after a stop timeout): %s", sum(lost.values()),
                            ", ".join(f"{edge} {n}" for edge, n in sorted(lost.items(), key=lambda e: -e[1])[:8])
                            + (f", ... ({len(lost) - 8} more)" if len(lost) > 8 else ""))
            for child in self.children:
                if child.proc is not None and child.proc.returncode not in (0, None, -signal.SIGTERM):
                    if not child.done:
                        child.exit_codes.append(child.proc.returncode)
                        child.failed = child.failed or child.proc.returncode != 0
            self._stop_recorder()
            if self._registry_path is not None:
                registry.unregister(self._registry_path)
            for child in self.children:
                if child.spec.state_file:
                    Path(child.spec.state_file).unlink(missing_ok=True)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        failed = [c.id for c in self.children if c.failed] + (["recorder"] if self.recorder_failures else [])
        if failed:
            log.error("failed: %s", ", ".join(failed))
        return 1 if failed else 0

    def _stop_recorder(self) -> None:
        """Stopped after the nodes, so it has their last messages; a non-zero exit counts as a failure."""
        if self.recorder is None:
            return
        if self.recorder.poll() is not None:   # died just before the end: counted, no new segment
            self.recorder_failures += 1
            log.error("the recorder died (exit %d) writing %s", self.recorder.returncode, self.recorder_segments[-1])
            return
        # A recorder still starting (a short run on a loaded or small machine: it imports for about
        # 0.3 s of CPU) would die of the SIGTERM before setting its handlers, leaving no log at all:
        # it finishes starting first (within the stop timeout), then stops with a complete file.
        deadline = time.monotonic() + self.stop_timeout_s
        while (not self._recorder_ready.wait(0.02) and self.recorder.poll() is None
               and time.monotonic() < deadline):
            pass
        self.recorder.send_signal(signal.SIGTERM)
        try:
            code = self.recorder.wait(self.stop_timeout_s)
        except subprocess.TimeoutExpired:
            log.error("the recorder did not stop within %g s: killed", self.stop_timeout_s)
            self.recorder.kill()
            code = self.recorder.wait()
        if code != 0:
            self.recorder_failures += 1
            log.error("the recorder exited with code %d: %s may be incomplete", code, self.recorder_segments[-1])

    def _reap(self) -> None:
        now = time.monotonic()
        for child in self.children:
            if child.restart_at is not None and now >= child.restart_at:
                child.restart_at = None
                child.restarts += 1
                log.warning("restarting %s (%d/%d)", child.id, child.restarts, child.max_restarts)
                self._start(child)
                continue
            if child.proc is None or child.done or child.failed or child.restart_at is not None:
                continue
            code = child.proc.poll()
            if code is None:
                continue
            child.exit_codes.append(code)
            if code == 0:
                log.info("%s finished", child.id)
                child.done = True
            elif child.restart == "on-failure" and child.restarts < child.max_restarts:
                delay = min(BACKOFF_MAX_S, BACKOFF_START_S * 2 ** child.restarts)
                log.error("%s exited with code %d; restart in %.1f s", child.id, code, delay)
                child.restart_at = now + delay
            else:
                log.error("%s exited with code %d%s", child.id, code,
                          " (restart limit reached)" if child.restart == "on-failure" else "")
                child.failed = True
