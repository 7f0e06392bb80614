"""Look-compute-move models of two robots on a discrete ring, for checking gathering (seed 06).

Two anonymous, oblivious robots without a common sense of direction (no chirality) live on
the nodes of a ring of ``n`` nodes. A robot looks, sees the other at ring distance
``delta = min(d, n - d)`` (or nothing, ``None``, beyond its visibility radius), computes
from that view alone, and moves at most one edge: ``stay``, ``toward`` or ``away`` along
the shorter arc (either way, chosen by the adversary, when both arcs are equal), or, when
it sees nothing, ``stay`` or ``move`` in a direction it cannot choose. An *algorithm* is
the table view -> action; gathered robots stay.

Schedulers (the adversary picks, fairness makes it activate every robot infinitely often):

* ``fsync``: every round both robots look, compute and move together;
* ``ssync``: every round a non-empty subset does, atomically;
* ``async``: looks and moves are separate events of either robot, so a robot can move on
  a view that is stale by then.

States are (p1, p2, who acted last, pending moves) with absolute positions. The labels are
``gathered`` (p1 == p2), ``acted_r1`` / ``acted_r2`` (for the fairness constraints) and
``delta_<k>``; each robot observes its own view and pending move (agents ``r1``, ``r2``).

The discrete ring keeps one fact of the plane: synchronous symmetric moves change the
distance by 0 or 2. With n odd the two arcs have different parities and an FSYNC algorithm
can always work on the even one; in the plane, Suzuki and Yamashita's (1999) impossibility
for two oblivious robots under SSYNC has the same root -- an adversary that activates both
robots when a single move would gather them and one when a joint move would.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Iterator

from nodes.verify.kripke import Kripke, explore

SCHEDULERS = ("fsync", "ssync", "async")
VISIBLE_ACTIONS = ("stay", "toward", "away")
BLIND_ACTIONS = ("stay", "move")


@dataclass(frozen=True)
class Algorithm:
    """The table: ``visible[delta - 1]`` for delta = 1 .. n // 2, and ``blind`` when the other is out of sight."""

    visible: tuple[str, ...]
    blind: str = "stay"

    def action(self, delta: int | None) -> str:
        if delta is None:
            return self.blind
        return "stay" if delta == 0 else self.visible[delta - 1]

    def __str__(self) -> str:
        cells = [f"{d + 1}:{a}" for d, a in enumerate(self.visible)]
        return "{" + ", ".join(cells) + (f", blind:{self.blind}" if self.blind != "stay" else "") + "}"


def all_algorithms(n: int, visibility: int | None = None) -> Iterator[Algorithm]:
    """Every algorithm for a ring of ``n`` (3^(views) x 2 when some distances are out of sight)."""
    half = n // 2
    seen = half if visibility is None else min(visibility, half)
    blind = BLIND_ACTIONS if seen < half else ("stay",)
    for table in itertools.product(VISIBLE_ACTIONS, repeat=seen):
        for b in blind:
            yield Algorithm(tuple(table) + ("stay",) * (half - seen), b)


def view(me: int, other: int, n: int, visibility: int | None) -> int | None:
    d = (other - me) % n
    delta = min(d, n - d)
    return None if visibility is not None and delta > visibility else delta


def moves(me: int, other: int, n: int, algo: Algorithm, visibility: int | None) -> tuple[int, ...]:
    """The steps (-1, 0, +1 around the ring) the adversary may make the robot take."""
    delta = view(me, other, n, visibility)
    act = algo.action(delta)
    if act == "stay":
        return (0,)
    if delta is None:
        return (-1, 1)
    d = (other - me) % n
    toward = (1,) if d < n - d else (-1,) if d > n - d else (-1, 1)
    return toward if act == "toward" else tuple(-s for s in toward)


def gathering_model(n: int, scheduler: str, algo: Algorithm, *, visibility: int | None = None,
                    max_states: int = 2_000_000) -> Kripke:
    """The Kripke structure of ``algo`` on a ring of ``n`` under ``scheduler`` from every configuration."""
    if n < 2:
        raise ValueError(f"a ring needs n >= 2 nodes, got {n}")
    if scheduler not in SCHEDULERS:
        raise ValueError(f"scheduler {scheduler!r} must be one of {SCHEDULERS}")
    if len(algo.visible) != n // 2:
        raise ValueError(f"algorithm has {len(algo.visible)} views; a ring of {n} needs {n // 2}")

    def step(state: tuple) -> Iterator[tuple]:
        p1, p2, _, pend1, pend2 = state
        pos = (p1, p2)
        if scheduler == "async":
            pend = (pend1, pend2)
            for i in (0, 1):
                if pend[i] is None:               # look and compute on the current view
                    for m in moves(pos[i], pos[1 - i], n, algo, visibility):
                        new = list(pend)
                        new[i] = m
                        yield (p1, p2, i + 1, new[0], new[1])
                else:                             # move on the view taken earlier
                    q = list(pos)
                    q[i] = (q[i] + pend[i]) % n
                    new = list(pend)
                    new[i] = None
                    yield (q[0], q[1], i + 1, new[0], new[1])
            return
        subsets = ((0, 1),) if scheduler == "fsync" else ((0,), (1,), (0, 1))
        for who in subsets:
            options = [moves(pos[i], pos[1 - i], n, algo, visibility) if i in who else (0,) for i in (0, 1)]
            for m1, m2 in itertools.product(*options):
                yield ((p1 + m1) % n, (p2 + m2) % n, 3 if len(who) == 2 else who[0] + 1, None, None)

    initial = [(0, p2, 3, None, None) for p2 in range(n)]      # rotations of these are the same configurations
    props = {"gathered": lambda s: s[0] == s[1],
             "acted_r1": lambda s: s[2] in (1, 3), "acted_r2": lambda s: s[2] in (2, 3),
             "idle": lambda s: s[3] is None and s[4] is None}
    for k in range(n // 2 + 1):
        props[f"delta_{k}"] = (lambda k: lambda s: view(s[0], s[1], n, None) == k)(k)
    observe = {"r1": lambda s: (view(s[0], s[1], n, visibility), s[3]),
               "r2": lambda s: (view(s[1], s[0], n, visibility), s[4])}
    return explore(initial, step, props, max_states=max_states, observe=observe)


FAIRNESS = ("acted_r1", "acted_r2")
