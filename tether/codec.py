"""Typed msgpack codec: messages to ZeroMQ frames (arrays out of band) and to log records.

An array field (annotated ``numpy.ndarray``) is a msgpack map. On the wire its buffer
travels as a separate frame and the map says which one::

    {"dtype": "<u1", "shape": [512, 2048], "frame": 0}     # frame 0 = first after the body

In a log (and anywhere a single blob is needed) the buffer is inline::

    {"dtype": "<u1", "shape": [512, 2048], "data": <bin>}

So plain ``msgpack.unpackb`` reads every message. Encoding for the wire copies nothing
(non-contiguous arrays are made contiguous first, one copy); decoding from the wire
gives read-only arrays that view the received frames.
"""
from __future__ import annotations

import functools
import math
from typing import Any, Sequence

import msgspec
import numpy as np

from tether.errors import DecodeError
from tether.message import Message

_KINDS = set("biufcm" "M")  # bool, ints, float, complex, timedelta, datetime (no object/void/str)


def _check_dtype(dtype: np.dtype) -> None:
    if dtype.kind not in _KINDS or dtype.fields is not None:
        raise TypeError(f"array dtype {dtype} cannot travel as a message field; "
                        "use a numeric or bool dtype (split structured arrays into columns)")


#: dtypes by their header string (a message carries a handful; bounded against floods of new names)
_DTYPES: dict[Any, np.dtype] = {}


def _dtype_of(name: Any) -> np.dtype:
    dtype = _DTYPES.get(name) if isinstance(name, str) else None
    if dtype is None:
        dtype = np.dtype(name)
        if dtype.kind not in _KINDS or dtype.fields is not None:
            raise DecodeError(f"array dtype {dtype} is not allowed")
        if isinstance(name, str) and len(_DTYPES) < 256:
            _DTYPES[name] = dtype
    return dtype


