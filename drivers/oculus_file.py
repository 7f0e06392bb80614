"""Read recorded Oculus data as SonarPing messages: raw TCP message streams and ViewPoint ``.oculus`` v1 logs.

``iter_oculus_file(path)`` detects the format from the first bytes:

* ViewPoint v1 ("RmLog", magic 0x11223344): a 48 B file header, then items of a 40 B header and a
  payload; type-10 items hold one SimplePingResult (``compression`` 1 = Qt ``qCompress``: a 4-byte
  big-endian length and a zlib stream). Stamps are the item times (seconds since the epoch, to the microsecond).
* Anything else is read as a raw back-to-back message stream (what TCP 52100 carries, like the
  shared liboculus samples), resynchronising on the 0x4F53 magic. Raw streams carry no host time:
  V2 pings are stamped with ``pingStartTime`` (device seconds), V1 pings ``start_ns + k * period_s``.

ViewPoint v2 logs (SQLite) raise ``ValueError``. Bad items are skipped, each reported with its
byte offset (``on_skip``), and nothing is allocated beyond the file's size and ``max_bytes``.
"""
from __future__ import annotations

import logging
import math
import mmap
import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Callable, Iterator

import msgspec
import numpy as np

from drivers.oculus import sonar_ping_from
from drivers.oculus_protocol import MSG_PING, Header, ProtocolError, decode_ping
from drivers.oculus_stream import Frame, StreamParser
from msgs.sonar import SonarPing

if TYPE_CHECKING:
    from tether.imports import ImportResult

log = logging.getLogger("tether.oculus_file")

RMLOG_MAGIC = 0x11223344
RMLOG_ITEM_MAGIC = 0xAABBCCDD
ITEM_MAGIC_BYTES = struct.pack("<I", RMLOG_ITEM_MAGIC)
RMLOG_HEADER = struct.Struct("<2I16s2H4xqd")     # 48 B
RMLOG_ITEM = struct.Struct("<2I2H4xdH2x2I4x")    # 40 B
RT_OCULUS_SONAR = 10
_VERTICAL_APERTURE_DEG = {1: 20.0, 2: 12.0}       # M1200d, by master mode
_CHUNK = 4 << 20


def _to_ping(result_bytes: bytes, stamp_ns: int | None, *, index: int, start_ns: int, period_s: float,
             gain_encoding: str, frame_id: str) -> SonarPing:
    result = decode_ping(result_bytes, gain_encoding=gain_encoding)
    vertical = float(np.radians(_VERTICAL_APERTURE_DEG.get(result.fire.master_mode, 0.0)))
    ping = sonar_ping_from(result, stamp_ns=0, vertical_aperture_rad=vertical, frame_id=frame_id)
    if stamp_ns is None:
        stamp_ns = ping.device_stamp_ns or start_ns + int(round(index * period_s * 1e9))
    return msgspec.structs.replace(ping, stamp_ns=stamp_ns)


#: Called with (byte offset, reason) for every record skipped; the default logs it.
OnSkip = Callable[[int, str], None]
MAX_ITEM_HEADER = 4096                            # an item header longer than this is a damaged length
DEFAULT_MAX_BYTES = 64 << 20                      # one decompressed item; a M1200d ping is < 2 MiB
_NS_LIMIT_S = ((1 << 63) - 1) / 1e9               # item times past 2262 do not fit a stamp


def _log_skip(offset: int, reason: str) -> None:
    log.warning("skipping the record at byte %d: %s", offset, reason)


def _iter_raw(f: BinaryIO, skip: OnSkip, max_bytes: int, **kw) -> Iterator[SonarPing]:
    parser = StreamParser(accept=None, max_message_bytes=max_bytes)
    index = 0
    offset = 0                     # bytes fed so far: problems are reported at the chunk they were found in
    while chunk := f.read(_CHUNK):
        for item in parser.feed(chunk):
            if not isinstance(item, Frame):
                skip(offset, f"raw stream {item.kind}: {item.detail}")
                continue
            if item.header.msg_id != MSG_PING:
                continue
            try:
                yield _to_ping(item.data, None, index=index, **kw)
                index += 1
            except Exception as exc:  # noqa: BLE001 - any content error is this message's, not the file's
                skip(offset, f"bad ping (message {parser.frames}): {type(exc).__name__}: {exc}")
        offset += len(chunk)
    if parser.buffered():
        skip(offset - parser.buffered(), f"the stream ends with {parser.buffered()} B of an incomplete message")


