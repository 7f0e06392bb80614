"""Peers of the chaos benchmark (``bench/chaos.py``): a finite counter, sinks, and a raw-frame fuzzer.

:class:`RawFuzzer` is an attacker on purpose: it writes crafted frames straight onto its
runtime's publisher socket, past the codec, so the nodes wired to it see what a buggy or
hostile publisher would send. Nothing else in the tree may touch the runtime this way.
"""
from __future__ import annotations

import json
import os
import time
from typing import Any, Callable

import msgpack
import msgspec
import numpy as np

from msgs.sensor import Image
from msgs.std import Float64
from tether import Input, Node, NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt, Tick
from tether.message import Message, message_type
from tether.node import Ports

U64_MAX = (1 << 64) - 1
I64_MAX = (1 << 63) - 1


class QuietSink(Node):
    """Takes ``value`` and does nothing with it (the runtime's counters are what is measured)."""

    inputs = {"value": Input(Float64, depth=1000)}

    def on_value(self, msg: Float64) -> None:
        return None


class TypedSinkConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    types: list[str] = []          # message tags; one input per tag, named by input_name(tag)
    depth: PositiveInt = 1000


def input_name(tag: str) -> str:
    """The input of :class:`TypedSink` that takes messages of type ``tag`` (``sonar.SonarPing`` -> ``sonar_SonarPing``)."""
    return tag.replace(".", "_")


class TypedSink(Node):
    """One input per message type named in ``types``, each taken and dropped: a receiver of every type.

    The fault tests wire a raw publisher to it and check that whatever arrives on any
    input is handled or counted and that the node lives on.
    """

    Config = TypedSinkConfig

    @classmethod
    def resolve_ports(cls, config: msgspec.Struct) -> Ports:
        inputs = {input_name(tag): Input(message_type(tag), depth=config.depth) for tag in config.types}
        return Ports(inputs=inputs, outputs={}, timers={})

    def handler(self, input_name: str) -> Callable[[Message], None]:
        return self._take

    def _take(self, msg: Message) -> None:
        return None


class SlowSinkConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    delay_ms: NonNegativeFloat = 100.0


class SlowSink(Node):
    """Takes ``image`` and spends ``delay_ms`` on each: a consumer slower than its producer."""

    Config = SlowSinkConfig
    inputs = {"image": Input(Image, depth=64)}

    def on_image(self, msg: Image) -> None:
        if self.config.delay_ms > 0:
            self.stopping.wait(self.config.delay_ms / 1000)


class RawFuzzerConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rate_hz: PositiveFloat = 200.0
    seed: NonNegativeInt = 0
    result_path: str = ""          # JSON {case: count}, rewritten every second and at the end
    oversize_bytes: NonNegativeInt = 0   # > 0: also send frames of this many bytes (past a receiver's limit)


def _head(tag: str, *, seq: int = 1, stamp_ns: int = 1, **fields: Any) -> dict[str, Any]:
    return {"type": tag, "stamp_ns": stamp_ns, "frame_id": "", "seq": seq, **fields}


def _pack(doc: Any) -> bytes:
    return msgpack.packb(doc, use_bin_type=True)


