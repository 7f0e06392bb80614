"""Shared-memory pool for large array buffers between node processes on one host.

A publisher copies each array buffer of at least ``TETHER_SHM_MIN_BYTES`` (64 KiB) into a
*slot* of a file in ``/dev/shm`` (mode 0600, one file per output) and sends, through
ZeroMQ, only the message body and a small *slot table* naming the file, the slot, its
*generation* and where each buffer lies. A subscriber maps the file once and hands the
node read-only numpy arrays that view the slot.

Ownership, with the kernel as the arbiter (Linux open-file-description record locks,
which are released when their holder dies, however it dies):

* **Lease** -- a subscriber holds a shared lock on its slot's byte for as long as any
  array of the message is alive in its process (a finalizer on the arrays' common base
  releases it), so a slot is never rewritten under a node that still holds it, however
  slow, latest-only queue or not. The publisher writes a slot only under an exclusive lock
  it can take without waiting, after setting the slot's generation to 0 (torn); a
  subscriber that locks a slot checks the generation its table names: a publisher killed
  mid-write leaves generation 0, never a torn array that passes.
* **In flight** -- between the send and the subscriber's lease, a slot is protected by
  the subscriber's *reader cell* (the highest generation it has received), written only
  by that subscriber: a slot is reused only once every live reader's cell has passed its
  generation. A reader is live while it holds the lock on its reader byte: a crashed
  subscriber stops pinning the pool at once.
* **Exhaustion** -- when no slot is free the publisher waits for one, polling, at most
  ``TETHER_SHM_WAIT_MS`` (20 ms: back-pressure on a publisher that outruns its subscribers'
  queues), then sends that message as ordinary frames (counted in :attr:`Pool.fallbacks`):
  it never blocks for longer and never drops. After a wait that ran out it does not wait
  again until a slot comes free, so a subscriber that pins the pool costs one wait, not one
  per message. A message larger than half the pool travels as frames too (:attr:`Pool.oversize`).

Wire: a Tether subscriber of an ``ipc://`` endpoint subscribes to ``@shm/<topic>``, and until
the first message arrives there also to ``<topic>`` (a publisher that is not a Tether node
sends only that) with the marker ``@dual/<topic>``, which no message matches. The publisher
sends ``[@shm/<topic>, table, body, *frames]`` to them and ordinary ``[<topic>, body, *frames]``
only when a subscriber without the marker (a plain ZeroMQ client, a recorder, ``tether topic
echo``, every tcp subscriber) wants it. The table is a msgpack array ``[segment, slot,
generation, [[k, offset, nbytes], ...]]``: buffer ``k`` of the body's array maps (``"frame": k``)
lies at ``offset`` in the slot; buffers not listed follow the body as frames, in order. A
message with no buffer in shared memory has no table (a body is a msgpack map, a table an
array: the first byte tells).
"""
from __future__ import annotations

import fcntl
import logging
import math
import mmap
import os
import re
import stat
import struct
import threading
import time
import weakref
from dataclasses import dataclass
from typing import Any, Sequence

import msgspec
import numpy as np

from tether.errors import DecodeError

log = logging.getLogger("tether.shm")

SHM_DIR = "/dev/shm"
TOPIC_PREFIX = b"@shm/"
DRAFT_PREFIX = ".tether-draft-"     # + uid: a segment being made, before it has its name
DRAFT_GRACE_S = 10.0             # a draft this young may be one being made: sweeps leave it (a dead maker's goes later)
DUAL_PREFIX = b"@dual/"          # marker: this subscriber takes slot tables but is subscribed plain too, for now
MAGIC = b"TETHSHM1"
MAX_SLOTS = 256
MAX_READERS = 64
ALIGN = 64                       # every buffer starts on a cache line (and any dtype's alignment)
_HEAD = struct.Struct("<8sIIQQI")   # magic, version, slots, slot_bytes, data_offset, max_readers
_GENS_AT = 64
_LOCK_OWNER, _LOCK_SLOT, _LOCK_READER = 0, 1, 1 + MAX_SLOTS
_FLOCK = struct.Struct("hhqqi4x")   # struct flock on Linux x86-64/aarch64
_NAME_RE = re.compile(r"^tether-(\d+)-[A-Za-z0-9_.-]{1,180}$")
#: first byte of a slot table (a msgpack array); a message body is always a map
_NO_READER = (1 << 64) - 1
_I64_MAX = (1 << 63) - 1
_TABLE_ENCODER = msgspec.msgpack.Encoder()
_TABLE_DECODER = msgspec.msgpack.Decoder(tuple[str, int, int, list[tuple[int, int, int]]])
TABLE_MARKERS = frozenset(range(0x90, 0xA0)) | {0xDC, 0xDD}


