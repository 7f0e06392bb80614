"""Shared-memory pool: leases, in-flight protection, crashes on either side, exhaustion, permissions."""
from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from tether import shm
from tether.codec import Codec
from tether.errors import DecodeError

pytestmark = pytest.mark.skipif(not shm.Settings.from_env().enabled, reason="no /dev/shm or OFD locks here")

REPO = Path(__file__).resolve().parents[2]
MIB = 1 << 20


def _frames(value: int, nbytes: int = MIB) -> list:
    """What the codec hands the pool: ``[body, buffer]``, the buffer filled with ``value``."""
    return [b"\x80", np.full(nbytes, value, np.uint8)]


def _pool(slots: int = 4, slot_bytes: int = MIB) -> shm.Pool:
    return shm.Pool("test.node.out", shm.Settings(pool_bytes=slots * slot_bytes))


def _resolve(reader: shm.Reader, placed: tuple) -> np.ndarray | None:
    table, rest, _ = placed
    got = reader.resolve(table, rest)
    return None if got is None else np.frombuffer(got[0][1], np.uint8)


def _slot(placed: tuple) -> int:
    return msgpack.unpackb(placed[0])[1]


def _child(code: str) -> subprocess.Popen:
    """A Python process that runs ``code`` with the repo importable, talking over pipes."""
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)


def _end(child: subprocess.Popen) -> None:
    """Kill ``child`` if it still runs, reap it and close its pipes (no ResourceWarning left behind)."""
    child.kill()
    child.wait(30)
    for pipe in (child.stdin, child.stdout):
        try:
            pipe.close()
        except BrokenPipeError:
            pass                     # what we wrote to a child that died unread


def test_round_trip_gives_read_only_views_of_the_slot() -> None:
    pool, reader = _pool(), shm.Reader()
    try:
        placed = pool.place(_frames(7), readers=1)
        assert placed is not None and placed[1] == [b"\x80"] and placed[2] == MIB
        array = _resolve(reader, placed)
        assert array is not None and array.shape == (MIB,) and (array == 7).all()
        assert not array.flags.writeable
        with pytest.raises(ValueError):
            array[0] = 1
    finally:
        pool.close()


def test_small_buffers_stay_frames() -> None:
    pool = _pool()
    try:
        assert pool.place([b"\x80", np.zeros(100, np.uint8)]) is None
        assert pool.segment is None                        # nothing created for small messages
    finally:
        pool.close()


def test_a_held_slot_is_never_rewritten_and_exhaustion_falls_back_to_frames() -> None:
    """A subscriber keeping every array pins every slot: the publisher sends frames (counted), never blocks."""
    pool, reader = _pool(slots=4), shm.Reader()
    try:
        kept = []
        for value in range(1, 9):
            placed = pool.place(_frames(value), readers=1)
            if placed is None:
                continue
            kept.append((value, _resolve(reader, placed)))
        assert len(kept) == 4 and pool.fallbacks == 4      # back-pressure is neither a drop nor a block
        assert all((array == value).all() for value, array in kept)
        del kept
        assert pool.place(_frames(9), readers=1) is not None   # leases gone with the arrays: the pool is free
    finally:
        pool.close()


def test_in_flight_slots_wait_for_a_registered_reader() -> None:
    """Sent but not yet received: the reader's cell keeps the slot until it has seen that generation."""
    pool, reader = _pool(slots=2), shm.Reader()
    try:
        first = pool.place(_frames(1), readers=1)
        del first                                          # never received
        # No reader has registered yet (a subscriber that joined): slots are not reused.
        second = pool.place(_frames(2), readers=1)
        assert second is not None and pool.place(_frames(3), readers=1) is None
        assert (_resolve(reader, second) == 2).all()       # registers; the first is behind it now
        third = pool.place(_frames(4), readers=1)
        assert third is not None and (_resolve(reader, third) == 4).all()
    finally:
        pool.close()


