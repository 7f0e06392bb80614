"""Reading raw Oculus streams and ViewPoint .oculus v1 logs into SonarPing messages."""
from __future__ import annotations

import hashlib
import sqlite3
import struct
import zlib

import numpy as np
import pytest

from drivers.oculus_file import RMLOG_HEADER, RMLOG_ITEM, iter_oculus_file, write_rmlog
from drivers.oculus_protocol import FireSettings, encode_ping


def _ping(ping_id: int, version: int = 1) -> bytes:
    image = np.random.default_rng(ping_id).integers(0, 255, size=(20, 256), dtype=np.uint8)
    return encode_ping(image, np.linspace(-6500, 6500, 256).astype(np.int16),
                       fire=FireSettings.make(range_m=5.0, frequency="low", beams=256), version=version,
                       ping_id=ping_id, range_resolution_m=0.25, ping_start_time=3.5)


def test_shared_raw_stream_gives_three_sonar_pings(shared_data):
    pings = list(iter_oculus_file(shared_data / "sonar/oculus-m1200d/three_pings_8bit.raw", period_s=0.05))
    assert [p.ping_id for p in pings] == [415323, 415324, 415325]
    assert [p.stamp_ns for p in pings] == [0, 50_000_000, 100_000_000]
    first = pings[0]
    assert first.intensities.shape == (703, 256) and first.intensities.dtype == np.uint8
    assert hashlib.sha256(first.intensities.tobytes()).hexdigest().startswith("cd46b919b737")
    assert first.bearings_rad[0] == pytest.approx(np.radians(-30.0)) and first.master_mode == 2
    assert first.vertical_aperture_rad == pytest.approx(np.radians(12.0)) and first.device_id == 7892
    assert first.range_resolution_m == pytest.approx(0.0028421889710794315)


@pytest.mark.parametrize("compress", [False, True])
def test_viewpoint_v1_log_round_trip_with_item_stamps(tmp_path, compress):
    path = tmp_path / "log.oculus"
    write_rmlog(path, [(1700000000.25, _ping(1)), (1700000000.5, _ping(2, version=2))], compress=compress)
    pings = list(iter_oculus_file(path))
    assert [p.ping_id for p in pings] == [1, 2]
    assert [p.stamp_ns for p in pings] == [1_700_000_000_250_000_000, 1_700_000_000_500_000_000]
    assert pings[1].device_stamp_ns == 3_500_000_000


def test_truncated_log_and_garbage_in_raw_stream_do_not_crash(tmp_path):
    log = tmp_path / "cut.oculus"
    write_rmlog(log, [(1.0, _ping(1)), (2.0, _ping(2))])
    data = log.read_bytes()
    log.write_bytes(data[:-100])
    assert [p.ping_id for p in iter_oculus_file(log)] == [1]
    raw = tmp_path / "stream.raw"
    raw.write_bytes(b"junk" * 10 + _ping(5) + b"SO\x01" + _ping(6, version=2)[:-7] + _ping(7))
    assert [p.ping_id for p in iter_oculus_file(raw)] == [5, 7]


def test_viewpoint_v2_sqlite_log_is_refused_with_a_clear_error(tmp_path):
    path = tmp_path / "v2.oculus"
    sqlite3.connect(path).execute("create table data (x)").connection.commit()
    with pytest.raises(ValueError, match="v2"):
        list(iter_oculus_file(path))


def _item_offset(data: bytes, k: int) -> int:
    """Byte offset of item ``k`` of a ViewPoint v1 log."""
    off = RMLOG_HEADER.size
    for _ in range(k):
        off += RMLOG_ITEM.size + struct.unpack_from("<I", data, off + 32)[0]
    return off


def _three(tmp_path, compress=False) -> bytes:
    path = tmp_path / "ref.oculus"
    write_rmlog(path, [(1700000000.0 + i, _ping(i + 1)) for i in range(3)], compress=compress)
    return path.read_bytes()


