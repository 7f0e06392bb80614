"""Import / export CAN logs in ``candump -L`` form and python-can's ``.log`` variant, and
replay them onto a bus or into a pipeline.

``candump -L`` lines are ``(1699584944.440580) can0 701#00``; python-can's
``CanutilsLogWriter`` appends `` R`` / `` T`` (received / transmitted). Both read the same
way here: extended ids have 8 hex digits, ``123#R`` / ``123#R4`` is a remote frame
(optional length), ``123##1AABB`` a CAN FD frame with its flags nibble, ``_X`` after the
data is a DLC extension (kept out of the payload), id ``2xxxxxxx`` with the error flag an
error frame. Bad lines raise ``ValueError`` naming the line, or with
``errors="skip"`` are logged once each, counted and skipped.

Command line: ``python -m drivers.candump IN [--out OUT] [--pylog] [--describe]``.
"""
from __future__ import annotations

import argparse
import logging
import math
import re
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Iterator, TextIO

import can
import msgspec

from drivers.can_bus import frame_from_message, message_from_frame, open_bus
from drivers.cia402 import describe_frame
from msgs.can import CanFrame
from tether import Node

if TYPE_CHECKING:
    from tether.imports import ImportResult

log = logging.getLogger(__name__)

CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000
_LINE = re.compile(r"^\((?P<ts>[0-9]+(?:\.[0-9]*)?)\)\s+(?P<ch>\S+)\s+(?P<id>[0-9A-Fa-f]+)#(?P<rest>\S*)"
                   r"(?:\s+(?P<dir>[RTrt]))?\s*$")


def parse_line(line: str) -> CanFrame | None:
    """One log line -> CanFrame (None for blank / ``#`` comment lines)."""
    text = line.strip()
    if not text or text.startswith("#"):
        return None
    m = _LINE.match(text)
    if m is None:
        raise ValueError(f"not a candump -L line: {text!r} (expected '(seconds) channel ID#DATA')")
    id_text, rest = m["id"], m["rest"]
    raw_id = int(id_text, 16)
    extended = len(id_text) > 3
    stamp_ns = _seconds_to_ns(m["ts"])
    common = dict(stamp_ns=stamp_ns, channel=m["ch"], is_rx=(m["dir"] or "R").upper() == "R")
    if extended and raw_id & CAN_ERR_FLAG:
        data = bytes.fromhex(rest[:16]) if rest else b""
        return CanFrame(arbitration_id=raw_id & 0x1FFFFFFF, data=data, is_extended_id=True, is_error_frame=True,
                        dlc=len(data), **common)
    if raw_id > (0x1FFFFFFF if extended else 0x7FF):
        raise ValueError(f"CAN id {id_text} does not fit {'29' if extended else '11'} bits in {text!r}")
    is_fd = rest.startswith("#")
    if is_fd:
        rest = rest[2:]                                  # '#' + flags nibble
    if rest[:1] in ("R", "r") and not is_fd:
        if len(rest) > 2:
            raise ValueError(f"a remote frame's length is one hex digit (0-F): {text!r}")
        dlc = int(rest[1:], 16) if len(rest) > 1 else 0
        return CanFrame(arbitration_id=raw_id, is_extended_id=extended, is_remote_frame=True, dlc=dlc, **common)
    payload = rest.split("_", 1)[0].replace(".", "")
    if len(payload) % 2:
        raise ValueError(f"odd number of hex digits in the data of {text!r}")
    data = bytes.fromhex(payload)
    if len(data) > (64 if is_fd else 8):
        raise ValueError(f"{len(data)} data bytes in a {'CAN FD' if is_fd else 'classic CAN'} frame: {text!r}")
    return CanFrame(arbitration_id=raw_id, data=data, is_extended_id=extended, is_fd=is_fd, dlc=len(data), **common)


MAX_STAMP_NS = (1 << 63) - 1
MAX_STAMP_S = MAX_STAMP_NS // 1_000_000_000        # 2262: the last second an int64 ns stamp holds


def _seconds_to_ns(text: str) -> int:
    whole, _, frac = text.partition(".")
    if len(whole) > 12 or int(whole) > MAX_STAMP_S:
        raise ValueError(f"time {text[:40]} s is past what a nanosecond stamp holds (year 2262)")
    ns = int(whole) * 1_000_000_000 + int((frac + "000000000")[:9])
    if ns > MAX_STAMP_NS:                          # 9223372036.9 s: the last second holds only 0.85 s
        raise ValueError(f"time {text[:40]} s is past what a nanosecond stamp holds (year 2262)")
    return ns