class RawFuzzer(Node):
    """Sends crafted frames on ``value`` (Float64) and ``image`` (Image) at ``rate_hz``.

    Cases: header extremes on valid messages (seq 0, 2^63, 2^64-1 then a reset to 1;
    stamp -1, 0, 2^63-1), and malformed ones (a 0-byte body, random bytes, truncated
    msgpack, a non-map body, the wrong message type, huge declared lengths, an array
    whose shape disagrees with its buffer, a missing buffer frame); with ``oversize_bytes``
    also a ``big`` stream (see :meth:`_send_big`). ``malformed_*`` cases must each be a
    counted decode error at every receiver.
    """

    Config = RawFuzzerConfig
    outputs = {"value": Float64, "image": Image, "big": Float64}

    def setup(self) -> None:
        self.rng = np.random.default_rng(self.config.seed)
        self.counts: dict[str, int] = {}
        self._seq = 0
        cases: list[tuple[str, Callable[[], list[bytes]]]] = [
            ("valid_seq_extreme", self._seq_extreme), ("valid_stamp_extreme", self._stamp_extreme),
            ("malformed_empty", lambda: [b""]), ("malformed_random", self._random),
            ("malformed_truncated", self._truncated), ("malformed_not_a_map", lambda: [_pack([1, 2, 3])]),
            ("malformed_wrong_type", lambda: [_pack(_head("std.String", data="hello"))]),
            ("malformed_huge_length", lambda: [b"\xc6\xff\xff\xff\xf0" + b"\0" * 8]),
            ("malformed_field_type", lambda: [_pack(_head("std.Float64", data="not a float"))]),
        ]
        self._value_cases = cases
        self._image_cases: list[tuple[str, Callable[[], list[bytes]]]] = [
            ("malformed_array_shape", self._array_shape), ("malformed_array_frame", self._array_frame),
            ("valid_image", self._image),
        ]
        self._big_seq = 0

    # -- cases ------------------------------------------------------------------------
    def _seq_extreme(self) -> list[bytes]:
        seq = [0, 1, 1 << 63, U64_MAX, 1][self._seq % 5]
        self._seq += 1
        return [_pack(_head("std.Float64", seq=seq, data=1.0))]

    def _stamp_extreme(self) -> list[bytes]:
        stamp = [-1, 0, I64_MAX][int(self.rng.integers(3))]
        return [_pack(_head("std.Float64", stamp_ns=stamp, seq=int(self.rng.integers(1, 1 << 62)), data=2.0))]

    def _random(self) -> list[bytes]:
        return [self.rng.bytes(int(self.rng.integers(1, 64)))]

    def _truncated(self) -> list[bytes]:
        body = _pack(_head("std.Float64", data=3.0))
        return [body[: int(self.rng.integers(1, len(body)))]]

    def _array(self, shape: list[int], frame: int = 0) -> dict[str, Any]:
        return {"dtype": "|u1", "shape": shape, "frame": frame}

    def _array_shape(self) -> list[bytes]:
        return [_pack(_head("sensor.Image", data=self._array([64, 64]), encoding="mono8")), b"\0" * 100]

    def _array_frame(self) -> list[bytes]:
        return [_pack(_head("sensor.Image", data=self._array([4, 4], frame=3), encoding="mono8")), b"\0" * 16]

    def _image(self) -> list[bytes]:
        return [_pack(_head("sensor.Image", data=self._array([4, 4]), encoding="mono8")), b"\1" * 16]

    # -- loop -------------------------------------------------------------------------
    def _send(self, output: str, frames: list[bytes]) -> None:
        from tether.runtime import _send

        runtime = self._context
        with runtime._pub_lock:                      # the attacker's privilege: raw frames on our socket
            _send(runtime.pub, f"{self.id}/{output}".encode(), frames)

    def run(self) -> None:
        period = 1.0 / self.config.rate_hz
        next_write = time.monotonic() + 1.0
        while not self.stopping.wait(period):
            output, cases = ("image", self._image_cases) if self.rng.random() < 0.25 else ("value", self._value_cases)
            name, make = cases[int(self.rng.integers(len(cases)))]
            self._send(output, make())
            self.counts[name] = self.counts.get(name, 0) + 1
            if self.config.oversize_bytes > 0:
                self._send_big()
            if time.monotonic() >= next_write:
                next_write += 1.0
                self._write()
        self._write()

    def _send_big(self) -> None:
        """On ``big``: valid Float64 with consecutive seq, and one oversize frame in ten.

        A receiver whose limit is below ``oversize_bytes`` loses its connection at each
        oversize frame; what it misses while redialling shows as a seq gap (counted).
        """
        if self.rng.random() < 0.1:
            self._send("big", [b"\0" * self.config.oversize_bytes])
            self.counts["oversize"] = self.counts.get("oversize", 0) + 1
            return
        self._big_seq += 1
        self._send("big", [_pack(_head("std.Float64", seq=self._big_seq, stamp_ns=time.time_ns(), data=1.0))])
        self.counts["big_valid"] = self.counts.get("big_valid", 0) + 1

    def _write(self) -> None:
        if self.config.result_path:
            tmp = f"{self.config.result_path}.tmp"
            with open(tmp, "w") as fh:
                json.dump(self.counts, fh)
            os.replace(tmp, self.config.result_path)


class CrasherConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    after_s: NonNegativeFloat = 0.1
    hang: bool = False          # instead of exiting, block the handler forever: a node that cannot stop when asked


class Crasher(Node):
    """Exits the process with code 3 ``after_s`` seconds after it starts (a restart storm under ``on-failure``),
    or with ``hang`` blocks there forever."""

    Config = CrasherConfig
    timers = {"tick": 50.0}

    def setup(self) -> None:
        self.started = time.monotonic()

    def on_tick(self, tick: Tick) -> None:
        if time.monotonic() - self.started >= self.config.after_s:
            if self.config.hang:
                self.log.info("hanging in on_tick from now on")
            while self.config.hang:            # a stop request sets an event nobody looks at again
                time.sleep(3600)
            os._exit(3)

