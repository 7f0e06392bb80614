"""The node base class: declarations plus ``on_<input>`` handlers; the runtime does the rest.

A node declares a ``Config`` (msgspec Struct, validated at launch: field types, ``Meta``
bounds such as :data:`NonNegativeInt`, ``__post_init__``), ``inputs`` (message
type, or :class:`Input` with a queue policy), ``outputs`` and ``timers``. Handlers
``on_<input>(msg)`` return outputs as ``{"name": msg}`` (or a list of ``(name, msg)``
pairs, or ``None``). Source nodes (drivers, simulators) may instead override
:meth:`Node.run`, a loop that calls :meth:`Node.publish` until :attr:`Node.stopping` is
set. Node code never touches a socket or a clock other than :meth:`Node.now_ns`.

The same class runs in a launched pipeline, alone (``tether run``), in
:mod:`tether.testing` and under ``tether replay --into``.
"""
from __future__ import annotations

import difflib
import logging
import math
import re
import threading
from dataclasses import dataclass
from typing import Annotated, Any, Callable, ClassVar, Iterable, Mapping

import msgspec
import numpy as np

from tether.errors import ConfigError
from tether.message import Message


MAX_TIMER_HZ = 10_000.0        # a timer faster than this is a typo (or an attack), not a design

# Bounds of Config fields (msgspec ``Meta``): checked by :meth:`Node.make_config`, so ``tether run
# --param``, launch files and ``tether check`` refuse a value outside its meaning in one line
# ("count=-1: expected `int` >= 0"). Others: ``Annotated[float, msgspec.Meta(ge=0, le=1)]``.
# Like every msgspec constraint they are not checked when a Config is built in Python.
NonNegativeInt = Annotated[int, msgspec.Meta(ge=0)]
PositiveInt = Annotated[int, msgspec.Meta(gt=0)]
NonNegativeFloat = Annotated[float, msgspec.Meta(ge=0)]
PositiveFloat = Annotated[float, msgspec.Meta(gt=0)]


class Tick(Message, tag="std.Tick"):
    """What a timer input delivers: ``stamp_ns`` is the scheduled firing time."""

    period_ns: int = 0


class NoConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Config of a node that takes no parameters."""


@dataclass(frozen=True)
class Input:
    """An input port: its message type and queue policy.

    ``depth`` messages are kept (oldest dropped first, counted); ``latest=True`` keeps
    only the newest, for sensor streams that a slow node should sample, not queue.
    ``max_queue_bytes`` bounds the same queue in bytes, and sizes ZeroMQ's receive queue
    for this input from the largest message seen, so a slow node fed large messages
    holds a bounded amount of memory whatever the message count.
    """

    type: type[Message]
    depth: int = 16
    latest: bool = False
    max_queue_bytes: int = 64 << 20

    def __post_init__(self) -> None:
        if self.depth < 1:
            raise ValueError("Input depth must be >= 1")
        if self.max_queue_bytes < 1:
            raise ValueError("Input max_queue_bytes must be >= 1")

    @property
    def maxlen(self) -> int:
        return 1 if self.latest else self.depth


@dataclass(frozen=True)
class Ports:
    """A node's resolved inputs, outputs and timers (timer name -> period in ns)."""

    inputs: Mapping[str, Input]
    outputs: Mapping[str, type[Message]]
    timers: Mapping[str, int]


