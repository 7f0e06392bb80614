"""Importers of foreign logs into tether logs (``tether import KIND FILE -o LOG``).

Each importer lives with its driver and is found by entry point (group ``tether.importers``),
so the runtime holds no protocol code and imports no driver; it streams the foreign file
through the driver's parser and writes a tether MCAP log (:func:`write_messages`). Foreign files are
untrusted input: a parser bounds what it allocates by the file's own size (and by
``max_bytes`` for anything it decompresses), and a bad record is skipped and reported
with its offset, never fatal. :class:`ImportResult` says what came in and what did not.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from importlib.metadata import EntryPoint, entry_points
from typing import Callable, Iterable

from tether.errors import ConfigError

from tether.log import LogWriter
from tether.message import Message

log = logging.getLogger("tether.import")

GROUP = "tether.importers"
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


def write_messages(messages: Iterable[Message], dst: str | Path, topic: str, result: ImportResult) -> ImportResult:
    """Write an importer's messages to a tether log, log time = acquisition stamp (kept monotonic)."""
    with LogWriter(dst) as out:
        last = 0
        for msg in messages:
            # Log time = acquisition stamp, kept monotonic for files whose clock steps back.
            last = max(last + 1, msg.stamp_ns) if msg.stamp_ns > 0 else last + 1
            out.write(topic, msg, log_time_ns=last)
            result.imported += 1
    return result


def importers() -> dict[str, EntryPoint]:
    """Import verbs by name: every ``tether.importers`` entry point of the installed packages
    (this project's drivers register theirs in pyproject.toml; a third-party package adds one the
    same way, as python-can finds its backends). Nothing is imported until a verb is used."""
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def importer(kind: str) -> Callable[..., ImportResult]:
    """The import function registered as ``kind``; a ConfigError naming the known ones otherwise."""
    found = importers()
    if kind not in found:
        known = ", ".join(sorted(found)) or "none (is the package installed? pip install -e .)"
        raise ConfigError(f"no importer {kind!r}; registered: {known}")
    return found[kind].load()
