"""Importers of foreign logs into tether logs (``tether import KIND FILE -o LOG [--skip-bad]``).

Each importer lives with its driver and is found by entry point (group ``tether.importers``),
so the runtime holds no protocol code and imports no driver; it streams the foreign file
through the driver's parser and writes a tether MCAP log (:func:`write_messages`). Foreign files are
untrusted input: a parser bounds what it allocates by the file's own size (and by
``max_bytes`` for anything it decompresses) and reports every bad record to
:meth:`ImportResult.skip` with its offset. By default the first bad record ends the import
with one :class:`DecodeError` line naming the file and the place (no log is left behind);
with ``skip_bad`` (``--skip-bad``) it is counted, the first few are logged, and the rest of
the file is imported. Whatever an importer's parser or the log writer raises beyond that
becomes the same one line (or, with ``skip_bad``, a counted skip): never a traceback.

An importer is ``import_KIND(src, dst, *, topic=None, max_bytes=None, skip_bad=False) -> ImportResult``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Callable, Iterable

from tether.errors import ConfigError, DecodeError, TetherError
from tether.log import LogWriter
from tether.message import Message

log = logging.getLogger("tether.import")

GROUP = "tether.importers"
MAX_SKIP_LINES = 20         # then one summary: a wholly damaged file must not flood the terminal
INT64_MAX = (1 << 63) - 1   # a stamp the codec and every reader of the log can hold
SKIP_HINT = "--skip-bad skips such records and imports the rest"


def _one_line(text: str, limit: int = 300) -> str:
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[:limit] + "..."


@dataclass
class ImportResult:
    """``imported`` messages written; ``skipped`` records refused (the first few logged with where and why).

    ``skip_bad=False``: :meth:`skip` raises :class:`DecodeError` instead of counting.
    ``source`` names the file in that error."""

    imported: int = 0
    skipped: int = 0
    unit: str = "byte"          # what a skip's offset counts: "byte", "line" or "message"
    skip_bad: bool = False
    source: str = ""

    def skip(self, offset: int, reason: str, *, unit: str | None = None) -> None:
        where = f"{unit or self.unit} {offset}"
        if not self.skip_bad:
            prefix = f"{self.source}: " if self.source else ""
            raise DecodeError(f"{prefix}{where}: {_one_line(reason)} ({SKIP_HINT})")
        self.skipped += 1
        if self.skipped <= MAX_SKIP_LINES:
            log.warning("skipped the record at %s: %s", where, _one_line(reason))
        elif self.skipped == MAX_SKIP_LINES + 1:
            log.warning("more records skipped; the count follows at the end")

    def summary(self, src: str | Path, dst: str | Path) -> str:
        text = f"imported {self.imported} messages from {src} into {dst}"
        return text + (f"; skipped {self.skipped} bad records" if self.skipped else "")


def write_messages(messages: Iterable[Message], dst: str | Path, topic: str, result: ImportResult) -> ImportResult:
    """Write an importer's messages to a tether log, log time = acquisition stamp (kept monotonic).

    A message the log cannot hold (a stamp outside int64, a field the codec refuses) is a bad
    record like any other (:meth:`ImportResult.skip`, counted by message). A parser that fails
    with anything but its own ``ValueError`` (a bug, a third-party reader's surprise) ends the
    import with one line, or with ``skip_bad`` keeps what was read and counts the failure.
    On an error the partial log is removed."""
    dst = Path(dst)
    try:
        with LogWriter(dst) as out:
            last = 0
            produced = 0
            iterator = iter(messages)
            while True:
                try:
                    msg = next(iterator)
                except StopIteration:
                    break
                except (TetherError, ValueError, OSError):
                    raise
                except Exception as exc:  # noqa: BLE001 - a parser's surprise ends the file, never in a traceback
                    result.skip(produced + 1, f"the reader stopped: {type(exc).__name__}: {exc}", unit="message")
                    break
                produced += 1
                problem = _unwritable(msg)
                if problem:
                    result.skip(produced, problem, unit="message")
                    continue
                # Log time = acquisition stamp, kept monotonic for files whose clock steps back.
                stamp = msg.stamp_ns
                last = min(max(last + 1, stamp) if stamp > 0 else last + 1, INT64_MAX)
                try:
                    out.write(topic, msg, log_time_ns=last)
                except (OverflowError, ValueError, TypeError) as exc:
                    result.skip(produced, f"cannot be written: {type(exc).__name__}: {exc}", unit="message")
                    continue
                result.imported += 1
    except BaseException:
        dst.unlink(missing_ok=True)
        raise
    return result


def _unwritable(msg: Message) -> str:
    stamp = getattr(msg, "stamp_ns", None)
    if not isinstance(stamp, int) or not -INT64_MAX - 1 <= stamp <= INT64_MAX:
        return f"stamp {stamp!r} ns does not fit a signed 64-bit time"
    return ""


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