def test_a_reused_slot_is_reported_stale_never_read() -> None:
    pool, reader = _pool(slots=2), shm.Reader()
    try:
        old = pool.place(_frames(1), readers=0)            # nobody known: a reader arriving late loses it
        for value in range(2, 5):
            pool.place(_frames(value), readers=0)
        assert _resolve(reader, old) is None and reader.stale == 1
    finally:
        pool.close()


def test_subscriber_killed_while_holding_a_buffer_frees_the_pool() -> None:
    pool = _pool(slots=2)
    child = _child("""
        import sys, numpy as np
        from tether import shm
        reader = shm.Reader()
        table = bytes.fromhex(sys.stdin.readline())
        got = reader.resolve(table, [b"\\x80"])
        held = np.frombuffer(got[0][1], np.uint8)
        print(int(held[0]), flush=True)
        sys.stdin.readline()                      # hold it until killed
    """)
    try:
        placed = pool.place(_frames(5), readers=1)
        child.stdin.write(placed[0].hex() + "\n")
        child.stdin.flush()
        assert child.stdout.readline().strip() == "5"
        assert pool.place(_frames(6), readers=1) is not None     # the other slot
        assert pool.place(_frames(7), readers=1) is None         # one leased, one in flight for the child
        child.send_signal(signal.SIGKILL)
        child.wait(30)                                           # a hang guard
        again = pool.place(_frames(8), readers=0)
        assert again is not None and _slot(again) == _slot(placed)   # its lease and its cell went with it
    finally:
        _end(child)
        pool.close()


