"""sim.cia402_drive.SimDrive at the frame level: what a real CiA 402 drive answers."""
from __future__ import annotations

import csv
import struct

import pytest

from drivers import cia402 as p
from sim.cia402_drive import DriveFaults, SimDrive

N = 2                     # node id


def sdo(drive: SimDrive, req: bytes, t: float = 0.0) -> bytes | None:
    out = [d for cob, d in drive.receive(p.SDO_RX + N, req, t) if cob == p.SDO_TX + N]
    return out[0] if out else None


def write(drive: SimDrive, index: int, sub: int, value: int, size: int, t: float = 0.0) -> None:
    assert sdo(drive, p.sdo_download_request(index, sub, value, size), t)[0] == 0x60


def read(drive: SimDrive, index: int, sub: int = 0, t: float = 0.0) -> int:
    return p.parse_sdo_response(sdo(drive, p.sdo_upload_request(index, sub), t)).value(signed=True)


def start(drive: SimDrive, t: float = 0.0) -> list:
    return drive.receive(p.NMT, bytes([p.NMT_START, N]), t)


def cw(drive: SimDrive, word: int, target: int | None, t: float) -> list:
    data = struct.pack("<H", word) + (b"" if target is None else struct.pack("<i", target))
    return drive.receive(p.RPDO_BASE[0] + N, data, t)


def map_rpdo_with_target(drive: SimDrive, target_obj: int) -> None:
    write(drive, 0x1600, 0, 0, 1)
    write(drive, 0x1600, 2, p.pdo_mapping_entry(target_obj, 0, 32), 4)
    write(drive, 0x1600, 0, 2, 1)


def enable(drive: SimDrive, t: float, target: int | None = 0) -> float:
    for word in (p.CW_SHUTDOWN, p.CW_SWITCH_ON, p.CW_ENABLE_OPERATION):
        cw(drive, word, target, t)
        t += 0.001
        drive.advance(t)
    assert drive.state == p.OPERATION_ENABLED
    return t


def run(drive: SimDrive, t0: float, t1: float, dt: float = 0.001) -> tuple[float, list]:
    frames, t = [], t0
    while t < t1:
        t += dt
        frames += drive.advance(t)
    return t, frames


def test_boot_up_and_device_type():
    d = SimDrive(N)
    assert d.advance(0.0)[0] == (p.HEARTBEAT + N, b"\x00")
    assert sdo(d, p.sdo_upload_request(0x1000, 0)) == bytes.fromhex("4300100092010200")
    assert p.decode_state(d.statusword()) == p.SWITCH_ON_DISABLED


@pytest.mark.parametrize("req, code", [
    (p.sdo_upload_request(0x2345, 0), 0x06020000),                    # no object
    (p.sdo_upload_request(0x1018, 9), 0x06090011),                    # no sub-index
    (p.sdo_download_request(0x6041, 0, 0x27, 2), 0x06010002),         # statusword is read-only
    (p.sdo_download_request(0x60FF, 0, 5, 2), 0x06070010),            # 2 bytes into an int32
    (p.sdo_download_request(0x6060, 0, 42, 1), 0x06090030),           # no such mode
])
def test_sdo_abort_codes(req, code):
    resp = p.parse_sdo_response(sdo(SimDrive(N), req))
    assert resp.kind == "abort" and resp.abort_code == code


def test_injected_abort_silence_and_junk():
    faults = DriveFaults(sdo_abort={(0x1017, 0): 0x08000022}, sdo_silent={(0x1000, 0)}, junk=b"\x8f\xaf\x8f\xaf")
    d = SimDrive(N, faults=faults)
    assert p.parse_sdo_response(sdo(d, p.sdo_download_request(0x1017, 0, 100, 2))).abort_code == 0x08000022
    assert sdo(d, p.sdo_upload_request(0x1000, 0)) is None
    raw = sdo(d, p.sdo_upload_request(0x6041, 0))
    assert raw[4:] == bytes.fromhex("40068faf")                        # like the real 4B 41 60 00 18 02 8F AF
    assert p.parse_sdo_response(raw).value() == 0x0640