def format_line(frame: CanFrame, *, direction: bool = False, channel: str = "can0") -> str:
    """CanFrame -> ``candump -L`` line (``direction=True``: python-can's `` R``/`` T`` suffix)."""
    ts = f"({frame.stamp_ns // 1_000_000_000}.{frame.stamp_ns % 1_000_000_000 // 1000:06d})"
    ch = frame.channel or channel
    if frame.is_error_frame:
        ident = f"{CAN_ERR_FLAG | frame.arbitration_id:08X}"
    else:
        ident = f"{frame.arbitration_id:08X}" if frame.is_extended_id else f"{frame.arbitration_id:03X}"
    if frame.is_remote_frame:
        body = "R" + (f"{frame.dlc:X}" if frame.dlc else "")
    elif frame.is_fd:
        body = "#0" + frame.data.hex().upper()
    else:
        body = frame.data.hex().upper()
    suffix = (" R" if frame.is_rx else " T") if direction and not frame.is_error_frame else ""
    return f"{ts} {ch} {ident}#{body}{suffix}"


MAX_LINE = 512          # a CAN FD line with 64 data bytes is < 200 characters


def iter_frames(lines: Iterable[str], *, errors: str = "raise",
                on_skip: Callable[[int, str], None] | None = None) -> Iterator[CanFrame]:
    """Parse lines lazily; ``errors='skip'`` skips bad lines instead of raising, calling
    ``on_skip(line_number, reason)`` (default: a log line each)."""
    if errors not in ("raise", "skip"):
        raise ValueError("errors must be 'raise' or 'skip'")
    for number, line in enumerate(lines, start=1):
        try:
            if len(line) > MAX_LINE:
                raise ValueError(f"a line of {len(line)} characters (at most {MAX_LINE})")
            frame = parse_line(line)
        except ValueError as exc:
            if errors == "raise":
                raise ValueError(f"line {number}: {exc}") from None
            (on_skip or _log_skip)(number, str(exc)[:200])
            continue
        if frame is not None:
            yield frame


def _log_skip(number: int, reason: str) -> None:
    log.warning("skipped line %d: %s", number, reason)


def read_candump(source: str | Path | TextIO, *, errors: str = "raise",
                 on_skip: Callable[[int, str], None] | None = None) -> list[CanFrame]:
    """All frames of a ``candump -L`` / python-can ``.log`` file (path or open text file)."""
    if isinstance(source, (str, Path)):
        with open(source, encoding="ascii", errors="replace") as f:
            return list(iter_frames(f, errors=errors, on_skip=on_skip))
    return list(iter_frames(source, errors=errors, on_skip=on_skip))


def write_candump(frames: Iterable[CanFrame], target: str | Path | TextIO, *, pylog: bool = False) -> int:
    """Write frames as ``candump -L`` (or, ``pylog=True``, with python-can's R/T suffix); returns the count."""
    lines = [format_line(f, direction=pylog) + "\n" for f in frames]
    if isinstance(target, (str, Path)):
        Path(target).write_text("".join(lines), encoding="ascii")
    else:
        target.writelines(lines)
    return len(lines)


def replay(frames: Iterable[CanFrame], bus: can.BusABC, *, speed: float = 1.0,
           stopping: threading.Event | None = None) -> int:
    """Send frames onto ``bus`` keeping their relative timing (``speed`` x; 0 = as fast as
    possible). Error frames are not sent. Returns the number of frames sent."""
    start_wall, start_log, sent = time.monotonic(), None, 0
    for frame in frames:
        if stopping is not None and stopping.is_set():
            break
        if frame.is_error_frame:
            continue
        if start_log is None:
            start_log = frame.stamp_ns
        if speed > 0:
            delay = (frame.stamp_ns - start_log) * 1e-9 / speed - (time.monotonic() - start_wall)
            if delay > 0:
                if stopping is not None:
                    stopping.wait(delay)
                else:
                    time.sleep(delay)
        bus.send(message_from_frame(frame))
        sent += 1
    return sent


class PlayerConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str
    speed: float = 1.0
    loop: bool = False
    interface: str = ""          # '' = publish only; else also send onto this python-can bus
    channel: str = "239.74.163.2"
    port: int = 43113


class CandumpPlayer(Node):
    """Replay a candump log: publishes each frame on ``frames`` (stamped now) at the
    log's pace and, when ``interface`` is set, sends it onto that bus too."""

    Config = PlayerConfig
    outputs = {"frames": CanFrame}

    def setup(self) -> None:
        self._frames = read_candump(self.config.path, errors="skip")
        cfg = self.config
        self._bus = open_bus(cfg.interface, cfg.channel, **({"port": cfg.port} if cfg.interface == "udp_multicast"
                                                            else {})) if cfg.interface else None

    def run(self) -> None:
        while not self.stopping.is_set():
            start_wall, start_log = time.monotonic(), self._frames[0].stamp_ns if self._frames else 0
            for frame in self._frames:
                delay = (frame.stamp_ns - start_log) * 1e-9 / max(self.config.speed, 1e-9) - (time.monotonic() - start_wall)
                if delay > 0 and self.stopping.wait(delay):
                    return
                if self._bus is not None and not frame.is_error_frame:
                    self._bus.send(message_from_frame(frame))
                self.publish("frames", msgspec.structs.replace(frame, stamp_ns=0))
            if not self.config.loop:
                return

    def teardown(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Read a candump -L / python-can .log file; convert or describe it.")
    ap.add_argument("log", help="input log")
    ap.add_argument("--out", help="write the frames here")
    ap.add_argument("--pylog", action="store_true", help="write python-can's variant (R/T suffix)")
    ap.add_argument("--describe", action="store_true", help="print each frame decoded as CANopen")
    args = ap.parse_args(argv)
    try:
        frames = read_candump(args.log)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}")
        return 1
    if args.describe:
        t0 = frames[0].stamp_ns if frames else 0
        for f in frames:
            print(f"{(f.stamp_ns - t0) * 1e-6:10.3f} ms  {format_line(f)[20:]:<30} {describe_frame(f.arbitration_id, f.data)}")
    if args.out:
        print(f"wrote {write_candump(frames, args.out, pylog=args.pylog)} frames to {args.out}")
    elif not args.describe:
        print(f"{len(frames)} frames, {len({f.arbitration_id for f in frames})} ids")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


