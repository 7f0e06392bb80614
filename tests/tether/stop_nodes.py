"""Nodes for the launcher's stop tests (launched as ``tests.tether.stop_nodes:Class``): a slow stage, a stuck one."""
from __future__ import annotations

import time

import msgspec

from msgs.std import Float64
from tether import Input, Node


class SlowScaleConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    gain: float = 2.0
    delay_ms: float = 10.0          # spent on each message: slower than its source, so messages queue
    hang_on_stop: bool = False      # teardown never returns: a node that cannot stop when asked


class SlowScale(Node):
    """``out = gain * in``, ``delay_ms`` per message; a deep queue, so nothing is dropped while it lags."""

    Config = SlowScaleConfig
    inputs = {"value": Input(Float64, depth=1000)}
    outputs = {"value": Float64}

    def on_value(self, msg: Float64) -> dict[str, Float64]:
        time.sleep(self.config.delay_ms / 1000)      # not self.stopping.wait: it must stay slow while stopping
        return {"value": Float64(data=self.config.gain * msg.data, stamp_ns=msg.stamp_ns)}

    def teardown(self) -> None:
        if self.config.hang_on_stop:
            self.log.info("hanging in teardown")
        while self.config.hang_on_stop:
            time.sleep(3600)


class Add(Node):
    """``out = a + b`` on each message of either input (the last of the other): two inputs, to wire cycles."""

    inputs = {"a": Float64, "b": Float64}
    outputs = {"value": Float64}

    def setup(self) -> None:
        self.last = {"a": 0.0, "b": 0.0}

    def on_a(self, msg: Float64) -> dict[str, Float64]:
        self.last["a"] = msg.data
        return {"value": Float64(data=self.last["a"] + self.last["b"], stamp_ns=msg.stamp_ns)}

    def on_b(self, msg: Float64) -> None:
        self.last["b"] = msg.data
