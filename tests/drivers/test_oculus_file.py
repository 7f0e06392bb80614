"""Reading raw Oculus streams and ViewPoint .oculus v1 logs into SonarPing messages."""
from __future__ import annotations

import hashlib
import sqlite3

import numpy as np
import pytest

from drivers.oculus_file import iter_oculus_file, write_rmlog
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
