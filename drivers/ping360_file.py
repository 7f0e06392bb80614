"""``tether import ping360``: a recorded Ping360 byte stream (what came down the serial line,
e.g. ``cat /dev/ttyUSB0 > scan.bin`` or a serial sniffer's capture) -> ``sonar/ping`` beams.

Ping Viewer's own ``.bin`` logs wrap the same frames in a Qt serialisation whose layout is
not documented; they are read here only as far as the Ping frames inside them go (the parser
skips everything between frames, so the beams come out, without Ping Viewer's timestamps).
Stamps: the file has none, so beam k is stamped ``start_ns + k * period_s``.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from drivers import ping_protocol as pp
from drivers.ping360 import beam_ping
from msgs.sonar import SonarPing

if TYPE_CHECKING:
    from tether.imports import ImportResult

CHUNK = 1 << 16


def iter_ping360_stream(path: str | Path, *, start_ns: int = 0, period_s: float = 0.01, sound_speed_mps: float = 1500.0,
                        on_skip=None) -> Iterator[SonarPing]:
    """Beams of a raw stream; ``on_skip(offset, reason)`` for frames that cannot be beams and for
    checksum failures (offsets are approximate: the chunk the parser was reading)."""
    parser = pp.PingParser()
    seen_bad = 0
    k = 0
    offset = 0
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            for frame in parser.feed(chunk):
                if frame.message_id not in (pp.DEVICE_DATA, pp.AUTO_DEVICE_DATA):
                    continue
                try:
                    beam = pp.decode_beam(frame.message_id, frame.payload)
                except pp.PingProtocolError as exc:
                    if on_skip:
                        on_skip(offset, str(exc))
                    continue
                if not len(beam.samples):
                    continue
                k += 1
                yield beam_ping(beam, stamp_ns=start_ns + int(round((k - 1) * period_s * 1e9)),
                                sound_speed_mps=sound_speed_mps, frame_id="ping360", seq_id=k)
            bad = parser.checksum_errors + parser.bad_lengths
            if on_skip:
                for _ in range(bad - seen_bad):
                    on_skip(offset, "a frame with a wrong checksum or an impossible length")
            seen_bad = bad
            offset += len(chunk)


def import_ping360(src: str | Path, dst: str | Path, *, topic: str | None = None, skip_bad: bool = False,
                   **_: object) -> "ImportResult":
    """``tether import ping360``: raw Ping360 byte streams -> ``sonar/ping`` (one beam per message).
    A bad frame ends the import with one line, or with ``skip_bad`` is counted and skipped."""
    from tether.imports import ImportResult, write_messages

    result = ImportResult(skip_bad=skip_bad, source=str(src))
    beams = iter_ping360_stream(src, on_skip=result.skip)
    return write_messages(beams, dst, topic or "sonar/ping", result)
