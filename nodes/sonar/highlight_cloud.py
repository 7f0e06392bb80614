"""Highlight cloud node: sonar pings + sonar pose -> accumulated world-frame 3D point cloud (seed 01, eq. 7-17).

Conventions: the world is z-up; ``pose`` is the sonar's pose in it, body frame FRD by default (x
along the boresight, y starboard, z down: the paper's eq. 15-17 and ``sim.fls``; ``body_frame="flu"``
for x, port, up). Tilt, roll and altitude come from the pose (altitude = z - ``seafloor_z_m``)
unless given as parameters.

Each ping is placed with the pose at its own stamp, interpolated between the two poses around it
(:mod:`nodes.sonar.pose_buffer`). A ping newer than the newest pose waits (at most ``max_wait_s``
and ``max_pending`` pings) for the pose after it; a ping between two poses more than
``max_pose_gap_s`` apart, older than the pose buffer, or that waited too long is dropped. All
counted in ``dropped``; ``placed`` counts pings placed at a pose of their own stamp ("exact") and
interpolated ones, ``waited`` those that had to wait.
"""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Literal

import msgspec
import numpy as np

from msgs.geometry import Pose3D
from msgs.sensor import PointCloud
from msgs.sonar import SonarPing
from nodes.sonar.gain import compensate_row_gains
from nodes.sonar.highlight import down_from_tilt, extract_line_scan
from nodes.sonar.pose_buffer import PoseBuffer
from tether import Input, Node

_FLIP = np.diag([1.0, -1.0, -1.0])      # FLU <-> FRD (its own inverse)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    spread_rad: float = math.radians(20.0)   # vertical aperture s, used when the ping does not carry one
    tilt_rad: float = math.radians(15.0)     # used with attitude="param" (pose gives heading only)
    attitude: Literal["pose", "param"] = "pose"
    altitude_m: float = 0.0                  # > 0: fixed altitude h; 0: pose z - seafloor_z_m
    seafloor_z_m: float = 0.0
    body_frame: Literal["frd", "flu"] = "frd"      # sim.fls and the paper: FRD
    model: Literal["beam", "paper"] = "beam"
    sigma_px: float = 1.5                    # Gaussian blur along range (cells)
    sigma_beam_px: float = -1.0              # across beams; < 0: same as sigma_px
    threshold: float = 0.12                  # front-end rise, fraction of full scale
    guard_px: float = -1.0                   # rows kept clear before M_emin; < 0: 2 sigma + 2
    include_seafloor: bool = True            # m(j) = M_emin points where no highlight (the paper)
    max_points: int = 200_000                # accumulated cloud keeps the newest points
    publish_every: int = 1                   # publish the accumulated cloud every n-th ping
    publish_scan: bool = False               # also publish each ping's line scan (sonar frame)
    max_pose_gap_s: float = 0.5              # the poses around a ping further apart than this: drop the ping
    max_wait_s: float = 0.5                  # a ping newer than the newest pose waits this long (node clock) ...
    max_pending: int = 32                    # ... and at most this many pings wait
    pose_buffer_s: float = 5.0               # poses kept behind the newest
    row_gains: Literal["apply", "ignore"] = "apply"   # detect on gain-compensated samples (nodes.sonar.gain)
    world_frame: str = "world"

    def __post_init__(self) -> None:
        if not (0 < self.spread_rad < math.pi) or self.max_points < 1 or self.publish_every < 1:
            raise ValueError("need 0 < spread_rad < pi, max_points >= 1 and publish_every >= 1")
        if self.sigma_px < 0 or not (0 < self.threshold < 1) or self.altitude_m < 0:
            raise ValueError("need sigma_px >= 0, 0 < threshold < 1 (fraction of full scale), altitude_m >= 0")
        if not (self.max_pose_gap_s > 0 and self.max_wait_s >= 0 and self.max_pending >= 1
                and self.pose_buffer_s >= self.max_pose_gap_s):
            raise ValueError("need max_pose_gap_s > 0, max_wait_s >= 0, max_pending >= 1 and "
                             "pose_buffer_s >= max_pose_gap_s")