@dataclass(frozen=True)
class Settings:
    """Knobs read from the environment when a runtime starts (a launch file's ``env`` sets them per node)."""

    enabled: bool = True
    min_bytes: int = 64 << 10      # ``TETHER_SHM_MIN_BYTES``: smaller buffers stay ordinary frames
    pool_bytes: int = 256 << 20    # ``TETHER_SHM_POOL_BYTES``: per output (tmpfs pages are used only when touched)
    wait_ms: int = 20              # ``TETHER_SHM_WAIT_MS``: longest wait for a free slot before sending frames

    @classmethod
    def from_env(cls) -> "Settings":
        enabled = os.environ.get("TETHER_SHM", "1") != "0" and os.path.isdir(SHM_DIR) and hasattr(fcntl, "F_OFD_SETLK")
        return cls(enabled, _env_int("TETHER_SHM_MIN_BYTES", cls.min_bytes), _env_int("TETHER_SHM_POOL_BYTES", cls.pool_bytes),
                   _env_int("TETHER_SHM_WAIT_MS", cls.wait_ms, low=0, high=10_000))


def _env_int(name: str, default: int, *, low: int = 1024, high: int = 1 << 62) -> int:
    text = os.environ.get(name, "")
    return int(text) if text.isdigit() and low <= int(text) <= high else default


def shm_topic(topic: bytes) -> bytes:
    """The topic a shared-memory-capable subscriber of ``topic`` subscribes to."""
    return TOPIC_PREFIX + topic


def _lock(fd: int, kind: int, offset: int) -> bool:
    """Take (or with ``F_UNLCK`` drop) an open-file-description lock on one byte, never waiting."""
    request = _REQUESTS.get((kind, offset))
    if request is None:
        request = _REQUESTS[kind, offset] = _FLOCK.pack(kind, os.SEEK_SET, offset, 1, 0)
    try:
        fcntl.fcntl(fd, _SETLK, request)
        return True
    except OSError:
        return False


_SETLK = getattr(fcntl, "F_OFD_SETLK", 37)
#: packed ``struct flock`` per (kind, byte): a few hundred at most (owner, slot and reader bytes)
_REQUESTS: dict[tuple[int, int], bytes] = {}


class ShmUnavailable(DecodeError):
    """A segment this process cannot (or must not) map: the subscriber falls back to ordinary frames.

    ``missing`` says the file is gone (its publisher ended or moved to a larger one), which on
    a topic already read through shared memory is a lost message, not a reason to fall back."""

    def __init__(self, text: str, *, missing: bool = False) -> None:
        super().__init__(text)
        self.missing = missing


