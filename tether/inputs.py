"""Per-input bookkeeping of the live runtime: untrusted sequence numbers, bounded queues, counters.

Everything a publisher puts in a header is untrusted. ``seq`` is used only to count
losses, and only when the jump is plausible: a backwards step (the publisher restarted)
or a forward jump of more than :data:`MAX_SEQ_GAP` (a bug or an attack) is a counted
*reset*, never arithmetic on the absurd value. Counters are Python ints but every
exported value saturates at :data:`I64_MAX`, so statistics always stay encodable.

Queues are bounded twice: by message count (the input's ``depth`` / ``latest`` policy)
and by bytes (``max_queue_bytes``); either bound drops the oldest message, counted.

:class:`SeqStore` keeps the last handled ``seq`` of each input and the last published
``seq`` of each output in a small memory-mapped file, so a node restarted by its launcher
counts what it missed while it was down, and its outputs continue their numbering (its
subscribers then count what died in its send queue as an ordinary gap).
"""
from __future__ import annotations

import collections
import mmap
import os
from pathlib import Path
from typing import Any, Iterable

from tether.message import Message
from tether.stats import InputStats
from tether.transport import check_private_dir

#: Largest forward ``seq`` jump still counted as loss; beyond it the jump is a counted reset.
#: 2^32 messages is more than a day at 40 kHz: no real outage loses that many.
MAX_SEQ_GAP = 1 << 32
I64_MAX = (1 << 63) - 1
U64_MAX = (1 << 64) - 1

COUNTERS = ("received", "handled", "dropped_seq_gap", "dropped_queue", "decode_errors", "handler_errors",
            "seq_resets", "dropped_restart", "link_resets", "received_bytes", "dropped_link")


def saturate(value: int) -> int:
    """``value`` clipped to ``[0, 2^63-1]``: a counter that can always be encoded."""
    return 0 if value < 0 else I64_MAX if value > I64_MAX else value


class InputState:
    """One input of a running node: its queue, its counters and its view of the publisher's ``seq``."""

    __slots__ = ("name", "topic", "type", "queue", "maxlen", "max_bytes", "queued_bytes", "last_seq",
                 "restart_seq", "stats", "handler_ns", "handler_max_ns",
                 "handler", "slot", "link")

    def __init__(self, name: str, topic: str, tp: type[Message], maxlen: int, max_bytes: int = 1 << 62,
                 slot: int = -1) -> None:
        self.name, self.topic, self.type, self.maxlen, self.max_bytes = name, topic, tp, maxlen, max_bytes
        self.queue: collections.deque[tuple[int, Message, int]] = collections.deque()
        self.queued_bytes = 0
        self.last_seq = 0
        self.restart_seq = 0          # last seq handled before this node restarted (0: unknown)
        self.stats = dict.fromkeys(COUNTERS, 0)
        self.handler_ns = 0
        self.handler_max_ns = 0
        self.handler: Any = None
        self.slot = slot              # index in the node's SeqStore, -1 when not persisted
        self.link: Any = None         # a tether.link.LinkModel the messages cross (launch file ``links:``)

    def track_seq(self, seq: int) -> None:
        """Count what the jump from the last ``seq`` to this one says was lost (or a reset)."""
        last = self.last_seq
        if seq == last + 1 and 0 < last < U64_MAX:
            self.last_seq = seq           # the next one, nothing lost: the common case
            return
        if seq <= 0 or seq > U64_MAX:
            self.stats["seq_resets"] += 1          # no usable number: not a reference for gaps
            self.last_seq = 0
            return
        if last == 0 and self.restart_seq:
            self._across_restart(seq)
        elif last:
            gap = seq - last - 1
            if gap < 0 or gap > MAX_SEQ_GAP:
                self.stats["seq_resets"] += 1
            elif gap:
                self.stats["dropped_seq_gap"] += gap
        self.last_seq = seq

    def _across_restart(self, seq: int) -> None:
        gap = seq - self.restart_seq - 1
        if 0 < gap <= MAX_SEQ_GAP:
            self.stats["dropped_restart"] += gap
        elif gap < 0:
            self.stats["seq_resets"] += 1          # the publisher restarted too: the loss is unknowable
        self.restart_seq = 0

    def push(self, index: int, msg: Message, nbytes: int) -> None:
        """Queue ``msg``; drop the oldest (counted) while the count or the bytes exceed the bounds."""
        queue = self.queue
        while queue and (len(queue) >= self.maxlen or self.queued_bytes + nbytes > self.max_bytes):
            self.queued_bytes -= queue.popleft()[2]
            self.stats["dropped_queue"] += 1
        queue.append((index, msg, nbytes))
        self.queued_bytes += nbytes

    def pop(self) -> Message:
        _, msg, nbytes = self.queue.popleft()
        self.queued_bytes -= nbytes
        return msg

    def to_stats(self) -> InputStats:
        n = max(self.stats["handled"], 1)
        counters = {k: saturate(v) for k, v in self.stats.items()}
        return InputStats(name=self.name, topic=self.topic, **counters, handler_ms_mean=self.handler_ns / n / 1e6,
                          handler_ms_max=self.handler_max_ns / 1e6, queued_bytes=saturate(self.queued_bytes))


class SeqStore:
    """Last handled ``seq`` per input and last published ``seq`` per output, in a memory-mapped file.

    A plain store into a shared mapping costs a few hundred nanoseconds and survives SIGKILL
    (the page belongs to the kernel's page cache, not the process), which a periodic file
    write would not: a killed node would then over-count what it missed.
    """

    def __init__(self, path: Path, names: Iterable[str], *, fresh: bool) -> None:
        self.names = list(names)
        self.slots = {name: i for i, name in enumerate(self.names)}
        size = 8 * max(len(self.names), 1)
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        check_private_dir(path.parent)         # a planted folder would let another user rewrite our counts
        layout = "\n".join(self.names).encode()[:4095]
        fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o600)
        try:
            keep = not fresh and os.pread(fd, 4096, 0).rstrip(b"\0") == layout
            if not keep:           # a first start, or another node's layout: start from zeros
                os.ftruncate(fd, 0)
                os.pwrite(fd, layout.ljust(4096, b"\0"), 0)
            os.ftruncate(fd, 4096 + size)
            self._map = mmap.mmap(fd, 4096 + size)
        finally:
            os.close(fd)
        self._view = memoryview(self._map)[4096:].cast("Q")
        self.previous = {name: self._view[i] for name, i in self.slots.items()}

    def set(self, slot: int, seq: int) -> None:
        if slot >= 0 and 0 <= seq <= U64_MAX:
            self._view[slot] = seq

    def close(self) -> None:
        self._view.release()
        self._map.close()