def test_segmented_upload_of_the_device_name():
    d = SimDrive(N, role="steer")
    init = p.parse_sdo_response(sdo(d, p.sdo_upload_request(0x1008, 0)))
    assert init.kind == "upload-segmented"
    size, data, toggle = init.value(), b"", 0
    while True:
        seg = sdo(d, bytes([0x60 | toggle]) + bytes(7))
        assert seg[0] & 0x10 == toggle
        data += seg[1:8 - (seg[0] >> 1 & 7)]
        toggle ^= 0x10
        if seg[0] & 1:
            break
    assert data == b"tether sim steer drive" and len(data) == size


def test_maxon_enable_sequence_replays_exactly(shared_data):
    with open(shared_data / "can" / "machinekit_issue589_maxon_epos_enable.csv") as f:
        rows = [(int(r[0], 16), bytes.fromhex(r[1])) for r in csv.reader(l for l in f if not l.startswith("#"))
                if r[0].startswith("0x")]
    d = SimDrive(N, faults=DriveFaults(vendor_bits=0x0100))
    t, got = 0.0, []
    start(d, t)
    got += [f for f in d.advance(t) if f[0] == 0x182]
    for cob, data in rows:
        t += 0.001
        if cob == 0x202:
            d.receive(cob, data, t)
            got += [f for f in d.advance(t) if f[0] == 0x182]
        elif cob == 0x602:
            got += d.receive(cob, data, t)
    expected = [(cob, data) for cob, data in rows if cob in (0x182, 0x582)]
    assert got == expected


def test_profile_velocity_first_order_and_quick_stop():
    d = SimDrive(N, time_constant_s=0.02)
    map_rpdo_with_target(d, p.TARGET_VELOCITY)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PV, 1)
    write(d, p.PROFILE_ACCEL, 0, 10**9, 4)                          # no ramp: pure first order
    start(d)
    t = enable(d, 0.0, target=0)
    cw(d, p.CW_ENABLE_OPERATION, 10_000, t)
    t, _ = run(d, t, t + 0.02)                                      # one time constant
    assert d.velocity == pytest.approx(10_000 * (1 - 2.718281828 ** -1), rel=0.08)
    t, _ = run(d, t, t + 0.2)
    assert d.velocity == pytest.approx(10_000, rel=1e-3)
    assert d.statusword() & 0x0400                                  # target reached
    cw(d, p.CW_QUICK_STOP, 10_000, t)                               # target still 10000: must stop anyway
    assert d.state == p.QUICK_STOP_ACTIVE
    t, _ = run(d, t, t + 0.3)
    assert d.velocity == 0.0 and p.decode_state(d.statusword()) == p.QUICK_STOP_ACTIVE


def test_profile_position_set_point_handshake():
    d = SimDrive(N, role="steer", time_constant_s=0.01)
    map_rpdo_with_target(d, p.TARGET_POSITION)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PP, 1)
    start(d)
    t = enable(d, 0.0, target=0)
    cw(d, p.CW_ENABLE_OPERATION, 5000, t)                           # no new-set-point edge: no move
    t, _ = run(d, t, t + 0.1)
    assert abs(d.position) < 1
    cw(d, p.CW_ENABLE_OPERATION | p.CW_NEW_SET_POINT, 5000, t)
    assert d.statusword() & 0x1000                                  # set-point acknowledged
    cw(d, p.CW_ENABLE_OPERATION, 5000, t)
    t, _ = run(d, t, t + 1.0)
    assert d.position == pytest.approx(5000, abs=d.window)
    assert d.statusword() & 0x0400 and not d.statusword() & 0x1000


