"""Probes for fault tests and the chaos bench: live node statistics, processes, secrets, damaged logs.

Nothing here is used by a running graph; it watches one from outside, as a user's
tools (``tether node info``, ``ps``, ``tether log --check``) would.
"""
from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Any, Iterable

import numpy as np


# -- processes ---------------------------------------------------------------------------------
def pid_alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    if pid <= 0:
        return False
    try:
        with open(f"/proc/{pid}/stat") as fh:
            state = fh.read().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


def children_of(ppid: int) -> list[int]:
    """Direct children of ``ppid`` (from /proc; new sessions keep their parent)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == ppid:
            out.append(int(entry.name))
    return out


def wait_gone(pids: Iterable[int], timeout_s: float) -> list[int]:
    """Poll until every pid has exited (bounded); return those still alive."""
    pids = list(pids)
    deadline = time.monotonic() + timeout_s
    while True:
        alive = [p for p in pids if pid_alive(p)]
        if not alive or time.monotonic() >= deadline:
            return alive
        time.sleep(0.05)


def peak_rss_mb(pid: int) -> float:
    """The process's peak resident set (VmHWM) in MB, 0 when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _secret_values(doc: Any) -> list[str]:
    if isinstance(doc, dict):
        return [v for k, v in doc.items() if "secret" in str(k) and isinstance(v, str) and len(v) >= 20] + \
            [s for v in doc.values() if isinstance(v, (dict, list)) for s in _secret_values(v)]
    if isinstance(doc, list):
        return [s for v in doc for s in _secret_values(v)]
    return []


def find_secrets(keys_dir: Path, roots: Iterable[int] = ()) -> list[str]:
    """Where any secret key of ``keys_dir`` shows in a process's argv or environment.

    Every process of this user is scanned (not only ``roots``' children: an orphan counts
    too); returns one "pid NAME: argv|environ" line per leak.
    """
    secrets = set()
    for path in Path(keys_dir).rglob("*"):
        if path.is_file():
            try:
                secrets.update(_secret_values(json.loads(path.read_text())))
            except (OSError, ValueError):
                continue
    found = []
    me = os.getpid()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        for part in ("cmdline", "environ"):
            try:
                blob = (entry / part).read_bytes().decode(errors="replace")
            except OSError:
                continue
            if any(s in blob for s in secrets):
                found.append(f"{entry.name} {blob.split(chr(0))[0][:60]}: {'argv' if part == 'cmdline' else part}")
    return found


