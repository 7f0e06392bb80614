"""Standard messages: timer ticks, strings, scalars, node statistics."""
from __future__ import annotations

from tether.message import Message
from tether.node import Tick

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


class InputStats(Message, tag="std.InputStats"):
    """Counters of one input (cumulative since the node started)."""

    name: str = ""
    topic: str = ""
    received: int = 0
    handled: int = 0
    dropped_seq_gap: int = 0       # lost in transport: gaps in the publisher's seq
    dropped_queue: int = 0         # discarded by this input's queue policy (depth / latest-only)
    decode_errors: int = 0
    handler_errors: int = 0
    handler_ms_mean: float = 0.0
    handler_ms_max: float = 0.0
    seq_resets: int = 0            # the publisher's seq went backwards or jumped absurdly (restart, bug, attack)
    dropped_restart: int = 0       # published while this node was down (seq gap across its own restart)
    link_resets: int = 0           # connection dropped by ZeroMQ (e.g. a frame over the receive limit), redialled
    queued_bytes: int = 0          # bytes waiting in this input's queue now


class NodeStats(Message, tag="std.NodeStats"):
    """Published by every node on ``<node-id>/_stats`` once a second."""

    node_id: str = ""
    node_class: str = ""
    pid: int = 0
    uptime_s: float = 0.0
    inputs: list[InputStats] = []
    published: dict[str, int] = {}
    subscribers: dict[str, int] = {}
    errors: int = 0
    restarts: int = 0              # how many times the launcher restarted this node before this run
    stats_errors: int = 0          # failures while publishing these statistics (counted, never fatal)


class Bytes(Message, tag="std.Bytes"):
    """An opaque payload."""

    data: bytes = b""
