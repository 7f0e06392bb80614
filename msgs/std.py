"""Standard messages: timer ticks, strings, scalars, node statistics."""
from __future__ import annotations

from tether.message import Message
from tether.node import Tick
from tether.stats import InputStats, NodeStats     # the runtime's own messages, re-exported for users

__all__ = ["Tick", "Bytes", "String", "Float64", "Int64", "Bool", "Empty", "InputStats", "NodeStats"]


class String(Message, tag="std.String"):
    data: str = ""


class Float64(Message, tag="std.Float64"):
    data: float = 0.0


class Int64(Message, tag="std.Int64"):
    data: int = 0


class Bool(Message, tag="std.Bool"):
    data: bool = False


class Empty(Message, tag="std.Empty"):
    pass


class Bytes(Message, tag="std.Bytes"):
    """An opaque payload."""

    data: bytes = b""