def _item_payload(data: mmap.mmap | bytes, start: int, item: tuple, max_bytes: int) -> bytes:
    """The item's message bytes, decompressed within ``max_bytes``; ProtocolError when they cannot be trusted."""
    _, _, _, _, _, compression, original, size = item
    payload = data[start:start + size]
    if compression == 1:                          # Qt qCompress: 4-byte big-endian length, then zlib
        if size < 4:
            raise ProtocolError(f"a qCompress block of {size} B has no length")
        declared = struct.unpack_from(">I", payload)[0]
        if declared > max_bytes:
            raise ProtocolError(f"the qCompress block declares {declared} B, more than --max-bytes {max_bytes}")
        inflate = zlib.decompressobj()
        payload_out = inflate.decompress(payload[4:], declared + 1)      # bounded: never more than declared + 1
        if len(payload_out) > declared or inflate.unconsumed_tail:
            raise ProtocolError(f"the qCompress block inflates to more than the {declared} B it declares")
        if len(payload_out) < declared:
            raise ProtocolError(f"the qCompress block inflates to {len(payload_out)} B, not the {declared} B it declares")
        payload = payload_out
    elif compression != 0:
        raise ProtocolError(f"unknown compression {compression}")
    if original and len(payload) != original:
        raise ProtocolError(f"item payload is {len(payload)} B, header says {original} B")
    return payload


def _iter_rmlog(data: mmap.mmap | bytes, skip: OnSkip, max_bytes: int, **kw) -> Iterator[SonarPing]:
    """Items of a ViewPoint v1 log; every length is checked against the file before it is used."""
    size = len(data)
    if size < RMLOG_HEADER.size:
        raise ValueError(f"{size} B is too short for a ViewPoint log header ({RMLOG_HEADER.size} B)")
    magic, size_header, source, version, encryption, _, _ = RMLOG_HEADER.unpack_from(data)
    if encryption:
        raise ValueError("this .oculus log is encrypted; ViewPoint must export it unencrypted")
    if not RMLOG_HEADER.size <= size_header <= min(size, MAX_ITEM_HEADER):
        raise ValueError(f"the file header declares {size_header} B (expected {RMLOG_HEADER.size}..{MAX_ITEM_HEADER})")
    offset, index = size_header, 0
    while offset < size:
        if offset + RMLOG_ITEM.size > size:
            skip(offset, f"the file ends inside an item header ({size - offset} B)")
            return
        item = RMLOG_ITEM.unpack_from(data, offset)
        magic, head_size, item_type, _, time_s, _, _, payload_size = item
        start, end = offset + head_size, offset + head_size + payload_size
        problem = ("no 0xAABBCCDD item magic" if magic != RMLOG_ITEM_MAGIC else
                   f"an item header of {head_size} B" if not RMLOG_ITEM.size <= head_size <= MAX_ITEM_HEADER else
                   f"the item declares {payload_size} B but {size - start} B remain" if end > size else "")
        if problem:                                # a damaged length: find the next item rather than trust it
            nxt = data.find(ITEM_MAGIC_BYTES, offset + 1)
            if nxt < 0 and end > size and magic == RMLOG_ITEM_MAGIC:
                skip(offset, f"{problem}: the file was cut inside this item")
                return
            skip(offset, f"{problem}; " + (f"resuming at the next item, byte {nxt}" if nxt >= 0 else "no item follows"))
            if nxt < 0:
                return
            offset = nxt
            continue
        offset = end
        if item_type != RT_OCULUS_SONAR:
            continue
        if not (math.isfinite(time_s) and 0.0 <= time_s < _NS_LIMIT_S):
            skip(start - head_size, f"item time {time_s!r} s is not a time")
            continue
        try:
            payload = _item_payload(data, start, item, max_bytes)
            if Header.unpack(payload).msg_id != MSG_PING:
                continue
            yield _to_ping(payload, int(round(time_s * 1e6)) * 1000, index=index, **kw)   # f64 s: keep µs
            index += 1
        except Exception as exc:  # noqa: BLE001 - zlib, struct, protocol, numpy: this item is bad, the next may not be
            skip(start - head_size, f"bad item: {type(exc).__name__}: {exc}")


