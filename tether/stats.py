"""The runtime's own messages: node statistics, published by every node on ``<node-id>/_stats``.

They live in the runtime (which must not import the message library above it) and are
re-exported by :mod:`msgs.std` for users; their tags keep the ``std.`` namespace, so logs
and peers read them unchanged.
"""
from __future__ import annotations

from tether.message import Message


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
    received_bytes: int = 0        # bytes received (frames, before decoding), cumulative
    dropped_link: int = 0          # lost on the launch file's link model (loss, bandwidth cap, outage)


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
    published_bytes: dict[str, int] = {}   # per output: bytes sent (frames and topic), cumulative
    # shared memory (docs/wire.md section 10), cumulative over every output / input of the node:
    shm_placed: int = 0            # messages whose large buffers went through a pool slot
    shm_loaned: int = 0            # ... of which lay in a loaned slot already (no copy at all)
    shm_fallbacks: int = 0         # sent as ordinary frames: no slot came free in time (pool busy)
    shm_oversize: int = 0          # sent as ordinary frames: larger than half the pool
    shm_stale: int = 0             # slot tables received whose slot was reused before we could lease it
    rt_priority: int = 0           # the SCHED_FIFO priority the node runs at (0: normal scheduling)
