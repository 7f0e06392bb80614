"""Launcher supervision: start node processes, prefix their logs, restart per policy, stop cleanly."""
from __future__ import annotations

import fnmatch
import json
import logging
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

from tether import registry
from tether.launch import LaunchFile, plan
from tether.errors import ConfigError
from tether.runtime import RunSpec
from tether.transport import CurveKeys

log = logging.getLogger("tether.launch")

BACKOFF_START_S = 0.5
BACKOFF_MAX_S = 10.0
STOP_TIMEOUT_S = 10.0


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


def keys_path(launch: LaunchFile, override: str | None = None) -> Path:
    """Where a graph's CurveZMQ keys live (shared by every machine of the graph)."""
    if override:
        return Path(override)
    base = os.environ.get("TETHER_KEYS_DIR") or os.path.join(os.path.expanduser("~"), ".config", "tether", "keys")
    return Path(base) / f"{launch.name}.json"


class Supervisor:
    """Run the nodes of ``launch`` that belong to ``machine`` (all when there are no machines)."""

    def __init__(self, launch: LaunchFile, *, machine: str | None = None, record: str | None = None,
                 record_topics: list[str] | None = None, record_exclude: list[str] | None = None,
                 keys: str | None = None, out: IO[str] | None = None) -> None:
        self.launch = launch
        self.machine = machine or ""
        self.out = out or sys.stdout
        self.stop_event = threading.Event()
        self._write_lock = threading.Lock()
        curve = CurveKeys.load_or_create(keys_path(launch, keys)) if launch.machines else None
        self.curve = curve
        specs = plan(launch, token=uuid.uuid4().hex[:8], curve=curve.to_json() if curve else None)
        if launch.machines and self.machine not in launch.machines:
            raise SystemExit(f"{launch.path}: --machine must be one of {sorted(launch.machines)}")
        self.children = [Child(n.id, specs[n.id], n.restart, n.max_restarts, n.env)
                         for n in launch.nodes if not launch.machines or n.machine == self.machine]
        self.all_specs = specs
        self.record_path = record
        self.record_topics = self._recorded(record_topics, record_exclude) if record else {}
        for child in self.children:   # the recorder is one more subscriber those sources wait for
            child.spec.expect_subscribers = {t: n + (t in self.record_topics)
                                             for t, n in child.spec.expect_subscribers.items()}
        self.recorder: subprocess.Popen | None = None
        self._registry_path: Path | None = None

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
        secure = [t for t in self.record_topics if any(b.startswith("tcp://") for b in self.all_specs[t.split("/")[0]].binds)]
        spec = {"path": self.record_path, "topics": self.record_topics, "secure": secure,
                "curve": self.curve.to_json() if self.curve else None,
                "metadata": {"launch": str(self.launch.path), "graph": self.launch.name}}
        # Its own process: recording a camera stream costs CPU (the mcap writer copies every byte a
        # few times), which must not slow the supervisor's log pumping or restarts.
        self.recorder = subprocess.Popen([sys.executable, "-m", "tether.record", json.dumps(spec)],
                                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                         errors="replace", start_new_session=True)
        threading.Thread(target=self._pump, args=("record", self.recorder.stdout), daemon=True).start()

    # -- processes --------------------------------------------------------------------
    def _start(self, child: Child) -> None:
        child.spec.incarnation = child.restarts     # a restarted node counts what it missed while down
        env = {**os.environ, **child.env, "PYTHONUNBUFFERED": "1"}
        cmd = [sys.executable, "-m", "tether.runner", msgspec.json.encode(child.spec).decode()]
        child.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                                      text=True, errors="replace", start_new_session=True)
        threading.Thread(target=self._pump, args=(child.id, child.proc.stdout), daemon=True).start()
        self._register()

    def _pump(self, node_id: str, stream: IO[str]) -> None:
        for line in stream:
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
        self._registry_path = registry.register({"name": self.launch.name, "machine": self.machine,
                                                 "launch": str(self.launch.path), "topics": topics,
                                                 "nodes": nodes, "curve": self.curve.to_json() if self.curve else None})

    def _terminate_all(self) -> None:
        live = [c for c in self.children if c.proc is not None and c.proc.poll() is None]
        for child in live:
            try:
                os.killpg(child.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for child in live:
            try:
                child.proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.error("node %s did not stop within %.0f s: killed", child.id, STOP_TIMEOUT_S)
                os.killpg(child.proc.pid, signal.SIGKILL)
                child.proc.wait()
                child.failed = True

    # -- main loop --------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> int:
        """Run until Ctrl-C/SIGTERM, ``duration_s``, or every node has ended; 0 unless a node failed."""
        previous = {sig: signal.signal(sig, lambda *_: self.stop_event.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            if self.record_path:
                self._start_recorder()
            for child in self.children:
                self._start(child)
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while not self.stop_event.wait(0.05):
                self._reap()
                if all(c.done or c.failed for c in self.children):
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
        finally:
            self._terminate_all()
            for child in self.children:
                if child.proc is not None and child.proc.returncode not in (0, None, -signal.SIGTERM):
                    if not child.done:
                        child.exit_codes.append(child.proc.returncode)
                        child.failed = child.failed or child.proc.returncode != 0
            if self.recorder is not None:   # stopped after the nodes, so it has their last messages
                self.recorder.send_signal(signal.SIGTERM)
                try:
                    self.recorder.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    log.error("the recorder did not stop within %.0f s: killed", STOP_TIMEOUT_S)
                    self.recorder.kill()
            if self._registry_path is not None:
                registry.unregister(self._registry_path)
            for child in self.children:
                if child.spec.state_file:
                    Path(child.spec.state_file).unlink(missing_ok=True)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        failed = [c.id for c in self.children if c.failed]
        if failed:
            log.error("failed: %s", ", ".join(failed))
        return 1 if failed else 0

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
