"""RGB-D flow node: consecutive RGB-D frames + odometry -> 3D points with their own velocities (nav.FlowPoints)."""
from __future__ import annotations

import bisect
from collections import deque

import msgspec
import numpy as np

from msgs.geometry import Odometry2D
from msgs.nav import FlowPoints
from msgs.sensor import RgbdFrame
from nodes.nav.flow import PRESETS, FlowTracker, Intrinsics, Mount, relative_motion
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
    max_vertical_mps: float = 0.5     # ... and so are points rising or falling faster (people walk on the floor)
    # Both off by default: they remove the phantom motion of fast turns (bench/nav_flow.py (d)), but in
    # the closed loop (bench/social_nav.py, start 0) the robot then drove nearer people: students003
    # closest 0.91 -> 0.34 m (a contact), group 1.27 -> 0.81 m and 11.1 -> 14.9 s, 0.11 m from start +0.4 s.
    fb_max_px: float = 0.0            # forward and backward flow must agree this well (px; 0 = off, half the flow time)
    hole_edges: bool = False          # pixels next to depth holes (sky, out of range) count as depth edges
    border_px: int = 16               # points this near the image edge (either frame) are dropped: cut flow patches
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
        self.tracker = FlowTracker(Mount(cfg.camera_x_m, cfg.camera_y_m, cfg.camera_z_m), preset=cfg.method,
                                   scale=cfg.scale, ego_prior=cfg.ego_prior, stride_px=cfg.stride_px,
                                   min_depth_m=cfg.min_depth_m, max_depth_m=cfg.max_depth_m, edge_rel=cfg.edge_rel,
                                   max_speed_mps=cfg.max_speed_mps, max_vertical_mps=cfg.max_vertical_mps,
                                   border_px=cfg.border_px, min_height_m=cfg.min_height_m,
                                   max_height_m=cfg.max_height_m, max_gap_s=cfg.max_gap_s,
                                   fb_max_px=cfg.fb_max_px, hole_edges=cfg.hole_edges)
        self._odom: deque[tuple[int, float, float, float, float, float]] = deque(maxlen=400)
        self._prev_stamp: int | None = None
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

    def _motion(self, t_prev: int | None, t_cur: int) -> tuple[float, float, float]:
        a = self.pose_at(t_prev) if t_prev is not None else None
        b = self.pose_at(t_cur)
        if t_prev is not None and (a is None or b is None):
            if not self._warned_no_odom:
                self.log.warning("no odometry around the frames: the robot's own motion is NOT removed")
                self._warned_no_odom = True
        if a is None or b is None:
            return 0.0, 0.0, 0.0
        return relative_motion(a, b)

    def on_rgbd(self, frame: RgbdFrame) -> dict[str, FlowPoints] | None:
        depth = np.asarray(frame.depth_m, dtype=np.float32)
        if frame.rgb.shape[:2] != depth.shape or depth.ndim != 2 or frame.info.fx_px <= 0 or frame.info.fy_px <= 0:
            self.bad_frames += 1
            self.log.error("dropped frame %d: rgb %s / depth %s / fx %s do not fit", frame.stamp_ns,
                           frame.rgb.shape, depth.shape, frame.info.fx_px)
            return None
        intr = Intrinsics(frame.info.fx_px, frame.info.fy_px, frame.info.cx_px, frame.info.cy_px)
        prev_stamp, self._prev_stamp = self._prev_stamp, frame.stamp_ns
        if prev_stamp is not None and not 0 < (frame.stamp_ns - prev_stamp) / 1e9 <= self.config.max_gap_s:
            self.log.warning("frames %.3f s apart: restarting the flow", (frame.stamp_ns - prev_stamp) / 1e9)
        sf = self.tracker.update(frame.stamp_ns / 1e9, frame.rgb, depth, intr,
                                 motion=self._motion(prev_stamp, frame.stamp_ns))
        if sf is None:
            return None
        return {"flow": FlowPoints(stamp_ns=frame.stamp_ns, frame_id=self.config.frame_id, points_m=sf.points_m,
                                   velocity_mps=sf.velocity_mps)}