def _array_from(obj: Any, buffer: Any) -> np.ndarray:
    try:
        dtype = _dtype_of(obj["dtype"])
        shape = tuple(int(n) for n in obj["shape"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DecodeError(f"bad array header {obj!r:.80}: {exc}") from None
    if any(n < 0 for n in shape):
        raise DecodeError(f"negative array shape {shape}")
    count = math.prod(shape)          # Python ints: no overflow, and 10x faster than np.prod here
    nbytes = len(buffer) if isinstance(buffer, (bytes, bytearray)) else memoryview(buffer).nbytes
    if count * dtype.itemsize != nbytes:
        raise DecodeError(f"array of shape {shape} and dtype {dtype} needs {count * dtype.itemsize} bytes, got {nbytes}")
    return np.frombuffer(buffer, dtype=dtype, count=count).reshape(shape)


def _schema_hook(tp: type) -> dict[str, Any]:
    if tp is np.ndarray:
        return {"type": "object", "title": "Array",
                "description": "n-d array: numpy dtype string, shape, and raw C-order bytes",
                "properties": {"dtype": {"type": "string"},
                               "shape": {"type": "array", "items": {"type": "integer"}},
                               "data": {"type": "string", "contentEncoding": "base64"}},
                "required": ["dtype", "shape", "data"]}
    raise NotImplementedError(f"no schema for {tp}")


class Codec:
    """Encoder/decoder pair for one thread (it holds per-call state; do not share across threads)."""

    def __init__(self) -> None:
        self._buffers: list[Any] = []
        self._frames: Sequence[Any] = ()
        self._wire_encoder = msgspec.msgpack.Encoder(enc_hook=self._enc_wire)
        self._inline_encoder = msgspec.msgpack.Encoder(enc_hook=self._enc_inline)
        self._wire_decoders: dict[type, msgspec.msgpack.Decoder] = {}
        self._inline_decoders: dict[type, msgspec.msgpack.Decoder] = {}

    # -- encoding -------------------------------------------------------------------
    def _enc_wire(self, obj: Any) -> Any:
        if isinstance(obj, np.ndarray):
            _check_dtype(obj.dtype)
            arr = obj if obj.flags.c_contiguous else np.ascontiguousarray(obj)
            self._buffers.append(arr.reshape(-1).view(np.uint8) if arr.ndim and arr.size else arr.tobytes())
            return {"dtype": arr.dtype.str, "shape": list(arr.shape), "frame": len(self._buffers) - 1}
        return _enc_common(obj)

    def _enc_inline(self, obj: Any) -> Any:
        if isinstance(obj, np.ndarray):
            _check_dtype(obj.dtype)
            arr = obj if obj.flags.c_contiguous else np.ascontiguousarray(obj)
            data = memoryview(arr.reshape(-1).view(np.uint8)) if arr.ndim and arr.size else arr.tobytes()
            return {"dtype": arr.dtype.str, "shape": list(arr.shape), "data": data}
        return _enc_common(obj)

    def encode(self, msg: Message) -> list[Any]:
        """Frames for the wire: ``[body, *array_buffers]``; buffers are views, not copies."""
        # self._buffers is empty between calls (the hook fills it during one encode only)
        try:
            body = self._wire_encoder.encode(msg)
        except BaseException:
            self._buffers = []
            raise
        if not self._buffers:
            return [body]               # no array field: the common small message
        frames = [body, *self._buffers]
        self._buffers = []
        return frames

    def encode_inline(self, msg: Message) -> bytes:
        """One msgpack blob with arrays inline (the log record form)."""
        return self._inline_encoder.encode(msg)

    # -- decoding -------------------------------------------------------------------
    def _dec_wire(self, tp: type, obj: Any) -> Any:
        if tp is np.ndarray:
            if isinstance(obj, (bool, int, float)):
                return np.asarray(obj)   # a numpy scalar given for an array field encodes as a number
            if not isinstance(obj, dict):
                raise DecodeError(f"expected an array map, got {type(obj).__name__}")
            if "data" in obj:
                return _array_from(obj, obj["data"])
            index = obj.get("frame")
            if not isinstance(index, int) or not 0 <= index < len(self._frames):
                raise DecodeError(f"array refers to frame {index!r} but the message has {len(self._frames)} buffer frames")
            frame = self._frames[index]
            return _array_from(obj, getattr(frame, "buffer", frame))
        return _dec_common(tp, obj)

    def _dec_inline(self, tp: type, obj: Any) -> Any:
        if tp is np.ndarray:
            if isinstance(obj, (bool, int, float)):
                return np.asarray(obj)
            if not isinstance(obj, dict) or "data" not in obj:
                raise DecodeError("expected an inline array map with 'data'")
            return _array_from(obj, obj["data"])
        return _dec_common(tp, obj)

    def decode(self, tp: type[Message], frames: Sequence[Any]) -> Message:
        """Decode ``[body, *buffers]`` (bytes or ``zmq.Frame``) as ``tp``; arrays view the frames."""
        if not frames:
            raise DecodeError("empty message")
        dec = self._wire_decoders.get(tp)
        if dec is None:
            dec = self._wire_decoders[tp] = msgspec.msgpack.Decoder(tp, dec_hook=self._dec_wire)
        body = frames[0]
        if type(body) is not bytes:
            body = getattr(body, "buffer", body)
        # self._frames is () between calls: a message without buffer frames leaves it so
        if len(frames) > 1:
            self._frames = frames[1:]
        try:
            return dec.decode(body)
        except msgspec.DecodeError as exc:
            raise DecodeError(f"cannot decode {tp.type_name()}: {exc}") from None
        except (DecodeError, TypeError, ValueError) as exc:
            raise DecodeError(f"cannot decode {tp.type_name()}: {exc}") from None
        finally:
            self._frames = ()

    def decode_inline(self, tp: type[Message], data: bytes | memoryview) -> Message:
        """Decode a log record (arrays inline)."""
        dec = self._inline_decoders.get(tp)
        if dec is None:
            dec = self._inline_decoders[tp] = msgspec.msgpack.Decoder(tp, dec_hook=self._dec_inline)
        try:
            return dec.decode(data)
        except (msgspec.DecodeError, DecodeError, TypeError, ValueError) as exc:
            raise DecodeError(f"cannot decode {tp.type_name()}: {exc}") from None


def _enc_common(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    raise NotImplementedError(f"cannot encode {type(obj).__name__}")


def _dec_common(tp: type, obj: Any) -> Any:
    raise NotImplementedError(f"cannot decode {tp}")


def wire_to_inline(frames: Sequence[Any]) -> bytes:
    """Re-encode wire frames as one inline blob without knowing the message type.

    Used by the recorder: array maps ``{"frame": k}`` get their buffer as ``data``.
    """
    import msgpack

    body = frames[0]
    buffers = frames[1:]
    doc = msgpack.unpackb(getattr(body, "buffer", body), raw=False, strict_map_key=False)

    def fill(node: Any) -> Any:
        if isinstance(node, dict):
            if "frame" in node and "dtype" in node and "shape" in node and len(node) == 3:
                index = node["frame"]
                if not isinstance(index, int) or not 0 <= index < len(buffers):
                    raise DecodeError(f"array refers to missing frame {index!r}")
                buf = buffers[index]
                return {"dtype": node["dtype"], "shape": node["shape"], "data": getattr(buf, "buffer", buf)}
            return {k: fill(v) for k, v in node.items()}
        if isinstance(node, list):
            return [fill(v) for v in node]
        return node

    try:
        return msgpack.packb(fill(doc), use_bin_type=True)
    except (TypeError, ValueError) as exc:
        raise DecodeError(f"cannot re-encode message: {exc}") from None


@functools.cache
def json_schema(tp: type[Message]) -> dict[str, Any]:
    """The JSON schema of a message type (what logs carry)."""
    return msgspec.json.schema(_shadow(tp), schema_hook=_schema_hook)


@functools.cache
def _shadow(tp: Any) -> Any:
    """``tp`` with array defaults turned into factories (schemas list only static defaults)."""
    if isinstance(tp, type) and issubclass(tp, msgspec.Struct):
        fields = []
        for f in msgspec.structs.fields(tp):
            ftype = _shadow_type(f.type)
            if isinstance(f.default, np.ndarray):
                fields.append((f.name, ftype, msgspec.field(default_factory=f.default.copy)))
            elif f.default is not msgspec.NODEFAULT:
                fields.append((f.name, ftype, f.default))
            elif f.default_factory is not msgspec.NODEFAULT:
                fields.append((f.name, ftype, msgspec.field(default_factory=f.default_factory)))
            else:
                fields.append((f.name, ftype))
        cfg = tp.__struct_config__
        return msgspec.defstruct(tp.__name__, fields, kw_only=True, frozen=True, tag=cfg.tag,
                                 tag_field=cfg.tag_field, module=tp.__module__)
    return tp


def _shadow_type(tp: Any) -> Any:
    import typing

    args = typing.get_args(tp)
    origin = typing.get_origin(tp)
    if origin is not None and args:
        mapped = tuple(_shadow_type(a) for a in args)
        try:
            return origin[mapped] if origin not in (typing.Union,) else typing.Union[mapped]
        except TypeError:
            return tp
    return _shadow(tp)
