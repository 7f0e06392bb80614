"""dslam_agent: one robot of a decentralised SLAM team, one process per robot (seed 10).

Outputs ``to_<p>`` (PeerPacket, one per peer p: what this robot says to p alone) and
``trajectory`` (RobotTrajectory, its keyframes in the team frame); inputs ``from_<p>`` (the
peers' ``to_<robot>``) and a ``round`` timer. Wire ``robotP/to_R`` into ``robotR``'s
``from_P``; a link model between robots belongs in the launch file (``links:``), not here.

The robot's own sensing is simulated in-process from a pose-graph dataset
(``graph``): the dataset's trajectory is cut into ``robots`` contiguous blocks
(:func:`~nodes.slam.multirobot.split_graph`, with ``outlier_rate`` false inter-robot
closures) and this robot's keyframes arrive at ``keyframe_hz`` from the moment the team
started (``state_dir`` keeps that moment, so a restarted robot replays its own sensing up to
now and rejoins). Inter-robot closures come only through the exchange: place
recognition (:mod:`nodes.slam.place`) and relative-pose requests. Every ``round_hz`` the
agent takes one step (:class:`~nodes.slam.dslam.Agent`) and sends what it has to say.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import msgspec
import numpy as np

from msgs.slam import (ClosureSet, CondensedGraph, PeerPacket, PlaceMatch, PlaceQuery, RelPoseRequest,
                       RobotTrajectory, SeparatorValues)
from nodes.slam import dslam, place
from nodes.slam.dslam import Agent, Closures, Condensed, Packet, Separators
from nodes.slam.graph_io import read_graph
from nodes.slam.multirobot import centralised, feed, robot_stream, split_graph
from tether import Input, Node
from tether.codec import Codec

MAX_ROBOTS = 8


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    robot: int = 0
    robots: int = 2
    graph: str = "../shared/data/posegraphs/FR079_P_toro.graph"
    outlier_rate: float = 0.0
    seed: int = 0
    method: str = "ddf"                 # ddf | dgs | block_gs
    condense: str = "exact"             # ddf: exact | chain
    max_run: int = 0                    # ddf exact: keep every max_run-th keyframe too (0: only what must stay)
    keyframe_hz: float = 10.0
    round_hz: float = 5.0
    resend_s: float = 1.0               # ddf: a grown condensed graph is resent at most this often
    solve_s: float = 1.0                # re-optimise at least this often while only odometry grows
    solve_gap_s: float = 0.4            # and at most this often when closures or peer graphs keep arriving
    place_threshold: float = 0.5
    state_dir: str = ""                 # where the team's start time is kept across restarts ('' = none)

    def __post_init__(self) -> None:
        if not 1 <= self.robots <= MAX_ROBOTS or not 0 <= self.robot < self.robots:
            raise ValueError(f"robots is 1..{MAX_ROBOTS} and robot is 0..robots-1")
        if self.method not in dslam.METHODS or self.condense not in dslam.CONDENSE:
            raise ValueError(f"method is one of {dslam.METHODS}, condense one of {dslam.CONDENSE}")
        if not 0.0 <= self.outlier_rate < 1.0 or self.keyframe_hz <= 0 or self.round_hz <= 0:
            raise ValueError("outlier_rate in [0, 1), keyframe_hz > 0 and round_hz > 0")


class DslamAgent(Node):
    """One robot: simulated sensing from a dataset, the :class:`Agent`, and its packets."""

    Config = Config
    timers = {"round": "round_hz"}

    @classmethod
    def ports_for(cls, config: Config):
        peers = [p for p in range(config.robots) if p != config.robot]
        inputs = {f"from_{p}": Input(PeerPacket, depth=256) for p in peers}
        outputs = {f"to_{p}": PeerPacket for p in peers} | {"trajectory": RobotTrajectory}
        return inputs, outputs, cls.timers

    def setup(self) -> None:
        cfg = self.config
        graph = read_graph(cfg.graph)
        scenario = split_graph(graph, cfg.robots, outlier_rate=cfg.outlier_rate, seed=cfg.seed)
        truth = centralised(scenario).poses        # where the robots really were (the descriptors' places)
        describer = place.Describer()
        front = place.PlaceFrontEnd(cfg.robot, describer.train_centres(cfg.robots), threshold=cfg.place_threshold)
        self.agent = Agent(cfg.robot, cfg.robots, method=cfg.method, condense=cfg.condense, max_run=cfg.max_run,
                           epoch=time.time_ns() // 1_000_000,   # any change tells the peers we restarted
                           resend_rounds=max(1, round(cfg.resend_s * cfg.round_hz)),
                           solve_every=max(1, round(cfg.solve_s * cfg.round_hz)),
                           solve_gap=max(1, round(cfg.solve_gap_s * cfg.round_hz)),
                           front_end=front)
        self.stream = robot_stream(scenario, cfg.robot, truth=truth, describer=describer, seed=cfg.seed)
        self.fed = 0
        self.started = self._team_start()

    def _team_start(self) -> float:
        """When the team started: kept in ``state_dir`` with the launcher's pid, so a robot the
        launcher restarts knows how far its sensing got (a new launch starts afresh)."""
        if not self.config.state_dir:
            return time.monotonic()
        path = Path(self.config.state_dir) / f"robot{self.config.robot}.start"
        now, launcher = time.time(), os.getppid()
        try:
            pid, started = path.read_text().split()
            if int(pid) == launcher:
                self.log.info("robot %d restarted: replaying its own %.1f s of sensing", self.config.robot,
                              now - float(started))
                return time.monotonic() - (now - float(started))
        except (OSError, ValueError):
            pass
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{launcher} {now!r}")
        return time.monotonic()

    def _on_packet(self, msg: PeerPacket) -> None:
        if msg.receiver != self.config.robot or not 0 <= msg.sender < self.config.robots:
            self.log.warning("dropped a packet from robot %d addressed to %d", msg.sender, msg.receiver)
            return
        self.agent.receive(from_message(msg))

    def on_round(self, tick) -> list[tuple[str, object]]:
        due = min(len(self.stream), int((time.monotonic() - self.started) * self.config.keyframe_hz) + 1)
        while self.fed < due:
            feed(self.agent, self.stream[self.fed], given_closures=False)
            self.fed += 1
        out: list[tuple[str, object]] = []
        for packet in self.agent.step():              # the runtime counts the bytes of every output (_stats)
            out.append((f"to_{packet.receiver}", to_message(packet)))
        a = self.agent
        accepted, rejected = a.closure_pairs()
        out.append(("trajectory", RobotTrajectory(
            robot=a.robot, gauge_root=a.gauge_root, ids=np.array(a.ids, np.int64), poses=a.estimate.copy(),
            closures_accepted=len(accepted), closures_rejected=len(rejected), rounds=a.rounds,
            accepted=accepted, rejected=rejected)))
        return out

    def teardown(self) -> None:
        a = self.agent
        accepted, rejected = a.closure_pairs()
        self.log.info("robot %d: %d keyframes, %d rounds, %d inter-robot closures accepted, %d rejected%s",
                      a.robot, len(a.ids), a.rounds, len(accepted), len(rejected),
                      " -- tied to no lower-numbered robot: its own frame" if a.own_frame and a.robot else "")


def peer_handlers(cls: type[Node], prefix: str, handler: str, count: int) -> None:
    """``on_<prefix><k>`` for k < count, all calling ``handler`` (the runtime looks handlers up on the class)."""
    for k in range(count):
        setattr(cls, f"on_{prefix}{k}", getattr(cls, handler))


peer_handlers(DslamAgent, "from_", "_on_packet", MAX_ROBOTS)


# -- agent items <-> messages (float32 and int32 on the wire) -------------------------------------------
_F, _I = np.float32, np.int32


def _closures_msg(c: Closures) -> ClosureSet:
    return ClosureSet(ids=c.ids.astype(_I), z=c.z.astype(_F), info=c.info.astype(_F),
                      accepted=c.accepted.astype(bool), decision=c.decision, third_party=c.third_party)


def _closures_item(m: ClosureSet) -> Closures:
    return Closures(ids=np.asarray(m.ids, np.int64).reshape(-1, 2), z=np.asarray(m.z, float).reshape(-1, 3),
                    info=np.asarray(m.info, float).reshape(-1, 6), accepted=np.asarray(m.accepted, bool).reshape(-1),
                    decision=m.decision, third_party=m.third_party)


def to_message(packet: Packet) -> PeerPacket:
    items = []
    for it in packet.items:
        if isinstance(it, Condensed):
            items.append(CondensedGraph(robot=it.robot, version=it.version, ids=it.ids.astype(_I),
                                        edges=it.edges.astype(_I), z=it.z.astype(_F), info=it.info.astype(_F),
                                        base=it.base, removed=it.removed.astype(_I), nth=it.nth.astype(_I)))
        elif isinstance(it, Closures):
            items.append(_closures_msg(it))
        elif isinstance(it, Separators):
            items.append(SeparatorValues(phase=it.phase, ids=it.ids.astype(_I), values=it.values.astype(_F),
                                         converged=it.converged))
        elif isinstance(it, place.PlaceQueryItem):
            items.append(PlaceQuery(robot=it.robot, vertex=it.vertex, descriptor=it.descriptor.astype(np.float16)))
        elif isinstance(it, place.PlaceMatchItem):
            items.append(PlaceMatch(robot=it.robot, vertex=it.vertex, match_robot=it.match_robot,
                                    match_vertex=it.match_vertex, distance=it.distance))
        elif isinstance(it, place.RelPoseRequestItem):
            items.append(RelPoseRequest(vertex=it.vertex, match_vertex=it.match_vertex))
        elif isinstance(it, place.RelPoseReply):
            ids = np.array([(a, b) for a, b, _, _ in it.closures], np.int64).reshape(-1, 2)
            z = np.array([c[2] for c in it.closures], float).reshape(-1, 3)
            info = dslam.info_to6(np.array([c[3] for c in it.closures], float).reshape(-1, 3, 3))
            items.append(ClosureSet(ids=ids.astype(_I), z=z.astype(_F), info=info.astype(_F),
                                    accepted=np.ones(len(ids), bool), request=list(it.request)))
        else:
            raise TypeError(f"no message for {type(it).__name__}")
    return PeerPacket(sender=packet.sender, receiver=packet.receiver, gauge_root=packet.gauge_root,
                      epoch=packet.epoch, ack=list(packet.ack), items=items)


def from_message(msg: PeerPacket) -> Packet:
    items = []
    for it in msg.items:
        if isinstance(it, CondensedGraph):
            ids, edges, z = np.asarray(it.ids, np.int64), np.asarray(it.edges, np.int64).reshape(-1, 2), \
                np.asarray(it.z, float).reshape(-1, 3)
            items.append(Condensed(robot=it.robot, version=it.version, ids=ids, edges=edges, z=z,
                                   poses=dslam.condensed_poses(ids, edges, z) if it.base < 0 else np.zeros((len(ids), 3)),
                                   info=np.asarray(it.info, float).reshape(-1, 6), base=it.base,
                                   removed=np.asarray(it.removed, np.int64).reshape(-1, 3),
                                   nth=np.asarray(it.nth, np.int64).reshape(-1)))
        elif isinstance(it, ClosureSet) and it.request:
            c = _closures_item(it)
            items.append(place.RelPoseReply((int(it.request[0]), int(it.request[1])),
                                            [(int(a), int(b), z, dslam.info_from6(v))
                                             for (a, b), z, v in zip(c.ids.tolist(), c.z, c.info)]))
        elif isinstance(it, ClosureSet):
            items.append(_closures_item(it))
        elif isinstance(it, SeparatorValues):
            items.append(Separators(phase=it.phase, ids=np.asarray(it.ids, np.int64),
                                    values=np.asarray(it.values, float), converged=it.converged))
        elif isinstance(it, PlaceQuery):
            items.append(place.PlaceQueryItem(it.robot, it.vertex, np.asarray(it.descriptor, np.float16)))
        elif isinstance(it, PlaceMatch):
            items.append(place.PlaceMatchItem(it.robot, it.vertex, it.match_robot, it.match_vertex, it.distance))
        elif isinstance(it, RelPoseRequest):
            items.append(place.RelPoseRequestItem(it.vertex, it.match_vertex))
    ack = tuple(int(v) for v in msg.ack) if len(msg.ack) == 3 else (0, 0, 0)
    return Packet(msg.sender, msg.receiver, msg.gauge_root, items, epoch=msg.epoch, ack=ack)


def transmit(packet: Packet, codec: Codec | None = None) -> tuple[int, Packet]:
    """What the bus does to a packet: its bytes on the wire (frames plus the topic frame, as the
    runtime counts them), and the packet as the receiver decodes it."""
    codec = codec or Codec()
    msg = to_message(packet)
    frames = [bytes(memoryview(f).cast("B")) for f in codec.encode(msg)]
    nbytes = sum(map(len, frames)) + len(f"robot{msg.sender}/to_{msg.receiver}")
    return nbytes, from_message(codec.decode(PeerPacket, frames))
