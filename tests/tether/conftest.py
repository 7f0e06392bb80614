"""Fixtures for runtime tests that start real processes: a private runtime dir and key dir."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Iterator

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
    """Bounded poll until a running graph registers ``topic`` (and ``alive``, if given, still runs)."""
    import time

    deadline = time.monotonic() + timeout_s
    while topic not in tether("topic", "list", "--all", env=env).stdout:
        assert time.monotonic() < deadline, f"{topic} was never registered"
        assert alive is None or alive.poll() is None, "the process publishing it exited"