def iter_oculus_file(path: str | Path, *, gain_encoding: str = "float", start_ns: int = 0,
                     period_s: float = 0.1, frame_id: str = "sonar", on_skip: OnSkip | None = None,
                     max_bytes: int = DEFAULT_MAX_BYTES) -> Iterator[SonarPing]:
    """Yield every SimplePingResult in ``path`` as a SonarPing, in file order.

    Parameters
    ----------
    path : a raw message stream or a ViewPoint ``.oculus`` v1 log.
    gain_encoding : how to read the 4-byte row gain ('float' or 'u32').
    start_ns, period_s : stamps of V1 pings in raw streams (which carry no usable time).
    on_skip : called with (byte offset, reason) for each record skipped (default: a log line each).
    max_bytes : the most one message may take once decompressed; a larger declared size is skipped.

    Nothing is allocated beyond the file's own size and ``max_bytes``: v1 logs are memory-mapped,
    every declared length is checked against what the file holds, and damaged items are skipped
    (resynchronising on the next item magic).
    """
    skip = on_skip or _log_skip
    with open(path, "rb") as f:
        first = f.read(16)
        f.seek(0)
        if first.startswith(b"SQLite format 3\0"):
            raise ValueError(f"{path} is a ViewPoint v2 (SQLite) log; only v1 logs and raw streams are supported")
        kw = dict(start_ns=start_ns, period_s=period_s, gain_encoding=gain_encoding, frame_id=frame_id)
        if len(first) >= 4 and struct.unpack_from("<I", first)[0] == RMLOG_MAGIC:
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
                try:
                    yield from _iter_rmlog(data, skip, max_bytes, **kw)
                except ValueError as exc:              # the file header itself: nothing to import
                    raise ValueError(f"{path}: {exc}") from None
        else:
            yield from _iter_raw(f, skip, max_bytes, **kw)


def write_rmlog(path: str | Path, messages: list[tuple[float, bytes]], *, compress: bool = False) -> None:
    """Write ``(time_s, message_bytes)`` pairs as a ViewPoint v1 log (for tests and exports)."""
    with open(path, "wb") as f:
        f.write(RMLOG_HEADER.pack(RMLOG_MAGIC, RMLOG_HEADER.size, b"Oculus", 1, 0, 0,
                                  messages[0][0] if messages else 0.0))
        for t, data in messages:
            payload = struct.pack(">I", len(data)) + zlib.compress(data) if compress else data
            f.write(RMLOG_ITEM.pack(RMLOG_ITEM_MAGIC, RMLOG_ITEM.size, RT_OCULUS_SONAR, 0, t, int(compress),
                                    len(data), len(payload)))
            f.write(payload)


def import_oculus(src: str | Path, dst: str | Path, *, topic: str | None = None,
                  max_bytes: int | None = None, skip_bad: bool = False) -> "ImportResult":
    """``tether import oculus``: raw Oculus message streams and ViewPoint ``.oculus`` logs -> ``sonar/ping``.
    A bad record ends the import with one line naming its byte offset, or with ``skip_bad`` is counted."""
    from tether.imports import ImportResult, write_messages

    result = ImportResult(skip_bad=skip_bad, source=str(src))
    pings = iter_oculus_file(src, on_skip=result.skip, max_bytes=max_bytes or DEFAULT_MAX_BYTES)
    return write_messages(pings, dst, topic or "sonar/ping", result)
