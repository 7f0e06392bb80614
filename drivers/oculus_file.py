"""Read recorded Oculus data as SonarPing messages: raw TCP message streams and ViewPoint ``.oculus`` v1 logs.

``iter_oculus_file(path)`` detects the format from the first bytes:

* ViewPoint v1 ("RmLog", magic 0x11223344): a 48 B file header, then items of a 40 B header and a
  payload; type-10 items hold one SimplePingResult (``compression`` 1 = Qt ``qCompress``: a 4-byte
  big-endian length and a zlib stream). Stamps are the item times (seconds since the epoch, to the microsecond).
* Anything else is read as a raw back-to-back message stream (what TCP 52100 carries, like the
  shared liboculus samples), resynchronising on the 0x4F53 magic. Raw streams carry no host time:
  V2 pings are stamped with ``pingStartTime`` (device seconds), V1 pings ``start_ns + k * period_s``.

ViewPoint v2 logs (SQLite) raise ``ValueError``. Bad items are logged, counted and skipped.
"""
from __future__ import annotations

import logging
import struct
import zlib
from pathlib import Path
from typing import BinaryIO, Iterator

import msgspec
import numpy as np

from drivers.oculus import sonar_ping_from
from drivers.oculus_protocol import MSG_PING, Header, ProtocolError, decode_ping
from drivers.oculus_stream import Frame, StreamParser
from msgs.sonar import SonarPing

log = logging.getLogger("tether.oculus_file")

RMLOG_MAGIC = 0x11223344
RMLOG_ITEM_MAGIC = 0xAABBCCDD
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


def _iter_raw(f: BinaryIO, **kw) -> Iterator[SonarPing]:
    parser = StreamParser(accept=None)
    index = 0
    while chunk := f.read(_CHUNK):
        for item in parser.feed(chunk):
            if not isinstance(item, Frame):
                log.warning("raw oculus stream %s: %s", item.kind, item.detail)
                continue
            if item.header.msg_id != MSG_PING:
                continue
            try:
                yield _to_ping(item.data, None, index=index, **kw)
                index += 1
            except ProtocolError as exc:
                log.warning("skipping bad ping at message %d: %s", parser.frames, exc)
    if parser.buffered():
        log.warning("raw oculus stream ends with %d B of an incomplete message", parser.buffered())


def _item_payload(f: BinaryIO, item: tuple) -> bytes | None:
    _, _, _, _, _, compression, original, size = item
    payload = f.read(size)
    if len(payload) < size:
        log.warning("oculus log truncated inside an item (%d of %d B)", len(payload), size)
        return None
    if compression == 1:
        payload = zlib.decompress(payload[4:])       # Qt qCompress: 4-byte big-endian length, then zlib
    elif compression != 0:
        raise ProtocolError(f"unknown compression {compression}")
    if original and len(payload) != original:
        raise ProtocolError(f"item payload is {len(payload)} B, header says {original} B")
    return payload


def _iter_rmlog(f: BinaryIO, **kw) -> Iterator[SonarPing]:
    head = f.read(RMLOG_HEADER.size)
    magic, size_header, source, version, encryption, _, _ = RMLOG_HEADER.unpack(head)
    if encryption:
        raise ValueError("this .oculus log is encrypted; ViewPoint must export it unencrypted")
    f.seek(size_header)
    index = 0
    while raw := f.read(RMLOG_ITEM.size):
        if len(raw) < RMLOG_ITEM.size:
            log.warning("oculus log ends inside an item header (%d B)", len(raw))
            return
        item = RMLOG_ITEM.unpack(raw)
        if item[0] != RMLOG_ITEM_MAGIC:
            log.warning("oculus log item without the 0xAABBCCDD magic at byte %d; stopping", f.tell() - len(raw))
            return
        if item[1] > RMLOG_ITEM.size:
            f.seek(item[1] - RMLOG_ITEM.size, 1)
        try:
            payload = _item_payload(f, item)
            if payload is None:
                return
            if item[2] != RT_OCULUS_SONAR or Header.unpack(payload).msg_id != MSG_PING:
                continue
            yield _to_ping(payload, int(round(item[4] * 1e6)) * 1000, index=index, **kw)   # f64 s: keep µs
            index += 1
        except (ProtocolError, zlib.error, struct.error) as exc:
            log.warning("skipping bad oculus log item %d: %s", index, exc)


def iter_oculus_file(path: str | Path, *, gain_encoding: str = "float", start_ns: int = 0,
                     period_s: float = 0.1, frame_id: str = "sonar") -> Iterator[SonarPing]:
    """Yield every SimplePingResult in ``path`` as a SonarPing, in file order.

    Parameters
    ----------
    path : a raw message stream or a ViewPoint ``.oculus`` v1 log.
    gain_encoding : how to read the 4-byte row gain ('float' or 'u32').
    start_ns, period_s : stamps of V1 pings in raw streams (which carry no usable time).
    """
    with open(path, "rb") as f:
        first = f.read(16)
        f.seek(0)
        if first.startswith(b"SQLite format 3\0"):
            raise ValueError(f"{path} is a ViewPoint v2 (SQLite) log; only v1 logs and raw streams are supported")
        kw = dict(start_ns=start_ns, period_s=period_s, gain_encoding=gain_encoding, frame_id=frame_id)
        if len(first) >= 4 and struct.unpack_from("<I", first)[0] == RMLOG_MAGIC:
            yield from _iter_rmlog(f, **kw)
        else:
            yield from _iter_raw(f, **kw)


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
