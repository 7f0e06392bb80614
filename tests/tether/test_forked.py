"""Nodes forked from the launcher: exit codes, error lines on the pipe, and each node's own environment."""
from __future__ import annotations

import os

import pytest

from tether import forked
from tether.runtime import RunSpec

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")


def _crasher() -> RunSpec:
    return RunSpec(graph="f", node_id="crash", node="nodes.std.chaos:Crasher", params={"after_s": 0.1},
                   parent_pid=os.getpid())


def test_a_forked_node_reports_its_exit_code(runtime_env: dict) -> None:
    proc = forked.ForkedNode(_crasher(), dict(os.environ))
    proc.stdout.read()                          # until the child's end of the pipe closes
    assert proc.wait(60) == 3 and proc.poll() == 3


def test_a_forked_node_reads_its_own_environment(runtime_env: dict) -> None:
    env = {**os.environ, "TETHER_PUB_QUEUE_BYTES": "12"}      # invalid: only this child sees it
    proc = forked.ForkedNode(_crasher(), env)
    out = proc.stdout.read()
    assert proc.wait(60) == 2 and "TETHER_PUB_QUEUE_BYTES='12'" in out
    assert os.environ.get("TETHER_PUB_QUEUE_BYTES") != "12"   # the launcher's own is untouched


def test_fork_is_not_used_when_asked_or_unsafe(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TETHER_SPAWN", "exec")
    assert not forked.can_fork()
    monkeypatch.delenv("TETHER_SPAWN")
    monkeypatch.setitem(__import__("sys").modules, "torch", object())
    assert not forked.can_fork()