# -- damaged logs ------------------------------------------------------------------------------
def corrupt_chunks(src: Path, dst: Path, *, n: int, seed: int) -> dict[str, Any]:
    """Copy ``src`` to ``dst`` with one byte flipped inside ``n`` chunks' compressed records; check it.

    Returns corrupt_chunks_injected, corrupt_chunks_reported (the damaged chunks a reader
    names, as ``tether log`` does), and how many messages it still gets out of the damaged copy.
    """
    from tether.log import LogReader
    from tether.logcheck import chunk_refs

    if not Path(src).exists():
        return {"corrupt_chunks_injected": 0, "corrupt_chunks_reported": 0, "log_error": f"no log at {src}"}
    shutil.copyfile(src, dst)
    with open(dst, "rb") as fh:                     # (body offset, length) of every chunk record
        chunks = []
        for ref in chunk_refs(fh)[0]:
            fh.seek(ref.offset + 1)
            chunks.append((ref.offset + 9, int.from_bytes(fh.read(8), "little")))
    rng = np.random.default_rng(seed)
    picked = sorted(rng.choice(len(chunks), size=min(n, len(chunks)), replace=False).tolist()) if chunks else []
    with open(dst, "r+b") as fh:
        for index in picked:
            offset, length = chunks[index]
            # Past the chunk's fixed header (times, sizes, CRC, compression name) into its records.
            at = offset + length - 1 - int(rng.integers(0, max(1, length // 4)))
            fh.seek(at)
            byte = fh.read(1)[0]
            fh.seek(at)
            fh.write(bytes([byte ^ 0xFF]))
    damaged = LogReader(dst)
    read = 0
    error = ""
    try:
        read = sum(1 for _ in damaged.messages())       # CRC-checks every chunk: one pass, damage listed
    except Exception as exc:  # noqa: BLE001 - the bench reports what a user would see
        error = f"{type(exc).__name__}: {exc}"
    clean = sum(1 for _ in LogReader(src).messages())
    return {"corrupt_chunks_injected": len(picked), "corrupt_chunks_reported": len(damaged.damaged),
            "log_chunks": len(chunks), "messages_clean": clean, "messages_read_damaged": read,
            "damaged_read_error": error}


# -- live statistics ---------------------------------------------------------------------------
class StatsWatch:
    """Subscribe to ``<node>/_stats`` of the given nodes and keep the last stats of every incarnation (pid)."""

    def __init__(self, nodes: Iterable[str]) -> None:
        self.nodes = list(nodes)
        self.last: dict[str, dict[int, Any]] = {n: {} for n in self.nodes}
        self.seen_at: dict[str, dict[int, float]] = {n: {} for n in self.nodes}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stats-watch", daemon=True)

    def start(self) -> "StatsWatch":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _run(self) -> None:
        import zmq

        from tether.stats import NodeStats
        from tether.codec import Codec
        from tether.introspect import subscribe

        codec = Codec()
        socks: dict[str, Any] = {}
        poller = zmq.Poller()
        next_scan = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_scan:
                next_scan = time.monotonic() + 0.5
                for node in self.nodes:
                    if node not in socks:
                        try:
                            _, sock = subscribe(f"{node}/_stats")
                        except Exception:  # noqa: BLE001 - not running yet
                            continue
                        socks[node] = sock
                        poller.register(sock, zmq.POLLIN)
            for sock, _ in poller.poll(100):
                while sock.poll(0):
                    frames = sock.recv_multipart(copy=False)
                    try:
                        st = codec.decode(NodeStats, frames[1:])
                    except Exception:  # noqa: BLE001 - a watcher never dies on what it reads
                        continue
                    if st.node_id in self.last:
                        with self._lock:
                            self.last[st.node_id][st.pid] = st
                            self.seen_at[st.node_id][st.pid] = time.monotonic()
        for sock in socks.values():
            sock.close(linger=0)

    def missing(self) -> list[str]:
        with self._lock:
            return [n for n in self.nodes if not self.last[n]]

    def wait_all(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while self.missing():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.1)
        return True

    def settle(self, seconds: float) -> None:
        """Wait so every live node publishes its stats at least twice more (1 s period)."""
        time.sleep(seconds)

    def pid(self, node: str) -> int:
        """The pid of the node's newest incarnation (0 if it never reported)."""
        with self._lock:
            seen = self.seen_at[node]
            return max(seen, key=seen.get) if seen else 0

    def incarnations(self, node: str) -> int:
        with self._lock:
            return len(self.last[node])

    def alive(self) -> dict[str, bool]:
        return {n: pid_alive(self.pid(n)) for n in self.nodes}

    def stats(self, node: str) -> list[Any]:
        with self._lock:
            return list(self.last[node].values())

    def counter(self, node: str, key: str, input_name: str | None = None) -> int:
        """A per-input counter summed over inputs (or one input) and over the node's incarnations."""
        return sum(getattr(i, key, 0) for st in self.stats(node) for i in st.inputs
                   if input_name is None or i.name == input_name)

    def published(self, node: str, output: str) -> int:
        return sum(st.published.get(output, 0) for st in self.stats(node))

    def lost_uncounted(self, src: str, output: str, *, via: tuple[str, str], to: tuple[str, str]) -> dict[str, int]:
        """Messages ``src/output`` published, minus what ``to`` handled, minus every drop counted on the way.

        ``via`` and ``to`` are (node, input). Zero means every message is accounted for; a
        negative value means a message was counted twice (e.g. handled just before a SIGKILL
        and counted again as lost across the restart).
        """
        sent = self.published(src, output)
        handled = self.counter(to[0], "handled", to[1])
        kinds = ("dropped_seq_gap", "dropped_queue", "dropped_restart", "decode_errors", "handler_errors")
        drops = sum(self.counter(node, kind, name) for node, name in (via, to) for kind in kinds)
        return {"sent": sent, "handled": handled, "counted_drops": drops, "lost_uncounted": sent - handled - drops}