@pytest.mark.parametrize("field, value, reason", [
    (16, struct.pack("<d", float("inf")), "item time inf"),
    (16, struct.pack("<d", 1e300), "item time 1e+300"),
    (16, struct.pack("<d", float("nan")), "item time nan"),
    (16, struct.pack("<d", -1.0), "item time -1.0"),
    (32, struct.pack("<I", 0xFFFFFFF0), "declares 4294967280 B but"),
    (4, struct.pack("<I", 0xFFFFFFF0), "an item header of 4294967280 B"),
    (0, b"\0\0\0\0", "no 0xAABBCCDD item magic"),
])
def test_a_damaged_item_is_skipped_with_its_offset_and_the_others_read(tmp_path, field, value, reason):
    data = bytearray(_three(tmp_path))
    at = _item_offset(data, 1)
    data[at + field:at + field + len(value)] = value
    path = tmp_path / "bad.oculus"
    path.write_bytes(bytes(data))
    skipped = []
    pings = list(iter_oculus_file(path, on_skip=lambda off, why: skipped.append((off, why))))
    assert [p.ping_id for p in pings] == [1, 3]
    assert len(skipped) == 1 and skipped[0][0] == at and reason in skipped[0][1]


def test_a_qcompress_bomb_is_refused_by_its_declared_size_and_a_liar_by_its_output(tmp_path):
    bomb = zlib.compress(bytes(32 << 20), 9)                      # 32 MiB of zeros in ~32 KB
    for declared, max_bytes, why in [(3 << 30, 64 << 20, "declares 3221225472 B, more than --max-bytes"),
                                      (32 << 20, 1 << 20, "more than --max-bytes 1048576"),
                                      (4096, 64 << 20, "inflates to more than the 4096 B it declares")]:
        payload = struct.pack(">I", declared) + bomb
        path = tmp_path / "bomb.oculus"
        path.write_bytes(RMLOG_HEADER.pack(0x11223344, 48, b"Oculus", 1, 0, 0, 1.7e9)
                         + RMLOG_ITEM.pack(0xAABBCCDD, 40, 10, 0, 1.7e9, 1, 0, len(payload)) + payload)
        skipped = []
        # The reasons show it: refused by the declared size, or stopped at declared + 1 bytes -- never inflated.
        assert list(iter_oculus_file(path, max_bytes=max_bytes, on_skip=lambda o, w: skipped.append(w))) == []
        assert len(skipped) == 1 and why in skipped[0], skipped


def test_a_file_shorter_than_its_header_is_one_clear_error(tmp_path):
    path = tmp_path / "short.oculus"
    path.write_bytes(_three(tmp_path)[:20])
    with pytest.raises(ValueError, match="short.oculus: 20 B is too short for a ViewPoint log header"):
        list(iter_oculus_file(path))


@pytest.mark.parametrize("compress", [False, True])
def test_mutated_logs_never_raise_from_an_item(tmp_path, compress):
    """Seeded mutations (bit flips, extreme values, cuts, inserts): items are skipped, never fatal."""
    ref = _three(tmp_path, compress)
    rng = np.random.default_rng(21)
    extremes = [struct.pack("<d", float("inf")), struct.pack("<d", 1e300), struct.pack("<I", 0xFFFFFFF0)]
    path = tmp_path / "m.oculus"
    for _ in range(60):
        data = bytearray(ref)
        for _ in range(int(rng.integers(1, 5))):
            i = int(rng.integers(RMLOG_HEADER.size, len(data) - 8))
            kind = rng.random()
            if kind < 0.4:
                data[i] ^= 1 << int(rng.integers(8))
            elif kind < 0.7:
                value = extremes[int(rng.integers(len(extremes)))]
                data[i:i + len(value)] = value
            elif kind < 0.85:
                del data[i:i + int(rng.integers(1, 64))]
            else:
                data[i:i] = rng.bytes(int(rng.integers(1, 16)))
        path.write_bytes(bytes(data))
        pings = list(iter_oculus_file(path, on_skip=lambda o, w: None))
        assert len(pings) <= 3 and all(0 <= p.stamp_ns < 1 << 63 for p in pings)
