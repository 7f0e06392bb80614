"""Carved cloud node: sonar pings + sonar pose -> world cloud with elevations resolved by carving (nodes.sonar.carving).

Beside the highlight cloud (the paper's lower-edge elevation, seed 01): the same pings and poses, but
each return's elevation is chosen where the arcs of many poses cross and no ping saw free water
(:mod:`nodes.sonar.carving`). Output ``points`` (world frame): the voxels voted for whose elevation
1-sigma is at most ``max_sigma_m``, that sigma in ``sigma_m`` (metres, along the elevation arc) and the
number of arcs that chose each point in ``intensity``. Published every ``publish_every`` pings. With
``keep="evidence"`` the points are those the carving evidence filter (:mod:`nodes.sonar.carving_filter`) finds
likely on a surface, at any sigma: a point the views did not pin keeps its large sigma. With ``generative``
the cloud also holds the voxels the generative elevations of the pings voted for (:mod:`nodes.sonar.generative`,
per beam from the intensity profile; :mod:`nodes.sonar.generative_votes`, free space deciding between the
leading-edge hypotheses), ``generative_min_votes`` or more, with their own sigma (off by default: see
``bench/sonar_cloud.py`` for where it helps and where it does not).

Poses as in ``highlight_cloud``: each ping is placed with the pose at its own stamp, interpolated
between the two poses around it (:class:`nodes.sonar.pose_buffer.PoseBuffer`); a ping newer than the
newest pose waits (``max_wait_s``, ``max_pending``); a pose gap over ``max_pose_gap_s``, a ping older
than the buffer, a bad pose or a bad ping is dropped, one log line per reason, counted in ``dropped``.
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
from nodes.sonar.carving import CarvingGrid, CarvingParams
from nodes.sonar.gain import compensate_row_gains
from nodes.sonar.generative_votes import GenerativeVotes, fuse
from nodes.sonar.pose_buffer import PoseBuffer
from tether import Input, Node

_FLIP = np.diag([1.0, -1.0, -1.0])      # FLU <-> FRD (its own inverse)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # the mapped box, x0 y0 z0 x1 y1 z1 (m, world)
    bounds_m: tuple[float, float, float, float, float, float] = (-12.0, -12.0, -6.5, 12.0, 12.0, 0.0)
    voxel_m: float = 0.1
    seafloor_z_m: float | None = None        # flat seafloor: beams carve up to its near edge; None: the whole range
    spread_rad: float = math.radians(20.0)   # vertical aperture, used when the ping does not carry one
    returns: Literal["front", "all"] = "all"
    settle_pings: int = 20                   # an arc votes once this many later pings added their evidence
    occlusion: bool = False                  # arcs behind a front end skip what front surfaces shadow (carving.py)
    shadow_darks: bool = False               # a front surface's shadow is unknown, not empty (several passes)
    gap_weight: float = 0.0                  # score lost per ping that had a voxel in its fan but no return there
    max_sigma_m: float = 0.3                 # publish points whose elevation 1-sigma is at most this ("sigma")
    keep: Literal["sigma", "evidence"] = "sigma"   # "evidence": the carving evidence filter decides, any sigma
    min_surface_p: float | None = None       # "evidence": its probability threshold (None: the model's own)
    generative: bool = False                 # add the generative elevations' voxels (nodes.sonar.generative_votes)
    generative_min_votes: int = 8            # ... those with this many votes
    body_frame: Literal["frd", "flu"] = "frd"
    publish_every: int = 10
    max_pose_gap_s: float = 0.5
    max_wait_s: float = 0.5
    max_pending: int = 32
    pose_buffer_s: float = 5.0
    world_frame: str = "world"

    def __post_init__(self) -> None:
        lo, hi = np.array(self.bounds_m[:3]), np.array(self.bounds_m[3:])
        if not (np.all(np.isfinite(self.bounds_m)) and np.all(hi > lo)):
            raise ValueError("bounds_m is (x0, y0, z0, x1, y1, z1) with x1 > x0, y1 > y0, z1 > z0")
        if not (self.voxel_m > 0 and 0 < self.spread_rad < math.pi and self.publish_every >= 1
                and self.max_sigma_m > 0 and self.gap_weight >= 0 and self.generative_min_votes >= 1
                and (self.min_surface_p is None or 0 <= self.min_surface_p <= 1)):
            raise ValueError("need voxel_m > 0, 0 < spread_rad < pi, publish_every >= 1, max_sigma_m > 0, "
                             "gap_weight >= 0, generative_min_votes >= 1 and min_surface_p in [0, 1] or null")
        if not (self.max_pose_gap_s > 0 and self.max_wait_s >= 0 and self.max_pending >= 1
                and self.pose_buffer_s >= self.max_pose_gap_s and self.settle_pings >= 0):
            raise ValueError("need max_pose_gap_s > 0, max_wait_s >= 0, max_pending >= 1, "
                             "pose_buffer_s >= max_pose_gap_s and settle_pings >= 0")


class CarvedCloud(Node):
    """Inputs ``ping`` and ``pose``; output ``points`` (world; ``sigma_m`` elevation 1-sigma, ``intensity`` votes)."""

    Config = Config
    inputs = {"ping": Input(SonarPing, depth=16), "pose": Input(Pose3D, depth=256)}
    outputs = {"points": PointCloud}

    def setup(self) -> None:
        cfg = self.config
        v = cfg.voxel_m
        params = CarvingParams(voxel_m=v, arc_step_m=v, returns=cfg.returns, settle_pings=cfg.settle_pings,
                               occlusion=cfg.occlusion, shadow_darks=cfg.shadow_darks, gap_weight=cfg.gap_weight,
                               keep=cfg.keep, min_surface_p=cfg.min_surface_p)
        self.grid = CarvingGrid((cfg.bounds_m[:3], cfg.bounds_m[3:]), params, seafloor_z_m=cfg.seafloor_z_m)
        self.generative = (GenerativeVotes(self.grid, min_votes=cfg.generative_min_votes)
                           if cfg.generative else None)
        self._poses = PoseBuffer(span_ns=int(cfg.pose_buffer_s * 1e9))
        self._pending: deque[tuple[int, SonarPing]] = deque()
        self.dropped: dict[str, int] = {}
        self.pings = 0
        self.outside = 0
        self._work_ms: list[float] = []

    def on_pose(self, pose: Pose3D) -> list[tuple[str, PointCloud]]:
        transform = pose.matrix()
        q = np.array([pose.qw, pose.qx, pose.qy, pose.qz])
        if not (np.all(np.isfinite(transform)) and np.all(np.isfinite(q)) and float(q @ q) > 1e-12):
            self._drop("bad pose (non-finite or zero quaternion)")
        else:
            self._poses.add(pose.stamp_ns, transform)
        return self._drain()

    def on_ping(self, ping: SonarPing) -> list[tuple[str, PointCloud]]:
        self._pending.append((self.now_ns(), ping))
        return self._drain()

    def _drain(self) -> list[tuple[str, PointCloud]]:
        """Integrate every pending ping whose pose is known; drop those that cannot get one (counted)."""
        out: list[tuple[str, PointCloud]] = []
        cfg = self.config
        while self._pending:
            arrived, ping = self._pending[0]
            pose, status, _ = self._poses.at(ping.stamp_ns, int(cfg.max_pose_gap_s * 1e9))
            if status == "wait" and not (self.now_ns() - arrived > cfg.max_wait_s * 1e9
                                         or len(self._pending) > cfg.max_pending):
                break
            self._pending.popleft()
            if status == "wait":
                self._drop("no pose after the ping's stamp in time" if len(self._poses) else "no sonar pose yet",
                           expected=not len(self._poses))
            elif status == "before_first":
                self._drop("ping older than the oldest buffered pose", expected=True)
            elif status == "gap":
                self._drop(f"the poses around the ping are more than max_pose_gap_s ({cfg.max_pose_gap_s} s) apart")
            else:
                out += self._integrate(ping, pose)
        return out

    def _integrate(self, ping: SonarPing, pose: np.ndarray) -> list[tuple[str, PointCloud]]:
        begin = time.perf_counter()
        cfg = self.config
        raw = np.asarray(ping.intensities)
        gains = compensate_row_gains(raw, np.asarray(ping.row_gains), ping.gamma)
        img = gains.image
        # the generative levels read the raw samples with their row gains (clipping stays at full scale there);
        # gains repaired, invalid or absent: the image as carving reads it
        row_gains = np.asarray(ping.row_gains, np.float32) if gains.status == "applied" else None
        raw = raw if row_gains is not None else img
        bearings = np.asarray(ping.bearings_rad, float)
        resolution = ping.range_resolution_m
        if not resolution > 0 and ping.range_m > 0 and img.ndim == 2 and img.shape[0] > 0:
            resolution = ping.range_m / img.shape[0]
        spread = ping.vertical_aperture_rad if 0 < ping.vertical_aperture_rad < math.pi else cfg.spread_rad
        if bearings.size > 1 and bearings[0] > bearings[-1]:              # either order on the wire
            bearings, img, raw = bearings[::-1], img[:, ::-1], raw[:, ::-1]
        transform = np.array(pose, float)
        if cfg.body_frame == "flu":
            transform[:3, :3] = transform[:3, :3] @ _FLIP
        try:
            update = self.grid.integrate(img, bearings, resolution, transform, spread)
            if self.generative is not None:
                self.generative.integrate(raw, bearings, resolution, transform, spread, gamma=ping.gamma or None,
                                          row_gains=row_gains)
        except ValueError as exc:
            self._drop(f"ping {ping.ping_id}: {exc}".split(",")[0])
            return []
        self.pings += 1
        self.outside += update.outside
        self._work_ms.append((time.perf_counter() - begin) * 1e3)
        if self.pings % cfg.publish_every:
            return []
        return [("points", self.cloud(ping.stamp_ns))]

    def cloud(self, stamp_ns: int = 0, *, flush: bool = False) -> PointCloud:
        """The voxels voted for with elevation sigma <= ``max_sigma_m`` (or those the evidence filter keeps, at
        any sigma): that sigma (m), and the votes."""
        c = self.grid.cloud(flush=flush, max_sigma_m=self._max_sigma())
        points, sigma, votes = c.points_m, c.sigma_m, c.votes
        if self.generative is not None:
            points, sigma, votes = fuse(points, sigma, votes, self.generative.cloud(flush=flush), self.config.voxel_m)
        return PointCloud(stamp_ns=stamp_ns, frame_id=self.config.world_frame, points_m=points.astype(np.float32),
                          intensity=votes.astype(np.float32), sigma_m=sigma.astype(np.float32))

    def teardown(self) -> None:
        ms = np.asarray(self._work_ms) if self._work_ms else np.zeros(1)
        self.log.info("carved cloud: %d pings, %d candidate voxels, %d cloud points, arc samples outside the grid %d, "
                      "work per ping median %.1f ms (p90 %.1f), dropped %s", self.pings, self.grid.candidates,
                      len(self.grid.cloud(max_sigma_m=self._max_sigma()).points_m), self.outside,
                      float(np.median(ms)), float(np.percentile(ms, 90)), self.dropped or "none")

    def _max_sigma(self) -> float:
        return self.config.max_sigma_m if self.config.keep == "sigma" else math.inf

    def _drop(self, reason: str, *, expected: bool = False) -> None:
        key = reason.split(": ", 1)[-1] if reason.startswith("ping ") else reason
        first = key not in self.dropped
        self.dropped[key] = self.dropped.get(key, 0) + 1
        if first:
            (self.log.warning if expected else self.log.error)("dropping %s", reason)
