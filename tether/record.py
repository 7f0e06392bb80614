"""Recorder: subscribe to topics and write every message to an MCAP log, as received.

Messages are not decoded to their types: array buffers are folded back into the body
(:func:`tether.codec.wire_to_inline`), so recording costs one copy per message.
"""
from __future__ import annotations

import logging
import shutil
import threading
import time
from pathlib import Path
from typing import Callable, Mapping

import msgpack
import zmq

from tether.codec import wire_to_inline
from tether.errors import DecodeError
from tether.log import LogWriter
from tether.transport import CurveKeys, Subscriptions
from tether.runner import LOG_FORMAT, read_spec_arg, watch_parent

log = logging.getLogger("tether.record")

#: the line the launcher's recorder process logs once it records (its stop handlers are set by then)
READY_TEXT = "recording started:"
FINISH_IDLE_S = 0.1      # stopped: write on until nothing arrived for this long
FINISH_MAX_S = 2.0       # ... or for this long at most


class Recorder:
    """Record ``topics`` ({topic: endpoint}) into ``path`` until :meth:`stop`."""

    def __init__(self, path: str | Path, topics: Mapping[str, str], *, curve: CurveKeys | None = None,
                 secure: Mapping[str, str | bytes] | None = None,
                 ctx: zmq.Context | None = None, metadata: dict[str, str] | None = None,
                 max_bytes: int = 0, max_duration_s: float = 0.0) -> None:
        self.path = Path(path)
        self.max_bytes = max_bytes                  # > 0: start a new file past this many bytes (received)
        self.max_duration_s = max_duration_s        # > 0: ... or past this many seconds
        self.segments: list[Path] = []              # the files written: run.mcap, run_1.mcap, ...
        self._warned_disk = 0.0
        self.topics = dict(topics)
        self.curve = curve
        self.secure = dict(secure or {})    # topic -> server key, for topics whose publisher is a Curve server
        self.ctx = ctx or zmq.Context.instance()
        self.metadata = metadata or {}
        self.count = 0
        self.bytes = 0
        self.errors = 0
        self.failed: str = ""            # why the log could not be written on (disk full, ...); "" while fine
        self._last_error_log = 0.0
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "Recorder":
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        self._ready.wait(5.0)
        return self

    def _sockets(self) -> list[zmq.Socket]:
        subs = Subscriptions(self.ctx, self.curve)
        for topic, endpoint in self.topics.items():
            subs.add(topic, endpoint, secure=topic in self.secure, server_key=self.secure.get(topic, b""))
        return subs.sockets

    def _run(self) -> None:
        socks = self._sockets()
        poller = zmq.Poller()
        for s in socks:
            s.setsockopt(zmq.RCVHWM, 100_000)
            poller.register(s, zmq.POLLIN)
        wanted = {t.encode() for t in self.topics}
        writer: LogWriter | None = None
        try:
            writer, seg_bytes, seg_start = self._open_segment(), self.bytes, time.monotonic()
            self._ready.set()
            while not self._stop.is_set():
                self._take(poller, wanted, writer, 100)
                writer.maybe_flush()
                if (self.max_bytes and self.bytes - seg_bytes >= self.max_bytes) or \
                        (self.max_duration_s and time.monotonic() - seg_start >= self.max_duration_s):
                    writer.close()                   # a complete file; the next one starts now
                    writer, seg_bytes, seg_start = self._open_segment(), self.bytes, time.monotonic()
            # Stopped: what was sent before is written too (the launcher stops the recorder after
            # the nodes: their last messages may still be on their way through ZeroMQ).
            end, quiet = time.monotonic() + FINISH_MAX_S, time.monotonic() + FINISH_IDLE_S
            while time.monotonic() < min(end, quiet):
                if self._take(poller, wanted, writer, 20):
                    quiet = time.monotonic() + FINISH_IDLE_S
            writer.close()
        except OSError as exc:     # the file, not a message: disk full, file too large, I/O error
            self.failed = f"{type(exc).__name__}: {exc}"
            if writer is not None:
                writer.abandon()
            log.error("recording to %s stopped: %s; the %d messages written before stay readable "
                      "(tether log --recover)", self.path, self.failed, self.count)
        finally:
            self._ready.set()
            for s in socks:
                s.close(linger=0)

    def _take(self, poller: zmq.Poller, wanted: set[bytes], writer: LogWriter, timeout_ms: int) -> int:
        """Write what arrives within ``timeout_ms`` on the recorded topics; how many messages arrived."""
        n = 0
        for sock, _ in poller.poll(timeout_ms):
            while sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:
                frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
                n += 1
                if frames[0].bytes in wanted:
                    self._write(writer, frames)
        return n

    def _open_segment(self) -> LogWriter:
        k = len(self.segments)
        path = self.path if k == 0 else self.path.with_name(f"{self.path.stem}_{k}{self.path.suffix}")
        self.segments.append(path)
        if k:
            log.info("recording on into %s", path)
        return LogWriter(path, metadata={**self.metadata, "segment": str(k)})

    def check_disk(self, rate_bps: float) -> str:
        """A warning when at ``rate_bps`` the disk under the log fills within 10 minutes ('' otherwise)."""
        if rate_bps <= 0:
            return ""
        free = shutil.disk_usage(self.path.parent if self.path.parent.exists() else Path(".")).free
        left_s = free / rate_bps
        if left_s > 600 or (self._warned_disk and left_s > self._warned_disk / 4):
            return ""
        self._warned_disk = left_s
        return (f"at {rate_bps / 1e6:.1f} MB/s the disk under {self.path} ({free / 1e9:.2f} GB free) is full in "
                f"{left_s / 60:.1f} min; split with --max-size / --max-duration, or record fewer topics")

    def _write(self, writer: LogWriter, frames: list) -> None:
        """Write one message; content that cannot be written is counted and logged (rate-limited), never fatal."""
        now = time.time_ns()
        try:
            blob = wire_to_inline(frames[1:])
            head = msgpack.unpackb(frames[1].bytes, raw=False, strict_map_key=False)
            if not isinstance(head, dict):
                raise DecodeError(f"the body is a msgpack {type(head).__name__}, not a message map")
            stamp, seq = head.get("stamp_ns"), head.get("seq")
            writer.write_encoded(frames[0].bytes.decode(errors="replace"), str(head.get("type", "")), blob,
                                 log_time_ns=now, publish_time_ns=stamp if isinstance(stamp, int) else 0,
                                 sequence=seq if isinstance(seq, int) and seq >= 0 else 0)
        except OSError:
            raise                  # the file itself failed: the caller stops and says so
        except Exception as exc:  # noqa: BLE001 - a message's content must never stop a recording
            self.errors += 1
            if time.monotonic() - self._last_error_log >= 5.0:
                self._last_error_log = time.monotonic()
                log.error("recorder dropped an unwritable message on %s (%d so far): %s: %s",
                          frames[0].bytes[:80], self.errors, type(exc).__name__, exc)
            return
        self.count += 1
        self.bytes += sum(len(f.buffer) for f in frames)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)

    def run_until(self, stop: threading.Event, duration_s: float | None = None,
                  progress: Callable[[str], None] | None = None) -> None:
        """Block until ``stop`` is set or ``duration_s`` passes, reporting progress each second."""
        t0 = time.monotonic()
        last_count, last_bytes, last_t = 0, 0, t0
        while not stop.wait(1.0):
            now = time.monotonic()
            if progress is not None:
                rate = (self.count - last_count) / max(now - last_t, 1e-9)
                progress(f"recording {self.segments[-1].name if self.segments else self.path.name}: {self.count} "
                         f"msgs, {self.bytes / 1e6:.1f} MB, {rate:.0f} msg/s, {now - t0:.0f} s")
            warning = self.check_disk((self.bytes - last_bytes) / max(now - last_t, 1e-9))
            if warning:
                log.warning(warning)
            last_count, last_bytes, last_t = self.count, self.bytes, now
            if (duration_s is not None and now - t0 >= duration_s) or self.failed:
                break
        self.stop()