class HighlightCloud(Node):
    """Inputs ``ping`` and ``pose``; outputs ``points`` (world) and ``scan`` (sonar frame)."""

    Config = Config
    # every pose is kept (a "latest only" queue would widen the interpolation brackets when busy)
    inputs = {"ping": Input(SonarPing, depth=16), "pose": Input(Pose3D, depth=256)}
    outputs = {"points": PointCloud, "scan": PointCloud}

    def setup(self) -> None:
        self._poses = PoseBuffer(span_ns=int(self.config.pose_buffer_s * 1e9))
        self._pending: deque[tuple[int, SonarPing]] = deque()     # (arrival ns, ping) waiting for a pose
        self.placed = {"exact": 0, "interpolated": 0}
        self.gain_problems = {"invalid": 0, "mismatch": 0, "repaired": 0}
        self.waited = 0
        self._bracket_ms: list[float] = []
        self._xyz = np.zeros((self.config.max_points, 3), np.float32)
        self._strength = np.zeros(self.config.max_points, np.float32)
        self._count = 0
        self._head = 0
        self.pings = 0
        self.dropped: dict[str, int] = {}
        self._age_ms: list[float] = []
        self._work_ms: list[float] = []

    def on_pose(self, pose: Pose3D) -> list[tuple[str, PointCloud]]:
        q = np.array([pose.qw, pose.qx, pose.qy, pose.qz])
        transform = pose.matrix()
        if not (np.all(np.isfinite(transform)) and np.all(np.isfinite(q)) and float(q @ q) > 1e-12):
            self._drop("bad pose (non-finite or zero quaternion)")
            return self._drain()
        self._poses.add(pose.stamp_ns, transform)
        return self._drain()

    def on_ping(self, ping: SonarPing) -> list[tuple[str, PointCloud]]:
        self._age_ms.append((self.now_ns() - ping.stamp_ns) / 1e6)
        self._pending.append((self.now_ns(), ping))
        out = self._drain()
        if self._pending and self._pending[-1][1] is ping:
            self.waited += 1                    # its pose has not come yet
        return out

    def _drain(self) -> list[tuple[str, PointCloud]]:
        """Place every pending ping whose pose is known; drop those that cannot get one (counted)."""
        out: list[tuple[str, PointCloud]] = []
        cfg = self.config
        while self._pending:
            arrived, ping = self._pending[0]
            pose, status, bracket = self._poses.at(ping.stamp_ns, int(cfg.max_pose_gap_s * 1e9))
            if status == "wait":
                overdue = self.now_ns() - arrived > cfg.max_wait_s * 1e9 or len(self._pending) > cfg.max_pending
                if not overdue:
                    break
                self._pending.popleft()
                if len(self._poses):
                    self._drop("no pose after the ping's stamp in time (pose stream late or stopped)", ping.ping_id)
                else:
                    self._drop("no sonar pose received yet", ping.ping_id, expected=True)
                continue
            self._pending.popleft()
            if status == "before_first":
                self._drop("ping older than the oldest buffered pose", ping.ping_id, expected=True)
            elif status == "gap":
                self._drop(f"the poses around the ping are further apart than max_pose_gap_s "
                           f"({cfg.max_pose_gap_s} s)", ping.ping_id)
            else:
                self.placed[status] += 1
                if status == "interpolated":
                    self._bracket_ms.append(bracket / 1e6)
                out += self._place(ping, pose)
        return out

    def _place(self, ping: SonarPing, pose: np.ndarray) -> list[tuple[str, PointCloud]]:
        begin = time.perf_counter()
        rot, origin, down, tilt = self._sonar_in_world(pose)
        altitude = self.config.altitude_m or float(origin[2] - self.config.seafloor_z_m)
        cfg = self.config
        resolution = ping.range_resolution_m
        if not resolution > 0 and ping.range_m > 0 and ping.intensities.shape[0] > 0:
            resolution = ping.range_m / ping.intensities.shape[0]
        spread = ping.vertical_aperture_rad if 0 < ping.vertical_aperture_rad < math.pi else cfg.spread_rad
        intensities = np.asarray(ping.intensities)
        if cfg.row_gains == "apply":
            gained = compensate_row_gains(intensities, np.asarray(ping.row_gains), ping.gamma)
            if gained.status in self.gain_problems:
                self.gain_problems[gained.status] += 1
                if self.gain_problems[gained.status] == 1:
                    self.log.error("ping %d: row gains %s (%d bad rows); %s", ping.ping_id, gained.status,
                                   gained.bad_rows, "bad rows take their neighbours' gain" if gained.status == "repaired"
                                   else "detecting on the unscaled samples")
            intensities = gained.image
        try:
            scan = extract_line_scan(intensities, np.asarray(ping.bearings_rad), resolution,
                                     altitude_m=altitude, tilt_rad=tilt, spread_rad=spread, down_frd=down,
                                     model=cfg.model, sigma_px=cfg.sigma_px,
                                     sigma_beam_px=None if cfg.sigma_beam_px < 0 else cfg.sigma_beam_px,
                                     threshold=cfg.threshold, guard_px=None if cfg.guard_px < 0 else cfg.guard_px,
                                     include_seafloor=cfg.include_seafloor)
        except ValueError as exc:
            self._drop(str(exc).split(",")[0], ping.ping_id)
            return []
        self.pings += 1
        world = scan.points_m @ rot.T + origin
        self._append(world, scan.strength)
        out: list[tuple[str, PointCloud]] = []
        if cfg.publish_scan:
            body = scan.points_m if cfg.body_frame == "frd" else scan.points_m @ _FLIP
            out.append(("scan", PointCloud(stamp_ns=ping.stamp_ns, frame_id=ping.frame_id or "sonar",
                                           points_m=body.astype(np.float32), intensity=scan.strength)))
        if self.pings % cfg.publish_every == 0:
            out.append(("points", self.cloud(ping.stamp_ns)))
        self._work_ms.append((time.perf_counter() - begin) * 1e3)
        return out

    def cloud(self, stamp_ns: int = 0) -> PointCloud:
        """The accumulated cloud, oldest point first."""
        n, cap = self._count, self.config.max_points
        order = np.arange(n) if n < cap else (np.arange(cap) + self._head) % cap
        return PointCloud(stamp_ns=stamp_ns, frame_id=self.config.world_frame, points_m=self._xyz[order],
                          intensity=self._strength[order])

    def teardown(self) -> None:
        self.log.info("highlight cloud: %d pings, %d points accumulated, dropped %s, row-gain problems %s",
                      self.pings, min(self._count, self.config.max_points), self.dropped or "none", self.gain_problems)
        placed = sum(self.placed.values())
        if placed:
            self.log.info("highlight cloud poses: %d pings placed at a pose of their own stamp, %d interpolated "
                          "(bracket median %.1f ms), %d waited for their pose, %d still waiting; 0 placed with "
                          "another stamp's pose", self.placed["exact"], self.placed["interpolated"],
                          float(np.median(self._bracket_ms)) if self._bracket_ms else 0.0, self.waited,
                          len(self._pending))
        if self._work_ms:
            self.log.info("highlight cloud timing: ping age on arrival median %.1f ms (p90 %.1f), work per ping "
                          "median %.1f ms (p90 %.1f)", np.median(self._age_ms), np.percentile(self._age_ms, 90),
                          np.median(self._work_ms), np.percentile(self._work_ms, 90))

    # -- helpers ------------------------------------------------------------------------
    def _sonar_in_world(self, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Rotation world<-sonar FRD, sonar origin, gravity in sonar FRD, boresight depression (rad)."""
        rot = transform[:3, :3] if self.config.body_frame == "frd" else transform[:3, :3] @ _FLIP
        if self.config.attitude == "param":
            yaw = math.atan2(rot[1, 0], rot[0, 0])
            c, s, ct, st = math.cos(yaw), math.sin(yaw), math.cos(self.config.tilt_rad), math.sin(self.config.tilt_rad)
            flu = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.array([[ct, 0, st], [0, 1.0, 0], [-st, 0, ct]])
            rot = flu @ _FLIP
            return rot, transform[:3, 3], down_from_tilt(self.config.tilt_rad), self.config.tilt_rad
        down = rot.T @ np.array([0.0, 0.0, -1.0])
        return rot, transform[:3, 3], down, float(math.asin(np.clip(down[0], -1.0, 1.0)))

    def _append(self, points: np.ndarray, strength: np.ndarray) -> None:
        cap = self.config.max_points
        points, strength = points[-cap:], strength[-cap:]
        idx = (self._head + np.arange(len(points))) % cap
        self._xyz[idx] = points
        self._strength[idx] = strength
        self._head = (self._head + len(points)) % cap
        self._count += len(points)

    def _drop(self, reason: str, ping_id: int | None = None, *, expected: bool = False) -> None:
        first = reason not in self.dropped
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        if first:
            # Pings before the first pose are normal at start-up (two streams, no ordering): a warning.
            say = self.log.warning if expected else self.log.error
            say("dropping %s: %s", f"ping {ping_id}" if ping_id is not None else "input", reason)
