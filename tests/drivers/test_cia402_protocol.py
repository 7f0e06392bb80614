"""drivers.cia402: statusword decoding, the power state machine, SDO / EMCY codecs, int32 unwrap."""
from __future__ import annotations

import csv

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import cia402 as p


def _maxon_rows(shared_data):
    with open(shared_data / "can" / "machinekit_issue589_maxon_epos_enable.csv") as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))][1:]
    return [(int(r[0], 16), bytes.fromhex(r[1]), r[2]) for r in rows]


def test_real_statuswords_decode_to_their_states():
    # 0x0737 Maxon EPOS (vendor bit 8), 0x0637 another drive in PV, 0x0218 a faulted drive.
    assert p.decode_state(0x0740) == p.SWITCH_ON_DISABLED
    assert p.decode_state(0x0721) == p.READY_TO_SWITCH_ON
    assert p.decode_state(0x0723) == p.SWITCHED_ON
    assert p.decode_state(0x0737) == p.OPERATION_ENABLED
    assert p.decode_state(0x0637) == p.OPERATION_ENABLED
    assert p.decode_state(0x0218) == p.FAULT
    assert p.decode_state(0x0007) == p.QUICK_STOP_ACTIVE       # not FAULT REACTION (0x4F mask) nor enabled
    assert p.decode_state(0x000F) == p.FAULT_REACTION_ACTIVE
    bits = p.StatusBits.of(0x0737)
    assert bits.vendor == 0x0100 and bits.remote and bits.target_reached and bits.voltage_enabled
    assert bits.quick_stop is False                             # bit 5 set = quick stop NOT active


def test_maxon_enable_sequence_follows_the_state_machine(shared_data):
    rows = _maxon_rows(shared_data)
    statuswords = [int.from_bytes(d, "little") for cob, d, _ in rows if cob == 0x182]
    controlwords = [int.from_bytes(d, "little") for cob, d, _ in rows if cob == 0x202]
    # Each controlword is the one our state machine sends from the preceding statusword.
    for sw, cw in zip(statuswords, controlwords):
        assert p.next_controlword(p.decode_state(sw), p.OPERATION_ENABLED, 0) == cw
    sdo = [d for cob, d, _ in rows if cob == 0x582][0]
    r = p.parse_sdo_response(sdo)
    assert (r.kind, r.index, r.value()) == ("upload", 0x6041, 0x0737)


@pytest.mark.parametrize("state", [s for s, _, _ in p.STATE_MASKS])
def test_quick_stop_never_powers_a_drive_up(state):
    cw = p.next_controlword(state, p.QUICK_STOP_ACTIVE, 0)
    assert cw in (p.CW_QUICK_STOP, p.CW_SHUTDOWN, p.CW_DISABLE_VOLTAGE)
    assert cw != p.CW_ENABLE_OPERATION and not cw & p.CW_FAULT_RESET


def test_fault_reset_is_a_rising_edge_of_bit_7():
    assert p.next_controlword(p.FAULT, p.OPERATION_ENABLED, 0x0000) == p.CW_FAULT_RESET
    # bit 7 already high: drop it first so the next reset is an edge
    assert p.next_controlword(p.FAULT, p.OPERATION_ENABLED, p.CW_FAULT_RESET) == 0x0000
    assert p.next_controlword(p.FAULT, p.QUICK_STOP_ACTIVE, 0) == p.CW_QUICK_STOP   # no reset unless asked


def test_leaving_quick_stop_goes_through_switch_on_disabled():
    assert p.next_controlword(p.QUICK_STOP_ACTIVE, p.OPERATION_ENABLED, p.CW_QUICK_STOP) == p.CW_DISABLE_VOLTAGE
    with pytest.raises(ValueError, match="target must be"):
        p.next_controlword(p.SWITCHED_ON, "FLYING", 0)


def test_sdo_response_keeps_only_the_indicated_size():
    r = p.parse_sdo_response(bytes.fromhex("4B41600018028FAF"))     # real: 2 valid bytes, junk after
    assert r.data == b"\x18\x02" and r.value() == 0x0218
    assert p.parse_sdo_response(bytes.fromhex("4F606000FDEEEEEE")).value(signed=True) == -3
    assert p.parse_sdo_response(bytes.fromhex("4300100092010200")).value() == 0x00020192
    assert p.parse_sdo_response(bytes.fromhex("4260600001020304")).data == b"\x01\x02\x03\x04"   # size not indicated
    abort = p.parse_sdo_response(p.sdo_abort(0x1017, 0, 0x06010002))
    assert abort.kind == "abort" and abort.abort_code == 0x06010002 and "read-only" in abort.abort_text
    with pytest.raises(ValueError, match="truncated"):
        p.parse_sdo_response(b"\x4b\x41\x60")


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_sdo_download_request_layout(size):
    req = p.sdo_download_request(0x6060, 0, -1, size)
    assert req[0] == {1: 0x2F, 2: 0x2B, 3: 0x27, 4: 0x23}[size]
    assert req[1:4] == b"\x60\x60\x00" and req[4:4 + size] == b"\xff" * size and len(req) == 8
    with pytest.raises(ValueError, match="segmented"):
        p.sdo_download_request(0x1008, 0, 1, 5)


def test_emcy_and_heartbeat():
    e = p.parse_emcy(bytes.fromhex("B081010000000000"))               # real frame 083#B081010000000000
    assert (e.code, e.register, e.is_reset) == (0x81B0, 0x01, False)
    assert p.parse_emcy(p.emcy_frame(0, 0)).is_reset
    assert p.parse_emcy(p.emcy_frame(0x2310, 1)).text == "continuous over-current"
    with pytest.raises(ValueError, match="EMCY"):
        p.parse_emcy(b"\x10")
    assert p.parse_heartbeat(b"\x85") == "OPERATIONAL"                 # toggle bit masked
    assert p.parse_heartbeat(b"\x7f") == "PRE-OPERATIONAL"


def test_unwrap_int32_across_the_wrap():
    pos = p.unwrap_int32(None, 2**31 - 100)
    pos = p.unwrap_int32(pos, -2**31 + 50)          # counted up through the wrap
    assert pos == 2**31 + 50
    pos = p.unwrap_int32(pos, 2**31 - 10)           # and back down
    assert pos == 2**31 - 10
    assert p.unwrap_int32(None, 0xFFFFFFFF) == -1   # unsigned reading


@settings(max_examples=200, deadline=None)
@given(start=st.integers(-2**40, 2**40), steps=st.lists(st.integers(-2**30, 2**30), max_size=30))
def test_unwrap_int32_recovers_any_path(start, steps):
    truth = start
    est = p.unwrap_int32(None, truth % 2**32)
    est += truth - (truth + 2**31) % 2**32 + 2**31       # the first reading is only known modulo 2**32
    for s in steps:
        truth += s
        est = p.unwrap_int32(est, truth % 2**32)
        assert est == truth


def test_describe_frames_of_the_real_log():
    assert p.describe_frame(0x000, bytes.fromhex("8200")) == "NMT reset communication node 0"
    assert "0x1000:00 = 0x00020192" in p.describe_frame(0x582, bytes.fromhex("4300100092010200"))
    assert p.describe_frame(0x080, b"") == "SYNC"
    assert "EMCY node 3" in p.describe_frame(0x083, bytes.fromhex("B081010000000000"))
    assert "malformed" in p.describe_frame(0x083, b"\x01")
