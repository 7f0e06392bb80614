"""Multi-robot scenarios cut from one pose graph, and how a decentralised estimate is scored.

A dataset's trajectory is split into R contiguous blocks, one per robot. Edges inside a
block are that robot's odometry and intra-robot loop closures; edges that cross blocks
are inter-robot loop closures, which a robot only learns through an exchange with the
peer. Outliers -- false inter-robot closures, as perceptual aliasing produces -- are
injected at a chosen rate of all inter-robot closures.

The yardstick is the centralised optimum: the same back end (:func:`optimize`) on the
whole inlier graph. A decentralised run is scored by the chi2 of the robots' own
estimates, put together, on that same inlier graph.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nodes.slam.pose_graph import PoseGraph2D, chi2, optimize


@dataclass
class Scenario:
    """A graph shared out among ``robots``: ``owner`` (N,) robot of each vertex index;
    ``outlier`` (M,) marks injected false closures (appended after the dataset's edges)."""

    graph: PoseGraph2D
    owner: np.ndarray
    robots: int
    outlier: np.ndarray

    @property
    def inter(self) -> np.ndarray:
        """(M,) bool: edges between vertices of two different robots."""
        e = self.graph.edges
        return self.owner[e[:, 0]] != self.owner[e[:, 1]]

    def vertices(self, robot: int) -> np.ndarray:
        """Vertex indices of ``robot``, in trajectory order."""
        return np.flatnonzero(self.owner == robot)

    def edges_of(self, robot: int) -> tuple[np.ndarray, np.ndarray]:
        """(intra, inter) edge indices touching ``robot``."""
        e = self.graph.edges
        mine = (self.owner[e[:, 0]] == robot) | (self.owner[e[:, 1]] == robot)
        return np.flatnonzero(mine & ~self.inter), np.flatnonzero(mine & self.inter)

    def inter_pairs(self) -> set[tuple[int, int]]:
        """The dataset's own inter-robot closures as (id_a, id_b), as measured."""
        e = self.graph.edges[self.inter & ~self.outlier]
        return {(int(self.graph.ids[a]), int(self.graph.ids[b])) for a, b in e}

    def inlier_graph(self, closures: set[tuple[int, int]] | None = None) -> PoseGraph2D:
        """The dataset's own graph (injected outliers removed); with ``closures``, only those
        inter-robot closures (id pairs as measured) are kept."""
        keep = ~self.outlier
        if closures is not None:
            pairs = [(int(self.graph.ids[a]), int(self.graph.ids[b])) for a, b in self.graph.edges]
            keep &= ~self.inter | np.array([p in closures for p in pairs], bool)
        g = self.graph
        return PoseGraph2D(ids=g.ids, poses=g.poses, edges=g.edges[keep], z=g.z[keep], info=g.info[keep],
                           known=g.known, fixed=set(g.fixed))


def split_graph(graph: PoseGraph2D, robots: int, *, outlier_rate: float = 0.0, seed: int = 0) -> Scenario:
    """Cut ``graph`` into ``robots`` contiguous blocks of vertex ids and inject outliers.

    ``outlier_rate`` in [0, 1] is the fraction of inter-robot closures that are false
    after injection: rate r adds round(r / (1 - r) * n_inlier) random closures; rate 1
    replaces every true inter-robot closure by as many false ones. A false closure joins
    two random vertices of different robots with a measurement drawn uniformly over the
    span of the true closures' translations and any heading, and a true closure's information.
    """
    if robots < 1:
        raise ValueError("robots must be >= 1")
    if robots > graph.n:
        raise ValueError(f"{robots} robots for {graph.n} vertices: each robot needs at least one")
    if not 0.0 <= outlier_rate <= 1.0:
        raise ValueError("outlier_rate is a fraction in [0, 1]")
    order = np.argsort(graph.ids, kind="stable")
    owner = np.empty(graph.n, np.int64)
    for r, block in enumerate(np.array_split(order, robots)):
        owner[block] = r
    e = graph.edges
    inter = owner[e[:, 0]] != owner[e[:, 1]]
    n_in = int(inter.sum())
    keep = np.ones(len(e), bool)
    if outlier_rate >= 1.0:
        n_out, keep = n_in, ~inter
    else:
        n_out = int(round(outlier_rate / (1.0 - outlier_rate) * n_in))
    rng = np.random.default_rng(seed)
    if n_out and robots > 1:
        a = rng.integers(0, graph.n, n_out)
        other = (owner[a] + rng.integers(1, robots, n_out)) % robots       # any robot but a's
        b = np.array([rng.choice(np.flatnonzero(owner == o)) for o in other], dtype=np.int64)
        span = np.abs(graph.z[inter, :2]).max(axis=0) if n_in else np.array([5.0, 5.0])
        z_out = np.column_stack([rng.uniform(-span[0], span[0], n_out), rng.uniform(-span[1], span[1], n_out),
                                 rng.uniform(-np.pi, np.pi, n_out)])
        pool = graph.info[inter] if n_in else graph.info
        info_out = pool[rng.integers(0, len(pool), n_out)]
    else:
        n_out = 0
        a = b = np.zeros(0, np.int64)
        z_out, info_out = np.zeros((0, 3)), np.zeros((0, 3, 3))
    out = PoseGraph2D(ids=graph.ids, poses=graph.poses, known=graph.known, fixed=set(graph.fixed),
                      edges=np.vstack([e[keep], np.column_stack([a, b])]).astype(np.int64),
                      z=np.vstack([graph.z[keep], z_out]), info=np.concatenate([graph.info[keep], info_out]))
    outlier = np.zeros(len(out.edges), bool)
    outlier[int(keep.sum()):] = True
    return Scenario(graph=out, owner=owner, robots=robots, outlier=outlier)


@dataclass
class Centralised:
    """The yardstick: the inlier graph's optimum."""

    graph: PoseGraph2D
    poses: np.ndarray
    chi2: float


def centralised(scenario: Scenario, *, closures: set[tuple[int, int]] | None = None) -> Centralised:
    """The same back end on the whole inlier graph (or with only ``closures`` between robots, see
    :meth:`Scenario.inlier_graph`), from odometry, the first vertex anchored. GraphError when the
    robots are left in pieces."""
    g = scenario.inlier_graph(closures)
    result = optimize(g, initial="odometry")
    return Centralised(graph=g, poses=result.poses, chi2=result.chi2)


def assemble(scenario: Scenario, estimates: dict[int, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(N, 3) poses from each robot's own (vertex indices, poses); NaN where a robot has said nothing."""
    poses = np.full((scenario.graph.n, 3), np.nan)
    for _, (index, p) in estimates.items():
        poses[index] = p
    return poses


def cost_ratio(reference: Centralised, poses: np.ndarray) -> float:
    """chi2 of ``poses`` on the inlier graph over the centralised optimum's (inf when a pose is missing)."""
    if not np.isfinite(poses).all():
        return float("inf")
    return chi2(reference.graph, poses) / max(reference.chi2, 1e-300)


# -- a team in one process (the benchmark's and the tests' network) -----------------------------------
@dataclass
class RoundRecord:
    """The team after one round: cumulative bytes and packets sent, and the cost ratio."""

    round: int
    bytes: int
    packets: int
    cost_ratio: float


@dataclass
class KeyframeRecord:
    """What robot ``robot`` senses at one keyframe: its odometry from the previous one, the
    intra-robot closures that end here, its place descriptor, what registering it against
    other robots' keyframes would give (:class:`~nodes.slam.place.Registration`), and the
    inter-robot closures touching it (used directly when there is no place recognition)."""

    vertex: int
    odometry: np.ndarray | None
    info: np.ndarray | None
    intra: list
    inter: list
    descriptor: np.ndarray | None = None
    registrations: list = field(default_factory=list)


def robot_stream(scenario: Scenario, robot: int, *, truth: np.ndarray | None = None, describer=None,
                 seed: int = 0) -> list[KeyframeRecord]:
    """Robot ``robot``'s keyframes in order (the scenario as its sensors would give it).

    The odometry is the edge between consecutive own vertices (an error if the dataset has
    none). Descriptors (when ``describer`` and ``truth`` (N, 3) poses are given) describe the
    true positions, with seeded noise.
    """
    from nodes.slam.place import Registration
    g = scenario.graph
    mine = scenario.vertices(robot)
    intra, inter = scenario.edges_of(robot)
    odometry: dict[int, int] = {}
    for k in intra:
        a, b = g.edges[k]
        if b == a + 1 and int(a) not in odometry:
            odometry[int(a)] = int(k)
    used = set(odometry.values())
    ends_at: dict[int, list] = {}
    for k in intra:
        if int(k) not in used:
            a, b = g.edges[k]
            ends_at.setdefault(int(max(a, b)), []).append((int(g.ids[a]), int(g.ids[b]), g.z[k], g.info[k]))
    touching: dict[int, list] = {}
    for k in inter:
        a, b = (int(v) for v in g.edges[k])
        own, other = (a, b) if scenario.owner[a] == robot else (b, a)
        touching.setdefault(own, []).append((int(g.ids[a]), int(g.ids[b]), g.z[k], g.info[k],
                                             int(scenario.owner[other]), int(g.ids[other])))
    rng = np.random.default_rng(seed * 1000 + robot)
    out = []
    for n, v in enumerate(mine):
        v = int(v)
        if n == 0:
            z = w = None
        else:
            k = odometry.get(int(mine[n - 1]))
            if k is None:
                raise ValueError(f"robot {robot}: no odometry edge from vertex {g.ids[mine[n - 1]]} to {g.ids[v]}")
            z, w = g.z[k], g.info[k]
        closures = touching.get(v, [])
        desc = describer.describe(truth[v, :2], rng) if describer is not None and truth is not None else None
        regs = [Registration(peer, other, (a, b, zz, ww)) for a, b, zz, ww, peer, other in closures]
        out.append(KeyframeRecord(int(g.ids[v]), z, w, ends_at.get(v, []),
                                  [(a, b, zz, ww, peer) for a, b, zz, ww, peer, _ in closures], desc, regs))
    return out


def feed(agent, record: KeyframeRecord, *, given_closures: bool = True) -> None:
    """Give ``agent`` one keyframe and what its sensors measured there; ``given_closures``: the
    inter-robot closures too (as the scenario's range-limited sensor), else only through
    place recognition."""
    agent.add_keyframe(record.vertex, record.odometry, record.info, descriptor=record.descriptor,
                       registrations=record.registrations)
    for a, b, z, w in record.intra:
        agent.add_closure(a, b, z, w)
    if given_closures:
        for a, b, z, w, peer in record.inter:
            agent.add_closure(a, b, z, w, peer=peer)


def feed_all(agent, scenario: Scenario, **kwargs) -> None:
    """Every keyframe of the agent's robot at once (see :func:`robot_stream`, :func:`feed`)."""
    given = kwargs.pop("given_closures", True)
    for record in robot_stream(scenario, agent.robot, **kwargs):
        feed(agent, record, given_closures=given)


def run_team(scenario: Scenario, agents: list, *, rounds: int, transmit, reference: Centralised,
             deliver=None, before_round=None, progress=None) -> list[RoundRecord]:
    """Sequential rounds (robot 0 first, each robot reading what arrived before its turn):
    Gauss-Seidel order. ``transmit(packet)`` gives (bytes on the wire, the packet as received);
    ``deliver(packet, round)`` False drops it (the link model); ``before_round(round, agents)``
    may feed keyframes or replace an agent (a restart). Returns one :class:`RoundRecord` per round."""
    index = {int(v): k for k, v in enumerate(scenario.graph.ids)}
    inbox: dict[int, list] = {a.robot: [] for a in agents}
    sent = packets = 0
    records = []
    for rnd in range(1, rounds + 1):
        if before_round is not None:
            before_round(rnd, agents)
        for agent in agents:
            for packet in inbox[agent.robot]:
                agent.receive(packet)
            inbox[agent.robot] = []
            for packet in agent.step():
                nbytes, received = transmit(packet)
                sent += nbytes
                packets += 1
                if deliver is None or deliver(packet, rnd):
                    inbox[packet.receiver].append(received)
        poses = assemble(scenario, {a.robot: (np.array([index[v] for v in a.ids], np.int64), a.estimate)
                                    for a in agents})
        records.append(RoundRecord(rnd, sent, packets, cost_ratio(reference, poses)))
        if progress is not None:
            progress(records[-1])
    return records
