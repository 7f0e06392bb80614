"""Codec: arrays of every dtype, byte order, 0-d/empty/non-contiguous; plain msgpack interop; bad frames."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from msgs.geometry import Pose3D, PoseWithCovariance
from msgs.sensor import Image, PointCloud
from msgs.std import NodeStats, InputStats, String
from tether.codec import Codec, json_schema, wire_to_inline
from tether.errors import DecodeError
from tether.message import Message, registered_types

DTYPES = ["?", "i1", "u1", "<i2", ">i2", "<u2", ">u2", "<i4", ">i4", "<u4", "<i8", ">i8", "<u8",
          "<f2", "<f4", ">f4", "<f8", ">f8", "<c8", "<c16", "<m8[ns]", "<M8[ms]"]


def _frames(codec: Codec, msg: Message) -> list[bytes]:
    return [bytes(memoryview(f).cast("B")) if not isinstance(f, bytes) else f for f in codec.encode(msg)]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(), (0,), (3, 0), (5,), (4, 7), (2, 3, 4)])
def test_array_round_trip_every_dtype_and_shape(dtype: str, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(1)
    arr = np.asarray((rng.integers(0, 100, size=shape) if np.dtype(dtype).kind in "mM" else
                      rng.normal(size=shape) * 50)).astype(dtype)
    codec = Codec()
    msg = Image(data=arr, encoding="x")
    wire = codec.decode(Image, _frames(codec, msg))
    inline = codec.decode_inline(Image, codec.encode_inline(msg))
    for got in (wire.data, inline.data):
        assert got.dtype == arr.dtype and got.shape == arr.shape
        np.testing.assert_array_equal(got, arr)


def test_non_contiguous_and_fortran_arrays_round_trip() -> None:
    base = np.arange(60, dtype=np.float32).reshape(6, 10)
    codec = Codec()
    for arr in (base[:, ::3], base.T, np.asfortranarray(base), base[::-1]):
        got = codec.decode(Image, _frames(codec, Image(data=arr))).data
        np.testing.assert_array_equal(got, arr)


def test_wire_encoding_does_not_copy_the_array() -> None:
    arr = np.zeros((512, 2048), np.uint8)
    frames = Codec().encode(Image(data=arr))
    assert len(frames) == 2 and len(frames[0]) < 200          # small body, buffer out of band
    assert np.shares_memory(np.asarray(frames[1]), arr)       # the buffer frame views the caller's array


def test_wire_decoding_views_the_received_buffer() -> None:
    codec = Codec()
    frames = _frames(codec, Image(data=np.arange(1 << 16, dtype=np.uint16)))
    buffer = bytearray(frames[1])
    got = codec.decode(Image, [frames[0], buffer]).data
    buffer[0:2] = b"\xff\xff"
    assert got[0] == 0xFFFF                                    # zero-copy: same memory
    assert not got.flags.writeable or got.base is not None


def test_plain_msgpack_reads_every_message_type() -> None:
    codec = Codec()
    samples = [Image(data=np.ones((2, 3), np.uint8), encoding="mono8", stamp_ns=5, frame_id="cam", seq=7),
               PointCloud(points_m=np.zeros((4, 3), np.float32)),
               PoseWithCovariance(pose=Pose3D(x_m=1.0), covariance=np.eye(6)),
               NodeStats(node_id="n", inputs=[InputStats(name="a")], published={"x": 3}),
               String(data="hello")]
    for msg in samples:
        doc = msgpack.unpackb(codec.encode_inline(msg), raw=False)
        assert doc["type"] == msg.type_name()
        assert doc["stamp_ns"] == msg.stamp_ns and doc["frame_id"] == msg.frame_id and doc["seq"] == msg.seq
        body = msgpack.unpackb(codec.encode(msg)[0], raw=False)
        assert body["type"] == msg.type_name()
    doc = msgpack.unpackb(codec.encode_inline(samples[0]), raw=False)
    assert doc["data"]["dtype"] == "|u1" and doc["data"]["shape"] == [2, 3] and doc["data"]["data"] == b"\x01" * 6


def test_wire_to_inline_equals_inline_encoding() -> None:
    codec = Codec()
    msg = PoseWithCovariance(pose=Pose3D(y_m=2.0), covariance=np.arange(36.0).reshape(6, 6), stamp_ns=9)
    assert msgpack.unpackb(wire_to_inline(_frames(codec, msg))) == msgpack.unpackb(codec.encode_inline(msg))


def test_every_registered_message_has_a_json_schema_and_a_unique_tag() -> None:
    import importlib
    import pkgutil

    import msgs
    for mod in pkgutil.iter_modules(msgs.__path__):
        importlib.import_module(f"msgs.{mod.name}")
    types = registered_types()                  # raises on a duplicated or missing tag
    assert len(types) >= 20
    for tag, tp in types.items():
        schema = json_schema(tp)
        assert tp.__name__ in schema["$defs"], tag


def test_object_and_structured_dtypes_are_refused_with_a_clear_error() -> None:
    codec = Codec()
    with pytest.raises(TypeError, match="cannot travel"):
        codec.encode(Image(data=np.array([object()], dtype=object)))
    with pytest.raises(TypeError, match="structured"):
        codec.encode(Image(data=np.zeros(3, dtype=[("a", "<f4"), ("b", "<i4")])))


@pytest.mark.parametrize("frames, why", [
    ([], "empty"),
    ([b"\xc1"], "cannot decode"),
    ([msgpack.packb({"type": "std.String", "data": 3})], "cannot decode"),
    ([msgpack.packb({"type": "sensor.Image", "data": {"dtype": "<f4", "shape": [4], "frame": 0}})], "frame"),
    ([msgpack.packb({"type": "sensor.Image", "data": {"dtype": "<f4", "shape": [4], "frame": 0}}), b"\x00" * 15], "bytes"),
    ([msgpack.packb({"type": "sensor.Image", "data": {"dtype": "O", "shape": [1], "frame": 0}}), b"\x00" * 8], "not allowed"),
    ([msgpack.packb({"type": "sensor.Image", "data": {"dtype": "<f4", "shape": [-1], "frame": 0}}), b""], "negative"),
    ([msgpack.packb({"type": "std.String", "data": "x"})], "cannot decode"),  # wrong type for Image
])
def test_malformed_frames_raise_decode_error(frames: list[bytes], why: str) -> None:
    with pytest.raises(DecodeError, match=why):
        Codec().decode(Image, frames)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=64), min_size=0, max_size=4))
def test_random_frames_only_ever_raise_decode_error(frames: list[bytes]) -> None:
    codec = Codec()
    for tp in (Image, String, NodeStats):
        try:
            codec.decode(tp, frames)
        except DecodeError:
            pass
