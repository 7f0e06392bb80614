"""A launch graph as a Kripke structure: one tracked message through queues, crashes and restarts.

What is modelled (the runtime's behaviour, see tether/runner.py and tether/inputs.py):

* every node is ``up`` or down; a node may crash (at most ``faults`` times, the fault
  hypothesis) and comes back if its restart policy allows it (``on-failure`` with restarts
  left -- at most ``min(max_restarts, faults)`` are modelled -- ``never`` leaves it dead);
* one *tracked* message is published on the focus topic when its publisher is up; each
  subscriber's copy is then ``queued`` (or ``lost`` if the subscriber is down), and is
  ``handled``, or ``dropped`` by its bounded queue (other traffic from a live publisher can
  always push it out: depth and latest-only bound the queue, the drop is counted), or
  ``lost`` when the subscriber crashes with it queued. A loss is ``counted`` when the
  subscriber restarts: its sequence numbers survive restarts, so the next message shows the
  gap (the runtime's ``dropped_seq_gap``); a subscriber that never restarts never counts it;
* other traffic is abstracted away (data independence): an up node can always do
  something else (a self-loop), so only a state with every node dead for good is a deadlock.

Fairness (justice, as Buchi sets): an up subscriber does not leave a queued copy for ever,
an up publisher does not hold the message for ever, and a restart that is due happens.

Labels: ``up(node)``, ``dead(node)``, ``published``, and per subscribing input
``queued(node.input)``, ``handled(...)``, ``dropped(...)``, ``lost(...)``, ``counted(...)``,
``has_publisher(...)``; ``settled`` when every copy is handled, dropped or counted.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from nodes.verify.kripke import Kripke, explore

QUEUED, HANDLED, DROPPED, LOST, COUNTED = "queued", "handled", "dropped", "lost", "counted"


@dataclass(frozen=True)
class GraphNode:
    id: str
    restart: str = "never"           # never | on-failure
    max_restarts: int = 3


@dataclass(frozen=True)
class GraphEdge:
    source: str                      # "node/output" or "timer/..."
    node: str
    input: str
    depth: int = 16                  # 1 for latest-only inputs

    @property
    def publisher(self) -> str | None:
        return None if self.source.startswith("timer/") else self.source.split("/", 1)[0]

    @property
    def name(self) -> str:
        return f"{self.node}.{self.input}"


@dataclass(frozen=True)
class GraphSpec:
    nodes: tuple[GraphNode, ...]
    edges: tuple[GraphEdge, ...]

    def node(self, node_id: str) -> GraphNode:
        return next(n for n in self.nodes if n.id == node_id)

    def topics(self) -> list[str]:
        """Node-output topics that something subscribes to, in order of first use."""
        return list(dict.fromkeys(e.source for e in self.edges if e.publisher is not None))


def graph_model(spec: GraphSpec, focus: str | None, *, faults: int = 1,
                max_states: int = 1_000_000) -> tuple[Kripke, list[np.ndarray]]:
    """The structure tracking one message on topic ``focus`` (None: node faults only), and its fairness sets."""
    ids = [n.id for n in spec.nodes]
    pos = {n: i for i, n in enumerate(ids)}
    edges = [e for e in spec.edges if e.source == focus] if focus else []
    if focus and not edges:
        raise ValueError(f"no input subscribes to {focus!r}; topics with subscribers: {spec.topics()}")
    pub = pos.get(edges[0].publisher) if edges else None
    if edges and pub is None:
        raise ValueError(f"topic {focus!r} has no publisher in the launch file")
    sub = [pos[e.node] for e in edges]
    budget = [min(n.max_restarts, faults) if n.restart != "never" else 0 for n in spec.nodes]

    # state: (up tuple, crashes tuple, restarts tuple, published, copies tuple)
    def step(s: tuple) -> Iterator[tuple]:
        up, crashes, restarts, published, copies = s
        if any(up):
            yield s                                            # other traffic
        if pub is not None and not published and up[pub]:
            yield (up, crashes, restarts, True, tuple(QUEUED if up[k] else LOST for k in sub))
        for j, (k, c) in enumerate(zip(sub, copies)):
            if c == QUEUED and up[k]:
                yield (up, crashes, restarts, published, _set(copies, j, HANDLED))
            if c == QUEUED and up[pub]:
                yield (up, crashes, restarts, published, _set(copies, j, DROPPED))
        for i in range(len(ids)):
            if up[i] and crashes[i] < faults:
                lost = tuple(LOST if k == i and c == QUEUED else c for k, c in zip(sub, copies))
                yield (_set(up, i, False), _set(crashes, i, crashes[i] + 1), restarts, published, lost)
            if not up[i] and restarts[i] < budget[i]:
                counted = tuple(COUNTED if k == i and c == LOST else c for k, c in zip(sub, copies))
                yield (_set(up, i, True), crashes, _set(restarts, i, restarts[i] + 1), published, counted)

    n = len(ids)
    start = ((True,) * n, (0,) * n, (0,) * n, False, tuple("" for _ in sub))
    props: dict = {"published": lambda s: s[3],
                   "settled": lambda s: s[3] and all(c in (HANDLED, DROPPED, COUNTED) for c in s[4])}
    for i, node in enumerate(ids):
        props[f"up({node})"] = (lambda i: lambda s: s[0][i])(i)
        props[f"dead({node})"] = (lambda i: lambda s: not s[0][i] and s[2][i] >= budget[i])(i)
    for j, e in enumerate(edges):
        for state in (QUEUED, HANDLED, DROPPED, LOST):
            props[f"{state}({e.name})"] = (lambda j, st: lambda s: s[4][j] == st)(j, state)
        props[f"counted({e.name})"] = (lambda j: lambda s: s[4][j] in (DROPPED, COUNTED))(j)
    for e in spec.edges:
        wired = e.publisher is None or e.publisher in pos
        props.setdefault(f"has_publisher({e.name})", lambda s, w=wired: w)
    k = explore([start], step, props, max_states=max_states)
    fairness = _justice(k, spec, sub, pub, budget)

    def describe(st: tuple) -> str:
        up, crashes, restarts, published, copies = st
        nodes = " ".join(n if u else f"{n}:DOWN" for n, u in zip(ids, up))
        msg = ("published: " + ", ".join(f"{e.name}={c}" for e, c in zip(edges, copies))) if published else \
            ("not yet published" if edges else "")
        return f"{nodes}  {msg}".rstrip()

    k.names = _Described(k.names, describe)
    return k, fairness


class _Described:
    """State names made readable on demand (traces print a handful of states out of many)."""

    def __init__(self, states: list, describe) -> None:
        self.states, self.describe = states, describe

    def __getitem__(self, i: int) -> str:
        return self.describe(self.states[i])

    def __len__(self) -> int:
        return len(self.states)


def _set(t: tuple, i: int, v: object) -> tuple:
    return t[:i] + (v,) + t[i + 1:]


def _justice(k: Kripke, spec: GraphSpec, sub: list[int], pub: int | None, budget: list[int]) -> list[np.ndarray]:
    """Buchi sets: states where no enabled duty is being postponed."""
    out = []
    states = k.names                       # the raw states: called before they are given readable names
    for j, node in enumerate(sub):
        out.append(np.fromiter((not (s[4][j] == QUEUED and s[0][node]) for s in states), bool, len(states)))
    if pub is not None:
        out.append(np.fromiter((s[3] or not s[0][pub] for s in states), bool, len(states)))
    for i in range(len(spec.nodes)):
        if budget[i]:
            out.append(np.fromiter((s[0][i] or s[2][i] >= budget[i] for s in states), bool, len(states)))
    return out


def spec_from_launch(launch: object) -> GraphSpec:
    """A :class:`GraphSpec` from a validated :class:`tether.launch.LaunchFile`."""
    nodes = tuple(GraphNode(n.id, n.restart, n.max_restarts) for n in launch.nodes)
    edges = []
    for n in launch.nodes:
        for name, src in n.inputs.items():
            port = n.ports.inputs[name]
            edges.append(GraphEdge(src, n.id, name, port.maxlen))
    return GraphSpec(nodes, tuple(edges))


def default_properties(spec: GraphSpec) -> list[tuple[str | None, str]]:
    """(focus topic, formula): every subscribed message handled or counted; no deadlock; every input wired."""
    props: list[tuple[str | None, str]] = [(None, "AG !deadlock")]
    for topic in spec.topics():
        for e in spec.edges:
            if e.source == topic:
                props.append((topic, f"AG (published -> AF (handled({e.name}) | counted({e.name})))"))
    for e in spec.edges:
        props.append((None, f"AG has_publisher({e.name})"))
    return props


def focus_of(spec: GraphSpec, formula: str) -> str | None:
    """The topic a formula's message propositions refer to (``handled(imager.ping)`` -> its source)."""
    import re

    names = set(re.findall(r"\b(?:queued|handled|dropped|lost|counted)\(([^()]*)\)", formula))
    topics = {e.source for e in spec.edges if e.name in names}
    if len(topics) > 1:
        raise ValueError(f"the formula follows messages of {sorted(topics)}: one tracked topic at a time (--focus)")
    if names and not topics:
        raise ValueError(f"no input named {sorted(names)}; inputs: {', '.join(e.name for e in spec.edges)}")
    return topics.pop() if topics else None


def verify_spec(spec: GraphSpec, checks: list[tuple[str | None, str]], *, faults: int = 1,
                max_states: int = 1_000_000) -> list:
    """Check each (focus topic, formula); a list of :class:`nodes.verify.ctl.Result`."""
    from nodes.verify.ctl import Checker

    out = []
    models: dict[str | None, tuple] = {}
    for focus, formula in checks:
        if focus not in models:
            models[focus] = graph_model(spec, focus, faults=faults, max_states=max_states)
        k, fair = models[focus]
        result = Checker(k, fair).check(formula)
        result.formula = f"[{focus}] {result.formula}" if focus else result.formula
        out.append(result)
    return out
