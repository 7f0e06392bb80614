"""Oculus protocol codec: golden real pings, V1/V2 round trips, 16-bit + row gains, stream resync."""
from __future__ import annotations

import hashlib
import json
import struct

import numpy as np
import pytest

from drivers.oculus_protocol import (FIRE_V1_SIZE, FIRE_V2_SIZE, FLAG_16BIT, FLAG_512_BEAMS, FLAG_ROW_GAIN,
                                     MSG_DUMMY, MSG_PING, FireSettings, Header, ProtocolError, StatusInfo,
                                     decode_fire, decode_ping, decode_status, encode_fire, encode_ping, encode_status)
from drivers.oculus_stream import Frame, Problem, StreamParser

SAMPLES = "sonar/oculus-m1200d"


def _bearings(n: int, half_deg: float = 65.0) -> np.ndarray:
    u = np.linspace(-1.0, 1.0, n)
    return np.round(np.degrees(np.arcsin(u * np.sin(np.radians(30)))) / 30 * half_deg * 100).astype(np.int16)


def _ping(rng: np.random.Generator, *, version: int = 2, bits: int = 8, beams: int = 256, ranges: int = 50,
          gains: bool = False, ping_id: int = 7, align: int = 0, descending: bool = False) -> tuple[bytes, np.ndarray]:
    dtype = np.uint16 if bits == 16 else np.uint8
    image = rng.integers(0, np.iinfo(dtype).max + 1, size=(ranges, beams), dtype=dtype)
    bearings = _bearings(beams)[::-1] if descending else _bearings(beams)
    fire = FireSettings.make(range_m=10.0, bits=bits, beams=512 if beams == 512 else 256, row_gain=gains)
    row_gains = rng.uniform(1.0, 4.0, ranges) if gains else None
    data = encode_ping(image, bearings, fire=fire, version=version, ping_id=ping_id, range_resolution_m=0.02,
                       row_gains=row_gains, image_align=align, ping_start_time=12.5, src=4242)
    return data, image


def test_shared_pings_parse_as_expected_parse_json(shared_data):
    expected = json.loads((shared_data / SAMPLES / "expected_parse.json").read_text())
    for name, pings in expected.items():
        raw = (shared_data / SAMPLES / name).read_bytes()
        for exp in pings:
            off = exp["message_offset_in_file"]
            r = decode_ping(raw[off:off + exp["messageSize"]])
            h, fire = r.header, r.fire
            got = {"oculusId": f"{h.oculus_id:#x}", "src": h.src, "dst": h.dst, "msgId": f"{h.msg_id:#x}",
                   "msgVersion": h.version, "payloadSize": h.payload_size, "masterMode": fire.master_mode,
                   "pingRate": fire.ping_rate, "networkSpeed": fire.network_speed, "gamma": fire.gamma,
                   "flags": fire.flags, "range": fire.range, "gain": fire.gain_percent,
                   "sos": fire.speed_of_sound, "salinity": fire.salinity, "pingId": r.ping_id,
                   "status": r.status, "frequency": r.frequency_hz, "sosUsed": r.sound_speed_mps,
                   "pingStartTime": r.ping_start_time, "dataSize": r.data_size,
                   "rangeResolution": r.range_resolution_m, "nRanges": r.n_ranges, "nBeams": r.n_beams,
                   "imageOffset": r.image_offset, "imageSize": r.image_size, "messageSize": r.message_size,
                   "bearings_centideg_first5": r.bearings_cdeg[:5].tolist(),
                   "bearings_centideg_last5": r.bearings_cdeg[-5:].tolist(),
                   "image_mean": round(float(r.image.mean()), 4), "image_max": int(r.image.max()),
                   "image_sha256": hashlib.sha256(r.image.tobytes()).hexdigest()}
            for key, value in got.items():
                assert value == exp[key], (name, off, key)
            assert r.version == 1 and r.row_gains is None
            steps = np.diff(r.bearings_cdeg)
            assert steps.min() == 22 and steps.max() == 26          # non-uniform table


