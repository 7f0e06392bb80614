"""Importers of foreign logs into tether logs (``tether import KIND FILE -o LOG``).

Each importer streams the foreign file through a parser that lives with its driver
(the runtime holds no protocol code) and writes a tether MCAP log.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

from tether.log import LogWriter
from tether.message import Message


def _write(messages: Iterable[Message], dst: str | Path, topic: str) -> int:
    n = 0
    with LogWriter(dst) as log:
        last = 0
        for msg in messages:
            # Log time = acquisition stamp, kept monotonic for files whose clock steps back.
            last = max(last + 1, msg.stamp_ns) if msg.stamp_ns else last + 1
            log.write(topic, msg, log_time_ns=last)
            n += 1
    return n


def import_oculus(src: str | Path, dst: str | Path, *, topic: str | None = None) -> int:
    """Raw Oculus message streams and ViewPoint ``.oculus`` logs -> ``sonar/ping``."""
    from drivers.oculus_file import iter_oculus_file

    return _write(iter_oculus_file(src), dst, topic or "sonar/ping")


def import_candump(src: str | Path, dst: str | Path, *, topic: str | None = None) -> int:
    """``candump -L`` and python-can ``.log`` files -> ``can/frame``."""
    from drivers.candump import read_candump

    return _write(read_candump(src), dst, topic or "can/frame")


IMPORTERS: dict[str, Callable[..., int]] = {"oculus": import_oculus, "candump": import_candump}
