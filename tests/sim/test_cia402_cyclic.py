"""The simulated drive in the cyclic synchronous modes (CSP 8, CSV 9) and in homing (6), frame by
frame: set-points act at SYNC, CSP interpolates between SYNCs, SYNC jitter is tolerated, a drive
that misses SYNC for three cycles quick-stops with EMCY 0x8700, homing by method 0x6098."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers import cia402 as p
from sim.cia402_drive import DriveFaults, SimDrive

N = 3
PERIOD = 0.01                 # 100 Hz SYNC


def sdo(drive: SimDrive, req: bytes, t: float) -> p.SdoResponse:
    out = [d for cob, d in drive.receive(p.SDO_RX + N, req, t) if cob == p.SDO_TX + N]
    return p.parse_sdo_response(out[0])


def write(drive: SimDrive, index: int, sub: int, value: int, size: int, t: float = 0.0) -> p.SdoResponse:
    return sdo(drive, p.sdo_download_request(index, sub, value, size), t)


def rpdo(drive: SimDrive, word: int, target: int, t: float) -> list:
    return drive.receive(p.RPDO_BASE[0] + N, struct.pack("<Hi", word, target), t)


def sync(drive: SimDrive, t: float) -> list:
    return drive.receive(p.SYNC, b"", t)


def cyclic_drive(mode: int, **faults) -> SimDrive:
    """A drive in ``mode``, RPDO1 = controlword + target (synchronous), 0x1006 = 10 ms, enabled at t = 0.03."""
    role = "wheel" if mode == p.MODE_CSV else "steer"
    drive = SimDrive(N, role=role, faults=DriveFaults(**faults))
    target = p.TARGET_VELOCITY if mode == p.MODE_CSV else p.TARGET_POSITION
    for index, sub, value, size in ((0x1600, 0, 0, 1), (0x1600, 2, p.pdo_mapping_entry(target, 0, 32), 4),
                                    (0x1600, 0, 2, 1), (0x1400, 2, 1, 1), (p.COMM_CYCLE_PERIOD, 0, 10_000, 4),
                                    (p.MODES_OF_OPERATION, 0, mode, 1)):
        assert write(drive, index, sub, value, size).kind == "download"
    drive.receive(p.NMT, bytes([p.NMT_START, N]), 0.0)
    for k, word in enumerate((p.CW_SHUTDOWN, p.CW_SWITCH_ON, p.CW_ENABLE_OPERATION)):
        if drive.faults.sync_deaf:                    # its RPDOs would never act: enable it by SDO
            write(drive, p.CONTROLWORD, 0, word, 2, k * PERIOD)
        else:
            rpdo(drive, word, 0, k * PERIOD)
            sync(drive, k * PERIOD)
    assert drive.state == p.OPERATION_ENABLED
    return drive


def test_csv_set_point_waits_for_the_sync():
    drive = cyclic_drive(p.MODE_CSV)
    rpdo(drive, p.CW_ENABLE_OPERATION, 40_000, 0.025)
    drive.advance(0.029)
    assert drive.velocity == 0.0                                  # received, not yet acted on
    t = 0.03
    for k in range(30):                                          # 300 ms of SYNC
        sync(drive, t + k * PERIOD)
        drive.advance(t + k * PERIOD + 0.005)
    assert drive.velocity == pytest.approx(40_000, rel=1e-3)
    assert drive.statusword() & 0x1000                           # bit 12: follows the command value


def test_csp_interpolates_a_ramp_between_syncs():
    drive = cyclic_drive(p.MODE_CSP)
    t, speeds = 0.03, []
    for k in range(100):                                         # 1 s at 100 000 counts/s, one set-point per SYNC
        rpdo(drive, p.CW_ENABLE_OPERATION, 1000 * (k + 1), t)
        sync(drive, t)
        for j in range(1, 11):
            drive.advance(t + j * 1e-3)
            if k > 50:
                speeds.append(drive.velocity)
        t += PERIOD
    # linear interpolation over the period: the motor runs smoothly, it does not step from SYNC to SYNC
    assert np.ptp(speeds) < 0.01 * 100_000 and np.mean(speeds) == pytest.approx(100_000, rel=1e-3)
    assert abs(drive.position_actual - 100_000) < 3_000          # a period and a little lag behind


def run_syncs(drive: SimDrive, times: np.ndarray, target=lambda t: 0, word: int = p.CW_ENABLE_OPERATION) -> list[int]:
    """SYNC at ``times`` (set-point before each), 1 ms motor steps in between; the EMCY codes sent."""
    emcy = []
    for a, b in zip(times[:-1], times[1:]):
        frames = rpdo(drive, word, int(target(a)), a) + sync(drive, a)
        for tt in np.arange(a + 1e-3, b, 1e-3):
            frames += drive.advance(float(tt))
        emcy += [p.parse_emcy(d).code for cob, d in frames if cob == p.EMCY + N]
    return emcy


def test_sync_jitter_is_tolerated():
    rng = np.random.default_rng(7)
    drive = cyclic_drive(p.MODE_CSP)
    times = 0.03 + np.cumsum(PERIOD + rng.uniform(-0.4, 0.4, 300) * PERIOD)   # +-40 % of the period
    assert run_syncs(drive, times, lambda t: 50_000 * t) == []
    assert drive.state == p.OPERATION_ENABLED and drive.syncs >= 300
    assert abs(drive.position_actual - 50_000 * times[-2]) < 2_000


@pytest.mark.parametrize("mode", [p.MODE_CSP, p.MODE_CSV])
def test_lost_sync_producer_quick_stops_after_three_cycles(mode):
    drive = cyclic_drive(mode)
    speed = 40_000 if mode == p.MODE_CSV else 0
    times = 0.03 + PERIOD * np.arange(50)
    run_syncs(drive, times, (lambda t: speed) if mode == p.MODE_CSV else (lambda t: 40_000 * t))
    assert abs(drive.velocity) > 30_000
    last = times[-2]                                             # the last SYNC; the producer is gone
    emcy = []
    for tt in last + 1e-3 * np.arange(1, 300):
        frames = drive.advance(float(tt))
        emcy += [(float(tt), p.parse_emcy(d).code) for cob, d in frames if cob == p.EMCY + N]
        if tt < last + 3 * PERIOD:
            assert drive.state == p.OPERATION_ENABLED            # two, even three late SYNCs: still running
    assert [c for _, c in emcy] == [0x8700]
    assert 3 * PERIOD < emcy[0][0] - last <= 3.5 * PERIOD + 1e-3
    assert drive.state == p.QUICK_STOP_ACTIVE and drive.velocity == 0.0      # stopped on the quick-stop ramp
    # SYNC back, and the quick stop the master sends once tripped: the drive stays stopped
    run_syncs(drive, last + 0.3 + PERIOD * np.arange(10), lambda t: 40_000, word=p.CW_QUICK_STOP)
    assert drive.state == p.QUICK_STOP_ACTIVE and drive.velocity == 0.0


def test_the_drive_records_its_longest_sync_gap():
    """The watchdog's diagnostic: the longest time without SYNC it saw while armed (a bench reports it
    beside a run's trips: how close a run came to the 3.5-period limit)."""
    drive = cyclic_drive(p.MODE_CSV)
    times = np.concatenate([0.03 + PERIOD * np.arange(20), 0.22 + 0.031 + PERIOD * np.arange(10)])
    assert run_syncs(drive, times, lambda t: 40_000) == []                # 31 ms: under 35, no stop
    assert drive.state == p.OPERATION_ENABLED
    assert 0.030 <= drive.max_sync_gap_s <= 0.031 + 1e-9
    assert drive.max_sync_gap_at_s == pytest.approx(0.22 + 0.031, abs=1.5e-3)            # that gap's end