def test_stream_parser_finds_every_shared_ping_in_odd_chunks(shared_data):
    raw = (shared_data / SAMPLES / "three_pings_8bit.raw").read_bytes()
    parser = StreamParser()
    frames = [item for i in range(0, len(raw), 65537) for item in parser.feed(raw[i:i + 65537])]
    assert [decode_ping(f.data).ping_id for f in frames] == [415323, 415324, 415325]
    assert parser.resyncs == 0 and parser.bad_messages == 0


def test_reencoding_a_real_ping_reproduces_its_bytes_except_padding(shared_data):
    raw = (shared_data / SAMPLES / "one_ping_8bit.raw").read_bytes()
    r = decode_ping(raw)
    again = encode_ping(r.image, r.bearings_cdeg, fire=r.fire, version=0, ping_id=r.ping_id,
                        range_resolution_m=r.range_resolution_m, frequency_hz=r.frequency_hz,
                        sound_speed_mps=r.sound_speed_mps, ping_start_time=r.ping_start_time, status=r.status,
                        image_align=2048, src=r.header.src, temperature_c=r.temperature_c,
                        pressure_bar=r.pressure_bar)
    assert len(again) == len(raw)
    struct_end = 122 + 2 * r.n_beams
    assert again[:struct_end] == raw[:struct_end]
    assert again[r.image_offset:] == raw[r.image_offset:]


@pytest.mark.parametrize("encoding", ["float", "u32"])
def test_v2_16bit_ping_with_row_gains_round_trips(encoding):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 65536, size=(40, 512), dtype=np.uint16)
    gains = np.arange(40) + 1.0
    fire = FireSettings.make(range_m=30.0, bits=16, beams=512, row_gain=True, frequency="low")
    data = encode_ping(image, _bearings(512), fire=fire, version=2, ping_id=99, range_resolution_m=0.03,
                       row_gains=gains, gain_encoding=encoding, image_align=2048, ping_start_time=1.25)
    r = decode_ping(data, gain_encoding=encoding)
    assert r.version == 2 and r.data_size == 1 and r.image.dtype == np.uint16
    np.testing.assert_array_equal(r.image, image)
    np.testing.assert_array_equal(r.row_gains, gains)
    assert r.image_size == 40 * (4 + 512 * 2) and r.image_offset == 2048
    assert r.fire.flags & (FLAG_16BIT | FLAG_512_BEAMS | FLAG_ROW_GAIN) == FLAG_16BIT | FLAG_512_BEAMS | FLAG_ROW_GAIN
    assert r.ping_start_time == 1.25 and r.ping_id == 99


@pytest.mark.parametrize("msg_version", [0, 1])
def test_v1_ping_decodes_for_msg_version_0_and_1(msg_version):
    data, image = _ping(np.random.default_rng(1), version=msg_version)
    r = decode_ping(data)
    assert r.version == 1 and r.header.version == msg_version
    np.testing.assert_array_equal(r.image, image)


def test_descending_bearing_table_is_kept_in_order():
    data, _ = _ping(np.random.default_rng(2), descending=True)
    r = decode_ping(data)
    assert np.all(np.diff(r.bearings_cdeg) <= 0) and r.bearings_cdeg[0] == 6500


def test_image_is_read_at_image_offset_not_after_bearings():
    data, image = _ping(np.random.default_rng(4), align=4096)
    r = decode_ping(data)
    assert r.image_offset == 4096
    np.testing.assert_array_equal(r.image, image)


def test_size_check_and_truncation_raise_protocol_errors():
    data, _ = _ping(np.random.default_rng(5), version=2)
    bad = bytearray(data)
    struct.pack_into("<I", bad, 194, 1234)                       # imageSize: breaks 16 + payload == off + size
    with pytest.raises(ProtocolError, match="imageOffset"):
        decode_ping(bytes(bad))
    with pytest.raises(ProtocolError):
        decode_ping(data[:-10])
    with pytest.raises(ProtocolError):
        decode_ping(data[:100])