#: Suffixes read by our ``candump -L`` parser; every other one goes to python-can's ``LogReader``.
CANDUMP_SUFFIXES = ("", ".log", ".candump", ".txt")


def iter_can_log(path: str | Path, *, on_skip: Callable[[int, str], None] | None = None) -> Iterator[CanFrame]:
    """Frames of any CAN log python-can reads (ASC, BLF, TRC, CSV, MF4, ... by suffix, through
    ``can.LogReader``), and of ``candump -L`` text through our parser. Ours stays for that one
    format because python-can's ``CanutilsLogReader`` reads the stamp as a float (the digits
    below the microsecond of a 2023 epoch stamp are lost), rejects the ``_X`` DLC extension and
    ``#`` comments, and stops at the first bad line (``tests/drivers/test_candump_io.py``
    measures both). A message python-can reads but a frame cannot hold (a time that is not a
    time, an id past 29 bits, more than 64 data bytes) is skipped with its number; a reader
    that fails mid-file (a truncated BLF, a mangled ASC) ends the import there: what was read
    is kept and the failure is reported like a skipped message."""
    path = Path(path)
    skip = on_skip or _log_skip
    if path.suffix.lower() in CANDUMP_SUFFIXES:
        with open(path, encoding="ascii", errors="replace") as f:
            yield from iter_frames(f, errors="skip", on_skip=skip)
        return
    try:
        reader = can.LogReader(path)
    except OSError:
        raise
    except Exception as exc:  # noqa: BLE001 - an unknown suffix, or a header the reader cannot parse
        if isinstance(exc, ValueError) and ("suffix" in str(exc).lower() or "unknown" in str(exc).lower()):
            raise ValueError(f"{path.name}: python-can has no reader for {path.suffix!r} ({exc})") from None
        skip(1, f"the reader could not start: {type(exc).__name__}: {str(exc)[:200]}")
        return
    count = 0
    with reader:
        messages = iter(reader)
        while True:
            try:
                msg = next(messages)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 - python-can's readers raise what their parsers meet
                skip(count + 1, f"the reader stopped: {type(exc).__name__}: {str(exc)[:200]}")
                return
            count += 1
            frame, problem = _frame_of(msg)
            if frame is None:
                skip(count, problem)
                continue
            yield frame


def _frame_of(msg: can.Message) -> tuple[CanFrame | None, str]:
    """A python-can message as a CanFrame, or None and why it cannot be one."""
    ts = msg.timestamp
    if not isinstance(ts, (int, float)) or not math.isfinite(ts) or not 0 <= ts <= MAX_STAMP_S:
        return None, f"time {ts!r} s is not a time a nanosecond stamp holds (0 to year 2262)"
    ident, data = msg.arbitration_id, msg.data or b""
    if not isinstance(ident, int) or not 0 <= ident <= 0x1FFFFFFF:
        return None, f"CAN id {ident!r} does not fit 29 bits"
    if len(data) > 64 or not 0 <= int(msg.dlc or 0) <= 64:
        return None, f"{len(data)} data bytes / dlc {msg.dlc!r}: a CAN FD frame holds at most 64"
    try:
        return frame_from_message(msg, is_rx=bool(getattr(msg, "is_rx", True))), ""
    except (TypeError, ValueError, OverflowError) as exc:
        return None, f"not a CAN frame: {type(exc).__name__}: {exc}"


def import_candump(src: str | Path, dst: str | Path, *, topic: str | None = None,
                   max_bytes: int | None = None, skip_bad: bool = False) -> "ImportResult":
    """``tether import can`` (and its old name ``candump``): every CAN log format python-can
    reads, and ``candump -L`` text -> ``can/frame`` (``max_bytes`` unused). A bad line or
    message ends the import with one line naming it, or with ``skip_bad`` is counted and skipped."""
    from tether.imports import ImportResult, write_messages

    result = ImportResult(unit="line" if Path(src).suffix.lower() in CANDUMP_SUFFIXES else "message",
                          skip_bad=skip_bad, source=str(src))
    return write_messages(iter_can_log(src, on_skip=result.skip), dst, topic or "can/frame", result)
