"""rt_priority: a launched node asks for SCHED_FIFO; it gets it where the process may, and says
so in one line and runs normally where it may not. Scheduling is changed only in child
processes, never in the suite's own."""
from __future__ import annotations

import errno
import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import REPO, tether
from tether import runner

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling here")

_PROBE = """
import os, threading
from tether.runner import apply_rt_priority
from tether.runtime import fifo_priority
got = apply_rt_priority({priority}, "probe")
seen = []
t = threading.Thread(target=lambda: seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)))
t.start(); t.join()
print(got, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority, *seen[0], fifo_priority())
"""


def _may_use_fifo() -> bool:
    """Whether a child of this process may run SCHED_FIFO, asked of the kernel directly."""
    code = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def test_the_process_and_the_threads_it_starts_run_fifo_or_it_says_why_not() -> None:
    res = subprocess.run([sys.executable, "-c", _PROBE.format(priority=7)], capture_output=True, text=True,
                         cwd=REPO, timeout=60)
    assert res.returncode == 0, res.stderr
    got, policy, prio, thread_policy, thread_prio, in_stats = map(int, res.stdout.split())
    assert in_stats == got                                  # what NodeStats.rt_priority reports
    if _may_use_fifo():
        assert (got, policy, prio) == (7, os.SCHED_FIFO, 7)
        assert (thread_policy, thread_prio) == (os.SCHED_FIFO, 7)    # ZeroMQ's threads start after: they inherit
    else:
        assert (got, policy, thread_policy) == (0, os.SCHED_OTHER, os.SCHED_OTHER)
        assert "rt_priority 7 not applied" in res.stderr


def test_no_priority_leaves_scheduling_alone() -> None:
    res = subprocess.run([sys.executable, "-c", _PROBE.format(priority=0)], capture_output=True, text=True,
                         cwd=REPO, timeout=60)
    assert res.returncode == 0, res.stderr
    assert list(map(int, res.stdout.split())) == [0, os.SCHED_OTHER, 0, os.SCHED_OTHER, 0, 0]
    assert res.stderr == ""


def test_refused_priority_is_one_warning_and_normal_scheduling(monkeypatch: pytest.MonkeyPatch,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM))
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.INFO, logger="tether.runner"):
        assert runner.apply_rt_priority(40, "can") == 0
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "can: rt_priority 40 not applied (Operation not permitted)" in caplog.text
    assert "CAP_SYS_NICE" in caplog.text


def test_a_launched_node_reports_the_priority_it_runs_at(tmp_path: Path, runtime_env: dict) -> None:
    path = tmp_path / "rt.yaml"
    path.write_text(textwrap.dedent("""
        name: rt
        nodes:
          - id: counter
            node: nodes.std.demo:Counter
            params: {rate_hz: 20}
            rt_priority: 5
          - id: printer
            node: nodes.std.demo:Printer
            inputs: {value: counter/value}
    """))
    res = tether("launch", str(path), "--duration", "3", env=runtime_env)
    assert res.returncode == 0, res.stderr + res.stdout
    out = res.stdout + res.stderr
    if _may_use_fifo():
        assert "counter: running SCHED_FIFO at priority 5" in out
    else:
        assert "counter: rt_priority 5 not applied" in out
    assert out.count("SCHED_FIFO at priority") + out.count("not applied") == 1     # only the node that asked
    assert "value 1.0" in out                                       # and it runs either way
