"""Nodes forked from the launcher: exit codes, error lines on the pipe, each node's own environment,
stop signals right after the fork, and a node that cannot stop.

Forks happen in a fresh interpreter: the suite's own process has imported JAX, whose threads
do not survive a fork (the launcher itself never forks then, see ``forked.FORK_UNSAFE``)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from conftest import REPO, launch_until, tether
from tether import forked

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")

_PRELUDE = """
import os, signal, sys, time
from tether import forked
from tether.runtime import RunSpec
from tether.supervisor import signal_node

def crasher(**params):
    return RunSpec(graph="f", node_id="crash", node="nodes.std.chaos:Crasher", params=params or {"after_s": 0.1},
                   parent_pid=os.getpid())
"""


def _fork_script(code: str, env: dict) -> subprocess.CompletedProcess:
    out = subprocess.run([sys.executable, "-c", _PRELUDE + textwrap.dedent(code)], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return out


def test_a_forked_node_reports_its_exit_code(runtime_env: dict) -> None:
    out = _fork_script("""
        proc = forked.ForkedNode(crasher(), dict(os.environ))
        proc.stdout.read()                          # until the child's end of the pipe closes
        print(proc.wait(60), proc.poll())
    """, runtime_env)
    assert out.stdout.split() == ["3", "3"]


def test_a_forked_node_reads_its_own_environment(runtime_env: dict) -> None:
    out = _fork_script("""
        env = {**os.environ, "TETHER_PUB_QUEUE_BYTES": "12"}      # invalid: only this child sees it
        proc = forked.ForkedNode(crasher(), env)
        text = proc.stdout.read()
        print(proc.wait(60), "TETHER_PUB_QUEUE_BYTES='12'" in text, os.environ.get("TETHER_PUB_QUEUE_BYTES") == "12")
    """, runtime_env)
    assert out.stdout.split() == ["2", "True", "False"]   # the launcher's own environment is untouched


def test_a_stop_signal_right_after_the_fork_is_never_lost(runtime_env: dict) -> None:
    """SIGTERM sent the moment fork returns reaches a child that has not yet left the launcher's
    group nor set its own handlers: it stops at once (before: the launcher's handler ran in the
    child, swallowed it, and the node ran on until killed)."""
    out = _fork_script("""
        signal.signal(signal.SIGTERM, lambda *_: None)       # the launcher's handler, which a child inherits
        slow = []
        for _ in range(40):
            proc = forked.ForkedNode(crasher(after_s=60.0), dict(os.environ))
            signal_node(proc.pid, signal.SIGTERM)
            t0 = time.monotonic()
            try:
                code = proc.wait(10)
            except Exception:
                proc.kill()
                code = proc.wait()
            proc.stdout.close()
            slow.append(round(time.monotonic() - t0, 2))
            if code not in (0, -signal.SIGTERM):
                break                                        # swallowed: ran on until killed
        print(len(slow), max(slow))
    """, runtime_env)
    runs, slowest = out.stdout.split()
    assert int(runs) == 40 and float(slowest) < 10.0


def test_fork_is_not_used_when_asked_or_unsafe(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TETHER_SPAWN", "exec")
    assert not forked.can_fork()
    monkeypatch.delenv("TETHER_SPAWN")
    monkeypatch.setitem(__import__("sys").modules, "torch", object())
    assert not forked.can_fork()


@pytest.mark.parametrize("spawn", ["fork", "exec"])
def test_a_node_that_cannot_stop_is_killed_after_the_stop_timeout_with_its_stacks(
        tmp_path, runtime_env: dict, spawn: str) -> None:
    path = tmp_path / "hang.yaml"
    path.write_text(textwrap.dedent("""
        name: hang
        nodes:
          - {id: counter, node: "nodes.std.demo:Counter", params: {rate_hz: 20}}
          - {id: hang, node: "nodes.std.chaos:Crasher", params: {after_s: 0.2, hang: true}}
    """))
    env = {**runtime_env, "TETHER_STOP_TIMEOUT_S": "1", "TETHER_SPAWN": spawn}
    out = launch_until([str(path)], env, lambda out, err: "[hang] INFO tether.hang: hanging in on_tick" in out)
    assert out.returncode == 1, out.stderr[-2000:]
    assert "node hang did not stop within 1 s: its stacks follow, then it is killed" in out.stderr
    assert "failed: hang" in out.stderr and "counter" not in out.stderr.split("failed:")[-1]
    stacks = [line for line in out.stdout.splitlines() if line.startswith("[hang] ")]
    assert any("in on_tick" in line for line in stacks), out.stdout[-2000:]   # faulthandler's dump, on SIGUSR1
    bad = tether("launch", str(path), "--duration", "1", env={**env, "TETHER_STOP_TIMEOUT_S": "soon"})
    assert bad.returncode == 2 and "TETHER_STOP_TIMEOUT_S='soon'" in bad.stderr and "Traceback" not in bad.stderr


def test_a_forked_node_holds_none_of_its_launchers_descriptors(runtime_env: dict) -> None:
    """A node's launcher has the read ends of its siblings' and the recorder's pipes, and files,
    open; a forked node gets /dev/null in their place, as ``subprocess`` closes them (before, every
    later sibling held an earlier one's pipe open, so a node whose launcher died could still block
    on a full pipe instead of seeing it broken)."""
    out = _fork_script("""
        sibling_read, sibling_write = os.pipe()           # a sibling's pipe, as the launcher holds it
        log = open(os.path.join(os.environ["TETHER_RUNTIME_DIR"] + "-file"), "w")
        mine = [os.readlink(f"/proc/self/fd/{fd}") for fd in (sibling_read, sibling_write, log.fileno())]
        proc = forked.ForkedNode(crasher(after_s=60.0), dict(os.environ))
        deadline = time.monotonic() + 30.0                   # until the child has its own session: the
        while os.getsid(proc.pid) == os.getsid(0) and time.monotonic() < deadline:   # descriptors went first
            time.sleep(0.01)
        theirs = []
        for entry in os.listdir(f"/proc/{proc.pid}/fd"):
            try:
                theirs.append(os.readlink(f"/proc/{proc.pid}/fd/{entry}"))
            except OSError:
                pass
        own_pipe = os.readlink(f"/proc/self/fd/{proc.stdout.fileno()}")
        signal_node(proc.pid, signal.SIGTERM)
        proc.wait(30)
        print(sum(t in mine for t in theirs), own_pipe in theirs, len(theirs) > 3)
    """, runtime_env)
    assert out.stdout.split() == ["0", "True", "True"], out.stdout
