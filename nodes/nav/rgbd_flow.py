"""RGB-D flow node: consecutive RGB-D frames + odometry -> 3D points with their own velocities (nav.FlowPoints)."""
from __future__ import annotations

import bisect
from collections import deque

import msgspec
import numpy as np

from msgs.geometry import Odometry2D
from msgs.nav import FlowPoints
from msgs.sensor import RgbdFrame
from nodes.nav.flow import (PRESETS, Intrinsics, Mount, OpticalFlow, depth_usable, ego_flow_prior, relative_motion,
                            scene_flow, to_gray)
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    method: str = "dis_fast"          # a preset of nodes.nav.flow.PRESETS: farneback*, dis_*
    scale: float = 1.0                # flow is computed at this fraction of the image size
    ego_prior: bool = True            # start the flow from the static-world flow predicted by odometry
    stride_px: int = 4                # one output point per stride x stride pixels
    camera_x_m: float = 0.3           # camera optical centre in the robot frame (level, looking ahead)
    camera_y_m: float = 0.0
    camera_z_m: float = 1.0
    min_depth_m: float = 0.4
    max_depth_m: float = 8.0
    edge_rel: float = 0.1             # depth-discontinuity test (see nodes.nav.flow.depth_usable)
    min_height_m: float = 0.15        # points below this (the floor) are not output
    max_height_m: float = 2.2
    max_speed_mps: float = 3.0        # faster points are flow outliers
    max_gap_s: float = 0.5            # frames further apart than this restart the flow
    max_extrapolate_s: float = 0.2    # odometry may lag a frame by this much (extrapolated with its twist)
    frame_id: str = "base_link"


class RgbdFlow(Node):
    """Inputs ``rgbd`` (latest only) and ``odom``; output ``flow`` (robot frame at the frame's stamp)."""

    Config = Config
    inputs = {"rgbd": Input(RgbdFrame, latest=True), "odom": Input(Odometry2D, depth=64)}
    outputs = {"flow": FlowPoints}

    def setup(self) -> None:
        cfg = self.config
        if cfg.method not in PRESETS:
            raise ValueError(f"unknown flow method {cfg.method!r}; choose one of {sorted(PRESETS)}")
        self.estimator = OpticalFlow(cfg.method, cfg.scale)
        self.mount = Mount(cfg.camera_x_m, cfg.camera_y_m, cfg.camera_z_m)
        self._odom: deque[tuple[int, float, float, float, float, float]] = deque(maxlen=400)
        self._prev: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None   # stamp, grey, depth, usable
        self._warned_no_odom = False
        self.bad_frames = 0

    def on_odom(self, msg: Odometry2D) -> None:
        p, t = msg.pose, msg.twist
        if not all(np.isfinite((p.x_m, p.y_m, p.yaw_rad, t.vx_mps, t.wz_radps))):
            self.log.error("dropped non-finite odometry at %d", msg.stamp_ns)
            return
        entry = (msg.stamp_ns, p.x_m, p.y_m, p.yaw_rad, t.vx_mps, t.wz_radps)
        if self._odom and msg.stamp_ns <= self._odom[-1][0]:
            if msg.stamp_ns == self._odom[-1][0]:
                self._odom[-1] = entry
            return
        self._odom.append(entry)

    def pose_at(self, stamp_ns: int) -> tuple[float, float, float] | None:
        """Odometry pose at ``stamp_ns``: interpolated, or extrapolated a little past the newest sample."""
        if not self._odom:
            return None
        stamps = [o[0] for o in self._odom]
        k = bisect.bisect_left(stamps, stamp_ns)
        if k < len(stamps) and stamps[k] == stamp_ns:
            return self._odom[k][1:4]
        if k == 0:
            return self._odom[0][1:4] if stamps[0] - stamp_ns <= self.config.max_extrapolate_s * 1e9 else None
        if k == len(stamps):
            t, x, y, yaw, v, w = self._odom[-1]
            dt = (stamp_ns - t) / 1e9
            if dt > self.config.max_extrapolate_s:
                return None
            return x + v * dt * np.cos(yaw), y + v * dt * np.sin(yaw), yaw + w * dt
        (t0, x0, y0, a0, *_), (t1, x1, y1, a1, *_) = self._odom[k - 1], self._odom[k]
        r = (stamp_ns - t0) / (t1 - t0)
        da = np.arctan2(np.sin(a1 - a0), np.cos(a1 - a0))
        return x0 + r * (x1 - x0), y0 + r * (y1 - y0), a0 + r * da

    def _motion(self, t_prev: int, t_cur: int) -> tuple[float, float, float]:
        a, b = self.pose_at(t_prev), self.pose_at(t_cur)
        if a is None or b is None:
            if not self._warned_no_odom:
                self.log.warning("no odometry around the frames: the robot's own motion is NOT removed")
                self._warned_no_odom = True
            return 0.0, 0.0, 0.0
        return relative_motion(a, b)

    def on_rgbd(self, frame: RgbdFrame) -> dict[str, FlowPoints] | None:
        cfg = self.config
        depth = np.asarray(frame.depth_m, dtype=np.float32)
        if frame.rgb.shape[:2] != depth.shape or depth.ndim != 2 or frame.info.fx_px <= 0:
            self.bad_frames += 1
            self.log.error("dropped frame %d: rgb %s / depth %s / fx %s do not fit", frame.stamp_ns,
                           frame.rgb.shape, depth.shape, frame.info.fx_px)
            return None
        intr = Intrinsics(frame.info.fx_px, frame.info.fy_px, frame.info.cx_px, frame.info.cy_px)
        grey = to_gray(frame.rgb)
        usable = depth_usable(depth, min_m=cfg.min_depth_m, max_m=cfg.max_depth_m, edge_rel=cfg.edge_rel)
        prev, self._prev = self._prev, (frame.stamp_ns, grey, depth, usable)
        if prev is None or prev[1].shape != grey.shape:
            return None
        dt = (frame.stamp_ns - prev[0]) / 1e9
        if not 0 < dt <= cfg.max_gap_s:
            self.log.warning("frames %.3f s apart: restarting the flow", dt)
            return None
        motion = self._motion(prev[0], frame.stamp_ns)
        prior = (ego_flow_prior(depth, motion, intr, self.mount, self.estimator.processing_shape(depth.shape),
                                far_m=cfg.max_depth_m) if cfg.ego_prior else None)
        flow = self.estimator(grey, prev[1], prior=prior)
        sf = scene_flow(flow, prev[2], depth, motion, dt, intr, self.mount, stride_px=cfg.stride_px,
                        min_depth_m=cfg.min_depth_m, max_depth_m=cfg.max_depth_m, edge_rel=cfg.edge_rel,
                        max_speed_mps=cfg.max_speed_mps, usable_prev=prev[3], usable_cur=usable)
        keep = (sf.points_m[:, 2] >= cfg.min_height_m) & (sf.points_m[:, 2] <= cfg.max_height_m)
        return {"flow": FlowPoints(stamp_ns=frame.stamp_ns, frame_id=cfg.frame_id, points_m=sf.points_m[keep],
                                   velocity_mps=sf.velocity_mps[keep])}