def test_fire_messages_have_spec_sizes_and_round_trip():
    fire = FireSettings.make(range_m=12.5, gain_percent=60, gamma=153, ping_rate=1, frequency="low", bits=16,
                             beams=256, row_gain=False, salinity_ppt=35)
    v1, v2 = encode_fire(fire, version=1), encode_fire(fire, version=2)
    assert len(v1) == FIRE_V1_SIZE == 53 and len(v2) == FIRE_V2_SIZE == 89
    assert Header.unpack(v2).payload_size == 73 and Header.unpack(v1).payload_size == 37
    assert decode_fire(v1) == fire and decode_fire(v2) == fire
    assert fire.bits == 16 and fire.beams == 256 and not fire.row_gain and fire.master_mode == 1
    assert decode_fire(encode_fire(fire.standby())).ping_rate == 5
    with pytest.raises(ValueError, match="bits"):
        FireSettings.make(range_m=10, bits=12)


def test_status_round_trip_and_rejects_wrong_length():
    info = StatusInfo(device_id=4242, ip_address="127.0.0.1", mac=b"\x01\x02\x03\x04\x05\x06")
    data = encode_status(info)
    assert len(data) == 142
    assert data[52:56] == bytes([127, 0, 0, 1])                  # network order on the wire
    assert decode_status(data) == info
    with pytest.raises(ProtocolError, match="142"):
        decode_status(data + b"\0")


def test_stream_parser_resyncs_through_garbage_false_magic_and_corruption():
    rng = np.random.default_rng(11)
    good = [_ping(rng, ping_id=i, version=1 + i % 2, bits=8 if i % 2 else 16, gains=bool(i % 2))[0]
            for i in range(4)]
    false_magic = b"SO" + bytes(14)                              # magic + msgId 0 (unknown)
    huge = Header(MSG_PING, 1 << 30, version=2).pack()           # a ping header claiming 1 GiB
    corrupt = bytearray(good[0])
    struct.pack_into("<I", corrupt, 118, 7)                      # V1 messageSize field wrong
    dummy = Header(MSG_DUMMY, 0).pack()
    stream = (rng.bytes(1000) + good[0] + false_magic + rng.bytes(50) + huge + bytes(corrupt) + dummy
              + good[2][:5000] + good[3] + rng.bytes(333) + good[1])
    parser = StreamParser(max_message_bytes=8 << 20)
    items: list = []
    pos = 0
    while pos < len(stream):
        n = int(rng.integers(1, 20000))
        items += parser.feed(stream[pos:pos + n])
        pos += n
    frames = [i for i in items if isinstance(i, Frame)]
    pings = [decode_ping(f.data).ping_id for f in frames if f.header.msg_id == MSG_PING]
    assert pings == [0, 3, 1]                                    # truncated ping 2 and the corrupt copy are dropped
    assert [f.header.msg_id for f in frames].count(MSG_DUMMY) == 1
    assert parser.resyncs >= 3 and parser.bad_messages >= 3
    assert all(isinstance(i, Problem) for i in items if not isinstance(i, Frame))
    assert parser.buffered() < 2


def test_stream_parser_never_raises_on_random_bytes():
    rng = np.random.default_rng(12)
    parser = StreamParser(max_message_bytes=1 << 20)
    for _ in range(50):
        chunk = bytearray(rng.bytes(4096))
        for k in rng.integers(0, 4094, 8):                       # sprinkle magics to exercise header checks
            chunk[k:k + 2] = b"SO"
        for item in parser.feed(bytes(chunk)):
            if isinstance(item, Frame) and item.header.msg_id == MSG_PING:
                with pytest.raises(ProtocolError):               # never a valid ping by chance
                    decode_ping(item.data)
    assert parser.bytes_skipped > 0
