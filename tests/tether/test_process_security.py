"""Issue 21 §2-3: secrets stay with their owner, the runtime directory is private, children die
with their launcher, stale sockets are swept, and a dead recorder is restarted into a new segment."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Callable

import pytest

from conftest import REPO, two_machines, wait_for_topic
from tether.errors import ConfigError
from tether.log import LogReader


def _wait(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def _children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (from /proc)."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    out, stack = [], [pid]
    while stack:
        for child in parents.get(stack.pop(), []):
            out.append(child)
            stack.append(child)
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _where(pid: int) -> str:
    """What a process is and where each of its threads waits (for a failure message)."""
    proc = Path(f"/proc/{pid}")
    try:
        lines = [f"pid {pid}: {(proc / 'cmdline').read_bytes().replace(bytes(1), b' ').decode(errors='replace')}",
                 f"  stat {(proc / 'stat').read_text().strip()[:120]}"]
        for task in sorted((proc / "task").iterdir()):
            lines.append(f"  thread {(task / 'comm').read_text().strip()}: wchan {(task / 'wchan').read_text()}, "
                         f"syscall {(task / 'syscall').read_text().strip()[:60]}")
    except OSError as exc:
        lines = [f"pid {pid}: {exc}"]
    return "\n".join(lines)


def _two_machines(tmp_path: Path) -> Path:
    return two_machines(tmp_path, "sec", """
        - {id: sink, node: "nodes.std.chaos:QuietSink", inputs: {value: scale/value}, machine: shore}
    """)


def _launch(path: Path, env: dict, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tether.cli", "launch", str(path), *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_no_secret_key_on_any_command_line_environment_or_registry(tmp_path: Path, runtime_env: dict) -> None:
    path = _two_machines(tmp_path)
    boat = _launch(path, runtime_env, "--machine", "boat")
    shore = _launch(path, runtime_env, "--machine", "shore", "--record", str(tmp_path / "r.mcap"))
    try:
        wait_for_topic("sink/_stats", runtime_env, alive=shore)      # a sink publishes statistics too
        store = Path(runtime_env["TETHER_KEYS_DIR"]) / "sec"
        secrets = [json.loads((store / f"{m}.key").read_text())["secret"] for m in ("boat", "shore")]
        def _all() -> list[int]:
            return [p.pid for p in (boat, shore)] + _children(boat.pid) + _children(shore.pid)
        _wait(lambda: len(_all()) >= 6, 15.0, "launchers, 3 nodes and the recorder did not all start")
        pids = _all()
        for pid in pids:
            for what in ("cmdline", "environ"):
                text = Path(f"/proc/{pid}/{what}").read_bytes().decode(errors="replace")
                assert not any(s in text for s in secrets), f"a secret key is in /proc/{pid}/{what}"
        registry = Path(runtime_env["TETHER_RUNTIME_DIR"]) / "graphs"
        for entry in registry.glob("*.json"):
            assert not any(s in entry.read_text() for s in secrets), f"a secret key is in {entry}"
        info = subprocess.run([sys.executable, "-m", "tether.cli", "node", "info", "scale", "--wait", "20"],
                              cwd=REPO, env=runtime_env, capture_output=True, text=True, timeout=30)
        assert info.returncode == 0 and "<- value" in info.stdout   # tools still dial secured topics
    finally:
        for p in (boat, shore):
            p.send_signal(signal.SIGINT)
        outs = [p.communicate(timeout=30)[0] for p in (boat, shore)]
    assert boat.returncode == 0 and shore.returncode == 0, outs


def test_children_stop_when_the_launcher_is_killed_and_stale_sockets_are_swept(tmp_path: Path,
                                                                              runtime_env: dict) -> None:
    launcher = _launch(REPO / "launch" / "counter.yaml", runtime_env, "--record", str(tmp_path / "c.mcap"))
    wait_for_topic("printer/_stats", runtime_env, alive=launcher)
    children = _children(launcher.pid)
    assert len(children) >= 4                                          # three nodes and the recorder
    launcher.send_signal(signal.SIGKILL)
    launcher.wait(10)
    launcher.stdout.close()
    deadline = time.monotonic() + 30.0                                 # loaded CI: 15 s was marginal
    while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = [pid for pid in children if _alive(pid)]
    assert not survivors, "children outlived their launcher:\n" + "\n".join(_where(pid) for pid in survivors)
    sockets = Path(runtime_env["TETHER_RUNTIME_DIR"]) / "s"
    # A stale socket, as a node killed with SIGKILL leaves it: the next launcher sweeps it.
    stale = sockets / "counter.dead.x"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(stale))
    from tether.transport import sweep_stale_sockets

    assert sweep_stale_sockets() >= 1 and not stale.exists()


def test_a_killed_recorder_is_restarted_into_a_new_segment_and_the_launch_fails(tmp_path: Path,
                                                                             runtime_env: dict) -> None:
    log = tmp_path / "run.mcap"
    launcher = _launch(REPO / "launch" / "counter.yaml", runtime_env, "--record", str(log),
                       "--param", "counter.rate_hz=50")
    wait_for_topic("printer/_stats", runtime_env, alive=launcher)

    def recorder() -> int:
        found = [p for p in _children(launcher.pid)
                 if b"tether.record" in Path(f"/proc/{p}/cmdline").read_bytes() and _alive(p)]
        return found[0] if found else 0

    _wait(lambda: recorder() != 0, 10.0, "no recorder")

    def logged() -> int:
        return sum(1 for _ in LogReader(log).messages()) if log.exists() else 0

    _wait(lambda: logged() > 0, 15.0, "the first segment never got a chunk")
    os.kill(recorder(), signal.SIGKILL)
    second = tmp_path / "run.1.mcap"
    _wait(lambda: second.exists() and second.stat().st_size > 0, 15.0, "no second segment")
    time.sleep(1.0)
    launcher.send_signal(signal.SIGINT)
    out = launcher.communicate(timeout=30)[0]
    assert launcher.returncode != 0 and "the recorder died" in out and "run.1.mcap" in out
    assert sum(1 for _ in LogReader(second).messages()) > 0          # the new segment is a complete log
    assert sum(1 for _ in LogReader(log).messages()) > 0             # the killed one stays readable


def test_a_restart_storm_stays_bounded_and_the_launcher_responsive(tmp_path: Path, runtime_env: dict) -> None:
    path = tmp_path / "storm.yaml"
    path.write_text(textwrap.dedent("""
        name: storm
        nodes:
          - {id: crash, node: "nodes.std.chaos:Crasher", params: {after_s: 0.1}, restart: on-failure,
             max_restarts: 1000}
    """))
    launcher = _launch(path, runtime_env)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(launcher.stdout), daemon=True)
    reader.start()
    # The window opens at the first restart, not at launch: a loaded machine's start-up is not the backoff.
    _wait(lambda: any("restarting crash" in line for line in lines), 30.0, "the crashing node was never restarted")
    opened = time.monotonic()
    time.sleep(4.0)
    launcher.send_signal(signal.SIGINT)
    launcher.wait(timeout=30)                                        # a hang guard, not a measurement
    window = time.monotonic() - opened
    reader.join(timeout=10)
    launcher.stdout.close()
    out = "".join(lines)
    restarts = out.count("restarting crash")
    # Backoff 0.5, 1, 2, 4, 8 s between restarts: in `window` seconds after the first restart at
    # most 1 + (how many of 1, 2, 4, ... fit), against 40 without backoff; and the storm goes on.
    allowed = 1 + next(k for k in range(20) if sum(2.0 ** i for i in range(k + 1)) > window)
    assert 2 <= restarts <= allowed, out


def test_runtime_dir_must_be_private(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from tether.transport import runtime_dir

    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    link = tmp_path / "link"
    link.symlink_to(real)
    monkeypatch.setenv("TETHER_RUNTIME_DIR", str(link))
    with pytest.raises(ConfigError, match="symlink"):
        runtime_dir()
    open_dir = tmp_path / "open"
    open_dir.mkdir()
    open_dir.chmod(0o777)
    monkeypatch.setenv("TETHER_RUNTIME_DIR", str(open_dir))
    with pytest.raises(ConfigError, match="chmod 700"):
        runtime_dir()
    theirs = tmp_path / "theirs"
    theirs.mkdir(mode=0o700)
    os.chown(theirs, os.getuid() + 4242, -1) if os.getuid() == 0 else pytest.skip("needs root to chown")
    monkeypatch.setenv("TETHER_RUNTIME_DIR", str(theirs))
    with pytest.raises(ConfigError, match="not to you"):
        runtime_dir()
    fresh = tmp_path / "fresh"
    monkeypatch.setenv("TETHER_RUNTIME_DIR", str(fresh))
    assert runtime_dir() == fresh and fresh.stat().st_mode & 0o777 == 0o700


def test_registry_temp_file_does_not_follow_a_planted_symlink(tmp_path: Path, runtime_env: dict) -> None:
    from tether import registry

    victim = tmp_path / "victim"
    victim.write_text("precious")
    folder = Path(runtime_env["TETHER_RUNTIME_DIR"]) / "graphs"
    folder.mkdir(parents=True, exist_ok=True)
    name = f"g.local.{os.getpid()}.json"
    (folder / f".{name}.{os.getpid()}.tmp").symlink_to(victim)
    path = registry.register({"name": "g", "machine": "", "topics": {}, "nodes": {}})
    assert victim.read_text() == "precious" and json.loads(path.read_text())["name"] == "g"


def test_keystore_refuses_a_secret_others_can_read_and_an_unknown_subscriber(tmp_path: Path) -> None:
    from tether import keystore

    store = tmp_path / "ks"
    assert keystore.init(store, ["boat", "shore"]) == ["boat", "shore"]
    assert (store / "boat.key").stat().st_mode & 0o777 == 0o600
    keys = keystore.load(store, "boat")
    assert set(keys.peers) == {"boat", "shore"} and keys.peers["boat"] == keys.public
    (store / "shore.key").chmod(0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        keystore.load(store, "shore")
    (store / "shore.key").unlink()
    with pytest.raises(ConfigError, match="copy shore.key"):
        keystore.load(store, "shore")
    other = tmp_path / "other"
    keystore.init(other, ["boat"])
    (other / "boat.key").replace(store / "boat.key")                  # a key from another keystore
    with pytest.raises(ConfigError, match="different keystores"):
        keystore.load(store, "boat")
