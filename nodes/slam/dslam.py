"""Decentralised multi-robot pose-graph SLAM: one :class:`Agent` per robot, exchanging packets.

An agent holds its own odometry chain and intra-robot loop closures, candidate
inter-robot closures (from the scenario's sensor or from place recognition,
:mod:`nodes.slam.place`) and what its peers told it. Each :meth:`Agent.step` is one
round: read what arrived, decide which inter-robot closures to trust, take one step of
the back end, and say what to send to whom. Nothing here knows about sockets; the node
(:mod:`nodes.slam.dslam_agent`) and the benchmark move the packets.

Back ends (``method``), all built on :mod:`nodes.slam.pose_graph` (no second solver):

``ddf``
    DDF-SAM-style condensed graphs (Cunningham et al., IROS 2010 / ICRA 2013). Each robot
    optimises its own graph, condenses it onto its separators (the ends of its
    inter-robot closures, and its first pose) and sends that condensed graph to its peers;
    each robot then optimises its *neighbourhood graph* -- its own full graph, the peers'
    condensed graphs and the inter-robot closures. ``condense``:

    * ``exact`` (default): keyframes that only sit on the odometry chain are eliminated
      exactly (runs of odometry become one edge); separators and the ends of intra-robot
      closures stay, so the condensed graph is exact *and* sparse. Marginalising onto the
      separators alone would be exact too, but dense: 9S^2/2 numbers, far more than the
      graph itself on these datasets (hundreds of separators per robot).
    * ``chain``: separators only, chained in trajectory order, each link with the exact
      marginal information of its pair (one factorisation, 3S solves); correlations between
      non-adjacent pairs are dropped. Fewer bytes, and exact only when the robot closed
      no loop of its own (measured in ``bench/dslam.py``).
``dgs``
    Distributed two-stage Gauss-Seidel (Choudhary et al., IJRR 2017): chordal rotations
    first, then translations, each a linear least-squares problem solved block by block
    (one block per robot, its neighbours' separator estimates as fixed values, optional
    over-relaxation ``sor``), then nonlinear block refinement with the local LM solver.
    Separator estimates travel, only those that moved by ``send_tol`` (and each robot's
    condensed graph goes to the lower-numbered peers that run PCM on its closures).
``block_gs``
    The naive baseline: nonlinear block Gauss-Seidel from each robot's own odometry frame.

Inter-robot closures are vetted by PCM (:mod:`nodes.slam.pcm`) on the lower-numbered
robot of each pair, which sends its decision to the other, so both ends agree. The global
frame is that of the lowest-numbered robot a robot is connected to (learnt from the
peers' ``gauge_root``); a robot that has met nobody keeps its own frame and says so.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from nodes.slam.block_gs import BlockGaussSeidel
from nodes.slam.condense import (apply_delta, condense_exact, condensed_graph, condensed_poses, delta, edge_table,
                                 same_table)
from nodes.slam.exchange import (Candidate, Closures, Condensed, Packet, Separators, info_from6, info_to6,
                                 inverse_info)
from nodes.slam.pcm import Side, relative, right_perturbation, select_consistent
from nodes.slam.place import (PlaceFrontEnd, PlaceMatchItem, PlaceQueryItem, Registration, RelPoseReply,
                              RelPoseRequestItem)
from nodes.slam.pose_graph import PoseGraph2D, chordal_poses, compose, joint_covariance, optimize, spanning_tree_poses

log = logging.getLogger("nodes.slam.dslam")

METHODS = ("ddf", "dgs", "block_gs")
# PCM's gate on a pair's cycle error: the 99.9 % quantile of chi2(3). At 99 % the largest clique
# left out 11 true closures of one M3500 pair (1 % of true pairs fail by chance, and a clique
# must agree pairwise); random false closures are far beyond either gate.
CHI2_3DOF_999 = 16.266
CONDENSE = ("exact", "chain")
__all__ = ["Agent", "Closures", "Condensed", "Packet", "Separators", "METHODS", "CONDENSE",
           "condense_exact", "condensed_poses", "apply_delta", "delta", "info_to6", "info_from6", "inverse_info"]


# -- the agent --------------------------------------------------------------------------------------
class Agent(BlockGaussSeidel):
    """One robot of a decentralised pose-graph SLAM team (see the module docstring).

    Parameters (keyword): ``method`` and ``condense`` (above); ``max_run`` (exact
    condensation: keep every k-th keyframe too, 0 = only what must stay); ``pcm_gate``,
    ``pcm_min_clique``, ``trust_lone`` (PCM, :mod:`nodes.slam.pcm`); ``strong_pair`` (ddf: pairs
    with this many accepted closures anchor the first neighbourhood pass); ``sor``, ``tol``,
    ``stage_tol``, ``send_tol``, ``lm_iterations`` (dgs / block_gs); ``solve_every`` and
    ``solve_gap`` (rounds between solves while only odometry grows / while news keeps
    coming), ``resend_rounds``, ``heartbeat_rounds`` (pacing of the exchange); ``front_end``
    (place recognition; None: inter-robot closures come through :meth:`add_closure`);
    ``epoch`` (changes when the robot restarts).
    """

    def __init__(self, robot: int, robots: int, *, method: str = "ddf", condense: str = "exact", sor: float = 1.0,
                 pcm_gate: float = CHI2_3DOF_999, tol: float = 1e-4, stage_tol: float = 1e-2,
                 lm_iterations: int = 10, max_run: int = 0, front_end: PlaceFrontEnd | None = None,
                 epoch: int = 0, send_tol: float = 1e-4, pcm_min_clique: int = 2, trust_lone: bool = True, strong_pair: int = 3,
                 resend_rounds: int = 1, heartbeat_rounds: int = 5, solve_every: int = 1, solve_gap: int = 1) -> None:
        if method not in METHODS:
            raise ValueError(f"method {method!r}: choose one of {METHODS}")
        if not 0 <= robot < robots:
            raise ValueError(f"robot {robot} is not in 0..{robots - 1}")
        if condense not in CONDENSE:
            raise ValueError(f"condense {condense!r}: choose one of {CONDENSE}")
        if not 0.0 < sor < 2.0:
            raise ValueError("sor (over-relaxation) is in (0, 2)")
        self.robot, self.robots, self.method, self.condense = robot, robots, method, condense
        self.sor, self.pcm_gate, self.tol, self.lm_iterations = sor, pcm_gate, tol, lm_iterations
        self.stage_tol, self.max_run, self.send_tol = stage_tol, max_run, send_tol
        self.pcm_min_clique, self.trust_lone, self.strong_pair = pcm_min_clique, trust_lone, strong_pair
        self.solve_every = solve_every                    # rounds between solves while only odometry grows
        self.solve_gap = solve_gap                        # and at least this many between solves on new closures
        self._last_solve_round = -10**9
        self._last_structure: tuple = ()
        self.heartbeat_rounds = heartbeat_rounds          # an empty packet (acks only) after this many quiet rounds
        self._last_packet: dict[int, int] = {}
        self.resend_rounds = resend_rounds                # a grown condensed graph goes out at most this often
        self.epoch = epoch                                # changes when this robot restarts
        self.front_end = front_end                        # place recognition (None: closures come from add_closure)
        self.ids: list[int] = []
        self._index: dict[int, int] = {}
        self._odometry: list[np.ndarray] = []            # z from the previous keyframe (first: identity)
        self._odometry_info: list[np.ndarray] = []
        self._intra: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        self.local = np.zeros((0, 3))                      # own graph's optimum, own frame
        self.estimate = np.zeros((0, 3))                   # in the team's frame
        self._candidates: dict[int, dict[tuple[int, int], Candidate]] = {}   # peer -> key -> closure
        self._accepted: dict[int, set[tuple[int, int]]] = {}                 # peer -> accepted keys
        self._decided_for: dict[int, int] = {}             # peer -> candidate count PCM last decided on
        self._rejected: dict[int, int] = {}                # peer -> closures PCM turned down (our decisions)
        self._last_sent: dict[int, tuple] = {}
        self.gnc_rejected_pairs: list[tuple[int, int]] = []
        self._early: list[tuple] = []
        self._vetoed: set[tuple[int, int]] = set()        # closures we decided and the neighbourhood's GNC rejected
        self._third_party: dict[tuple[int, int], Candidate] = {}   # ddf: accepted closures between two peers
        self._team: dict[int, np.ndarray] = {}            # ddf: last neighbourhood estimate by vertex id
        self._fresh = True                                 # ddf: closures or peer graphs changed since the last solve
        self._neighbourhood_structure: tuple = ()
        self._peer_owner: dict[int, int] = {}             # peer vertex id -> robot
        self._chains: dict[int, Condensed] = {}            # latest condensed graph of each peer
        self._ghost: dict[int, dict[int, np.ndarray]] = {1: {}, 2: {}, 3: {}}
        self._peer_phase: dict[int, tuple[int, bool]] = {}
        self.gauge_root = robot
        self._peer_root: dict[int, int] = {}
        self.phase = 1 if method == "dgs" else 3
        self._solved_phase = 0 if method == "dgs" else 3   # block_gs starts from its odometry, a real estimate
        self._phase_team: tuple[int, ...] = ()
        self.converged = False
        self._version = 0                                  # bumps when the own graph changes
        self._local_version = -1
        self._peer_has: dict[int, int] = {}               # peer -> version of our condensed graph it acknowledged
        self._snapshots: dict[int, dict[int, dict]] = {}  # peer -> {version: edge table} it may hold
        self._sent_at: dict[int, tuple[int, int]] = {}    # peer -> (version, round) last sent
        self._content_version = 0
        self._content_table: dict | None = None           # versions start at 1 (0 and -1: nothing held)
        self._peer_epoch: dict[int, int] = {}
        self._heard_decided: dict[int, int] = {}          # peer -> closures in its last decision for us
        self._third_keys: dict[int, frozenset] = {}       # ddf: peer -> closures of other pairs last sent to it
        self._third_from: dict[int, set] = {}             # ddf: peer -> its closures with others, as we hold them
        self._third_heard: dict[int, int] = {}            # ddf: peer -> closures of other pairs it told us of
        self._neighbourhood_key: tuple = ()
        self._r = np.zeros((0, 2))
        self._chain_cache: tuple[int, Condensed] | None = None
        self.rounds = 0

    # -- what the robot's own sensors give --------------------------------------------------------
    def add_keyframe(self, vertex: int, odometry: np.ndarray | None = None, info: np.ndarray | None = None, *,
                     descriptor: np.ndarray | None = None, registrations: list[Registration] = ()) -> None:
        """A new keyframe; ``odometry`` (3,) is its pose in the previous keyframe's frame. With a
        front end, ``descriptor`` is its place descriptor and ``registrations`` what registering it
        against other robots' keyframes would measure (the simulated sensor)."""
        if vertex in self._index:
            return
        if self.front_end is not None and descriptor is not None:
            self.front_end.add(vertex, descriptor, list(registrations))
        if self.ids and odometry is None:
            raise ValueError("every keyframe after the first needs its odometry from the previous one")
        self._index[vertex] = len(self.ids)
        self.ids.append(vertex)
        if self._early:
            self._take_early()
        z = np.zeros(3) if odometry is None else np.asarray(odometry, float)
        self._odometry.append(z)
        self._odometry_info.append(np.eye(3) if info is None else np.asarray(info, float))
        prev = self.local[-1] if len(self.local) else np.zeros(3)
        pose = compose(prev, z) if len(self.local) else np.zeros(3)
        self.local = np.vstack([self.local, pose])
        prev_e = self.estimate[-1] if len(self.estimate) else np.zeros(3)
        self.estimate = np.vstack([self.estimate, compose(prev_e, z) if len(self.estimate) else np.zeros(3)])
        self._r = np.vstack([self._r, [math.cos(self.estimate[-1, 2]), math.sin(self.estimate[-1, 2])]])
        self._version += 1

    def add_closure(self, a: int, b: int, z: np.ndarray, info: np.ndarray, *, peer: int | None = None) -> None:
        """A loop closure: pose of vertex ``b`` in the frame of vertex ``a``. Intra-robot when both
        are own keyframes; otherwise one end is own and the other belongs to robot ``peer``."""
        z, info = np.asarray(z, float), np.asarray(info, float)
        if a in self._index and b in self._index:
            self._intra.append((a, b, z, info))
            self._version += 1
            return
        if peer is None or peer == self.robot or not 0 <= peer < self.robots:
            raise ValueError(f"closure {a} -> {b}: name the peer robot that owns the other end")
        own, other = (b, a) if b in self._index else (a, b)
        if own not in self._index:
            raise ValueError(f"closure {a} -> {b}: neither end is a keyframe of robot {self.robot}")
        key = (own, other)
        found = self._candidates.setdefault(peer, {})
        if key not in found:
            found[key] = Candidate(a, b, z, info, own, other)
            self._peer_owner[other] = peer
            self._version += 1

    # -- one round ----------------------------------------------------------------------------------
    def receive(self, packet: Packet) -> None:
        """Take in what a peer sent (any order; stale items are ignored)."""
        peer = packet.sender
        if peer == self.robot or not 0 <= peer < self.robots:
            raise ValueError(f"packet from robot {peer}: not a peer of robot {self.robot}")
        self._peer_root[peer] = packet.gauge_root
        decided, version, third = packet.ack
        if len(self._third_keys.get(peer, ())) != third:
            self._third_keys.pop(peer, None)              # our news of other pairs was lost: send it again
        if peer > self.robot and peer in self._decided_for and decided != self._decided_for[peer]:
            self._decided_for.pop(peer)                   # our decision was lost on the way: decide and send again
        self._peer_has[peer] = version                    # the condensed graph it holds from us (-1: none)
        if self._peer_epoch.setdefault(peer, packet.epoch) != packet.epoch:
            self._peer_epoch[peer] = packet.epoch       # it restarted: what we told it is gone, say it again
            for store in (self._peer_has, self._snapshots, self._sent_at, self._last_sent):
                store.pop(peer, None)
            self._decided_for.pop(peer, None)
            log.info("robot %d: robot %d restarted (epoch %d); resending", self.robot, peer, packet.epoch)
        for item in packet.items:
            if isinstance(item, Condensed):
                old = self._chains.get(item.robot)
                if item.base < 0 and (old is None or item.version > old.version):
                    self._chains[item.robot] = item
                elif item.base >= 0 and old is not None and old.version == item.base:
                    self._chains[item.robot] = apply_delta(old, item)   # else: the ack tells the sender what we hold
            elif isinstance(item, Closures):
                self._take_closures(peer, item)
            elif isinstance(item, (PlaceQueryItem, PlaceMatchItem, RelPoseRequestItem, RelPoseReply)):
                if self.front_end is not None:
                    self._early.extend(self.front_end.receive(peer, item))
                    self._take_early()
            elif isinstance(item, Separators):
                self._peer_phase[peer] = (item.phase, item.converged)
                store = self._ghost[item.phase]
                for vid, value in zip(item.ids.tolist(), np.asarray(item.values, float)):
                    store[vid] = value
                    self._peer_owner.setdefault(vid, peer)

    def _take_early(self) -> None:
        """Closures the exchange gave before our end's keyframe existed wait here for it."""
        waiting, self._early = self._early, []
        for a, b, z, w, owner in waiting:
            if a in self._index or b in self._index:
                self.add_closure(a, b, z, w, peer=owner)
            else:
                self._early.append((a, b, z, w, owner))
        del self._early[:-4096]                          # bounded: a peer cannot make us hoard

    def _take_closures(self, peer: int, item: Closures) -> None:
        decided = False
        if item.third_party:                              # the sender's whole set of closures between it and others
            for key in self._third_from.pop(peer, set()):
                self._third_party.pop(key, None)
            fresh = {}
            for (a, b), z, v in zip(item.ids.tolist(), item.z, item.info):
                if a not in self._index and b not in self._index:
                    fresh[(a, b)] = Candidate(a, b, np.asarray(z, float), info_from6(v))
            self._third_party.update(fresh)
            self._third_from[peer] = set(fresh)
            self._third_heard[peer] = len(item.ids)
            self._neighbourhood_key = ()
            return
        for (a, b), z, v, ok in zip(item.ids.tolist(), item.z, item.info, item.accepted.tolist()):
            if a not in self._index and b not in self._index:
                continue
            self.add_closure(a, b, z, info_from6(v), peer=peer)
            if item.decision:
                decided = True
                key = (b, a) if b in self._index else (a, b)
                acc = self._accepted.setdefault(peer, set())
                (acc.add if ok else acc.discard)(key)
        if decided:
            self._decided_for[peer] = len(self._candidates.get(peer, {}))
            self._heard_decided[peer] = len(item.ids)
            self._neighbourhood_key = ()

    def step(self) -> list[Packet]:
        """One round of the back end; returns the packets to send."""
        self.rounds += 1
        out: dict[int, list] = {}
        if self.front_end is not None:
            for p, items in self.front_end.tick().items():
                out.setdefault(p, []).extend(items)
        if not self.ids:
            return [Packet(self.robot, p, self.gauge_root, items, self.epoch, self._ack(p)) for p, items in sorted(out.items())]
        structure = self._structure()
        since = self.rounds - self._last_solve_round
        due = ((structure != self._last_structure and since >= self.solve_gap) or self._chain_cache is None
               or since >= self.solve_every)
        if due:                                   # new closures, decisions or peer graphs: at once; growth: at a pace
            self._update_local()
            self._last_solve_round, self._last_structure = self.rounds, structure
        condensed = self._condensed() if due else self._chain_cache[1]
        peers = sorted(set(self._candidates) | set(self._chains))
        if self.method == "ddf":
            send_to = [p for p in range(self.robots) if p != self.robot]     # the whole neighbourhood
        else:
            send_to = [p for p in peers if p < self.robot]                  # only PCM's deciders need it
        for p in send_to:
            item = self._condensed_for(p, condensed)
            if item is not None:
                out.setdefault(p, []).append(item)
        for p, items in self._decide(condensed).items():
            out.setdefault(p, []).extend(items)
        if self.method == "ddf":
            for p, item in self._third_party_news().items():
                out.setdefault(p, []).append(item)
        self.gauge_root = min([self.robot] + [self._peer_root[p] for p in self.neighbours() if p in self._peer_root])
        if self.method == "ddf":
            if due:
                self._neighbourhood()
        else:
            for p, item in self._block_step().items():
                out.setdefault(p, []).append(item)
        for p in range(self.robots):                      # heartbeat: the acks travel even when all is said
            if p != self.robot and p not in out and self.rounds - self._last_packet.get(p, 0) >= self.heartbeat_rounds:
                out[p] = []
        for p in out:
            self._last_packet[p] = self.rounds
        return [Packet(self.robot, p, self.gauge_root, items, self.epoch, self._ack(p)) for p, items in sorted(out.items())]

    @property
    def rejected(self) -> int:
        """Inter-robot closures PCM turned down, over the pairs this robot decides."""
        return sum(self._rejected.values())

    def _third_party_news(self) -> dict[int, Closures]:
        """ddf: each robot needs the closures we decided between us and *other* robots for its
        neighbourhood graph; the whole set is sent whenever it changed (grew, or lost a vetoed
        closure) or the robot says it holds another count."""
        out = {}
        for p in range(self.robots):
            if p == self.robot:
                continue
            rows = [c for q, keys in self._accepted.items() if q > self.robot and q != p
                    for k, c in self._candidates[q].items() if k in keys]
            keys = frozenset((c.a, c.b) for c in rows)
            if (rows or p in self._third_keys) and self._third_keys.get(p) != keys:
                out[p] = Closures(ids=np.array([(c.a, c.b) for c in rows], np.int64).reshape(-1, 2),
                                  z=np.array([c.z for c in rows]).reshape(-1, 3),
                                  info=info_to6(np.array([c.info for c in rows]).reshape(-1, 3, 3)),
                                  accepted=np.ones(len(rows), bool), decision=True, third_party=True)
                self._third_keys[p] = keys
        return out

    def _ack(self, peer: int) -> tuple[int, int, int]:
        """What we hold from ``peer``: the size of its last decision and its condensed graph's version
        (-1: nothing asked of it), so it can resend what the link lost."""
        chain = self._chains.get(peer)
        version = chain.version if chain is not None else -1
        return self._heard_decided.get(peer, 0), version, self._third_heard.get(peer, 0)

    def _condensed_for(self, peer: int, condensed: Condensed) -> Condensed | None:
        """What ``peer`` needs of our condensed graph: nothing (it holds this version, or it is on its
        way), a delta on the version it acknowledged, or the whole graph."""
        version = condensed.version
        has = self._peer_has.get(peer, -1)
        sent = self._sent_at.get(peer)
        if has == version:
            return None
        if sent is not None and ((sent[0] == version and self.rounds - sent[1] < 2 * self.heartbeat_rounds)
                                 or self.rounds - sent[1] < self.resend_rounds):
            return None                                   # in flight, or sent a moment ago
        table = self._content_table
        snapshots = self._snapshots.setdefault(peer, {})
        base = snapshots.get(has)
        item = condensed if base is None else delta(condensed, base, has, table)
        snapshots[version] = table
        for v in [v for v in snapshots if v not in (version, has)]:
            del snapshots[v]                              # the peer acknowledges monotonically: older ones are useless
        self._sent_at[peer] = (version, self.rounds)
        return item

    def neighbours(self) -> list[int]:
        """Peers with at least one accepted inter-robot closure."""
        return sorted(p for p, keys in self._accepted.items() if keys)

    @property
    def own_frame(self) -> bool:
        """True while this robot is tied to no lower-numbered robot (its estimate is in its own frame)."""
        return self.gauge_root == self.robot

    # -- own graph ------------------------------------------------------------------------------
    def _own_graph(self, extra: dict[int, np.ndarray] | None = None,
                   inter: list[Candidate] = ()) -> tuple[PoseGraph2D, dict[int, int]]:
        """Own keyframes (+ ``extra`` vertices by id with poses), odometry, intra closures and ``inter``."""
        extra = extra or {}
        ids = self.ids + [v for v in extra if v not in self._index]
        index = {v: k for k, v in enumerate(ids)}
        n_own = len(self.ids)
        rows_i = list(range(n_own - 1)) + [index[a] for a, _, _, _ in self._intra] + [index[c.a] for c in inter]
        rows_j = list(range(1, n_own)) + [index[b] for _, b, _, _ in self._intra] + [index[c.b] for c in inter]
        z = self._odometry[1:] + [z for _, _, z, _ in self._intra] + [c.z for c in inter]
        info = self._odometry_info[1:] + [w for _, _, _, w in self._intra] + [c.info for c in inter]
        poses = np.zeros((len(ids), 3))
        poses[:n_own] = self.estimate
        for v, p in extra.items():
            if v in index and v not in self._index:
                poses[index[v]] = p[:3] if len(p) >= 3 else 0.0
        graph = PoseGraph2D(ids=np.array(ids, np.int64), poses=poses,
                            edges=np.column_stack([rows_i, rows_j]).astype(np.int64).reshape(-1, 2),
                            z=np.array(z, float).reshape(-1, 3), info=np.array(info, float).reshape(-1, 3, 3),
                            known=np.ones(len(ids), bool))
        return graph, index

    def _update_local(self) -> None:
        if self._local_version == self._version:
            return
        graph, _ = self._own_graph()
        if len(graph.edges) and graph.n > 1:
            self.local = optimize(graph, initial=_extend(self.local, self._odometry), anchor=self.ids[0],
                                  max_iterations=50).poses
        self._local_version = self._version

    def _separator_ids(self) -> list[int]:
        ends = {c.own for found in self._candidates.values() for c in found.values()}
        return [v for v in self.ids if v in ends or v == self.ids[0]]

    def _condensed(self) -> Condensed:
        """This robot's condensed graph (cached per version); see ``condense`` in the module docstring."""
        if self._chain_cache is not None and self._chain_cache[0] == self._version:
            return self._chain_cache[1]
        sep = self._separator_ids()
        if self.condense == "exact":
            ids, edges, z, info = condense_exact(self.ids, self._odometry, self._odometry_info, self._intra, sep,
                                                 max_run=self.max_run)
        else:
            ids, edges, z, info = self._condense_chain(sep)
        rows = np.array([self._index[v] for v in ids], np.int64)
        out = Condensed(robot=self.robot, version=self._content_version, ids=np.array(ids, np.int64),
                        poses=self.local[rows].copy(), edges=edges, z=z, info=info_to6(info))
        table = edge_table(out)
        if self._content_table is None or not same_table(table, self._content_table):
            self._content_version += 1                    # peers hear of a new version only when content changed
            self._content_table = table
            out.version = self._content_version
        self._chain_cache = (self._version, out)
        return out

    def _condense_chain(self, sep: list[int]) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
        """Separators chained in trajectory order, each link with the exact marginal information of its pair."""
        graph, index = self._own_graph()
        rows = np.array([index[v] for v in sep])
        s = len(sep)
        if not len(graph.edges) or s < 2:
            return sep, np.zeros((0, 2), np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3))
        cov = joint_covariance(graph, self.local, rows, fixed={0})
        rel, sigma = relative(Side(self.local[rows], cov, np.arange(s)), np.arange(s - 1), np.arange(1, s))
        sigma = right_perturbation(rel, sigma)             # the solver's residual lives in the edge's own frame
        info = np.linalg.inv(sigma + 1e-12 * np.eye(3))
        return sep, np.column_stack([np.arange(s - 1), np.arange(1, s)]), rel, info

    # -- PCM ------------------------------------------------------------------------------------
    def _structure(self) -> tuple:
        """What, when it changes, must be acted on at once (rather than at the ``solve_every`` pace)."""
        return (sum(len(f) for f in self._candidates.values()), tuple(sorted((p, len(k)) for p, k in self._accepted.items())),
                frozenset(self._third_party), tuple(sorted((r, c.version) for r, c in self._chains.items())))

    def _decide(self, own_condensed: Condensed) -> dict[int, list[Closures]]:
        """PCM on each higher-numbered peer whose candidates changed and whose condensed graph we hold.
        Returns the items to send: each decision to its peer; with ddf, the accepted ones to everyone."""
        out: dict[int, Closures] = {}
        extra: dict[int, list[Closures]] = {}
        for peer, found in self._candidates.items():
            if peer < self.robot or self._decided_for.get(peer) == len(found) or peer not in self._chains:
                continue
            chain = self._chains[peer]
            keys = [k for k, c in found.items() if c.peer_id in set(chain.ids.tolist())]
            if len(keys) < len(found):
                continue                                   # the peer's summary predates some closures: wait
            cands = [found[k] for k in keys]
            own_sep = own_condensed
            own_pos = {v: k for k, v in enumerate(own_sep.ids.tolist())}
            if any(c.own not in own_pos for c in cands):
                continue                                   # our own summary predates some closures: next solve
            own = _side(own_sep, [own_pos[c.own] for c in cands])
            peer_pos = {v: k for k, v in enumerate(chain.ids.tolist())}
            other = _side(chain, [peer_pos[c.peer_id] for c in cands])
            measured = [c.from_own() for c in cands]
            keep = select_consistent(np.array([m[0] for m in measured]), np.array([m[1] for m in measured]), own, other,
                                     gate=self.pcm_gate, min_clique=self.pcm_min_clique, trust_lone=self.trust_lone)
            keep &= np.array([(c.a, c.b) not in self._vetoed for c in cands], bool)   # the team's GNC said no
            self._accepted[peer] = {k for k, ok in zip(keys, keep) if ok}
            self._rejected[peer] = int((~keep).sum())
            self._decided_for[peer] = len(found)           # == len(keys): all of them are in the summary
            self._neighbourhood_key = ()
            out[peer] = Closures(ids=np.array([(c.a, c.b) for c in cands], np.int64).reshape(-1, 2),
                                 z=np.array([c.z for c in cands]),
                                 info=info_to6(np.array([c.info for c in cands])), accepted=keep, decision=True)
        for p, item in out.items():
            extra.setdefault(p, []).insert(0, item)
        return extra

    def closure_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(accepted, rejected) inter-robot closures touching this robot, (C, 2) vertex ids as measured.
        Rejected: turned down by PCM (pairs already decided) or by the neighbourhood's GNC."""
        gnc = set(self.gnc_rejected_pairs)
        acc, rej = [], []
        for p, found in self._candidates.items():
            if p not in self._decided_for and p not in self._accepted:
                continue
            keys = self._accepted.get(p, set())
            for k, c in found.items():
                (acc if k in keys and (c.a, c.b) not in gnc else rej).append((c.a, c.b))
        as_array = lambda rows: np.array(rows, np.int64).reshape(-1, 2)   # noqa: E731
        return as_array(acc), as_array(rej)

    def accepted_closures(self) -> list[Candidate]:
        return [self._candidates[p][k] for p, keys in self._accepted.items() for k in keys]

    # -- method (a): neighbourhood optimisation over condensed graphs --------------------------------
    def _neighbourhood(self) -> None:
        """Optimise own graph + peers' condensed graphs + inter-robot closures, in two passes.

        PCM compares the closures of one pair only, so false closures can survive it: a pair of
        robots that never met can hold two that agree by chance, and a false closure far from
        the robots' first poses fits within their loose relative covariance. So the first pass
        uses the closures of pairs with at least ``strong_pair`` accepted closures, under a
        Cauchy kernel (a false one among them pulls little); the second starts there with every
        closure under GNC (only inter-robot closures can be rejected): each must agree with
        what the whole team's closures say.
        """
        key = (self._version, tuple((r, c.version) for r, c in sorted(self._chains.items())))
        if key == self._neighbourhood_key:
            return
        self._neighbourhood_key = key
        extra: dict[int, np.ndarray] = {}
        owner: dict[int, int] = {v: self.robot for v in self.ids}
        edges: list[Candidate] = []
        for r, chain in self._chains.items():
            for v, p in zip(chain.ids.tolist(), chain.poses):
                extra[v], owner[v] = p, r
            ids = chain.ids.tolist()
            for (a, b), z, v in zip(np.asarray(chain.edges).tolist(), chain.z, chain.info):
                edges.append(Candidate(ids[a], ids[b], np.asarray(z, float), info_from6(v)))
        closures = [c for c in self.accepted_closures() + list(self._third_party.values())
                    if c.a in owner and c.b in owner]
        pairs = [tuple(sorted((owner[c.a], owner[c.b]))) for c in closures]
        size = {p: pairs.count(p) for p in set(pairs)}
        strong = [c for c, p in zip(closures, pairs) if size[p] >= self.strong_pair]
        weak = [c for c, p in zip(closures, pairs) if size[p] < self.strong_pair]
        structure = self._structure()
        self._fresh = structure != self._neighbourhood_structure     # new closures or peer graphs: start afresh
        self._neighbourhood_structure = structure
        if not self._fresh:
            # The same closures, more odometry: one warm solve, GNC's last verdict kept (it runs again on news).
            out = set(self.gnc_rejected_pairs)
            self._solve_neighbourhood(extra, edges, [c for c in closures if (c.a, c.b) not in out], [], robust=None)
            self.gnc_rejected_pairs = sorted(out)
            return
        self._solve_neighbourhood(extra, edges, strong, [], robust="cauchy" if closures else None)
        if closures and self._solve_neighbourhood(extra, edges, [], strong + weak, robust="gnc"):
            # The passes above started among false closures and can end in their basin even once GNC has
            # weighed them out (M3500 with 30 % false: all rejected, cost 47x). Solve again without them.
            out = set(self.gnc_rejected_pairs)
            kept = [c for c in strong + weak if (c.a, c.b) not in out]
            self._solve_neighbourhood(extra, edges, kept, [], robust=None)
            self.gnc_rejected_pairs = sorted(out)
            for peer, found in self._candidates.items():  # closures we decided: withdraw them for everyone
                if peer > self.robot and any((c.a, c.b) in out for c in found.values()):
                    self._vetoed |= {(c.a, c.b) for c in found.values() if (c.a, c.b) in out}
                    self._decided_for.pop(peer, None)     # decide again (without them) and tell

    def _solve_neighbourhood(self, extra: dict[int, np.ndarray], edges: list[Candidate], closures: list[Candidate],
                             doubtful: list[Candidate], *, robust: str | None) -> int:
        """One neighbourhood solve (GNC on the inter-robot closures when some are ``doubtful``);
        returns how many closures GNC rejected."""
        graph, index = self._own_graph(extra, edges + closures + doubtful)
        first_inter = len(graph.edges) - len(closures) - len(doubtful)
        keep = _component(graph, 0)
        roots = {r: chain.ids[0] for r, chain in self._chains.items()
                 if chain.ids[0] in index and keep[index[chain.ids[0]]]}
        roots[self.robot] = self.ids[0]
        self.gauge_root = min(roots)
        inter = (np.arange(len(graph.edges)) >= first_inter)[keep[graph.edges[:, 0]] & keep[graph.edges[:, 1]]]
        graph = _subgraph(graph, keep)
        if graph.n < 2:
            return 0                                      # a lone first keyframe: nothing to solve
        index = {v: k for k, v in enumerate(graph.ids.tolist())}
        anchor = index[roots[self.gauge_root]]
        graph.poses = graph.poses.copy()
        graph.poses[anchor] = 0.0                          # the gauge robot's first pose is the team's origin
        if self._fresh and not doubtful and graph.n > len(self.ids):
            # What we knew was solved with less: a warm start from it can sit in a wrong basin (an
            # eighth robot joined through few closures landed 17 m off on intel). Chordal
            # initialisation of the whole neighbourhood does not depend on it.
            graph.known = np.zeros(graph.n, bool)
            graph.known[anchor] = True
            start = chordal_poses(graph, root=anchor)
        else:
            for v, pose in self._team.items():            # warm start where we already have an estimate
                if v in index:
                    graph.poses[index[v]] = pose
            graph.poses[anchor] = 0.0
            known = [anchor] + [index[v] for v in self._team if v in index and index[v] != anchor]
            start = spanning_tree_poses(graph, root=anchor, known=known)
        graph.fixed = {anchor}
        result = optimize(graph, initial=start, max_iterations=50, robust=robust, trusted=~inter)
        self._team = {v: result.poses[k] for v, k in index.items()}
        self.estimate = result.poses[:len(self.ids)]
        out = graph.edges[result.outliers]
        self.gnc_rejected_pairs = [(int(graph.ids[a]), int(graph.ids[b])) for a, b in out]
        return len(result.outliers)


