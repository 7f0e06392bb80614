"""Shared fixtures: where the real data lives (../shared/data), skipped cleanly when absent; and a
private runtime and key folder for each test process."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

_PRIVATE: list[str] = []


def pytest_configure(config: pytest.Config) -> None:
    """Give this test process (each xdist worker is one) its own ``TETHER_RUNTIME_DIR`` and
    ``TETHER_KEYS_DIR``, inherited by every node it launches.

    Without it, tests that launch graphs without the ``runtime_env`` fixture share
    ``/tmp/tether-<uid>`` (ipc sockets, registry) with the other worker, with any other test run on
    the machine and with a graph the user is running, and write keys into ``~/.config/tether``.
    Tests that need their own folders still set them (``runtime_env``, ``monkeypatch``).
    """
    base = tempfile.mkdtemp(prefix="tts", dir="/tmp")          # short: unix socket paths allow ~100 bytes
    _PRIVATE.append(base)
    os.environ["TETHER_RUNTIME_DIR"] = os.path.join(base, "rt")
    os.environ["TETHER_KEYS_DIR"] = os.path.join(base, "keys")


def pytest_unconfigure(config: pytest.Config) -> None:
    while _PRIVATE:
        shutil.rmtree(_PRIVATE.pop(), ignore_errors=True)


def shared_data_dir() -> Path:
    """``$TETHER_SHARED_DATA`` or ``<repo>/../shared/data``."""
    return Path(os.environ.get("TETHER_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def shared_data() -> Path:
    """The real-data folder; skips the test when it is not there."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path}")
    return path
