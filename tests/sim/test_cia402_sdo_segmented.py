"""Segmented SDO on the simulated drive (CiA 301 7.2.4.3): the server frame by frame (toggle bit,
abort codes, commit on the last segment) and the ``canopen`` SDO client against it, over the
shared EDS's objects longer than 4 bytes, with transfers aborted, silenced or mis-toggled half-way."""
from __future__ import annotations

import struct

import canopen
import pytest

from drivers import cia402 as p
from drivers.cia402_bringup import Drive, sdo_read_bytes, sdo_write_bytes
from drivers.cia402_config import DriveConfig
from sim.cia402_bank import LockstepDriveBank, SyncCanHub
from sim.cia402_device import SimDrive
from sim.cia402_od import DriveFaults, SdoServer, object_dictionary
from tether import DriverError

LONG_TYPES = (0x09, 0x0A, 0x0B, 0x0F)       # VISIBLE_STRING, OCTET_STRING, UNICODE_STRING, DOMAIN
COMMAND = b"home steering; report"           # 21 bytes: three segments


def server(**faults) -> SdoServer:
    return SdoServer(object_dictionary(1, "steer"), DriveFaults(**faults))


def one(srv: SdoServer, req: bytes) -> p.SdoResponse:
    out = srv.handle(req)
    assert len(out) == 1
    return p.parse_sdo_response(out[0])


def download(srv: SdoServer, key: tuple[int, int], data: bytes, *, toggles=None) -> list[p.SdoResponse]:
    """A segmented download frame by frame (``toggles`` overrides the toggle bit per segment)."""
    replies = [one(srv, p.sdo_download_initiate(*key, len(data)))]
    chunks = [data[i:i + 7] for i in range(0, len(data), 7)]
    for i, chunk in enumerate(chunks):
        toggle = i % 2 if toggles is None else toggles[i]
        replies.append(one(srv, p.sdo_segment(chunk, toggle=toggle, last=i == len(chunks) - 1)))
        if replies[-1].kind == "abort":
            break
    return replies


def test_segmented_download_and_upload_round_trip_with_alternating_toggle():
    srv = server()
    replies = download(srv, (0x1023, 1), COMMAND)
    assert replies[0].kind == "download" and [r.kind for r in replies[1:]] == ["download-segment"] * 3
    assert [r.toggle for r in replies[1:]] == [0, 1, 0]
    init = one(srv, p.sdo_upload_request(0x1023, 1))
    assert init.kind == "upload-segmented" and init.value() == len(COMMAND)
    data, toggle = b"", 0
    while True:
        seg = one(srv, p.sdo_segment_request(toggle))
        assert seg.kind == "segment" and seg.toggle == toggle
        data, toggle = data + seg.data, toggle ^ 1
        if seg.last:
            break
    assert data == COMMAND and not srv.busy


def test_a_toggle_bit_that_does_not_alternate_aborts_and_leaves_the_object_as_it_was():
    srv = server()
    replies = download(srv, (0x1023, 1), COMMAND, toggles=[0, 0, 1])
    assert replies[-1].kind == "abort" and replies[-1].abort_code == 0x05030000
    assert (replies[-1].index, replies[-1].subindex) == (0x1023, 1)
    assert srv._od[(0x1023, 1)].value == b"" and not srv.busy          # committed only on the last segment
    one(srv, p.sdo_upload_request(0x1008, 0))                           # upload: the client's toggle is checked too
    assert one(srv, p.sdo_segment_request(1)).abort_code == 0x05030000


def test_segments_without_a_transfer_wrong_size_and_a_new_initiate():
    srv = server()
    assert one(srv, p.sdo_segment(b"abc", toggle=0, last=True)).abort_code == 0x05040001
    assert one(srv, p.sdo_segment_request(0)).abort_code == 0x05040001
    one(srv, p.sdo_download_initiate(0x1023, 1, 10))                   # says 10 bytes, sends 12
    one(srv, p.sdo_segment(b"1234567", toggle=0, last=False))
    assert one(srv, p.sdo_segment(b"89abc", toggle=1, last=True)).abort_code == 0x06070010
    assert one(srv, p.sdo_download_initiate(p.TARGET_POSITION, 0, 6)).abort_code == 0x06070010   # an int32
    assert one(srv, p.sdo_download_initiate(0x1008, 0, 9)).abort_code == 0x06010002               # const
    one(srv, p.sdo_upload_request(0x1008, 0))                           # open, then a new initiate ends it
    assert one(srv, p.sdo_upload_request(p.STATUSWORD, 0)).kind == "upload" and not srv.busy
    one(srv, p.sdo_download_initiate(0x1023, 1, len(COMMAND)))
    assert srv.handle(p.sdo_abort(0x1023, 1, 0x05040000)) == [] and not srv.busy   # client abort: no answer
    assert srv.aborts_received == [0x05040000]