def main(argv: list[str] | None = None) -> int:
    """``python -m tether.record -``: the launcher's recorder process, spec on stdin (stops on SIGTERM/SIGINT).

    SPEC: {"path", "topics": {topic: endpoint}, "secure": {topic: server key}, "curve": keys or null,
    "parent_pid": launcher pid, "metadata": {}, "max_bytes": 0, "max_duration_s": 0}.
    """
    import signal
    import sys

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
    spec = read_spec_arg((argv if argv is not None else sys.argv[1:])[0])
    curve = CurveKeys.from_json(spec["curve"]) if spec.get("curve") else None
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    watch_parent(int(spec.get("parent_pid", 0)), stop.set)
    rec = Recorder(spec["path"], spec["topics"], curve=curve, secure=spec.get("secure") or {},
                   metadata=spec.get("metadata"), max_bytes=int(spec.get("max_bytes") or 0),
                   max_duration_s=float(spec.get("max_duration_s") or 0.0)).start()
    log.info("%s %d topics into %s", READY_TEXT, len(rec.topics), rec.path)
    rec.run_until(stop)
    log.info("recorded %d messages (%.1f MB) on %d topics to %s%s", rec.count, rec.bytes / 1e6, len(rec.topics),
             rec.path, f"; {rec.errors} malformed dropped" if rec.errors else "")
    return 1 if rec.failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