def test_publisher_killed_mid_write_never_yields_a_torn_array() -> None:
    child = _child("""
        import fcntl, os, signal, sys, numpy as np
        from tether import shm
        pool = shm.Pool("test.killed.out", shm.Settings(pool_bytes=4 << 20))
        placed = pool.place([b"\\x80", np.full(1 << 20, 1, np.uint8)], readers=0)
        print(placed[0].hex(), flush=True)
        sys.stdin.readline()
        seg = pool.segment                       # rewrite the same slot as place() would, and die halfway
        slot = pool._claim(seg, 0)
        seg.gens[slot] = 0
        pool._data[seg.slot_at(slot): seg.slot_at(slot) + (1 << 19)] = 2
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    reader = shm.Reader()
    try:
        table = bytes.fromhex(child.stdout.readline().strip())
        child.stdin.write("go\n")
        child.stdin.flush()
        child.wait(30)
        assert child.returncode == -signal.SIGKILL
        assert reader.resolve(table, [b"\x80"]) is None and reader.stale == 1
    finally:
        _end(child)
        name = msgpack.unpackb(table)[0]
        Path(shm.SHM_DIR, name).unlink(missing_ok=True)


def test_a_message_larger_than_the_pool_travels_as_frames() -> None:
    pool = _pool(slots=2, slot_bytes=MIB)                  # 2 MiB pool: a slot may use at most half
    try:
        assert pool.place(_frames(1, nbytes=2 * MIB)) is None and pool.oversize == 1
        assert pool.place(_frames(1, nbytes=MIB)) is not None
    finally:
        pool.close()


def test_growing_messages_move_to_a_larger_segment() -> None:
    pool, reader = shm.Pool("test.grow.out", shm.Settings(pool_bytes=64 * MIB)), shm.Reader()
    try:
        small = pool.place(_frames(1, nbytes=MIB))
        first = pool.segment.name
        big = pool.place(_frames(2, nbytes=3 * MIB))
        assert pool.segment.name != first
        assert (_resolve(reader, big) == 2).all() and (_resolve(reader, small) == 1).all()   # still in flight
        pool.place(_frames(3, nbytes=5 * MIB))
        assert not Path(shm.SHM_DIR, first).exists()      # unlinked at the next growth
    finally:
        pool.close()


def test_segments_are_private_and_others_are_refused() -> None:
    pool, reader = _pool(), shm.Reader()
    try:
        placed = pool.place(_frames(1))
        path = Path(shm.SHM_DIR, pool.segment.name)
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        path.chmod(0o644)
        with pytest.raises(shm.ShmUnavailable, match="not a private file"):
            reader.resolve(placed[0], placed[1])
        path.chmod(0o600)
        if os.getuid() == 0:
            os.chown(path, 4242, -1)
            with pytest.raises(shm.ShmUnavailable, match="not a private file"):
                reader.resolve(placed[0], placed[1])
        foreign = msgpack.packb([f"tether-{os.getuid() + 1}-1-x", 0, 1, [[0, 0, 10]]])
        with pytest.raises(shm.ShmUnavailable, match="not one of this user's"):
            reader.resolve(foreign, [b"\x80"])
        sneaky = msgpack.packb(["../etc/passwd", 0, 1, [[0, 0, 10]]])
        with pytest.raises(shm.ShmUnavailable):
            reader.resolve(sneaky, [b"\x80"])
    finally:
        pool.close()


@pytest.mark.parametrize("fields", [None, [1, 2], "x", [99, 1, [[0, 0, 10]]], [0, 1, [[0, 0, 1 << 30]]],
                                    [0, 1, [[0, -64, 10]]], [0, 1, [[5, 0, 10]]], [0, 0, [[0, 0, 10]]],
                                    [0, 1, [[0, 0, 10], [0, 64, 10]]]])
def test_bad_slot_tables_are_decode_errors(fields: object) -> None:
    pool, reader = _pool(), shm.Reader()
    try:
        pool.place(_frames(1))
        if fields is None:
            table = b"\xc1"                                # not msgpack at all
        elif isinstance(fields, list) and len(fields) == 3:
            table = msgpack.packb([pool.segment.name, *fields])
        else:
            table = msgpack.packb(fields)
        with pytest.raises(DecodeError):
            reader.resolve(table, [b"\x80"])
    finally:
        pool.close()


def test_stale_segments_of_killed_publishers_are_swept() -> None:
    live = _pool()
    live.place(_frames(1))                                 # its owner lock is held: never swept
    child = _child("""
        import os, signal, numpy as np
        from tether import shm
        pool = shm.Pool("test.swept.out", shm.Settings(pool_bytes=4 << 20))
        pool.place([b"\\x80", np.ones(1 << 20, np.uint8)])
        print(pool.segment.name, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    try:
        name = child.stdout.readline().strip()
        child.wait(30)
        assert Path(shm.SHM_DIR, name).exists()
        assert shm.sweep_stale_segments() >= 1
        assert not Path(shm.SHM_DIR, name).exists() and Path(shm.SHM_DIR, live.segment.name).exists()
    finally:
        _end(child)
        live.close()


def test_a_sweep_in_another_process_never_unlinks_a_segment_being_created() -> None:
    """Two publishers starting at once: one's sweep must not take the other's fresh file for a dead one's."""
    sweeper = _child("""
        import time
        from tether import shm
        print("ready", flush=True)
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            shm.sweep_stale_segments()
    """)
    try:
        assert sweeper.stdout.readline().strip() == "ready"
        lost = []
        for i in range(400):
            seg = shm.Segment.create(f"tether-{os.getuid()}-{os.getpid()}-race-{i}", 2, 64 << 10)
            if not Path(shm.SHM_DIR, seg.name).exists():
                lost.append(seg.name)
            shm._unlink(seg.name)
            seg.close()
        assert lost == []
    finally:
        _end(sweeper)


def test_a_sweep_leaves_a_young_unlocked_draft_and_takes_an_old_one() -> None:
    """A draft is unlocked for a moment while it is being made: only a draft older than the grace is a dead maker's."""
    young = Path(shm.SHM_DIR, f"{shm.DRAFT_PREFIX}{os.getuid()}-{os.getpid()}-young")
    old = Path(shm.SHM_DIR, f"{shm.DRAFT_PREFIX}{os.getuid()}-{os.getpid()}-old")
    try:
        for path in (young, old):
            path.write_bytes(b"")
            path.chmod(0o600)
        past = time.time() - shm.DRAFT_GRACE_S - 5
        os.utime(old, (past, past))
        shm.sweep_stale_segments()
        assert young.exists() and not old.exists()
    finally:
        for path in (young, old):
            path.unlink(missing_ok=True)


def test_a_loaned_array_is_published_without_a_copy() -> None:
    pool, reader = _pool(), shm.Reader()
    try:
        array = pool.loan((512, 2048), np.dtype(np.uint8), readers=1)
        assert array is not None and array.flags.writeable
        array[:] = 3
        from msgs.sensor import Image

        frames = Codec().encode(Image(data=array))
        placed = pool.place(frames, readers=1)
        where = msgpack.unpackb(placed[0])[3]
        assert where == [[0, 0, MIB]] and pool.placed == 1
        assert (_resolve(reader, placed) == 3).all()
        dropped = pool.loan((MIB,), np.dtype(np.uint8), readers=1)
        slot_of_dropped = next(iter(pool._loans))
        del dropped                                        # never published: its slot comes back
        assert slot_of_dropped not in pool._loans
    finally:
        pool.close()


def test_a_pinned_pool_costs_one_bounded_wait_then_frames_until_a_slot_frees() -> None:
    pool, reader = shm.Pool("test.node.out", shm.Settings(pool_bytes=2 * MIB, wait_ms=5)), shm.Reader()
    try:
        kept = [_resolve(reader, pool.place(_frames(v), readers=1)) for v in (1, 2)]
        assert all(pool.place(_frames(3 + i), readers=1) is None for i in range(4))
        assert pool.fallbacks == 4 and pool.waited == 1            # one wait for the episode, not one per message
        kept.pop()                                                 # a slot frees: waiting is allowed again
        assert pool.place(_frames(7), readers=1) is not None and pool.place(_frames(8), readers=1) is None
        assert pool.waited == 2 and pool.fallbacks == 5
        assert (kept[0] == 1).all()                                # the held slot was never rewritten
    finally:
        pool.close()


def test_a_publisher_waits_for_a_slot_a_subscriber_is_about_to_free() -> None:
    """Back-pressure: a slot released during the wait carries the message (no frames, nothing rewritten early)."""
    import threading

    pool, reader = shm.Pool("test.node.out", shm.Settings(pool_bytes=2 * MIB, wait_ms=10_000)), shm.Reader()
    try:
        kept = [_resolve(reader, pool.place(_frames(v), readers=1)) for v in (1, 2)]
        seen = []
        timer = threading.Timer(0.05, lambda: (seen.append(int(kept[0][0])), kept.clear()))
        timer.start()
        placed = pool.place(_frames(3), readers=1)
        timer.join()
        assert placed is not None and pool.fallbacks == 0 and pool.waited == 1
        assert seen == [1] and (_resolve(reader, placed) == 3).all()
    finally:
        pool.close()


def test_part_of_a_loan_is_published_from_where_it_lies() -> None:
    pool, reader = _pool(), shm.Reader()
    try:
        array = pool.loan((2, MIB // 2), np.dtype(np.uint8), readers=1)
        array[0], array[1] = 4, 5
        placed = pool.place([b"\x80", array[1].reshape(-1)], readers=1)
        assert msgpack.unpackb(placed[0])[3] == [[0, MIB // 2, MIB // 2]] and pool.loaned == 1
        assert (_resolve(reader, placed) == 5).all()
        other = np.full(MIB, 6, np.uint8)                          # not a loan: copied into a slot
        placed = pool.place([b"\x80", other], readers=1)
        assert pool.loaned == 1 and pool.placed == 2 and (_resolve(reader, placed) == 6).all()
    finally:
        pool.close()