class Context:
    """What the runtime gives a node: how to publish and what time it is."""

    def publish(self, node: "Node", output: str, msg: Message) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def now_ns(self) -> int:  # pragma: no cover - interface
        raise NotImplementedError

    def loan(self, node: "Node", output: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """A writable array for ``output`` (plain memory here; the live runtime's is shared)."""
        return np.empty(shape, dtype)


class Node:
    """Base of every node. Subclasses declare, the runtime runs."""

    Config: ClassVar[type[msgspec.Struct]] = NoConfig
    inputs: ClassVar[Mapping[str, type[Message] | Input]] = {}
    outputs: ClassVar[Mapping[str, type[Message]]] = {}
    #: timer input name -> rate in Hz, or the name of a Config field holding the rate in Hz
    timers: ClassVar[Mapping[str, float | str]] = {}

    def __init__(self, config: msgspec.Struct, *, node_id: str, context: Context) -> None:
        self.config = config
        self.id = node_id
        self.log = logging.getLogger(f"tether.{node_id}")
        self.stopping = threading.Event()
        self._context = context
        self.ports = type(self).resolve_ports(config)

    # -- declarations ---------------------------------------------------------------
    @classmethod
    def ports_for(cls, config: msgspec.Struct) -> tuple[Mapping[str, Any], Mapping[str, type[Message]], Mapping[str, Any]]:
        """Inputs, outputs and timers for this config. Override when they depend on it."""
        return cls.inputs, cls.outputs, cls.timers

    @classmethod
    def resolve_ports(cls, config: msgspec.Struct) -> Ports:
        raw_inputs, outputs, raw_timers = cls.ports_for(config)
        inputs = {name: spec if isinstance(spec, Input) else Input(spec) for name, spec in raw_inputs.items()}
        timers: dict[str, int] = {}
        for name, rate in raw_timers.items():
            rate_hz = getattr(config, rate) if isinstance(rate, str) else rate
            if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) \
                    or not 0 < rate_hz <= MAX_TIMER_HZ:      # also False for NaN
                raise ConfigError(f"{cls.__name__}: timer {name!r} needs a rate in (0, {MAX_TIMER_HZ}] Hz, "
                                  f"got {rate_hz!r}", key=rate if isinstance(rate, str) else "")
            timers[name] = int(round(1e9 / float(rate_hz)))
            inputs.setdefault(name, Input(Tick, depth=1, latest=True))
        for name in inputs:
            if not callable(getattr(cls, f"on_{name}", None)):
                raise ConfigError(f"{cls.__name__}: input {name!r} has no handler on_{name}(msg)")
        return Ports(inputs=inputs, outputs=dict(outputs), timers=timers)

    @classmethod
    def make_config(cls, params: Mapping[str, Any] | None = None) -> msgspec.Struct:
        """Validate ``params`` against ``Config``; raise ``ConfigError`` naming the field."""
        name = f"{cls.__module__}:{cls.__name__} params"
        params = dict(params or {})
        fields = tuple(getattr(cls.Config, "__struct_fields__", ()))
        for key in params:
            if key not in fields:
                close = difflib.get_close_matches(str(key), fields, n=1)
                hint = f"did you mean {close[0]!r}?" if close else f"known: {', '.join(fields) or 'none'}"
                raise ConfigError(f"{name}: unknown key {key!r} ({hint})", key=str(key))
        for key, value in params.items():
            where = _non_finite(value)
            if where is not None:
                raise ConfigError(f"{name}: {key}{where} must be a finite number, got {value!r}"[:300], key=str(key))
        try:
            config = msgspec.convert(params, cls.Config, strict=False)
        except msgspec.ValidationError as exc:
            found = re.fullmatch(r"(.*) - at `\$\.([A-Za-z0-9_]+)(.*)`", str(exc), re.S)
            if found is None or found.group(2) not in params:
                raise ConfigError(f"{name}: {exc}", key=found.group(2) if found else "") from None
            why, key, inner = found.groups()       # "count=-1: expected `int` >= 0" (msgspec: "Expected ... - at `$.count`")
            where = f" (at {key}{inner})" if inner else ""
            raise ConfigError(f"{name}: {key}={params[key]!r}: {why[:1].lower()}{why[1:]}{where}"[:300], key=key) from None
        for key in params:       # again once converted: the text 'nan' or 'inf' (--param x=nan) becomes a float
            where = _non_finite(msgspec.to_builtins(getattr(config, key)))
            if where is not None:
                raise ConfigError(f"{name}: {key}{where} must be a finite number, got {params[key]!r}"[:300], key=str(key))
        return config

    @classmethod
    def is_source(cls) -> bool:
        """True when the node has its own loop (overrides :meth:`run`)."""
        return cls.run is not Node.run

    # -- lifecycle (override) -------------------------------------------------------
    def setup(self) -> None:
        """Called once before any input is handled."""

    def teardown(self) -> None:
        """Called once at shutdown, after the last handler (summaries, files, standby)."""

    def run(self) -> None:
        """A source node's loop: publish until ``self.stopping`` is set. Runs in its own thread."""

    # -- services -------------------------------------------------------------------
    def publish(self, output: str, msg: Message) -> None:
        """Publish ``msg`` on ``output`` (seq is stamped per topic; a zero stamp gets now)."""
        if output not in self.ports.outputs:
            raise KeyError(f"{type(self).__name__} has no output {output!r} (declared: {sorted(self.ports.outputs)})")
        self._context.publish(self, output, msg)

    def loan(self, output: str, shape: tuple[int, ...], dtype: Any = np.uint8) -> np.ndarray:
        """A writable array to fill and publish on ``output`` without a copy (optional; any array publishes).

        In a live graph it lies in ``output``'s shared-memory pool, so publishing it costs no
        copy at all; once published it belongs to the subscribers: do not write to it again.
        Elsewhere (tests, replay, small arrays, shared memory off) it is an ordinary array.
        """
        if output not in self.ports.outputs:
            raise KeyError(f"{type(self).__name__} has no output {output!r} (declared: {sorted(self.ports.outputs)})")
        return self._context.loan(self, output, tuple(int(n) for n in shape), dtype)

    def now_ns(self) -> int:
        """Current time on the runtime's clock (virtual under tether.testing and lockstep replay)."""
        return self._context.now_ns()

    def handler(self, input_name: str) -> Callable[[Message], Any]:
        return getattr(self, f"on_{input_name}")

    def dispatch(self, input_name: str, msg: Message) -> None:
        """Call ``on_<input>`` and publish whatever it returns."""
        for output, out in iter_outputs(self.handler(input_name)(msg)):
            self.publish(output, out)


def _non_finite(value: Any, depth: int = 0) -> str | None:
    """Where inside ``value`` a NaN or infinity sits ("" for the value itself), or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else ""
    if depth < 8 and isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            inner = _non_finite(item, depth + 1)
            if inner is not None:
                return f"[{i}]{inner}"
    if depth < 8 and isinstance(value, Mapping):
        for k, item in value.items():
            inner = _non_finite(item, depth + 1)
            if inner is not None:
                return f".{k}{inner}"
    return None


def iter_outputs(result: Any) -> Iterable[tuple[str, Message]]:
    """Normalise a handler's return value to ``(output, msg)`` pairs."""
    if result is None:
        return ()
    if type(result) is dict:          # the common case, without an ABC check per message
        return result.items()
    if isinstance(result, Mapping):
        return result.items()
    if isinstance(result, (list, tuple)):
        return result
    raise TypeError(f"a handler returns a dict of outputs, a list of (output, msg) pairs or None, not {type(result).__name__}")