class Segment:
    """One mapped pool file: a header (slot generations, reader cells) and ``slots`` slots."""

    def __init__(self, name: str, fd: int, slots: int, slot_bytes: int, data_offset: int, size: int) -> None:
        self.name, self.fd, self.slots, self.slot_bytes, self.data_offset = name, fd, slots, slot_bytes, data_offset
        self.map = mmap.mmap(fd, size)
        self.gens = np.frombuffer(self.map, np.uint64, count=slots, offset=_GENS_AT)
        self.cells = np.frombuffer(self.map, np.uint64, count=MAX_READERS, offset=_GENS_AT + 8 * MAX_SLOTS)

    @staticmethod
    def layout(slots: int, slot_bytes: int) -> tuple[int, int]:
        data_offset = mmap.PAGESIZE * -(-(_GENS_AT + 8 * (MAX_SLOTS + MAX_READERS)) // mmap.PAGESIZE)
        return data_offset, data_offset + slots * slot_bytes

    @classmethod
    def create(cls, name: str, slots: int, slot_bytes: int) -> "Segment":
        """A new file, 0600, never one that exists nor a planted symlink, owner-locked before it has its name.

        It is made under a private draft name that :func:`sweep_stale_segments` sweeps only when
        no one holds it, written and locked, then linked under ``name``: another process's sweep
        must never find a named file unlocked and take it for a dead publisher's (it did, once in
        a few hundred creations, when the name came first)."""
        data_offset, size = cls.layout(slots, slot_bytes)
        path = os.path.join(SHM_DIR, name)
        for attempt in range(3):
            draft = os.path.join(SHM_DIR, f"{DRAFT_PREFIX}{os.getuid()}-{os.urandom(8).hex()}")
            fd = os.open(draft, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
            try:
                os.fchmod(fd, 0o600)
                os.ftruncate(fd, size)             # sparse: tmpfs pages exist only once written
                os.pwrite(fd, _HEAD.pack(MAGIC, 1, slots, slot_bytes, data_offset, MAX_READERS), 0)
                if _lock(fd, fcntl.F_WRLCK, _LOCK_OWNER):   # alive while we are
                    os.link(draft, path, follow_symlinks=False)   # refuses an existing name
                    os.unlink(draft)
                    return cls(name, fd, slots, slot_bytes, data_offset, size)
            except FileNotFoundError:              # a sweep took the draft before we locked it
                pass
            except BaseException:
                os.close(fd)
                _unlink(os.path.basename(draft))
                raise
            os.close(fd)
            _unlink(os.path.basename(draft))
        raise OSError(f"cannot create the shared-memory segment {name}: its draft was swept three times")

    @classmethod
    def open(cls, name: str) -> "Segment":
        """Map a publisher's file; ``DecodeError`` unless it is ours, private and well formed."""
        found = _NAME_RE.match(name)
        if not found or int(found.group(1)) != os.getuid():
            raise ShmUnavailable(f"shared-memory segment name {name[:80]!r} is not one of this user's")
        try:
            fd = os.open(os.path.join(SHM_DIR, name), os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError as exc:
            raise ShmUnavailable(f"cannot open shared-memory segment {name}: {exc.strerror}",
                                 missing=isinstance(exc, FileNotFoundError)) from None
        try:
            info = os.fstat(fd)
            if not stat.S_ISREG(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
                raise ShmUnavailable(f"shared-memory segment {name} is not a private file of this user "
                                  f"(mode {stat.S_IMODE(info.st_mode):o}, uid {info.st_uid}): refused")
            magic, version, slots, slot_bytes, data_offset, readers = _HEAD.unpack(os.pread(fd, _HEAD.size, 0))
            end = cls.layout(slots, slot_bytes)[1] if 0 < slots <= MAX_SLOTS else -1
            if magic != MAGIC or version != 1 or readers != MAX_READERS or end < 0 or end > info.st_size \
                    or data_offset != cls.layout(slots, slot_bytes)[0] or slot_bytes % ALIGN:
                raise DecodeError(f"shared-memory segment {name} has a bad header: refused")
            return cls(name, fd, slots, slot_bytes, data_offset, end)
        except BaseException:
            os.close(fd)
            raise

    def slot_at(self, slot: int) -> int:
        return self.data_offset + slot * self.slot_bytes

    def close(self) -> bool:
        """Unmap and close (dropping every lock); False while arrays still view it (try again later)."""
        self.gens = self.cells = None                # our own exports of the map
        try:
            self.map.close()
        except BufferError:
            self.gens = np.frombuffer(self.map, np.uint64, count=self.slots, offset=_GENS_AT)
            self.cells = np.frombuffer(self.map, np.uint64, count=MAX_READERS, offset=_GENS_AT + 8 * MAX_SLOTS)
            return False
        os.close(self.fd)
        return True


def _align(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


class Pool:
    """The publisher side for one output: places large buffers in slots, or says to send frames."""

    def __init__(self, stem: str, settings: Settings) -> None:
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in stem)[:120]
        self.stem = f"tether-{os.getuid()}-{os.getpid()}-{os.urandom(4).hex()}-{safe}"
        self.settings = settings
        self.segment: Segment | None = None
        self._serial = 0
        self._gen = 0
        self._local_gens = np.zeros(0, np.int64)  # generation last written per slot (our own copy)
        self._data: np.ndarray | None = None
        self._pending_since: int | None = 0     # a subscriber joined at this generation and has not registered
        self._loans: dict[int, tuple[int, Any]] = {}   # slot -> (id of the loaned array's base, its weak reference)
        self._loan_bases: dict[int, tuple[int, int]] = {}   # id of a loaned base -> (slot, its bytes)
        self._starved = False                      # the last wait for a slot ran out: do not wait again yet
        self._retired: list[Segment] = []
        self.placed = self.fallbacks = self.oversize = self.loaned = 0
        self.waited = 0                            # messages that waited for a slot (back-pressure)
        #: the last :meth:`place` took a loaned slot as it was: the caller's buffers *are* that slot,
        #: which is reused once the table's readers let go -- copy them before sending them elsewhere
        self.last_loaned = False

    def place(self, frames: Sequence[Any], readers: int = 0) -> tuple[bytes, list[Any], int] | None:
        """``(slot table, frames still to send, bytes placed)`` for ``[body, *buffers]``, or None (send as is).

        ``readers`` is how many shared-memory subscribers the publisher knows of: until as many
        have registered a reader cell, slots written since the newest joined are not reused.
        Buffers that lie in a slot :meth:`loan` handed out are not copied."""
        large = [i for i in range(1, len(frames)) if _nbytes(frames[i]) >= self.settings.min_bytes]
        if not large:
            return None
        sizes = [_nbytes(frames[i]) for i in large]
        slot, where = self._loaned_slot(frames, large, sizes) if self._loans else (-1, [])
        self.last_loaned = slot >= 0
        if slot >= 0:
            seg = self.segment
            self.loaned += 1
        else:
            need = sum(_align(n) for n in sizes)
            if need * 2 > self.settings.pool_bytes:
                self.oversize += 1
                return None
            seg = self.segment if self.segment is not None and self.segment.slot_bytes >= need else self._grow(need)
            slot = self._claim(seg, readers)
            if slot < 0:
                self.fallbacks += 1
                return None
            base = seg.slot_at(slot)
            seg.gens[slot] = 0                        # torn until written: a killed writer leaves 0
            off = 0
            for i, n in zip(large, sizes):
                src = frames[i]
                if not isinstance(src, np.ndarray):
                    src = np.frombuffer(src, np.uint8)
                np.copyto(self._data[base + off: base + off + n], src.reshape(-1).view(np.uint8))
                where.append((i - 1, off, n))
                off += _align(n)
        self._gen += 1
        seg.gens[slot] = self._gen
        self._local_gens[slot] = self._gen
        _lock(seg.fd, fcntl.F_UNLCK, _LOCK_SLOT + slot)
        self.placed += 1
        table = _TABLE_ENCODER.encode([seg.name, slot, self._gen, where])
        keep = set(large)
        return table, [frames[0], *(frames[i] for i in range(1, len(frames)) if i not in keep)], sum(sizes)

    def loan(self, shape: tuple[int, ...], dtype: np.dtype, readers: int = 0) -> np.ndarray | None:
        """A writable array in a free slot (locked for writing until published or dropped), or None.

        Publishing a message whose large arrays lie in it sends them without a copy; the array
        then belongs to the subscribers (the node must not write to it again)."""
        dtype = np.dtype(dtype)
        nbytes = math.prod(shape) * dtype.itemsize
        need = _align(max(nbytes, 1))
        if nbytes < self.settings.min_bytes or need * 2 > self.settings.pool_bytes:
            return None
        seg = self.segment if self.segment is not None and self.segment.slot_bytes >= need else self._grow(need)
        slot = self._claim(seg, readers)
        if slot < 0:
            return None                # a plain array: counted as a fallback if it cannot be placed either
        seg.gens[slot] = 0
        array = np.frombuffer(seg.map, dtype, count=nbytes // dtype.itemsize, offset=seg.slot_at(slot))
        # every view of the loan (reshaped, sliced, the codec's byte view) has ``array`` as its base
        key = id(array)
        self._loans[slot] = (key, weakref.ref(array, lambda _, seg=seg, slot=slot, key=key: self._unloan(seg, slot, key)))
        self._loan_bases[key] = (slot, nbytes)
        return array.reshape(shape)

    def _loaned_slot(self, frames: Sequence[Any], large: list[int], sizes: list[int]) -> tuple[int, list]:
        """The loaned slot every large buffer lies in, and where; ``(-1, [])`` if they do not."""
        seg = self.segment
        found, where = -1, []
        for i, n in zip(large, sizes):
            src = frames[i]
            slot, whole = self._loan_bases.get(id(getattr(src, "base", None)), (-1, 0))
            if slot < 0 or found not in (-1, slot):
                return -1, []
            if n == whole:
                off = 0                    # a contiguous view as large as the loan is all of it
            else:                          # part of the loan: where it starts
                off = src.__array_interface__["data"][0] - self._data.ctypes.data - seg.slot_at(slot)
                if off < 0 or off + n > seg.slot_bytes:
                    return -1, []
            found = slot
            where.append((i - 1, off, n))
        key, _ = self._loans.pop(found)
        del self._loan_bases[key]
        return found, where

    def _unloan(self, seg: Segment, slot: int, key: int) -> None:
        """A loaned array died unpublished: its slot is free again."""
        loan = self._loans.get(slot)
        if loan is not None and loan[0] == key and seg is self.segment:
            del self._loans[slot]
            self._loan_bases.pop(key, None)
            _lock(seg.fd, fcntl.F_UNLCK, _LOCK_SLOT + slot)

    def _grow(self, need: int) -> Segment:
        """A new file whose slots fit ``need`` bytes (powers of two, so a growing stream re-creates it rarely)."""
        slot_bytes = max(64 << 10, 1 << (need - 1).bit_length())
        slots = max(2, min(MAX_SLOTS, self.settings.pool_bytes // slot_bytes))
        if self.segment is None:
            sweep_stale_segments()
        self._retire(keep_linked=True)         # messages in flight still name it: unlinked at the next growth
        self._serial += 1
        seg = Segment.create(f"{self.stem}-{self._serial}", slots, slot_bytes)
        self.segment, self._local_gens, self._loans, self._loan_bases = seg, np.zeros(slots, np.int64), {}, {}
        self._pending_since = 0                    # a new file: no reader has registered in it yet
        self._data = np.frombuffer(seg.map, np.uint8)
        return seg

    def _claim(self, seg: Segment, readers: int) -> int:
        """A free slot, locked for writing, waiting for one (bounded, see the module's docstring); -1 if none."""
        slot = self._try_claim(seg, readers)
        if slot >= 0:
            self._starved = False
            return slot
        if self._starved or self.settings.wait_ms <= 0:
            return -1
        self.waited += 1
        deadline = time.monotonic() + self.settings.wait_ms / 1000
        pause = 20e-6
        while time.monotonic() < deadline:
            time.sleep(pause)          # readers release slots without telling: poll, backing off to 0.5 ms
            pause = min(2 * pause, 5e-4)
            slot = self._try_claim(seg, readers)
            if slot >= 0:
                return slot
        self._starved = True
        return -1

    def _try_claim(self, seg: Segment, readers: int) -> int:
        """The lowest slot no live reader holds or still waits for, locked for writing; -1 if none."""
        live = list(filter(None, seg.cells.tolist()))
        registered = len(live)
        if registered >= readers:
            self._pending_since = None
        elif self._pending_since is None:
            self._pending_since = self._gen
        for attempt in range(2):
            floor = min(live) if live else _NO_READER
            if self._pending_since is not None:
                floor = min(floor, self._pending_since)
            # Lowest first: a subscriber that keeps up leaves the same few slots warm in cache. Skipping
            # low slots found leased saves a refused lock (a system call) each, but sends the copy into
            # colder slots: slower in 5 of 6 paired runs of the node-unchanged 1 MiB stream.
            gens = self._local_gens
            for slot, gen in enumerate(gens[:8].tolist()):      # the usual case: a low slot is free
                if gen <= floor and _lock(seg.fd, fcntl.F_WRLCK, _LOCK_SLOT + slot):
                    return slot
            if len(gens) > 8:                                   # a busy pool: find candidates in C, not a loop
                for slot in (np.flatnonzero(gens[8:] <= min(floor, _I64_MAX)) + 8).tolist():
                    if _lock(seg.fd, fcntl.F_WRLCK, _LOCK_SLOT + slot):
                        return slot
            if attempt or not self._reap_readers(seg):
                return -1
            live = list(filter(None, seg.cells.tolist()))
        return -1

    @staticmethod
    def _reap_readers(seg: Segment) -> bool:
        """Forget readers whose process is gone (their lock went with them); True if any was."""
        reaped = False
        for r in np.flatnonzero(seg.cells):
            if _lock(seg.fd, fcntl.F_WRLCK, _LOCK_READER + int(r)):
                seg.cells[r] = 0
                _lock(seg.fd, fcntl.F_UNLCK, _LOCK_READER + int(r))
                reaped = True
        return reaped

    def close(self) -> None:
        """Unlink the files (readers keep their mappings) and unmap them (once no loaned array views them)."""
        self._retire(keep_linked=False)

    def _retire(self, *, keep_linked: bool) -> None:
        for old in self._retired:
            _unlink(old.name)
        self._retired = [old for old in self._retired if not old.close()]
        seg, self.segment, self._data = self.segment, None, None
        if seg is not None:
            if not keep_linked:
                _unlink(seg.name)
            self._retired.append(seg)
            if not keep_linked and seg.close():
                self._retired.remove(seg)


def _unlink(name: str) -> None:
    try:
        os.unlink(os.path.join(SHM_DIR, name))
    except OSError:
        pass


def _nbytes(buf: Any) -> int:
    return buf.nbytes if isinstance(buf, (np.ndarray, memoryview)) else len(buf)


class Reader:
    """The subscriber side for one process: maps segments, resolves slot tables, holds leases."""

    MAX_OPEN = 64

    def __init__(self) -> None:
        self._segments: dict[str, _Mapped] = {}
        self._leases: dict[int, tuple[weakref.ref, _Mapped, int]] = {}   # by id of the weak reference
        self._lock = threading.RLock()
        self.stale = 0                 # tables whose slot was rewritten before we could lease it
        self.closed = False

    def resolve(self, table: Any, frames: Sequence[Any]) -> tuple[list[Any], int] | None:
        """``[body, *buffers]`` with the table's buffers put back in place (read-only views of the slot)
        and the bytes they hold; None when the slot was already reused (counted in :attr:`stale`)."""
        try:
            name, slot, gen, where = _TABLE_DECODER.decode(table)
        except (ValueError, TypeError, msgspec.DecodeError) as exc:
            raise DecodeError(f"bad shared-memory slot table: {exc}") from None
        with self._lock:
            mapped = self._segments.get(name) or self._open(name)
            seg = mapped.segment
            if not 0 <= slot < seg.slots or gen <= 0:
                raise DecodeError(f"slot {slot} generation {gen} is outside segment {name}")
            end = 0
            for _, off, n in where:
                if off < 0 or n < 0:
                    end = seg.slot_bytes + 1
                elif off + n > end:
                    end = off + n
            if end > seg.slot_bytes:
                raise DecodeError(f"slot table reaches past the {seg.slot_bytes}-byte slot of {name}")
            if not mapped.hold(slot, gen, register_gen=gen):
                self.stale += 1
                return None
        lease = np.frombuffer(seg.map, np.uint8, count=end, offset=seg.slot_at(slot))
        lease.setflags(write=False)
        ref = weakref.ref(lease, self._release)
        self._leases[id(ref)] = (ref, mapped, slot)
        view = memoryview(lease)                      # its slices keep ``lease`` (and so the lease) alive
        if len(where) == 1 and len(frames) == 1:      # the usual message: one large array, nothing else
            k, off, n = where[0]
            if k != 0:
                raise DecodeError(f"slot table names buffer {k} of a message with one")
            return [frames[0], view[off:off + n]], n
        body, rest = frames[0], iter(frames[1:])
        out: list[Any] = [None] * (len(frames) - 1 + len(where))
        for k, off, n in where:
            if not 0 <= k < len(out) or out[k] is not None:
                raise DecodeError(f"slot table names buffer {k} twice or out of range")
            out[k] = view[off:off + n]
        for k in range(len(out)):
            if out[k] is None:
                out[k] = next(rest, None)
                if out[k] is None:
                    raise DecodeError("slot table and frames do not add up")
        return [body, *out], sum(n for _, _, n in where)

    def _open(self, name: str) -> "_Mapped":
        if len(self._segments) >= self.MAX_OPEN:
            for old in [m for m in self._segments.values() if not m.held]:
                if old.segment.close():
                    del self._segments[old.segment.name]
        mapped = self._segments[name] = _Mapped(Segment.open(name))
        return mapped

    def _release(self, ref: weakref.ref) -> None:
        """The last array of a message died: drop its lease."""
        with self._lock:
            _, mapped, slot = self._leases.pop(id(ref))
            mapped.release(slot)
            if self.closed and not mapped.held and mapped.segment.close():
                self._segments.pop(mapped.segment.name, None)

    def close(self) -> None:
        """Close every segment no array views any more; the others close when their last array goes."""
        with self._lock:
            self.closed = True
            for name, mapped in list(self._segments.items()):
                if not mapped.held:
                    mapped.unregister()
                    if mapped.segment.close():
                        del self._segments[name]


class _Mapped:
    """A segment as one reader sees it: its reader cell and its leases (counted per slot)."""

    def __init__(self, segment: Segment) -> None:
        self.segment = segment
        self.held: dict[int, int] = {}
        self.reader = -1

    def _register(self, gen: int) -> None:
        for r in range(MAX_READERS):
            if _lock(self.segment.fd, fcntl.F_WRLCK, _LOCK_READER + r):
                self.segment.cells[r] = gen
                self.reader = r
                return
        self.reader = -2            # every cell taken: leases still protect us, in-flight slots do not

    def hold(self, slot: int, gen: int, register_gen: int) -> bool:
        seg = self.segment
        count = self.held.get(slot, 0)
        if count == 0:
            if not _lock(seg.fd, fcntl.F_RDLCK, _LOCK_SLOT + slot):
                self._advance(register_gen)
                return False          # being rewritten right now
            if int(seg.gens[slot]) != gen:
                _lock(seg.fd, fcntl.F_UNLCK, _LOCK_SLOT + slot)
                self._advance(register_gen)
                return False
        elif int(seg.gens[slot]) != gen:
            return False              # we hold a newer message of this slot; this one is gone
        self.held[slot] = count + 1
        reader = self.reader
        if reader >= 0:               # _advance, inlined: once per message
            if register_gen > int(seg.cells[reader]):
                seg.cells[reader] = register_gen
        else:
            self._advance(register_gen)
        return True

    def _advance(self, gen: int) -> None:
        """Tell the publisher we have seen every generation up to ``gen`` (after the lease is taken)."""
        if self.reader == -1:
            self._register(gen)
        elif self.reader >= 0 and gen > int(self.segment.cells[self.reader]):
            self.segment.cells[self.reader] = gen

    def release(self, slot: int) -> None:
        count = self.held.get(slot, 0) - 1
        if count > 0:
            self.held[slot] = count
            return
        self.held.pop(slot, None)
        if self.segment.cells is not None:
            _lock(self.segment.fd, fcntl.F_UNLCK, _LOCK_SLOT + slot)

    def unregister(self) -> None:
        if self.reader >= 0:
            self.segment.cells[self.reader] = 0
            _lock(self.segment.fd, fcntl.F_UNLCK, _LOCK_READER + self.reader)
            self.reader = -1


def sweep_stale_segments() -> int:
    """Unlink this user's pool files whose publisher is gone (killed with SIGKILL); return how many."""
    removed = 0
    prefixes = (f"tether-{os.getuid()}-", f"{DRAFT_PREFIX}{os.getuid()}-")
    try:
        names = [n for n in os.listdir(SHM_DIR) if n.startswith(prefixes)]
    except OSError:
        return 0
    for name in names:
        try:
            fd = os.open(os.path.join(SHM_DIR, name), os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            # a draft is unlocked between its creation and its owner's lock: a sweep in a tight loop took
            # the same creator's draft three times running on a loaded machine ("its draft was swept three
            # times"). Young drafts stay; one left by a maker killed mid-creation is swept once it is old.
            if name.startswith(DRAFT_PREFIX) and time.time() - os.fstat(fd).st_mtime < DRAFT_GRACE_S:
                continue
            if _lock(fd, fcntl.F_WRLCK, _LOCK_OWNER):     # nobody owns it any more
                os.unlink(os.path.join(SHM_DIR, name))
                removed += 1
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed
