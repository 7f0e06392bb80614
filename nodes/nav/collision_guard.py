"""Collision guard (layer 3): pass velocity commands through, but never let the robot drive into anything.

It sits between a planner's ``cmd`` and the robot and overrides whatever the planners say.
Obstacles are the depth image's points (and/or 3D points) between ``z_min_m`` and
``z_max_m``, thinned to one per 5 cm. For each command it follows the path the robot
centre would take with that (v, w) (:mod:`nodes.nav.clearance`) and finds the first place
where the robot's disc plus ``margin_m`` would close in on a point:

- an obstacle on that path nearer than ``stop_distance_m`` (the paper's 1 m rule, applied to
  what the robot is driving toward, so it may pass beside a wall or a standing person; measured
  as the straight distance now; ``stop_along_path``, not safe: along the arc)
  zeroes forward motion; turning in place stays allowed unless
  ``allow_turn_in_place`` is false. It releases only after ``release_s`` of continuous
  clearance on the commanded path;
- otherwise the forward speed is capped so the robot can still brake (``decel_mps2``) to a
  stop before the conflict, counting ``latency_s`` plus the age of the data as time spent
  at the current speed: a 1 m rule alone is not enough at 1 m/s with 0.8 m/s^2 brakes
  (0.63 m of braking plus the delay of a live pipeline).

Moving points (input ``points`` carrying velocities, e.g. the flow node's ``FlowPoints``,
next to ``rgbd``) are extrapolated (each with its own velocity, or with its ``cell_m`` grid cell's median)
at constant velocity over the time the robot needs to
stop (``latency_s`` + v_max / ``decel_mps2``, at most ``predict_s``) and join the obstacles
along their way: a person walking into the robot's path counts from where they will be,
not only where they are. With odometry (input ``odom``) the points are kept in the world frame: they are moved with
the robot between frames, and points that leave the camera's view (outside its field of
view or nearer than ``min_range_m`` to it, where a depth camera reports holes) are
remembered for ``memory_s``. A depth frame with almost no valid pixels counts as blind and
stops the robot; so do a silent sensor (``sensor_timeout_s``) and a silent planner
(``cmd_timeout_s``, checked on a timer). Reversing is refused unless ``allow_reverse`` (the
camera looks ahead). What the guard cannot prevent is a person walking into a robot that
has stopped; the simulator counts those contacts separately (``sim.crowd.ContactEvent``).
"""
from __future__ import annotations

from collections import deque

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Twist2D
from msgs.nav import FlowPoints, PlanStatus
from msgs.sensor import RgbdFrame
from nodes.nav.clearance import (braking_speed_mps, cleared_by_depth, conflicting, free_distance_m, measured_through,
                                 unseen_mask)
from nodes.nav.grid_frame import to_robot, to_world
from nodes.nav.dwa_core import depth_to_robot, thin_points
from nodes.nav.features import point_velocity
from tether import Node


