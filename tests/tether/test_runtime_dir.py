"""The runtime directory rule, inside it too: sockets, registry and seq state only in folders this user controls."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from tether.errors import ConfigError
from tether.inputs import SeqStore
from tether.transport import ipc_endpoint, runtime_dir


@pytest.fixture
def rt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "rt"
    monkeypatch.setenv("TETHER_RUNTIME_DIR", str(path))
    return path


@pytest.mark.parametrize("mode", [0o720, 0o702, 0o770])
def test_group_or_world_writable_runtime_dir_is_refused(rt: Path, mode: int) -> None:
    rt.mkdir()
    rt.chmod(mode)
    with pytest.raises(ConfigError, match=f"chmod 700 {rt}"):
        ipc_endpoint("g", "n", "t")


def test_a_readable_but_private_runtime_dir_is_accepted(rt: Path) -> None:
    rt.mkdir()
    rt.chmod(0o750)
    assert ipc_endpoint("g", "n", "t").startswith(f"ipc://{rt}/s/")
    assert (rt / "s").stat().st_mode & 0o777 == 0o700


def test_planted_socket_folder_is_refused(rt: Path, tmp_path: Path) -> None:
    """A folder left by someone while the runtime dir was open: a symlink, an open one, another user's."""
    rt.mkdir(mode=0o700)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (rt / "s").symlink_to(elsewhere)
    with pytest.raises(ConfigError, match="symlink"):
        ipc_endpoint("g", "n", "t")
    (rt / "s").unlink()
    (rt / "s").mkdir()
    (rt / "s").chmod(0o777)
    with pytest.raises(ConfigError, match="writable by others"):
        ipc_endpoint("g", "n", "t")
    if os.getuid() == 0:
        (rt / "s").chmod(0o700)
        os.chown(rt / "s", 4242, -1)
        with pytest.raises(ConfigError, match="not to you"):
            ipc_endpoint("g", "n", "t")


def test_planted_registry_folder_is_refused(rt: Path) -> None:
    from tether import registry

    rt.mkdir(mode=0o700)
    (rt / "graphs").mkdir()
    (rt / "graphs").chmod(0o777)
    with pytest.raises(ConfigError, match="writable by others"):
        registry.register({"name": "g", "machine": "", "topics": {}, "nodes": {}})


def test_planted_state_folder_is_refused(rt: Path) -> None:
    runtime_dir()
    state = rt / "state"
    state.mkdir()
    state.chmod(0o733)
    with pytest.raises(ConfigError, match="writable by others"):
        SeqStore(state / "n.seq", ["in:x"], fresh=True)
    state.chmod(0o700)
    store = SeqStore(state / "n.seq", ["in:x"], fresh=True)
    store.close()
