"""Registry of running graphs: one JSON file per launcher, so CLI tools can find topics.

Each entry lists the graph's topics with their type and endpoint, and its nodes with
their pids. Entries of dead launchers are ignored and removed. Entries hold public facts
only: a tool that dials a secured topic loads this machine's keys from the keystore.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tether.errors import TetherError
from tether.transport import private_subdir


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    type_name: str
    endpoint: str
    graph: str
    secure: bool = False          # the publisher is a CurveZMQ server: dial it with the keystore's keys
    keystore: str = ""
    machine: str = ""

    def client_keys(self) -> tuple[Any, bytes]:
        """``(CurveKeys, server_key)`` to dial this topic, or ``(None, b"")`` when it is not secured."""
        if not self.secure:
            return None, b""
        from tether import keystore

        keys = keystore.load(Path(self.keystore), self.machine)
        return keys, keys.peers[self.machine]


def _dir() -> Path:
    return private_subdir("graphs")


def register(entry: dict[str, Any]) -> Path:
    """Write (or rewrite) this process's entry; returns its path."""
    path = _dir() / f"{entry['name']}.{entry.get('machine') or 'local'}.{os.getpid()}.json"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    # O_EXCL | O_NOFOLLOW: a symlink planted under the temporary name is refused, not followed.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    with os.fdopen(fd, "w") as fh:
        json.dump({**entry, "pid": os.getpid()}, fh)
    os.replace(tmp, path)
    return path


def unregister(path: Path) -> None:
    path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def running() -> list[dict[str, Any]]:
    """Entries of live graphs (stale files are removed)."""
    out = []
    for path in sorted(_dir().glob("*.json")):
        try:
            entry = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not _alive(int(entry.get("pid", 0))):
            path.unlink(missing_ok=True)
            continue
        out.append(entry)
    return out


def topics() -> dict[str, TopicInfo]:
    """Every topic published by a running graph."""
    out: dict[str, TopicInfo] = {}
    for entry in running():
        for topic, info in entry.get("topics", {}).items():
            secure = bool(info.get("secure") and entry.get("keystore"))
            out[topic] = TopicInfo(topic, info["type"], info["endpoint"], entry["name"], secure,
                                   entry.get("keystore") or "", entry.get("machine") or "")
    return out


def check_free(topics: Any, what: str) -> None:
    """Raise :class:`TetherError` when a running graph already publishes one of ``topics``: a topic
    has one publisher, and a second graph of the same name (left running in another terminal)
    would leave every tool reading whichever the registry listed last."""
    wanted = set(topics)
    for entry in running():
        taken = sorted(wanted & set(entry.get("topics", {})))
        if taken:
            more = f" and {len(taken) - 1} more" if len(taken) > 1 else ""
            raise TetherError(f"{what}: {taken[0]}{more} {'are' if more else 'is'} already published by the "
                              f"running graph {entry['name']!r} (pid {entry.get('pid', 0)}): stop it first, or use "
                              "another name or id")


def find_topic(topic: str) -> TopicInfo:
    found = topics()
    if topic not in found:
        hint = f" (running: {', '.join(sorted(found)[:12])})" if found else " (no graph is running)"
        raise TetherError(f"no running graph publishes {topic!r}{hint}")
    return found[topic]
