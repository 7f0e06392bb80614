"""Importers of foreign logs into tether logs (``tether import KIND FILE -o LOG``).

Each importer streams the foreign file through a parser that lives with its driver
(the runtime holds no protocol code) and writes a tether MCAP log. Foreign files are
untrusted input: a parser bounds what it allocates by the file's own size (and by
``max_bytes`` for anything it decompresses), and a bad record is skipped and reported
with its offset, never fatal. :class:`ImportResult` says what came in and what did not.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from tether.log import LogWriter
from tether.message import Message

log = logging.getLogger("tether.import")

MAX_SKIP_LINES = 20         # then one summary: a wholly damaged file must not flood the terminal


@dataclass
class ImportResult:
    """``imported`` messages written; ``skipped`` records refused (the first few logged with where and why)."""

    imported: int = 0
    skipped: int = 0
    unit: str = "byte"          # what a skip's offset counts: "byte" or "line"

    def skip(self, offset: int, reason: str) -> None:
        self.skipped += 1
        if self.skipped <= MAX_SKIP_LINES:
            log.warning("skipped the record at %s %d: %s", self.unit, offset, reason)
        elif self.skipped == MAX_SKIP_LINES + 1:
            log.warning("more records skipped; the count follows at the end")

    def summary(self, src: str | Path, dst: str | Path) -> str:
        text = f"imported {self.imported} messages from {src} into {dst}"
        return text + (f"; skipped {self.skipped} bad records" if self.skipped else "")


def _write(messages: Iterable[Message], dst: str | Path, topic: str, result: ImportResult) -> ImportResult:
    with LogWriter(dst) as out:
        last = 0
        for msg in messages:
            # Log time = acquisition stamp, kept monotonic for files whose clock steps back.
            last = max(last + 1, msg.stamp_ns) if msg.stamp_ns > 0 else last + 1
            out.write(topic, msg, log_time_ns=last)
            result.imported += 1
    return result


def import_oculus(src: str | Path, dst: str | Path, *, topic: str | None = None,
                  max_bytes: int | None = None) -> ImportResult:
    """Raw Oculus message streams and ViewPoint ``.oculus`` logs -> ``sonar/ping``."""
    from drivers.oculus_file import DEFAULT_MAX_BYTES, iter_oculus_file

    result = ImportResult()
    pings = iter_oculus_file(src, on_skip=result.skip, max_bytes=max_bytes or DEFAULT_MAX_BYTES)
    return _write(pings, dst, topic or "sonar/ping", result)


def import_candump(src: str | Path, dst: str | Path, *, topic: str | None = None,
                   max_bytes: int | None = None) -> ImportResult:
    """``candump -L`` and python-can ``.log`` files -> ``can/frame`` (``max_bytes`` unused: nothing is compressed)."""
    from drivers.candump import read_candump

    result = ImportResult(unit="line")
    frames = read_candump(src, errors="skip", on_skip=result.skip)
    return _write(frames, dst, topic or "can/frame", result)


IMPORTERS: dict[str, Callable[..., ImportResult]] = {"oculus": import_oculus, "candump": import_candump}