# -- helpers ---------------------------------------------------------------------------------------
def _extend(poses: np.ndarray, odometry: list[np.ndarray]) -> np.ndarray:
    """``poses`` lengthened by composing odometry up to ``len(odometry)`` keyframes."""
    out = list(poses)
    while len(out) < len(odometry):
        out.append(compose(out[-1], odometry[len(out)]) if out else np.zeros(3))
    return np.array(out).reshape(-1, 3)


def _side(item: Condensed, rows: list[int]) -> Side:
    """PCM's view of a robot from its condensed graph: joint covariance of the closure ends, first pose held."""
    rows = np.asarray(rows, np.int64)
    used = np.unique(rows)
    if len(item.ids) > 1 and len(item.edges):
        cov = joint_covariance(condensed_graph(item), np.asarray(item.poses, float), used, fixed={0})
    else:
        cov = np.zeros((3 * len(used), 3 * len(used)))
    return Side(np.asarray(item.poses, float)[used], cov, np.searchsorted(used, rows))


def _component(graph: PoseGraph2D, root: int) -> np.ndarray:
    """(N,) bool: vertices connected to ``root``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    n = graph.n
    adj = coo_matrix((np.ones(len(graph.edges)), (graph.edges[:, 0], graph.edges[:, 1])), shape=(n, n))
    _, labels = connected_components(adj, directed=False)
    return labels == labels[root]


def _subgraph(graph: PoseGraph2D, keep: np.ndarray) -> PoseGraph2D:
    new = np.cumsum(keep) - 1
    ok = keep[graph.edges[:, 0]] & keep[graph.edges[:, 1]]
    return PoseGraph2D(ids=graph.ids[keep], poses=graph.poses[keep], edges=new[graph.edges[ok]], z=graph.z[ok],
                       info=graph.info[ok], known=graph.known[keep])