def test_a_drive_deaf_to_sync_stops_itself():
    drive = cyclic_drive(p.MODE_CSV, sync_deaf=True)      # enabled by controlwords written by SDO
    assert drive.syncs == 0
    emcy = run_syncs(drive, 0.03 + PERIOD * np.arange(10), lambda t: 40_000)
    assert emcy == [0x8700] and drive.state == p.QUICK_STOP_ACTIVE and drive.velocity == 0.0


@pytest.mark.parametrize("method, switch, expect", [
    (37, 0, "attained"),            # current position is home: no motion
    (19, 0, "attained"),            # search the home switch edge at physical 0
    (21, None, "error"),            # no switch anywhere: give up after the search range
])
def test_homing_by_method(method, switch, expect):
    drive = SimDrive(N, role="steer", faults=DriveFaults(position_offset=3_000, encoder_offset=40_000,
                                                         home_switch=switch))
    assert write(drive, p.HOMING_METHOD, 0, method, 1).kind == "download"
    write(drive, p.HOME_OFFSET, 0, 500, 4)
    write(drive, p.MODES_OF_OPERATION, 0, p.MODE_HOMING, 1)
    for word in (p.CW_SHUTDOWN, p.CW_SWITCH_ON, p.CW_ENABLE_OPERATION):
        write(drive, p.CONTROLWORD, 0, word, 2)
    assert drive.statusword() & 0x3400 == 0x0400                  # not started: bit 10 only
    write(drive, p.CONTROLWORD, 0, p.CW_ENABLE_OPERATION | p.CW_HOMING_START, 2)
    t = 0.0
    while t < 20.0 and drive.statusword() & 0x0400 == 0:
        t += 0.001
        drive.advance(t)
    sw = drive.statusword()
    if expect == "error":
        assert sw & p.SW_HOMING_ERROR and not sw & p.SW_HOMING_ATTAINED
        return
    assert sw & p.SW_HOMING_ATTAINED and sw & p.SW_TARGET_REACHED
    home = 3_000 if method == 37 else 0                             # physical position of home
    assert drive.position == pytest.approx(home, abs=60)
    assert drive.position_actual == pytest.approx(500 + drive.position - home, abs=1)   # reads the home offset there


def test_an_unknown_homing_method_is_refused():
    drive = SimDrive(N, role="steer")
    assert write(drive, p.HOMING_METHOD, 0, 1, 1).abort_code == 0x06090030
