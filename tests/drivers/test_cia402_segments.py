"""CiA 301 segmented-SDO frame codecs: layout, toggle and c bits, the 7-byte limit."""
import pytest

from drivers import cia402 as p


def test_segment_layout_and_parse_round_trip():
    seg = p.sdo_segment(b"abc", toggle=1, last=True)
    assert seg == bytes([0x10 | 4 << 1 | 1]) + b"abc" + bytes(4)          # t=1, n=4 unused bytes, c=1
    r = p.parse_sdo_response(seg)
    assert (r.kind, r.data, r.toggle, r.last) == ("segment", b"abc", 1, True)
    assert p.sdo_segment_request(1)[0] == 0x70 and p.sdo_segment_request(0)[0] == 0x60
    assert p.parse_sdo_response(bytes([0x30]) + bytes(7)).kind == "download-segment"
    assert p.parse_sdo_response(bytes([0x30]) + bytes(7)).toggle == 1
    init = p.sdo_download_initiate(0x1023, 1, 21)
    assert init[0] == 0x21 and int.from_bytes(init[4:], "little") == 21


def test_a_segment_carries_at_most_seven_bytes():
    with pytest.raises(ValueError, match="at most 7"):
        p.sdo_segment(b"12345678", toggle=0, last=False)


def test_describe_frame_reads_segments_and_sync():
    assert p.describe_frame(0x080, b"") == "SYNC"
    assert "segment" in p.describe_frame(0x583, p.sdo_segment(b"ab", toggle=0, last=False))
    assert p.EMCY_CODES[0x8700].startswith("sync controller")
