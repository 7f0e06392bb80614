"""MCAP logs: msgpack-encoded channels with JSON schemas, zstd chunks, indexed.

A log written by :class:`LogWriter` is an ordinary MCAP file: any MCAP reader lists its
topics, and any msgpack reader decodes its messages (arrays are maps with inline
``data``). Chunks are finalised at least every ``flush_period_s``, so a recorder killed
mid-recording leaves every message up to the last completed chunk readable;
:class:`LogReader` recovers such a file by streaming it (it has no summary to seek by).
"""
from __future__ import annotations

import heapq
import itertools
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

import msgpack
from mcap.reader import make_reader
from mcap.records import Channel, Message as McapMessage, Schema
from mcap.writer import CompressionType, Writer

from tether.codec import Codec, json_schema
from tether.errors import DecodeError
from tether.logcheck import MAGIC, ChunkRef, DamagedChunk, chunk_refs, read_chunk
from tether.message import Message, message_type
from tether.paths import not_regular

log = logging.getLogger("tether.log")

U64_MAX = (1 << 64) - 1
MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"


@dataclass(frozen=True)
class LogRecord:
    """One message of a log, still encoded: decode with :meth:`LogReader.decode`."""

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    sequence: int = 0


class LogWriter:
    """Write tether messages (or already-encoded records) to an MCAP file.

    >>> with LogWriter("run.mcap") as log:
    ...     log.write("sonar/ping", ping)
    """

    def __init__(self, path: str | Path, *, chunk_size: int = 1 << 20, flush_period_s: float = 1.0,
                 compression: str = "zstd", metadata: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh: IO[bytes] = open(self.path, "wb")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
        self._writer = Writer(self._fh, chunk_size=chunk_size, compression=comp)
        self._writer.start(profile="tether", library="tether")
        if metadata:
            self._writer.add_metadata("tether", {k: str(v) for k, v in metadata.items()})
        self._fh.flush()         # a writer killed before its first chunk still leaves a valid start
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._codec = Codec()
        self._flush_period_ns = int(flush_period_s * 1e9)
        self._last_flush = time.monotonic_ns()
        self.count = 0
        self._closed = False

    def _schema_id(self, type_name: str) -> int:
        sid = self._schemas.get(type_name)
        if sid is None:
            try:
                schema = json.dumps(json_schema(message_type(type_name))).encode()
            except KeyError:
                schema = b"{}"   # a type this process cannot import: the record still round-trips as msgpack
            sid = self._schemas[type_name] = self._writer.register_schema(type_name, SCHEMA_ENCODING, schema)
        return sid

    def _channel_id(self, topic: str, type_name: str) -> int:
        key = (topic, type_name)
        cid = self._channels.get(key)
        if cid is None:
            cid = self._channels[key] = self._writer.register_channel(
                topic, MESSAGE_ENCODING, self._schema_id(type_name), metadata={"tether_type": type_name})
        return cid

    def write(self, topic: str, msg: Message, *, log_time_ns: int | None = None) -> None:
        """Append a typed message (log time defaults to now; publish time is its stamp)."""
        self.write_encoded(topic, msg.type_name(), self._codec.encode_inline(msg),
                           log_time_ns=log_time_ns, publish_time_ns=msg.stamp_ns, sequence=msg.seq % (1 << 32))

    def write_encoded(self, topic: str, type_name: str, data: bytes, *, log_time_ns: int | None = None,
                      publish_time_ns: int = 0, sequence: int = 0) -> None:
        """Append an already-encoded (inline msgpack) message."""
        now = time.time_ns() if log_time_ns is None or not 0 <= log_time_ns <= U64_MAX else log_time_ns
        # MCAP times are uint64: a stamp of -1 or beyond 2^64 is kept exactly in the message body and
        # indexed by the log time instead (an absurd stamp must never stop a recording).
        publish = publish_time_ns if 0 < publish_time_ns <= U64_MAX else now
        self._writer.add_message(self._channel_id(topic, type_name), log_time=now, data=data,
                                 publish_time=publish, sequence=sequence & 0xFFFFFFFF)
        self.count += 1
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Finalise the open chunk if ``flush_period_s`` has passed (crash tolerance for slow streams)."""
        if time.monotonic_ns() - self._last_flush >= self._flush_period_ns:
            self.flush()

    def flush(self) -> None:
        self._writer.flush()         # closes the open chunk ...
        self._fh.flush()             # ... and hands it to the OS, so a killed recorder keeps it
        self._last_flush = time.monotonic_ns()

    def close(self) -> None:
        """Finish the file (summary and footer) and close it; the file is closed even if finishing fails."""
        if not self._closed:
            self._closed = True
            try:
                self._writer.finish()
            finally:
                self._fh.close()

    def abandon(self) -> None:
        """Close the file without finishing it, after a write failed (disk full, I/O error): what was
        flushed before stays readable (``tether log --recover``); a failure to close is ignored."""
        if not self._closed:
            self._closed = True
            try:
                self._fh.close()
            except OSError:
                pass

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass
class LogInfo:
    """What a log holds."""

    path: str
    topics: dict[str, str] = field(default_factory=dict)        # topic -> type
    counts: dict[str, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    recovered: bool = False                                     # read by streaming an unfinished file

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.end_ns else 0.0


class LogReader:
    """Read a tether MCAP log, indexed when it is complete, by streaming when it is not."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"no log at {self.path}")
        what = not_regular(self.path)
        if what:
            raise DecodeError(f"{self.path}: {what}, not a log file (give a tether .mcap file)")
        try:
            with open(self.path, "rb") as fh:
                head = fh.read(len(MAGIC))
        except OSError as exc:
            raise DecodeError(f"{self.path}: cannot read: {exc.strerror}") from None
        if not MAGIC.startswith(head):      # a shorter head is a log cut before its first record: recovered below
            raise DecodeError(f"{self.path}: not an MCAP log (it does not start with MCAP's magic bytes; "
                              "a foreign log goes through 'tether import')")
        self._codec = Codec()
        self.recovered = False
        self._told_truncated = False
        self.damaged: list[DamagedChunk] = []      # chunks skipped by the last messages() pass
        self.truncated_at = -1                      # the byte the last messages() pass could read no further from
        self._summary = None
        with open(self.path, "rb") as fh:
            try:
                self._summary = make_reader(fh).get_summary()
            except Exception:  # noqa: BLE001 - no footer / truncated: fall back to streaming
                self._summary = None
        if self._summary is None:
            self.recovered = True

    def info(self) -> LogInfo:
        info = LogInfo(path=str(self.path), recovered=self.recovered)
        if self._summary is not None and self._summary.statistics is not None:
            stats = self._summary.statistics
            for cid, ch in self._summary.channels.items():
                info.topics[ch.topic] = ch.metadata.get("tether_type") or self._summary.schemas[ch.schema_id].name
                info.counts[ch.topic] = info.counts.get(ch.topic, 0) + stats.channel_message_counts.get(cid, 0)
            info.start_ns, info.end_ns = stats.message_start_time, stats.message_end_time
            return info
        for rec in self.messages():
            info.topics.setdefault(rec.topic, rec.type_name)
            info.counts[rec.topic] = info.counts.get(rec.topic, 0) + 1
            info.start_ns = rec.log_time_ns if not info.start_ns else min(info.start_ns, rec.log_time_ns)
            info.end_ns = max(info.end_ns, rec.log_time_ns)
        return info

    def messages(self, topics: Iterable[str] | None = None, *, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[LogRecord]:
        """Records in log-time order; ``start_ns``/``end_ns`` are absolute log times (end exclusive).

        Chunks are CRC-checked as they are read; a damaged one is skipped with one log line
        and listed in :attr:`damaged` (the messages of every other chunk still come).
        """
        wanted = set(topics) if topics is not None else None
        self.damaged = []
        with open(self.path, "rb") as fh:
            refs, indexed, truncated_at = chunk_refs(fh)
            self.truncated_at = truncated_at
            schemas: dict[int, Schema] = dict(self._summary.schemas) if indexed and self._summary else {}
            channels: dict[int, Channel] = dict(self._summary.channels) if indexed and self._summary else {}
            if indexed:   # with the summary's channels known, chunks outside the window need not be read
                refs = [r for r in refs if (start_ns is None or r.end_ns >= start_ns)
                        and (end_ns is None or r.start_ns < end_ns)]
            refs.sort(key=lambda r: (r.start_ns, r.offset))
            heap: list[tuple[int, int, McapMessage]] = []
            order = itertools.count()
            i = 0
            while i < len(refs) or heap:
                # Load every chunk that may hold a message older than the oldest pending one.
                if i < len(refs) and (not heap or refs[i].start_ns <= heap[0][0]):
                    for record in self._chunk(fh, refs[i]):
                        if isinstance(record, Schema):
                            schemas[record.id] = record
                        elif isinstance(record, Channel):
                            channels[record.id] = record
                        elif isinstance(record, McapMessage) and (start_ns is None or record.log_time >= start_ns) \
                                and (end_ns is None or record.log_time < end_ns):
                            heapq.heappush(heap, (record.log_time, next(order), record))
                    i += 1
                    continue
                _, _, message = heapq.heappop(heap)
                channel = channels.get(message.channel_id)
                if channel is None or (wanted is not None and channel.topic not in wanted):
                    continue     # not wanted, or its channel was defined in a damaged chunk
                yield self._record(schemas.get(channel.schema_id), channel, message)
            if truncated_at >= 0 and not self._told_truncated:    # once per reader: info() reads it all too
                self._told_truncated = True
                log.warning("%s: log ends early at byte %d; read every complete chunk before it", self.path,
                            truncated_at)

    def _chunk(self, fh: IO[bytes], ref: ChunkRef) -> list:
        try:
            return read_chunk(fh, ref)
        except Exception as exc:  # noqa: BLE001 - zstd, lz4, CRC and record errors all mean "damaged"
            bad = DamagedChunk(ref.index, ref.offset, ref.start_ns, ref.end_ns, f"{type(exc).__name__}: {exc}")
            self.damaged.append(bad)
            log.error("%s: skipping damaged %s (%d damaged so far)", self.path, bad.describe(), len(self.damaged))
            return []

    @staticmethod
    def _record(schema: Schema | None, channel: Channel, message: McapMessage) -> LogRecord:
        type_name = channel.metadata.get("tether_type") or (schema.name if schema else "")
        return LogRecord(channel.topic, type_name, message.log_time, message.publish_time, message.data,
                         message.sequence)

    def schemas(self) -> dict[str, bytes]:
        """The JSON schema each type had when it was recorded, by type name (empty for a recovered log)."""
        if self._summary is None:
            return {}
        return {schema.name: schema.data for schema in self._summary.schemas.values()}

    def decode_as(self, tp: type[Message], record: LogRecord) -> Message:
        """Decode a record as ``tp`` (a newer version of the recorded type reads an older record)."""
        return self._codec.decode_inline(tp, record.data)

    def decode(self, record: LogRecord) -> Message:
        """The typed message of a record (``DecodeError`` if its type is unknown here or it is malformed)."""
        try:
            tp = message_type(record.type_name)
        except KeyError as exc:
            raise DecodeError(str(exc)) from None
        return self.decode_as(tp, record)

    @staticmethod
    def decode_plain(record: LogRecord) -> Any:
        """The record as plain msgpack (dicts, lists, bytes): no type needed."""
        return msgpack.unpackb(record.data, raw=False, strict_map_key=False)


def recover_log(src: str | Path, dst: str | Path) -> tuple[int, list[DamagedChunk], int]:
    """Copy every readable message of ``src`` into a new, complete log ``dst``.

    Returns ``(written, damaged_chunks, lost)`` where ``lost`` is the count the source's
    statistics promised minus what was written (-1 when the source has no statistics).
    """
    reader = LogReader(src)
    expected = -1
    if reader._summary is not None and reader._summary.statistics is not None:
        expected = reader._summary.statistics.message_count
    written = 0
    with LogWriter(dst, metadata={"recovered_from": str(src)}) as writer:
        for rec in reader.messages():
            writer.write_encoded(rec.topic, rec.type_name, rec.data, log_time_ns=rec.log_time_ns,
                                 publish_time_ns=rec.publish_time_ns, sequence=rec.sequence)
            written += 1
    return written, reader.damaged, (expected - written if expected >= 0 else -1)
