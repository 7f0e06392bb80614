"""The runtime's own example pipeline: a counter, a scaler and a printer."""
from __future__ import annotations

import msgspec

from msgs.std import Float64
from tether import Node, NonNegativeInt, Tick


class CounterConfig(msgspec.Struct, frozen=True, kw_only=True):
    rate_hz: float = 10.0       # bounded by its timer: (0, MAX_TIMER_HZ]
    start: float = 0.0
    count: NonNegativeInt = 0   # > 0: stop after this many (a stream whose total is known); 0: forever


class Counter(Node):
    """Publishes start, start+1, ... on ``value`` at ``rate_hz`` (``count`` of them, or forever)."""

    Config = CounterConfig
    outputs = {"value": Float64}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        self._next = self.config.start
        self.sent = 0

    def on_tick(self, tick: Tick) -> dict[str, Float64] | None:
        if 0 < self.config.count <= self.sent:
            return None
        self.sent += 1
        value, self._next = self._next, self._next + 1.0
        return {"value": Float64(data=value, stamp_ns=tick.stamp_ns)}


class ScaleConfig(msgspec.Struct, frozen=True, kw_only=True):
    gain: float = 2.0
    fail_on: float | None = None      # raise in the handler on this value (fault-injection tests)
    exit_on: float | None = None      # exit the process on this value (restart tests)


class Scale(Node):
    """``out = gain * in``."""

    Config = ScaleConfig
    inputs = {"value": Float64}
    outputs = {"value": Float64}

    def on_value(self, msg: Float64) -> dict[str, Float64]:
        if self.config.fail_on is not None and msg.data == self.config.fail_on:
            raise ValueError(f"injected failure on {msg.data}")
        if self.config.exit_on is not None and msg.data == self.config.exit_on:
            import os
            os._exit(3)
        return {"value": Float64(data=self.config.gain * msg.data, stamp_ns=msg.stamp_ns)}


class Printer(Node):
    """Logs each value; at shutdown, how many it saw."""

    inputs = {"value": Float64}

    def setup(self) -> None:
        self.count = 0

    def on_value(self, msg: Float64) -> None:
        self.count += 1
        self.log.info("value %.1f (seq %d)", msg.data, msg.seq)

    def teardown(self) -> None:
        self.log.info("saw %d values", self.count)