def nearest_obstacle_m(points_m: np.ndarray, *, z_min_m: float = 0.1, z_max_m: float = 2.0) -> float:
    """Horizontal distance (m) from the robot centre to the nearest point with z in [z_min, z_max]; inf if none."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] >= z_min_m) & (p[:, 2] <= z_max_m)]
    return float(np.hypot(p[:, 0], p[:, 1]).min()) if len(p) else float("inf")


def obstacle_xy(points_m: np.ndarray, *, z_min_m: float, z_max_m: float, reach_m: float, cell_m: float = 0.05) -> np.ndarray:
    """Robot-frame points (N, 3) -> obstacle points (M, 2) in the height band, within ``reach_m``, one per ``cell_m``."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] >= z_min_m) & (p[:, 2] <= z_max_m)]
    p = p[np.hypot(p[:, 0], p[:, 1]) <= reach_m]
    return thin_points(p[:, :2], cell_m)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    stop_distance_m: float = 1.0      # an obstacle on the path ahead nearer than this (centre distance) stops the robot
    robot_radius_m: float = 0.35
    margin_m: float = 0.1             # kept free around the robot's disc
    decel_mps2: float = 0.8           # braking the robot can do (sim.crowd max_accel_mps2)
    latency_s: float = 0.15           # sensor -> wheels delay, on top of the measured age of the data
    check_m: float = 2.5              # how far along the path to look
    release_s: float = 0.5
    allow_turn_in_place: bool = True
    allow_reverse: bool = False
    camera_x_m: float = 0.3
    camera_y_m: float = 0.0
    camera_z_m: float = 1.0
    min_range_m: float = 0.4          # the depth camera reports holes nearer than this
    depth_max_m: float = 8.0          # ... and farther than this (rays meeting the floor beyond it do not clear)
    memory_s: float = 3.0             # unseen points are remembered this long (needs odom)
    predict_s: float = 0.7            # moving points are extrapolated this far ahead at most (0 = off)
    moving_mps: float = 0.3           # slower points are not extrapolated
    cell_m: float = 0.0               # > 0: each moves with the median velocity of its cell this size (0.25 m is
                                      # the planner's grid); 0: with its own flow vector
    v_max_mps: float = 1.0            # the robot's top speed (sets the extrapolation horizon)
    hold_min_points: int = 3          # a stop for predicted points only holds release_s (as one for seen points does)
                                      # when at least this many flow points are predicted onto the path; fewer (one
                                      # wrong flow vector) stop the robot only while they are predicted. Such
                                      # phantoms held it 0.5 s at a time (hallway: 1-3 ticks of a predicted obstacle,
                                      # then 8 of 'waiting'); a walker's body moves many points, and its prediction
                                      # may flicker at the path's edge, so it holds (0 = every stop holds)
    stop_along_path: bool = False     # True: 'nearer than stop_distance_m on the path' is measured along the commanded
                                      # arc (the travel until the disc would touch a point, plus the radius) instead of
                                      # as the straight distance now to any point the arc touches within check_m. It
                                      # spares walkers 0.9 m to the side that a tight turn's arc (a 0.5 m circle at 0.6
                                      # m/s, -1.2 rad/s) or an arc bending toward them touches only after most of a
                                      # metre (hallway, IRL: 39 -> 10 % of ticks braked), but it is not safe: a walker
                                      # drifting into the path from 1 m to the side was stopped for 0.3 s later, and
                                      # DWA touched one (group: closest 0.54 -> 0.30 m, 1 strict robot contact).
                                      # Off; bench/social_nav.py reports what it would brake (guard_frac_along_path)
    stride_px: int = 4
    z_min_m: float = 0.1
    z_max_m: float = 2.0
    min_valid_fraction: float = 0.02
    sensor_timeout_s: float = 0.5
    cmd_timeout_s: float = 0.5
    watchdog_hz: float = 10.0