def test_block_transfer_is_refused_so_a_client_falls_back():
    srv = server()
    assert one(srv, struct.pack("<BHB4x", 0xA0, 0x1008, 0)).abort_code == 0x05040001


# -- the canopen SDO client against the simulated drive, over the shared EDS ---------------------
@pytest.fixture
def eds(shared_data):
    return str(shared_data / "can" / "ros2_canopen_cia402_slave.eds")


@pytest.fixture
def client(eds):
    """``client(**faults)``: a canopen RemoteNode (the shared EDS) and a simulated drive on a lockstep hub."""
    buses = []

    def make(**faults):
        hub = SyncCanHub()
        buses.extend([hub.bus("drive"), hub.bus("client")])
        return _connect(eds, buses[-2], buses[-1], faults)
    yield make
    for bus in buses:
        bus.shutdown()


def _connect(eds: str, drive_bus, bus, faults: dict):
    drive = SimDrive(1, role="steer", faults=DriveFaults(**faults))
    LockstepDriveBank(drive_bus, {"drive": drive})
    network = canopen.Network(bus)
    bus.receivers.append(lambda m: [listener.on_message_received(m) for listener in list(network.listeners)])
    node = canopen.RemoteNode(1, eds)
    node.sdo.RESPONSE_TIMEOUT = 0.05
    network.add_node(node)
    return node, drive


def long_objects(od: canopen.ObjectDictionary) -> list:
    out = []
    for obj in od.values():
        for var in [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else obj.values():
            if var.data_type in LONG_TYPES:
                out.append(var)
    return out


def test_canopen_client_reads_and_writes_every_long_object_of_the_shared_eds(client):
    node, drive = client()
    objects = long_objects(node.object_dictionary)
    assert {(v.index, v.subindex) for v in objects} == {(0x1008, 0), (0x1009, 0), (0x100A, 0), (0x1023, 1),
                                                        (0x1023, 3)}
    for var in objects:
        value = node.sdo[var.index].raw if not var.subindex else node.sdo[var.index][var.subindex].raw
        assert len(value) > 4 or (var.index, var.subindex) in ((0x1023, 1), (0x1023, 3))   # empty until a command
    assert node.sdo[0x1008].raw == "tether sim steer drive"
    writable = [v for v in objects if "w" in v.access_type]
    assert [(v.index, v.subindex) for v in writable] == [(0x1023, 1)]
    node.sdo[0x1023][1].raw = COMMAND                                    # segmented download (21 bytes)
    assert node.sdo[0x1023][1].raw == COMMAND and node.sdo[0x1023][2].raw == 1
    assert node.sdo[0x1023][3].raw == b"ok: " + COMMAND                  # the drive's reply, 25 bytes back
    node.sdo.download(0x1023, 1, b"abc")                                 # short: expedited into the same object
    assert node.sdo.upload(0x1023, 1) == b"abc"
    with pytest.raises(canopen.SdoAbortedError) as err:
        node.sdo.download(0x1008, 0, b"not writable")
    assert err.value.code == 0x06010002
    assert drive.sdo.aborts_sent == [0x06010002]


@pytest.mark.parametrize("fault, cause, client_abort", [
    ("abort", "aborted: 0x08000000 general error", None),            # the drive aborts half-way
    ("silent", "No SDO response received", 0x05040000),              # it stops answering: the client times out
])
def test_a_download_aborted_half_way_changes_nothing_and_the_next_transfer_works(client, fault, cause, client_abort):
    node, drive = client(segment_fault=fault, segment_fault_at=2)
    # canopen's stream, closed after the failure, still sends a last segment; the drive, its transfer
    # gone, answers 0x05040001 -- the error the raw client raises; the master reports the first cause
    with pytest.raises(canopen.SdoAbortedError) as err:
        node.sdo.download(0x1023, 1, COMMAND)
    assert err.value.code == 0x05040001 and not drive.sdo.busy
    assert drive.sdo.aborts_received == ([client_abort] if client_abort else [])
    assert drive.od[(0x1023, 1)].value == b""                            # nothing committed
    d = Drive(DriveConfig(node_id=1, name="steer", role="steer"), node)
    with pytest.raises(DriverError, match=f"write 0x1023:01 \\(21 bytes\\).*{cause}"):
        sdo_write_bytes(d, 0x1023, 1, COMMAND)
    drive.faults.segment_fault = ""
    sdo_write_bytes(d, 0x1023, 1, COMMAND)
    assert sdo_read_bytes(d, 0x1023, 1) == COMMAND


def test_a_drive_that_breaks_the_toggle_bit_is_caught_by_the_client(client):
    node, drive = client(segment_fault="toggle", segment_fault_at=2)
    with pytest.raises(canopen.SdoCommunicationError, match="Toggle bit"):
        node.sdo.upload(0x1008, 0)
    assert drive.sdo.aborts_received == [0x05030000] and not drive.sdo.busy   # the client aborted it
    drive.faults.segment_fault = ""
    assert node.sdo.upload(0x1008, 0) == b"tether sim steer drive"
