"""Run a launch file in one process, in virtual time, deterministically: a lockstep pipeline.

Every node of the launch file runs in a :class:`tether.testing.Harness` on one shared
virtual clock advanced in steps of ``step_s``; each message published during a step is
delivered to its subscribers at the start of the next one (a transport latency of one
step). Nodes that talk CAN (they have an ``open_bus()`` method, like
``drivers.canopen402:Cia402Bus`` and ``sim.cia402_drive:Cia402DriveSim``) get an endpoint
of one :class:`sim.cia402_bank.SyncCanHub` instead of their configured interface, so a
CANopen master and the simulated drives exchange real frames -- SDO bring-up, PDOs, SYNC,
heartbeats, EMCY -- synchronously at the virtual time.

The same launch file therefore runs live (``tether launch``, real processes and a real
bus, wall-clock timing) and here (same node classes, same parameters and wiring, no
scheduling noise: identical results on every run, faster than real time). Source nodes
with their own ``run()`` loop cannot be stepped and are refused.

>>> run = run_lockstep("launch/ackermann_can.yaml", duration_s=10.0, overrides={"eval": {"png": ""}})
>>> run.node("eval").evaluate(0.0)[0]["rms_mm"]            # doctest: +SKIP
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from sim.cia402_bank import SyncCanHub
from tether.launch import TIMER_RE, load_launch, timer_period_ns
from tether.message import Message
from tether.node import Node, Tick
from tether.testing import Harness

log = logging.getLogger(__name__)


def _on_hub(cls: type[Node], hub: SyncCanHub) -> type[Node]:
    """``cls`` whose ``open_bus()`` returns an endpoint of ``hub`` (a subclass made for this run)."""
    def open_bus(self: Node):   # noqa: ANN202 - a SyncCanBus
        return hub.bus(self.id)
    return type(cls.__name__, (cls,), {"open_bus": open_bus, "__module__": cls.__module__})


@dataclass
class LockstepRun:
    """Harnesses of a launch file's nodes after a lockstep run (torn down), and what they published."""

    harnesses: dict[str, Harness]
    hub: SyncCanHub
    t_s: float = 0.0
    delivered: int = 0
    errors: list[tuple[str, str, BaseException]] = field(default_factory=list)

    def node(self, node_id: str) -> Node:
        return self.harnesses[node_id].node

    def of(self, topic: str) -> list[Message]:
        """Every message published on ``node/output``."""
        node_id, _, output = topic.partition("/")
        return self.harnesses[node_id].of(output)


def run_lockstep(path: str | Path, *, duration_s: float, overrides: Mapping[str, Mapping[str, Any]] | None = None,
                 step_s: float = 0.001, catch_errors: bool = False) -> LockstepRun:
    """Run the launch file at ``path`` for ``duration_s`` seconds of virtual time.

    Parameters
    ----------
    path : launch file (validated as ``tether launch`` does)
    duration_s : float, s, virtual time
    overrides : {node_id: {param: value}}, like ``tether launch --param node.key=value``
    step_s : float, s
        Clock step: timers fire at their exact times inside it, messages travel one step.
    catch_errors : bool
        True mimics the live runtime (a failing handler is logged and counted in ``errors``);
        False (the default, for tests) lets the exception propagate.

    Returns
    -------
    LockstepRun
        Every node has been torn down (summaries logged, files written).
    """
    if not duration_s > 0 or not step_s > 0:
        raise ValueError("duration_s and step_s must be > 0 (seconds of virtual time)")
    launch = load_launch(path, overrides)
    hub = SyncCanHub()
    harnesses: dict[str, Harness] = {}
    subscribers: dict[str, list[tuple[str, str]]] = {}
    timers: list[tuple[str, str, int]] = []                # (node, input, period ns) of timer/hz/N inputs
    for entry in launch.nodes:
        if entry.cls is not None and entry.cls.is_source():
            raise ValueError(f"{path}: node {entry.id!r} ({entry.node}) runs its own loop (run()); lockstep needs "
                             "nodes driven by inputs and timers")
    for entry in launch.nodes:
        cls = entry.cls
        assert cls is not None
        if callable(getattr(cls, "open_bus", None)):
            cls = _on_hub(cls, hub)
        harnesses[entry.id] = Harness(cls, params=entry.params, node_id=entry.id, catch_errors=catch_errors)
        for name, src in entry.inputs.items():
            if TIMER_RE.match(src):
                timers.append((entry.id, name, timer_period_ns(src)))
            else:
                subscribers.setdefault(src, []).append((entry.id, name))
    run = LockstepRun(harnesses, hub)
    try:
        _drive(run, subscribers, timers, duration_s, step_s)
    finally:
        for node_id, h in harnesses.items():
            try:
                h.close()
            except Exception:  # noqa: BLE001 - tear every node down even if one fails
                log.exception("teardown of %s failed", node_id)
        for node_id, h in harnesses.items():
            run.errors.extend((node_id, name, exc) for name, exc in h.errors)
    return run


def _drive(run: LockstepRun, subscribers: dict[str, list[tuple[str, str]]], timers: list[tuple[str, str, int]],
           duration_s: float, step_s: float) -> None:
    """Advance the shared clock step by step: devices on the CAN hub, last step's messages, timers."""
    routed = {node_id: 0 for node_id in run.harnesses}
    pending: list[tuple[str, Message]] = []
    step_ns = int(round(step_s * 1e9))
    for k in range(int(round(duration_s / step_s)) + 1):
        t = k * step_s
        t_ns = int(round(t * 1e9))
        run.hub.advance(t)
        inbox: dict[str, list[tuple[float, str, Message]]] = {}
        for topic, msg in pending:
            for node_id, name in subscribers.get(topic, ()):
                inbox.setdefault(node_id, []).append((t, name, msg))
        for node_id, name, period in timers:
            if t_ns % period < step_ns:
                inbox.setdefault(node_id, []).append((t, name, Tick(stamp_ns=t_ns, period_ns=period)))
        pending = []
        for node_id, h in run.harnesses.items():
            events = inbox.get(node_id, [])
            run.delivered += len(events)
            h.feed(events, until_s=t)
            pending.extend((f"{node_id}/{o.output}", o.msg) for o in h.outputs[routed[node_id]:])
            routed[node_id] = len(h.outputs)
        run.t_s = t