class CollisionGuard(Node):
    """Inputs ``cmd`` (planner), ``rgbd`` and/or ``points`` (robot-frame FlowPoints), optional ``odom``;
    outputs ``cmd`` (the safe command) and ``status`` (why it was changed)."""

    Config = Config
    inputs = {"cmd": Twist2D, "rgbd": RgbdFrame, "points": FlowPoints, "odom": Odometry2D}
    outputs = {"cmd": Twist2D, "status": PlanStatus}
    timers = {"tick": "watchdog_hz"}

    def setup(self) -> None:
        self.nearest_m = float("inf")
        self.blind = False
        self.stops = 0
        self.capped = 0
        self._hold_until_ns: int | None = None      # forward motion refused until then (release_s)
        self._obstacle_ns: int | None = None        # last time an obstacle stopped the robot
        self._sensor_ns: int | None = None
        self._cmd_ns: int | None = None
        self._last = Twist2D()
        self._sent: tuple[float, float] | None = None
        self._stopped = False
        self._points = np.zeros((0, 2))             # world frame with odometry (_world), else the frame's robot frame
        self._points_t = np.zeros(0, np.int64)      # when each point was last seen
        self._points_ns = 0
        self._world = False
        self._poses: deque[tuple[int, tuple[float, float, float]]] = deque(maxlen=64)
        self._half_fov = np.pi / 2
        self._rgbd = False
        self._movers = np.zeros((0, 2))             # robot frame at _movers_ns, or world with odometry
        self._movers_src = np.zeros(0, np.int64)    # which flow point each predicted place comes from
        self._movers_ns = 0
        self._movers_world = False

    # -- sensing ------------------------------------------------------------------------------
    def on_odom(self, msg: Odometry2D) -> None:
        pose = (msg.pose.x_m, msg.pose.y_m, msg.pose.yaw_rad)
        if np.all(np.isfinite(pose)) and (not self._poses or msg.stamp_ns >= self._poses[-1][0]):
            self._poses.append((msg.stamp_ns, pose))

    def _pose_at(self, stamp_ns: int) -> tuple[float, float, float] | None:
        if not self._poses:
            return None
        stamp, pose = min(self._poses, key=lambda sp: abs(sp[0] - stamp_ns))
        return pose if abs(stamp - stamp_ns) <= 0.2e9 else None

    def _sense(self, points_m: np.ndarray, blind: bool, stamp_ns: int, seen_free=None) -> list[tuple[str, object]]:
        """Take a frame's points; ``seen_free`` (optional, two robot-frame (N, 2) -> (N,) bool functions) tells
        which remembered points the frame shows to be empty space, and which it measured anything through."""
        c = self.config
        self._sensor_ns = self.now_ns()
        self.blind = blind
        self.nearest_m = nearest_obstacle_m(points_m, z_min_m=c.z_min_m, z_max_m=c.z_max_m)
        xy = obstacle_xy(points_m, z_min_m=c.z_min_m, z_max_m=c.z_max_m, reach_m=c.check_m + c.robot_radius_m + 1.0)
        pose = self._pose_at(stamp_ns)
        if pose is not None and c.memory_s > 0:
            # one world-frame set: what is seen now, plus what was seen within memory_s where the
            # camera cannot look now (outside its view, or too near it to measure)
            seen_t = np.full(len(xy), stamp_ns, np.int64)
            if self._world and len(self._points):
                rel = to_robot(pose, self._points)
                keep = ((stamp_ns - self._points_t <= c.memory_s * 1e9)
                        & (np.hypot(rel[:, 0], rel[:, 1]) <= c.check_m + c.robot_radius_m + 1.0))
                unseen = unseen_mask(rel, camera_x_m=c.camera_x_m, half_fov_rad=self._half_fov, min_range_m=c.min_range_m)
                if seen_free is None:
                    keep &= unseen
                elif keep.any():
                    # in view by geometry is not enough to forget a point: its rays must have measured
                    # something. A walker who stepped up to 0.65 m of the robot centre turned their pixels
                    # into depth holes while the points last seen on them were 0.45 m from the camera, in
                    # view; dropped, the path looked clear, the guard released and the robot drove into
                    # them (hallway, t = 16.4 s). And a point goes only when rays through it reach the
                    # floor or a wall beyond it: a person who came within the camera's minimum range and
                    # walked on left a point there (hallway stood 3 s at a time before an empty spot).
                    keep &= unseen | ~seen_free[1](rel)
                    keep[keep] = ~seen_free[0](rel[keep])
                xy = np.vstack([xy, rel[keep]])
                seen_t = np.concatenate([seen_t, self._points_t[keep]])
            xy, first = thin_points(xy, 0.05, return_index=True)
            self._points, self._points_t, self._world = to_world(pose, xy), seen_t[first], True
        else:
            self._points, self._points_t, self._world = xy, np.full(len(xy), stamp_ns, np.int64), False
        self._points_ns = stamp_ns
        return self._emit(self._last, stamp_ns, resend=False)

    def on_rgbd(self, msg: RgbdFrame) -> list[tuple[str, object]]:
        i, c = msg.info, self.config
        depth = np.asarray(msg.depth_m)
        if depth.ndim != 2 or i.fx_px <= 0 or i.fy_px <= 0:
            self.log.error("RGB-D frame without depth or intrinsics: treated as blind")
            return self._sense(np.zeros((0, 3)), True, msg.stamp_ns)
        self._half_fov = float(np.arctan2(max(i.cx_px, i.width_px - 1 - i.cx_px) + 0.5, i.fx_px))
        pts, valid = depth_to_robot(depth, i.fx_px, i.fy_px, i.cx_px, i.cy_px, stride=max(1, c.stride_px),
                                    mount_xyz_m=(c.camera_x_m, c.camera_y_m, c.camera_z_m))
        self._rgbd = True
        mount = (c.camera_x_m, c.camera_y_m, c.camera_z_m)

        def seen_free(rel: np.ndarray) -> np.ndarray:
            return cleared_by_depth(rel, depth, i.fx_px, i.fy_px, i.cx_px, i.cy_px, mount_xyz_m=mount,
                                    z_min_m=c.z_min_m, z_max_m=c.z_max_m, max_range_m=c.depth_max_m)

        def measured(rel: np.ndarray) -> np.ndarray:
            return measured_through(rel, depth, i.fx_px, i.fy_px, i.cx_px, i.cy_px, mount_xyz_m=mount,
                                    z_min_m=c.z_min_m, z_max_m=c.z_max_m, max_range_m=c.depth_max_m)
        return self._sense(pts, valid < c.min_valid_fraction, msg.stamp_ns, (seen_free, measured))

    def on_points(self, msg: FlowPoints) -> list[tuple[str, object]]:
        pts = np.asarray(msg.points_m, dtype=np.float64).reshape(-1, 3)
        vel = np.asarray(msg.velocity_mps, dtype=np.float64).reshape(-1, 3)
        self._predict(pts, vel if len(vel) == len(pts) else np.zeros_like(pts), msg.stamp_ns)
        if self._rgbd:
            return self._emit(self._last, msg.stamp_ns, resend=False)   # the depth image is the geometry
        return self._sense(pts, False, msg.stamp_ns)

    def _predict(self, pts: np.ndarray, vel: np.ndarray, stamp_ns: int) -> None:
        """Where moving points (robot frame, with velocities) will be while the robot stops."""
        c = self.config
        horizon = min(c.predict_s, c.latency_s + c.v_max_mps / c.decel_mps2)
        ok = (np.isfinite(pts).all(axis=1) & np.isfinite(vel).all(axis=1) & (pts[:, 2] >= c.z_min_m)
              & (pts[:, 2] <= c.z_max_m))
        if horizon <= 0 or not ok.any():
            self._movers, self._movers_src = np.zeros((0, 2)), np.zeros(0, np.int64)
            return
        # cell_m > 0: each point moves with the median velocity of its grid cell, as in the planner's
        # prediction (nodes.nav.plan_geometry.predict_conflicts): dense flow is wrong on a few percent
        # of a person's pixels, and one such vector extrapolated alone put an obstacle on the robot's
        # path where nobody was going (hallway, t = 10.3 s: a point 0.3 m ahead from a walker passing
        # 0.9 m to the side). Off by default (cell_m 0): it also weakened the guard for DWA, which drives nearer people
        # (bench, one episode each: group closest 0.54 -> 0.02 m with 2 strict robot contacts, zara03
        # 0.41 -> 0.15 m); a safety layer may brake for a phantom but must not miss a person.
        xy, v = pts[ok, :2], vel[ok, :2]
        if c.cell_m > 0:
            v, _ = point_velocity(xy, v, c.cell_m)
        moving = np.hypot(v[:, 0], v[:, 1]) >= c.moving_mps
        taus = np.arange(0.1, horizon + 1e-9, 0.1)
        ahead = (xy[moving, None, :] + v[moving, None, :] * taus[None, :, None]).reshape(-1, 2)
        src = np.repeat(np.arange(int(moving.sum())), len(taus))
        near = np.hypot(ahead[:, 0], ahead[:, 1]) <= c.check_m + 1.0
        ahead, first = thin_points(ahead[near], 0.05, return_index=True)
        self._movers_src = src[near][first]
        pose = self._pose_at(stamp_ns)
        self._movers_world = pose is not None
        self._movers = to_world(pose, ahead) if pose is not None else ahead
        self._movers_ns = stamp_ns

    def obstacles_now(self) -> tuple[np.ndarray, float]:
        """Obstacle points (N, 2) in the robot frame now (seen, remembered and predicted), and the
        age (s) of the pose they were placed with."""
        points, age = self._seen_now()
        return np.vstack([points, self._predicted_now()]), age

    def _predicted_now(self) -> np.ndarray:
        """The moving points' extrapolated places (N, 2), robot frame now; none when the flow is stale."""
        if not len(self._movers) or (self.now_ns() - self._movers_ns) * 1e-9 > self.config.sensor_timeout_s:
            return np.zeros((0, 2))
        return to_robot(self._poses[-1][1], self._movers) if self._movers_world and self._poses else self._movers

    def _predicted_sources(self, predicted: np.ndarray, v: float, w: float) -> int:
        """How many flow points have a predicted place (``predicted``, as :meth:`_predicted_now`) on the (v, w) path."""
        c = self.config
        hit = conflicting(predicted, v, w, radius_m=c.robot_radius_m + c.margin_m, length_m=c.check_m)
        return len(np.unique(self._movers_src[hit])) if len(self._movers_src) == len(hit) else int(hit.sum())

    def _seen_now(self) -> tuple[np.ndarray, float]:
        now = self.now_ns()
        if not self._world or not self._poses:
            return self._points, max(now - self._points_ns, 0) * 1e-9
        stamp, pose = self._poses[-1]
        return to_robot(pose, self._points), max(now - stamp, 0) * 1e-9

    # -- commands -----------------------------------------------------------------------------
    def _stale(self, since_ns: int | None, timeout_s: float) -> bool:
        return since_ns is None or (self.now_ns() - since_ns) * 1e-9 > timeout_s

    def limit(self, v: float, w: float) -> tuple[float, float, str]:
        """The safe version of the command (v, w) and why it was changed ('' = unchanged)."""
        c = self.config
        if not (np.isfinite(v) and np.isfinite(w)):
            return 0.0, 0.0, "non-finite command"
        if self.blind:
            return 0.0, 0.0, "depth blind"
        if self._stale(self._sensor_ns, c.sensor_timeout_s):
            return 0.0, 0.0, "sensor silent"
        if v < 0 and not c.allow_reverse:
            return 0.0, w, "reverse refused (blind behind)"
        if v <= 0:
            return v, w, ""
        now = self.now_ns()
        seen, age_s = self._seen_now()
        predicted = self._predicted_now()
        radius = c.robot_radius_m + c.margin_m
        free, near = free_distance_m(seen, v, w, radius_m=radius, length_m=c.check_m)
        free_p, near_p = free_distance_m(predicted, v, w, radius_m=radius, length_m=c.check_m)
        if c.stop_along_path:       # how far along the path: travel to touching, plus the radius
            near = free + radius if np.isfinite(free) else near
            near_p = free_p + radius if np.isfinite(free_p) else near_p
        free = min(free, free_p)
        turn = w if c.allow_turn_in_place else 0.0
        if min(near, near_p) < c.stop_distance_m:
            self._obstacle_ns = now
            if near < c.stop_distance_m or self._predicted_sources(predicted, v, w) >= c.hold_min_points:
                self._hold_until_ns = now + int(c.release_s * 1e9)
                return 0.0, turn, f"obstacle at {min(near, near_p):.2f} m on the path"
            return 0.0, turn, f"obstacle predicted at {near_p:.2f} m on the path"
        if self._hold_until_ns is not None and now < self._hold_until_ns:
            return 0.0, turn, "waiting for the path to stay clear"
        cap = braking_speed_mps(free, decel_mps2=c.decel_mps2, latency_s=c.latency_s + age_s)
        if v > cap:
            return cap, w, f"slowed to {cap:.2f} m/s: {free:.2f} m free on the path"
        return v, w, ""

    def _emit(self, cmd: Twist2D, stamp_ns: int, *, resend: bool = True) -> list[tuple[str, object]]:
        v, w, reason = self.limit(cmd.vx_mps, cmd.wz_radps)
        stopped = v == 0.0 and cmd.vx_mps > 0 and reason.startswith(("obstacle", "depth", "sensor"))
        if stopped and not self._stopped:
            self.stops += 1
            self.log.info("stop: %s", reason)
        self._stopped = stopped
        if not resend and (self._cmd_ns is None or self._sent == (v, w)):
            return []          # a sensor frame re-sends the command only when it changes it
        out: list[tuple[str, object]] = []
        if reason:
            self.capped += reason.startswith("slowed")
            out.append(("status", PlanStatus(stamp_ns=stamp_ns, state="stopped" if v == 0.0 else "following",
                                             reason=reason)))
        self._sent = (v, w)
        out.append(("cmd", Twist2D(stamp_ns=stamp_ns, frame_id=cmd.frame_id or "base", vx_mps=float(v), wz_radps=float(w))))
        return out

    def on_cmd(self, msg: Twist2D) -> list[tuple[str, object]]:
        self._cmd_ns = self.now_ns()
        self._last = msg
        return self._emit(msg, msg.stamp_ns)

    def on_tick(self, msg: object) -> list[tuple[str, object]] | None:
        if self._cmd_ns is not None and self._stale(self._cmd_ns, self.config.cmd_timeout_s) and self._sent != (0.0, 0.0):
            self._last = Twist2D()
            self._sent = (0.0, 0.0)
            return [("status", PlanStatus(stamp_ns=self.now_ns(), state="stopped", reason="planner silent")),
                    ("cmd", Twist2D(stamp_ns=self.now_ns(), frame_id="base"))]
        return None

    def teardown(self) -> None:
        self.log.info("collision guard: %d stops, %d slowed commands, nearest obstacle last seen at %.2f m",
                      self.stops, self.capped, self.nearest_m)
