"""Transport benchmark peers: round-trip pinger/echo and a 1 MiB image source/sink.

Results are written as JSON to ``result_path`` when the node finishes its count
(used by ``bench/transport.py``; the bench process waits for the file).
"""
from __future__ import annotations

import json
import os
import time

import msgspec
import numpy as np

from msgs.sensor import Image
from msgs.std import Bytes
from tether import Input, Node, NonNegativeFloat, NonNegativeInt, PositiveInt


class PingConfig(msgspec.Struct, frozen=True, kw_only=True):
    count: PositiveInt = 2000
    warmup: NonNegativeInt = 200
    payload_bytes: NonNegativeInt = 64
    result_path: str = ""


class Pinger(Node):
    """Publishes ``ping``, times each ``pong`` (round trip, ns), publishes the next ping.

    The first ping (and a replacement for a lost one) goes out from a 2 Hz timer, so the node
    has no thread besides its runtime loop.
    """

    Config = PingConfig
    inputs = {"pong": Bytes}
    outputs = {"ping": Bytes}
    timers = {"tick": 2.0}

    def setup(self) -> None:
        self._payload = os.urandom(self.config.payload_bytes)
        self._rtts: list[int] = []
        self._sent_ns = 0
        self._done = False

    def _send(self) -> None:
        self._sent_ns = time.perf_counter_ns()
        self.publish("ping", Bytes(data=self._payload, stamp_ns=1))

    def on_tick(self, tick) -> None:
        if not self._done and time.perf_counter_ns() - self._sent_ns > 4e8:   # first, or lost
            self._send()

    def on_pong(self, msg: Bytes) -> None:
        self._rtts.append(time.perf_counter_ns() - self._sent_ns)
        if len(self._rtts) >= self.config.count + self.config.warmup:
            if not self._done:
                self._done = True
                _write_result(self.config.result_path, {"rtt_ns": self._rtts[self.config.warmup:]})
            return
        self._send()


class Echo(Node):
    """Republishes every ``ping`` as ``pong``."""

    inputs = {"ping": Bytes}
    outputs = {"pong": Bytes}

    def on_ping(self, msg: Bytes) -> dict[str, Bytes]:
        return {"pong": msg}


class BlobConfig(msgspec.Struct, frozen=True, kw_only=True):
    count: PositiveInt = 2000
    rows: PositiveInt = 512
    cols: PositiveInt = 2048
    result_path: str = ""
    rate_hz: NonNegativeFloat = 0.0     # 0: as fast as the socket takes them
    loan: bool = False        # write each image into a loaned (shared-memory) array: no copy at publish


class BlobSource(Node):
    """Publishes ``count`` rows x cols uint8 images as fast as the socket takes them."""

    Config = BlobConfig
    outputs = {"image": Image}

    def run(self) -> None:
        rng = np.random.default_rng(0)
        shape = (self.config.rows, self.config.cols)
        image = rng.integers(0, 255, shape, dtype=np.uint8)
        period_ns = int(1e9 / self.config.rate_hz) if self.config.rate_hz > 0 else 0
        start = time.monotonic_ns()
        for i in range(self.config.count):
            if self.stopping.is_set():
                return
            if period_ns:
                self.stopping.wait(max(0.0, (start + i * period_ns - time.monotonic_ns()) / 1e9))
            data = image
            if self.config.loan:
                # A driver decoding straight into the loaned buffer: here only a stamp row is written.
                data = self.loan("image", shape)
                data[0, :8] = i & 0xFF
            self.publish("image", Image(data=data, encoding="mono8", stamp_ns=time.time_ns()))
        self.stopping.wait(2.0)   # let the last frames leave before the socket closes


class BlobSink(Node):
    """Counts images and bytes; writes the receive rate once ``count`` arrived or input went quiet."""

    Config = BlobConfig
    # A burst of 1000 x 1 MiB is what this benchmark measures: the queue is sized for it on
    # purpose (the default 64 MiB bound would drop most of a burst, counted, by design).
    inputs = {"image": Input(Image, depth=1000, max_queue_bytes=1 << 30)}
    timers = {"tick": 2.0}

    def setup(self) -> None:
        self._times: list[int] = []
        self._latency: list[int] = []
        self._checksum = 0
        self._written = False

    def on_image(self, msg: Image) -> None:
        self._times.append(time.perf_counter_ns())
        self._latency.append(time.time_ns() - msg.stamp_ns)     # publish to handler, same host clock
        self._checksum += int(msg.data[0, 0]) + int(msg.data[-1, -1])
        if len(self._times) == self.config.count:
            self._flush()

    def on_tick(self, tick) -> None:
        # Some messages were dropped at a high-water mark: report what arrived once it goes quiet.
        if self._times and not self._written and time.perf_counter_ns() - self._times[-1] > 1.5e9:
            self._flush()

    def _flush(self) -> None:
        self._written = True
        _write_result(self.config.result_path, {"recv_ns": self._times, "latency_ns": self._latency,
                                                "checksum": self._checksum})

    def teardown(self) -> None:
        if not self._written:
            self._flush()


def _write_result(path: str, doc: dict) -> None:
    if path:
        tmp = path + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(doc, fh)
        os.replace(tmp, path)