def test_injected_fault_sends_emcy_and_stops_then_resets():
    d = SimDrive(N)
    map_rpdo_with_target(d, p.TARGET_VELOCITY)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PV, 1)
    start(d)
    t = enable(d, 0.0, target=50_000)
    t, _ = run(d, t, t + 0.5)
    assert d.velocity > 40_000
    d.inject_fault(0x2310)
    t, frames = run(d, t, t + 0.01)
    emcy = [p.parse_emcy(data) for cob, data in frames if cob == p.EMCY + N]
    assert [e.code for e in emcy] == [0x2310]
    assert d.state == p.FAULT_REACTION_ACTIVE
    cw(d, p.CW_ENABLE_OPERATION, 50_000, t)                         # still commanded: must not matter
    t, _ = run(d, t, t + 0.5)
    assert d.velocity == 0.0 and d.state == p.FAULT
    assert read(d, p.ERROR_CODE) == 0x2310
    cw(d, p.CW_FAULT_RESET, 0, t)
    assert d.state == p.SWITCH_ON_DISABLED and d.emcy_sent[-1] == 0x0000


def test_fault_at_start_looks_like_the_real_0x0218_and_sticky_faults_stay():
    d = SimDrive(N, faults=DriveFaults(start_in_fault=0x7300))
    frames = d.advance(0.0)
    assert frames[0] == (p.HEARTBEAT + N, b"\x00") and frames[1][0] == p.EMCY + N
    assert d.statusword() == 0x0218
    d2 = SimDrive(N, faults=DriveFaults(start_in_fault=0x7300, sticky_fault=True))
    for word in (0x0000, p.CW_FAULT_RESET, 0x0000, p.CW_FAULT_RESET):
        d2.receive(p.SDO_RX + N, p.sdo_download_request(p.CONTROLWORD, 0, word, 2), 0.0)
    assert d2.state == p.FAULT


def test_lost_master_heartbeat_faults_and_stops_the_motor():
    d = SimDrive(N)
    map_rpdo_with_target(d, p.TARGET_VELOCITY)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PV, 1)
    write(d, 0x1016, 1, 127 << 16 | 100, 4)                         # consume node 127's heartbeat, 100 ms
    start(d)
    t = enable(d, 0.0, target=30_000)
    for _ in range(50):                                             # master alive for 0.5 s
        d.receive(p.HEARTBEAT + 127, b"\x05", t)
        t, _ = run(d, t, t + 0.01)
    assert d.velocity > 25_000
    t, frames = run(d, t, t + 0.15)                                 # master silent
    assert any(cob == p.EMCY + N and p.parse_emcy(data).code == 0x8130 for cob, data in frames)
    t, _ = run(d, t, t + 0.5)
    assert d.velocity == 0.0 and d.state == p.FAULT


def test_position_actual_wraps_int32():
    d = SimDrive(N, faults=DriveFaults(position_offset=2**31 - 5_000))
    map_rpdo_with_target(d, p.TARGET_VELOCITY)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PV, 1)
    start(d)
    t = enable(d, 0.0, target=100_000)
    t, _ = run(d, t, t + 0.5)
    assert d.position > 2**31
    raw = read(d, p.POSITION_ACTUAL, t=t)
    assert raw < 0 and raw == int(round(d.position)) - 2**32


def test_nmt_gates_pdos_and_sdos():
    d = SimDrive(N)
    map_rpdo_with_target(d, p.TARGET_VELOCITY)
    cw(d, p.CW_SHUTDOWN, 0, 0.0)                                    # PRE-OPERATIONAL: RPDO ignored
    assert d.state == p.SWITCH_ON_DISABLED
    d.receive(p.NMT, bytes([p.NMT_STOP, 0]), 0.0)                   # broadcast stop
    assert sdo(d, p.sdo_upload_request(0x1000, 0)) is None          # STOPPED: no SDO
    start(d)
    write(d, p.MODES_OF_OPERATION, 0, p.MODE_PV, 1)
    t = enable(d, 0.0, target=10_000)
    d.receive(p.NMT, bytes([p.NMT_PRE_OPERATIONAL, N]), t)          # communication lost while running
    assert d.state == p.QUICK_STOP_ACTIVE
    run(d, t, t + 0.5)
    assert d.velocity == 0.0
