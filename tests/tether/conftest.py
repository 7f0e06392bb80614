"""Fixtures for runtime tests that start real processes: a private runtime dir and key dir."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, Iterator

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def runtime_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Isolate registry, ipc sockets and keys (short path: unix sockets allow ~100 bytes)."""
    base = tempfile.mkdtemp(prefix="tt", dir="/tmp")
    monkeypatch.setenv("TETHER_RUNTIME_DIR", os.path.join(base, "rt"))
    monkeypatch.setenv("TETHER_KEYS_DIR", os.path.join(base, "keys"))
    yield dict(os.environ)
    shutil.rmtree(base, ignore_errors=True)


def tether(*args: str, env: dict[str, str], timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """Run the CLI as a user would, from the repo root."""
    return subprocess.run([sys.executable, "-m", "tether.cli", *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=timeout, **kw)


def wait_for_topic(topic: str, env: dict[str, str], *, timeout_s: float = 30.0,
                   alive: subprocess.Popen | None = None) -> None:
    """Bounded poll until a running graph registers ``topic`` (and ``alive``, if given, still runs),
    then ``tether topic list --all`` must list it too.

    The poll reads ``env``'s registry in this process every 20 ms: polling with the command line
    started one Python process after another (~0.3 s of CPU each) while the graph itself was
    starting, on a machine whose two cores the other test worker shares.
    """
    import time
    from unittest import mock

    from tether import registry

    deadline = time.monotonic() + timeout_s
    while True:
        with mock.patch.dict(os.environ, {"TETHER_RUNTIME_DIR": env["TETHER_RUNTIME_DIR"]}):
            if topic in registry.topics():
                break
        assert time.monotonic() < deadline, f"{topic} was never registered"
        assert alive is None or alive.poll() is None, "the process publishing it exited"
        time.sleep(0.02)
    while topic not in tether("topic", "list", "--all", env=env).stdout:
        assert time.monotonic() < deadline, f"{topic} was never listed by tether topic list"
        assert alive is None or alive.poll() is None, "the process publishing it exited"


def free_port(count: int = 1) -> int:
    """A free port (the first of ``count``), below the ephemeral range (see ``free_port_base``)."""
    from tether.transport import free_port_base

    return free_port_base(count)


def two_machines(tmp_path: Path, name: str, more_nodes: str = "") -> Path:
    """A launch file: a counter on machine 'boat' feeding a scaler on 'shore' (tcp + CurveZMQ),
    plus ``more_nodes`` (YAML list items, indented like the others)."""
    import textwrap

    base = free_port(20)
    path = tmp_path / "two.yaml"
    path.write_text(textwrap.dedent(f"""
        name: {name}
        machines:
          boat:  {{host: 127.0.0.1, port_base: {base}}}
          shore: {{host: 127.0.0.1, port_base: {base + 10}}}
        nodes:
          - {{id: counter, node: nodes.std.demo:Counter, params: {{rate_hz: 20}}, machine: boat}}
          - {{id: scale, node: nodes.std.demo:Scale, inputs: {{value: counter/value}}, machine: shore}}
    """) + textwrap.indent(textwrap.dedent(more_nodes).strip("\n") + "\n", "  "))
    return path


def launch_until(args: list[str], env: dict[str, str], until: Callable[[str, str], bool], *,
                 timeout_s: float = 60.0, verb: str = "launch") -> subprocess.CompletedProcess:
    """``tether launch *args`` (no ``--duration``; or another ``verb``: ``run``, ``replay``), stopped with Ctrl-C once ``until(stdout, stderr)``
    holds (or after ``timeout_s``, or when it exits by itself). The result's ``stop_s`` is the time from
    the Ctrl-C to the exit (None when it exited by itself: ``running_at_stop`` False).

    For tests that need something to have happened before the graph stops: a fixed duration
    counts the start-up too, which a loaded 2-core machine stretches past it (a recorder process
    still importing when a 2 s launch ended: no messages, or no log at all).
    """
    import signal
    import threading
    import time

    proc = subprocess.Popen([sys.executable, "-m", "tether.cli", verb, *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out: list[str] = []
    err: list[str] = []
    readers = [threading.Thread(target=lambda s=s, into=into: into.extend(s), daemon=True)
               for s, into in ((proc.stdout, out), (proc.stderr, err))]
    for reader in readers:
        reader.start()
    deadline = time.monotonic() + timeout_s
    try:
        while proc.poll() is None and time.monotonic() < deadline and not until("".join(out), "".join(err)):
            time.sleep(0.02)
        stop_s = None
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            stopping = time.monotonic()
            proc.wait(timeout=60)                            # a hang guard
            stop_s = time.monotonic() - stopping
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for reader in readers:
            reader.join(timeout=10)
        proc.stdout.close()
        proc.stderr.close()
    result = subprocess.CompletedProcess(proc.args, proc.returncode, "".join(out), "".join(err))
    result.stop_s, result.running_at_stop = stop_s, stop_s is not None
    return result


def recording_for(seconds: float) -> Callable[[str, str], bool]:
    """A :func:`launch_until` condition: true ``seconds`` after the launch's recorder said it records
    (sources wait for it to subscribe: the run is that long for the log, whatever the start-up took)."""
    import time

    from tether.record import READY_TEXT

    started: list[float] = []

    def until(out: str, err: str) -> bool:
        if not started and READY_TEXT in out:
            started.append(time.monotonic())
        return bool(started) and time.monotonic() - started[0] >= seconds

    return until
