"""dslam_monitor: watches a decentralised SLAM team and scores it at the end (seed 10).

Inputs ``robot_<r>`` (RobotTrajectory of each robot) and ``stats_<r>`` (the robot's own
``_stats``: the runtime counts the bytes every output sent). Every ``report_s`` seconds it
logs the team's cost ratio -- chi2 of the robots' own estimates on the whole (inlier) graph
over the centralised optimum's, the same back end on the full graph -- and the bytes the
robots sent to each other (their ``to_<p>`` outputs, summed over restarts); at shutdown it logs the final figures and writes ``out_dir``/dslam_team.png
(trajectories by robot, accepted and rejected inter-robot closures). The monitor is an
observer: it sends nothing to the robots.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import msgspec
import numpy as np

from msgs.slam import RobotTrajectory
from msgs.std import NodeStats
from nodes.slam.dslam_agent import MAX_ROBOTS, peer_handlers
from nodes.slam.graph_io import read_graph
from nodes.slam.multirobot import assemble, centralised, cost_ratio, split_graph
from nodes.slam.pose_graph import GraphError
from nodes.slam.team_plot import draw_team
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    robots: int = 2
    graph: str = "../shared/data/posegraphs/FR079_P_toro.graph"
    outlier_rate: float = 0.0
    seed: int = 0
    report_s: float = 5.0
    out_dir: str = ""

    def __post_init__(self) -> None:
        if not 1 <= self.robots <= MAX_ROBOTS:
            raise ValueError(f"robots is 1..{MAX_ROBOTS}")


class TeamMonitor(Node):
    """Scores the team's trajectories against the centralised optimum (see the module docstring)."""

    Config = Config

    @classmethod
    def ports_for(cls, config: Config):
        inputs = {f"robot_{r}": Input(RobotTrajectory, latest=True) for r in range(config.robots)}
        inputs |= {f"stats_{r}": Input(NodeStats, latest=True) for r in range(config.robots)}
        return inputs, {}, {}

    def setup(self) -> None:
        cfg = self.config
        self.scenario = split_graph(read_graph(cfg.graph), cfg.robots, outlier_rate=cfg.outlier_rate, seed=cfg.seed)
        self.reference = centralised(self.scenario)
        self.index = {int(v): k for k, v in enumerate(self.scenario.graph.ids)}
        self.latest: dict[int, RobotTrajectory] = {}
        self.sent: dict[str, tuple[int, int]] = {}            # node id -> (pid, bytes sent to peers by that process)
        self.banked = 0                                        # bytes sent by processes that have since restarted
        self.last_report = time.monotonic()

    def _take(self, msg: RobotTrajectory) -> None:
        if not 0 <= msg.robot < self.config.robots:
            self.log.warning("trajectory of robot %d: not in this team", msg.robot)
            return
        self.latest[msg.robot] = msg
        if time.monotonic() - self.last_report >= self.config.report_s:
            self.last_report = time.monotonic()
            ratio, nbytes, frames = self.score()
            self.log.info("team: cost ratio %.4f, %d B sent, keyframes %s, frames %s", ratio, nbytes,
                          [len(self.latest[r].ids) if r in self.latest else 0 for r in range(self.config.robots)], frames)

    def _stats(self, msg: NodeStats) -> None:
        sent = sum(n for out, n in msg.published_bytes.items() if out.startswith("to_"))
        previous = self.sent.get(msg.node_id)
        if previous is not None and previous[0] != msg.pid:
            self.banked += previous[1]                         # a restarted robot counts from zero again
        self.sent[msg.node_id] = (msg.pid, sent)

    @property
    def bytes_sent(self) -> int:
        return self.banked + sum(n for _, n in self.sent.values())

    def team_poses(self) -> np.ndarray:
        """(N, 3) the robots' latest own estimates by vertex; NaN where none has spoken yet."""
        estimates = {}
        for r, msg in self.latest.items():
            rows = np.array([self.index.get(int(v), -1) for v in np.asarray(msg.ids).tolist()], np.int64)
            ok = rows >= 0                                 # vertices this team does not know are ignored
            estimates[r] = (rows[ok], np.asarray(msg.poses, float).reshape(-1, 3)[ok])
        return assemble(self.scenario, estimates)

    def score(self) -> tuple[float, int, list[int]]:
        """(cost ratio of the complete team's estimate -- inf until every keyframe has one --, bytes, gauge roots)."""
        return (cost_ratio(self.reference, self.team_poses()), self.bytes_sent,
                [self.latest[r].gauge_root if r in self.latest else -1 for r in range(self.config.robots)])

    def found_ratio(self) -> tuple[float, int]:
        """(cost ratio against the centralised optimum *given the closures the team used*, their count):
        the back end's own error, apart from what place recognition missed."""
        used = {tuple(p) for m in self.latest.values() for p in np.asarray(m.accepted).reshape(-1, 2).tolist()}
        used &= self.scenario.inter_pairs()
        try:
            best = centralised(self.scenario, closures=used)
        except GraphError:
            return math.inf, len(used)                     # the closures used leave the team in pieces
        return cost_ratio(best, self.team_poses()), len(used)

    def teardown(self) -> None:
        ratio, nbytes, frames = self.score()
        self.log.info("team final: cost ratio %.5f against the centralised optimum, %d B sent in all, frames %s",
                      ratio, nbytes, frames)
        back_end, used = self.found_ratio()
        self.log.info("team final: %d of %d inter-robot closures in use; cost ratio %.5f against the centralised "
                      "optimum with those closures (the back end's share)", used, int(self.scenario.inter.sum()), back_end)
        if self.config.out_dir and self.latest:
            acc = np.concatenate([np.asarray(m.accepted).reshape(-1, 2) for m in self.latest.values()])
            rej = np.concatenate([np.asarray(m.rejected).reshape(-1, 2) for m in self.latest.values()])
            ref = {int(v): self.reference.poses[k, :2] for v, k in self.index.items()}
            path = draw_team(Path(self.config.out_dir) / "dslam_team.png",
                             {r: (np.asarray(m.ids), np.asarray(m.poses, float).reshape(-1, 3)) for r, m in self.latest.items()},
                             accepted=acc, rejected=rej, reference=ref,
                             title=f"{Path(self.config.graph).name}, {self.config.robots} robots: cost ratio {ratio:.4f}, "
                                   f"{nbytes} B exchanged")
            self.log.info("wrote %s", path)


peer_handlers(TeamMonitor, "robot_", "_take", MAX_ROBOTS)
peer_handlers(TeamMonitor, "stats_", "_stats", MAX_ROBOTS)
