"""Export a tether log for Foxglove: the live view's conversion (:mod:`tether.foxglove_convert`)
written to an MCAP file by the Foxglove SDK, so an exported log renders like the live graph."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from tether.errors import ConfigError, DecodeError
from tether.foxglove_bridge import Counters, FoxgloveSink
from tether.foxglove_convert import foxglove
from tether.log import LogReader
from tether.message import message_type


def export_foxglove(src: str | Path | LogReader, dst: str | Path,
                    progress: Callable[[int, int], None] | None = None) -> Counters:
    """Rewrite ``src`` (a log, or its open reader: its ``damaged`` and ``truncated_at`` then tell
    what was skipped) into ``dst`` with Foxglove's schemas (images, clouds, poses, grids) and
    JSON for the rest; log times are kept. Returns the counters (``converted``, ``errors``, ...)."""
    reader = src if isinstance(src, LogReader) else LogReader(src)
    total = sum(reader.info().counts.values())
    context = foxglove.Context()
    sink = FoxgloveSink(context)
    try:
        writer = foxglove.open_mcap(dst, allow_overwrite=True, context=context)
    except OSError as exc:                   # its message does not name the file
        raise ConfigError(f"{dst}: cannot write the export there: {exc.strerror or exc}") from None
    with writer:
        for k, rec in enumerate(reader.messages(), 1):
            sink.counters.received += 1
            try:
                try:
                    msg = reader.decode_as(message_type(rec.type_name), rec)
                except KeyError:           # a type unknown here still exports, as plain JSON
                    msg = LogReader.decode_plain(rec)
            except (DecodeError, ValueError) as exc:
                sink.error(f"dropped an undecodable record on {rec.topic}: {exc}")
                continue
            sink.log(rec.topic, rec.type_name, msg, rec.log_time_ns)
            if progress is not None:
                progress(k, total)
    return sink.counters
