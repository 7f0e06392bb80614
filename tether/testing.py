"""Run a node in-process on scripted inputs: deterministic, virtual clock, no sockets.

>>> h = Harness(PolarImager, params={"width_px": 256})
>>> outs = h.feed([(0.0, "ping", ping0), (0.1, "ping", ping1)])
>>> [o.output for o in outs]
['image', 'image']

Every message in and out goes through the wire codec (so what a node emits is what a
pipeline would carry). Timers fire at their virtual times, interleaved with inputs in
time order. Handler exceptions propagate (tests want to see them) unless
``catch_errors=True``, which mimics the live runtime: logged, counted, dropped.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import msgspec

from tether.codec import Codec
from tether.message import Message
from tether.node import Context, Node, Tick


@dataclass(frozen=True)
class Output:
    """One published message: virtual time (ns), output name and the message."""

    t_ns: int
    output: str
    msg: Message


@dataclass
class Harness(Context):
    """Hold a node instance; feed it inputs; collect what it publishes."""

    node_cls: type[Node]
    params: Mapping[str, Any] | None = None
    config: msgspec.Struct | None = None
    node_id: str = "node"
    roundtrip: bool = True
    catch_errors: bool = False
    start_ns: int = 0
    outputs: list[Output] = field(default_factory=list)
    errors: list[tuple[str, BaseException]] = field(default_factory=list)

    def __post_init__(self) -> None:
        cfg = self.config if self.config is not None else self.node_cls.make_config(self.params)
        self._now = self.start_ns
        self._codec = Codec()
        self._seq: dict[str, int] = {}
        self.node = self.node_cls(cfg, node_id=self.node_id, context=self)
        self._next_tick = {name: self.start_ns for name in self.node.ports.timers}
        self.node.setup()
        self._closed = False

    # -- Context ----------------------------------------------------------------------
    def now_ns(self) -> int:
        return self._now

    def publish(self, node: Node, output: str, msg: Message) -> None:
        expected = node.ports.outputs[output]
        if not isinstance(msg, expected):
            raise TypeError(f"{type(node).__name__} published {type(msg).__name__} on {output!r}, declared {expected.__name__}")
        seq = self._seq.get(output, 0) + 1
        self._seq[output] = seq
        changes: dict[str, Any] = {"seq": seq}
        if msg.stamp_ns == 0:
            changes["stamp_ns"] = self._now
        msg = msgspec.structs.replace(msg, **changes)
        if self.roundtrip:
            msg = self._codec.decode(expected, [bytes(memoryview(f).cast("B")) if not isinstance(f, bytes) else f
                                                for f in self._codec.encode(msg)])
        self.outputs.append(Output(self._now, output, msg))

    # -- driving ----------------------------------------------------------------------
    def _deliver(self, name: str, msg: Message) -> None:
        spec = self.node.ports.inputs[name]
        if not isinstance(msg, spec.type):
            raise TypeError(f"input {name!r} takes {spec.type.__name__}, got {type(msg).__name__}")
        if self.roundtrip:
            frames = self._codec.encode(msg)
            msg = self._codec.decode(spec.type, [bytes(memoryview(f).cast("B")) if not isinstance(f, bytes) else f
                                                 for f in frames])
        try:
            self.node.dispatch(name, msg)
        except Exception as exc:  # noqa: BLE001 - mirrors the live runtime when asked to
            if not self.catch_errors:
                raise
            self.errors.append((name, exc))

    def _fire_timers_until(self, t_ns: int) -> None:
        while self._next_tick:
            name, due = min(self._next_tick.items(), key=lambda kv: (kv[1], kv[0]))
            if due > t_ns:
                return
            self._now = due
            period = self.node.ports.timers[name]
            self._next_tick[name] = due + period
            self._deliver(name, Tick(stamp_ns=due, period_ns=period))

    def feed(self, events: Iterable[tuple[float, str, Message]], *, until_s: float | None = None) -> list[Output]:
        """Deliver ``(t_s, input, msg)`` events in time order (timers interleaved); return the new outputs.

        Times are seconds from ``start_ns``; events at equal times keep their given order.
        """
        first = len(self.outputs)
        queue = [(self.start_ns + int(round(t * 1e9)), i, name, msg) for i, (t, name, msg) in enumerate(events)]
        heapq.heapify(queue)
        while queue:
            t_ns, _, name, msg = heapq.heappop(queue)
            if t_ns < self._now:
                raise ValueError(f"event at {t_ns} ns is before the harness clock ({self._now} ns)")
            self._fire_timers_until(t_ns)
            self._now = t_ns
            self._deliver(name, msg)
        if until_s is not None:
            self.advance_to(until_s)
        return self.outputs[first:]

    def advance_to(self, t_s: float) -> list[Output]:
        """Move the virtual clock to ``t_s`` (seconds from start), firing due timers."""
        first = len(self.outputs)
        t_ns = self.start_ns + int(round(t_s * 1e9))
        self._fire_timers_until(t_ns)
        self._now = max(self._now, t_ns)
        return self.outputs[first:]

    def close(self) -> list[Output]:
        """Call the node's teardown; returns anything it published then."""
        first = len(self.outputs)
        if not self._closed:
            self._closed = True
            self.node.stopping.set()
            self.node.teardown()
        return self.outputs[first:]

    def of(self, output: str) -> list[Message]:
        """All messages published so far on ``output``."""
        return [o.msg for o in self.outputs if o.output == output]

    def __enter__(self) -> "Harness":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def run_node(node_cls: type[Node], events: Iterable[tuple[float, str, Message]], *,
             params: Mapping[str, Any] | None = None, until_s: float | None = None) -> list[Output]:
    """One-shot: build a harness, feed ``events``, close, and return every output."""
    with Harness(node_cls, params=params) as h:
        h.feed(events, until_s=until_s)
    return h.outputs
