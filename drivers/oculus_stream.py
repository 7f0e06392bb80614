"""Frame an Oculus TCP byte stream into messages, resynchronising on the ``0x4F53`` magic (pure, no I/O)."""
from __future__ import annotations

from dataclasses import dataclass

from drivers.oculus_protocol import (HEADER, MAGIC_BYTES, MAX_SMALL_PAYLOAD, MSG_PING, MSG_PING_FULL, PING_V1_SIZE,
                                     PING_V2_SIZE, Header, ping_layout_error)


@dataclass(frozen=True)
class Frame:
    """One framed message: its header and all its bytes (header included)."""

    header: Header
    data: bytes


@dataclass(frozen=True)
class Problem:
    """Something the parser skipped: ``kind`` is 'resync' (garbage before a magic) or 'bad_message'."""

    kind: str
    detail: str
    skipped_bytes: int = 0


class StreamParser:
    """Frame a byte stream into Oculus messages, resynchronising on the ``0x4F53`` magic.

    ``feed(chunk)`` returns the complete :class:`Frame` s and :class:`Problem` s found so far, in
    stream order (one 'resync' problem per run of garbage, one 'bad_message' per rejected header;
    ``resyncs`` counts the times sync was lost). A header is accepted only when its msgId is known and its payloadSize plausible;
    a ping must also pass :func:`ping_layout_error` before the parser waits for its payload, so a
    false magic inside garbage costs a rescan, not a stall. Counters: ``resyncs``,
    ``bytes_skipped``, ``bad_messages``, ``frames``.
    """

    def __init__(self, *, max_message_bytes: int = 32 << 20, accept: tuple[int, ...] | None = None) -> None:
        self.max_message_bytes = max_message_bytes
        self.accept = accept
        self._buf = bytearray()
        self._lost = False              # inside a run of garbage: one resync per run, not per chunk
        self.resyncs = self.bytes_skipped = self.bad_messages = self.frames = 0

    def buffered(self) -> int:
        return len(self._buf)

    def _header_error(self, head: Header) -> str | None:
        if self.accept is not None and head.msg_id not in self.accept:
            return f"unexpected msgId {head.msg_id:#x}"
        if head.msg_id in (MSG_PING, MSG_PING_FULL):
            if head.payload_size + HEADER.size > self.max_message_bytes:
                return f"payloadSize {head.payload_size} exceeds max_message_bytes {self.max_message_bytes}"
            if head.payload_size + HEADER.size < PING_V1_SIZE:
                return f"payloadSize {head.payload_size} is too small for a ping"
            return None
        limit = MAX_SMALL_PAYLOAD.get(head.msg_id)
        if limit is None:
            return f"unknown msgId {head.msg_id:#x}"
        if head.payload_size > limit:
            return f"payloadSize {head.payload_size} too large for msgId {head.msg_id:#x}"
        return None

    def _embedded_message(self, total: int) -> int | None:
        """Offset of a valid message header inside the first ``total`` bytes (a truncated ping), or None."""
        buf = self._buf
        k = buf.find(MAGIC_BYTES, 2, total)
        while k >= 0:
            if len(buf) - k >= HEADER.size:
                head = Header.unpack(bytes(buf[k:k + HEADER.size]))
                if self._header_error(head) is None:
                    if head.msg_id != MSG_PING:
                        return k
                    need = PING_V2_SIZE if head.version == 2 else PING_V1_SIZE
                    if len(buf) - k >= need and ping_layout_error(bytes(buf[k:k + need])) is None:
                        return k
            k = buf.find(MAGIC_BYTES, k + 1, total)
        return None

    def _skip(self, n: int, out: list, kind: str, detail: str) -> None:
        del self._buf[:n]
        self.bytes_skipped += n
        if kind == "bad_message":
            self.bad_messages += 1
            out.append(Problem(kind, detail, n))
        elif not self._lost:
            out.append(Problem(kind, detail, n))
        if not self._lost:
            self.resyncs += 1
            self._lost = True

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame | Problem]:
        self._buf += chunk
        out: list[Frame | Problem] = []
        while True:
            buf = self._buf
            i = buf.find(MAGIC_BYTES)
            if i < 0:
                keep = 1 if buf[-1:] == MAGIC_BYTES[:1] else 0
                if len(buf) - keep > 0:
                    self._skip(len(buf) - keep, out, "resync", "no 0x4F53 magic in the stream")
                return out
            if i > 0:
                self._skip(i, out, "resync", f"{i} B of garbage before the 0x4F53 magic")
                continue
            if len(buf) < HEADER.size:
                return out
            head = Header.unpack(buf)
            problem = self._header_error(head)
            if problem is None and head.msg_id == MSG_PING:
                need = PING_V2_SIZE if head.version == 2 else PING_V1_SIZE
                if len(buf) < need:
                    return out
                problem = ping_layout_error(buf)
            if problem is not None:
                self._skip(2, out, "bad_message", problem)
                continue
            total = HEADER.size + head.payload_size
            if len(buf) < total:
                return out
            cut = self._embedded_message(total) if head.msg_id == MSG_PING else None
            if cut is not None:
                self._skip(cut, out, "bad_message", f"truncated ping: a new message starts {cut} B into it")
                continue
            out.append(Frame(head, bytes(buf[:total])))
            del buf[:total]
            self.frames += 1
            self._lost = False
