"""Chunk-level integrity of MCAP logs: find damaged chunks, read around them, recover the rest.

Every MCAP chunk carries the CRC32 of its uncompressed records. A flipped bit in a chunk
either breaks its zstd/lz4 frame or fails that CRC; both make the chunk *damaged*, and
every other chunk still reads. Chunks are located from the summary's chunk index when the
file has one (robust to damage elsewhere in the file) and by walking the records when it
does not (a recorder killed mid-write leaves no summary).
"""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import breakup_chunk

MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK = 0x06
OP_DATA_END = 0x0F
OP_FOOTER = 0x02


@dataclass(frozen=True)
class DamagedChunk:
    """A chunk that cannot be read: where it is, what time it covered, why."""

    index: int
    offset: int
    start_ns: int
    end_ns: int
    reason: str

    def describe(self) -> str:
        return (f"chunk {self.index} at byte {self.offset} (log time {self.start_ns}..{self.end_ns} ns): "
                f"{self.reason}")


@dataclass
class LogCheck:
    """The result of :func:`check_log`."""

    path: str
    chunks: int = 0
    damaged: list[DamagedChunk] = field(default_factory=list)
    indexed: bool = False          # chunks found from the summary (else by walking the file)
    truncated_at: int = -1         # walking stopped at this byte: the rest is unreadable (-1: read to the end)

    @property
    def ok(self) -> bool:
        return not self.damaged and self.truncated_at < 0


@dataclass(frozen=True)
class ChunkRef:
    index: int
    offset: int                    # of the chunk record's opcode byte
    start_ns: int
    end_ns: int


def _summary_chunks(fh: IO[bytes]) -> list[ChunkRef] | None:
    try:
        summary = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - no footer or a damaged summary: walk the file instead
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    ordered = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    return [ChunkRef(i, c.chunk_start_offset, c.message_start_time, c.message_end_time) for i, c in enumerate(ordered)]


def _walk_chunks(fh: IO[bytes], size: int) -> tuple[list[ChunkRef], int]:
    """Chunks found by following record lengths from the start; and where that stopped early (-1: it did not)."""
    fh.seek(0)
    if fh.read(8) != MAGIC:
        return [], 0
    refs: list[ChunkRef] = []
    offset = 8
    while offset + 9 <= size:
        fh.seek(offset)
        opcode, length = struct.unpack("<BQ", fh.read(9))
        if offset + 9 + length > size:
            return refs, offset
        if opcode == OP_CHUNK and length >= 16:
            start, end = struct.unpack("<QQ", fh.read(16))
            refs.append(ChunkRef(len(refs), offset, start, end))
        if opcode in (OP_DATA_END, OP_FOOTER):
            return refs, -1
        offset += 9 + length
    return refs, -1 if offset == size else offset


def read_chunk(fh: IO[bytes], ref: ChunkRef) -> list:
    """The records of one chunk, CRC-checked; raises on any damage."""
    fh.seek(ref.offset)
    opcode, length = struct.unpack("<BQ", fh.read(9))
    if opcode != OP_CHUNK:
        raise ValueError(f"no chunk record at byte {ref.offset} (opcode {opcode:#x})")
    chunk = Chunk.read(ReadDataStream(io.BytesIO(fh.read(length))))
    return list(breakup_chunk(chunk, validate_crc=True))


def chunk_refs(fh: IO[bytes]) -> tuple[list[ChunkRef], bool, int]:
    """``(chunks, indexed, truncated_at)`` of an open log."""
    fh.seek(0, io.SEEK_END)
    size = fh.tell()
    fh.seek(0)
    refs = _summary_chunks(fh)
    if refs is not None:
        return refs, True, -1
    walked, stopped = _walk_chunks(fh, size)
    return walked, False, stopped


def check_log(path: str | Path) -> LogCheck:
    """Read every chunk of ``path`` and verify it; damaged chunks are listed, none is fatal."""
    result = LogCheck(str(path))
    with open(path, "rb") as fh:
        refs, result.indexed, result.truncated_at = chunk_refs(fh)
        result.chunks = len(refs)
        for ref in refs:
            try:
                read_chunk(fh, ref)
            except Exception as exc:  # noqa: BLE001 - zstd, lz4, CRC and record errors all mean "damaged"
                result.damaged.append(DamagedChunk(ref.index, ref.offset, ref.start_ns, ref.end_ns,
                                                   f"{type(exc).__name__}: {str(exc)[:120]}"))
    return result
