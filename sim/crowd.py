"""Crowd simulator: pedestrians (social force, straight lines or real ETH/UCY replay), a wheelchair robot and its RGB-D camera.

In-process API (no sockets; what ``bench/social_nav.py`` drives)::

    from sim.crowd import CrowdWorld, RobotLimits
    from sim.crowd_render import CameraModel
    world = CrowdWorld("toward")                 # bundled name, YAML path, dict or Scene
    world.step(v_mps=0.6, w_radps=0.0, dt_s=1/15)   # advance; commands are clipped to the limits
    rgb, depth = world.render()                 # (480, 640, 3) uint8 RGB, (480, 640) float32 m, 0 = no return
    world.pose, world.twist                     # (x_m, y_m, yaw_rad) world frame; (v_mps, w_radps) body frame
    peds = world.pedestrians()                  # PedestrianState: ids (N,), xy_m (N, 2), vel_mps (N, 2), radius_m (N,)
    world.goal, world.goal_reached              # (x_m, y_m, tolerance_m) of the scene; bool
    world.collisions, world.blocked_steps       # pedestrian contacts (counted once per contact); steps stopped by a wall
    world.contacts                              # ContactEvent per contact: who closed the gap (see below)
    world.goal_t_s                              # sim time the goal was first reached (None before)
    world.min_clearance_m                       # smallest centre-to-centre robot-pedestrian distance so far
    world.occupancy(0.1)                        # OccupancyGrid of walls and obstacles (rows = y, cols = x)
    world.t_s, world.scene.duration_s

A closed loop in-process (sim -> perception -> planner -> sim), as ``bench/social_nav.py`` runs it::

    from nodes.nav.flow import FlowTracker, Intrinsics, Mount
    from nodes.nav.features import GridSpec, extract_features, goal_in_robot_frame
    cam = world.camera
    intr = Intrinsics(cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px)
    tracker = FlowTracker(Mount(cam.x_m, cam.y_m, cam.z_m))          # what nodes.nav.rgbd_flow runs
    while world.t_s < world.scene.duration_s and not world.goal_reached:
        rgb, depth = world.render()
        sf = tracker.update(world.t_s, rgb, depth, intr, world.pose)   # None on the first frame
        if sf is not None:
            feats = extract_features(sf.points_m, sf.velocity_mps,
                                     goal_in_robot_frame(world.goal[:2], world.pose), GridSpec()).features
            v, w = ...                                                # your planner on feats (robot frame)
        world.step(v, w, 1 / 15)

The robot is a unicycle: speed and yaw rate follow the commands within acceleration
limits; a step that would put its disc (``radius_m``) into a wall or obstacle is refused
(the robot stops there). Pedestrian contact is counted, not prevented, and attributed: at the
onset of a contact the robot's own speed toward the pedestrian is compared with the
pedestrian's speed toward the robot (:class:`ContactEvent`); ``by_robot`` means the robot was
driving into the person (faster than ``robot_fault_mps`` and at least half as fast as the person
closed in, :func:`robot_drove_in`), otherwise the person walked into a robot that was stopped,
braking or moving away. Simulated
pedestrians avoid the robot only when the scene says ``pedestrians_see_robot: true``;
replayed pedestrians never react (they are recordings).

Node ``sim.crowd:CrowdSim``: input ``cmd`` (geometry.Twist2D; a watchdog stops the robot
when commands stop for ``watchdog_s``). The world holds still (pedestrians too) until the
first command arrives, for at most ``wait_for_cmd_s``: in a launched pipeline the planner's
processes start in their own time, and a scenario's timing must not depend on that; outputs ``rgbd`` (sensor.RgbdFrame, frame
``camera``: x right, y down, z forward, mounted ``camera_x_m`` ahead of the robot centre at
``camera_z_m`` height), ``odom`` (geometry.Odometry2D, pose in ``world``, twist in the
body frame), ``pedestrians`` (nav.Pedestrians, ground truth, ``world``), ``goal``
(nav.Goal2D) and ``map`` (sensor.Grid occupancy 0/1), both published at start and every
``map_period_s``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.nav import Goal2D, Pedestrians
from msgs.sensor import CameraInfo, Grid, RgbdFrame
from sim.crowd_render import CameraModel, Renderer
from sim.crowd_scenes import OccupancyGrid, Scene, Walkers, load_scene, occupancy_grid, segment_distances
from tether import Input, Node


@dataclass(frozen=True)
class RobotLimits:
    """Wheelchair-like unicycle limits (SI units)."""

    max_speed_mps: float = 1.0
    min_speed_mps: float = -0.3
    max_yaw_rate_radps: float = 1.2
    max_accel_mps2: float = 0.8
    max_yaw_accel_radps2: float = 2.5
    radius_m: float = 0.35


@dataclass(frozen=True)
class ContactEvent:
    """Onset of a robot-pedestrian contact: sim time, pedestrian id, centre distance (m), and the
    closing speeds (m/s) of the robot toward the pedestrian and of the pedestrian toward the robot."""

    t_s: float
    ped_id: int
    distance_m: float
    robot_closing_mps: float
    ped_closing_mps: float
    by_robot: bool


@dataclass(frozen=True)
class PedestrianState:
    """Pedestrians present now (world frame): ids (N,), xy_m (N, 2), vel_mps (N, 2), radius_m (N,), height_m (N,)."""

    ids: np.ndarray
    xy_m: np.ndarray
    vel_mps: np.ndarray
    radius_m: np.ndarray
    height_m: np.ndarray


def robot_drove_in(robot_closing_mps: float, ped_closing_mps: float, fault_mps: float = 0.1) -> bool:
    """Attribute a contact: the robot drove into the person when, at the onset, it was closing the
    gap faster than ``fault_mps`` and at least half as fast as the person was. Head-on at walking
    pace, or into someone standing, is the robot's doing; a robot nearly stopped (still braking)
    that someone walks into at full pace is not."""
    return bool(robot_closing_mps > fault_mps and robot_closing_mps >= 0.5 * ped_closing_mps)


def _approach(value: float, target: float, max_delta: float) -> float:
    return value + float(np.clip(target - value, -max_delta, max_delta))


def unicycle_step(pose: tuple[float, float, float], twist: tuple[float, float], cmd: tuple[float, float],
                  dt_s: float, limits: RobotLimits) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """One step: velocities move toward the clipped command within the acceleration limits, then integrate.

    Integration is exact for a constant (v, w) over the step (an arc; a line when w = 0).
    Returns the new pose (x_m, y_m, yaw_rad) and twist (v_mps, w_radps).
    """
    v_cmd = float(np.clip(cmd[0], limits.min_speed_mps, limits.max_speed_mps))
    w_cmd = float(np.clip(cmd[1], -limits.max_yaw_rate_radps, limits.max_yaw_rate_radps))
    v = _approach(twist[0], v_cmd, limits.max_accel_mps2 * dt_s)
    w = _approach(twist[1], w_cmd, limits.max_yaw_accel_radps2 * dt_s)
    x, y, yaw = pose
    if abs(w) < 1e-9:
        x, y = x + v * dt_s * np.cos(yaw), y + v * dt_s * np.sin(yaw)
    else:
        x += v / w * (np.sin(yaw + w * dt_s) - np.sin(yaw))
        y -= v / w * (np.cos(yaw + w * dt_s) - np.cos(yaw))
    yaw = float(np.arctan2(np.sin(yaw + w * dt_s), np.cos(yaw + w * dt_s)))
    return (float(x), float(y), yaw), (v, w)


class CrowdWorld:
    """Scene + pedestrians + robot + camera, stepped by hand (see the module docstring)."""

    def __init__(self, scene: Scene | str | Path | Mapping[str, Any], *, camera: CameraModel = CameraModel(),
                 limits: RobotLimits = RobotLimits(), tracks: Any = None, max_substep_s: float = 0.05,
                 robot_fault_mps: float = 0.1) -> None:
        self.robot_fault_mps = float(robot_fault_mps)
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self.camera = camera
        self.limits = limits
        self.max_substep_s = float(max_substep_s)
        self.walkers = Walkers(self.scene, tracks=tracks)
        obstacle = np.zeros(len(self.scene.segments), bool)
        obstacle[len(self.scene.segments) - 4 * len(self.scene.polygons):] = True    # box faces come last
        self.renderer = Renderer(self.scene.segments, self.scene.segment_heights_m, self.scene.cylinders,
                                 self.scene.cylinder_heights_m, obstacle=obstacle, camera=camera)
        self.reset()

    def reset(self) -> None:
        """Back to t = 0: robot at the scene's start, pedestrians at their first positions."""
        self.t_s = 0.0
        self.pose: tuple[float, float, float] = self.scene.robot_start
        self.twist: tuple[float, float] = (0.0, 0.0)
        self.collisions = 0
        self.blocked_steps = 0
        self.min_clearance_m = float("inf")
        self.contacts: list[ContactEvent] = []
        self.goal_t_s: float | None = None
        self._in_contact: set[int] = set()
        self.walkers.reset()
        self._update_contacts()

    @property
    def goal(self) -> tuple[float, float, float]:
        return self.scene.goal

    @property
    def goal_reached(self) -> bool:
        gx, gy, tol = self.scene.goal
        return bool(np.hypot(self.pose[0] - gx, self.pose[1] - gy) <= tol)

    def step(self, v_mps: float, w_radps: float, dt_s: float) -> None:
        """Advance ``dt_s`` seconds with the command (v, w) held; sub-steps of at most ``max_substep_s``."""
        if not np.isfinite(v_mps) or not np.isfinite(w_radps):
            raise ValueError(f"command must be finite, got v={v_mps}, w={w_radps}")
        if dt_s < 0 or not np.isfinite(dt_s):
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        n = max(1, int(np.ceil(dt_s / self.max_substep_s)))
        for _ in range(n):
            self._substep((v_mps, w_radps), dt_s / n)

    def _substep(self, cmd: tuple[float, float], dt: float) -> None:
        pose, twist = unicycle_step(self.pose, self.twist, cmd, dt, self.limits)
        if self._hits_static(pose[:2]) and not self._hits_static(self.pose[:2]):
            self.blocked_steps += 1
            twist = (0.0, 0.0)
            pose = (self.pose[0], self.pose[1], self.pose[2])
        self.pose, self.twist = pose, twist
        robot = (self.pose[0], self.pose[1], self.twist[0] * np.cos(self.pose[2]),
                 self.twist[0] * np.sin(self.pose[2]), self.limits.radius_m)
        self.walkers.keep_clear = (self.pose[0], self.pose[1], self.limits.radius_m)
        self.walkers.step(self.t_s, dt, robot if self.scene.pedestrians_see_robot else None)
        self.t_s += dt
        self._update_contacts()
        if self.goal_t_s is None and self.goal_reached:
            self.goal_t_s = self.t_s

    def advance_crowd(self, dt_s: float, step_s: float = 0.05) -> None:
        """Let the pedestrians walk ``dt_s`` seconds while the robot is not there yet (nobody sees it,
        no contact counts); the robot then appears at its pose. How an episode starts once the
        robot's start is clear of everyone's path (``bench/social_nav.py``: ``clear_start_s``)."""
        n = max(1, int(np.ceil(max(dt_s, 0.0) / step_s)))
        self.walkers.keep_clear = None
        for _ in range(n if dt_s > 0 else 0):
            self.walkers.step(self.t_s, dt_s / n, None)
            self.t_s += dt_s / n
        self._in_contact = set()
        self._update_contacts()

    def _hits_static(self, xy: tuple[float, float]) -> bool:
        p = np.asarray(xy, float)[None, :]
        r = self.limits.radius_m
        if len(self.scene.segments) and segment_distances(p, self.scene.segments).min() < r:
            return True
        for poly in self.scene.polygons:      # fully inside a box
            if _inside_convex(p[0], poly):
                return True
        cyl = self.scene.cylinders
        return bool(len(cyl) and (np.hypot(cyl[:, 0] - p[0, 0], cyl[:, 1] - p[0, 1]) - cyl[:, 2]).min() < r)

    def _update_contacts(self) -> None:
        peds = self.pedestrians()
        if not len(peds.ids):
            self._in_contact = set()
            return
        dist = np.hypot(peds.xy_m[:, 0] - self.pose[0], peds.xy_m[:, 1] - self.pose[1])
        self.min_clearance_m = min(self.min_clearance_m, float(dist.min()))
        touch = dist < peds.radius_m + self.limits.radius_m
        touching = {int(i) for i in peds.ids[touch]}
        new = touching - self._in_contact
        self.collisions += len(new)
        self._in_contact = touching
        if new:
            x, y, yaw = self.pose
            v_robot = self.twist[0] * np.array([np.cos(yaw), np.sin(yaw)])
            for k in np.flatnonzero(touch):
                if int(peds.ids[k]) not in new:
                    continue
                u = (peds.xy_m[k] - (x, y)) / max(dist[k], 1e-9)          # robot -> pedestrian
                robot_mps, ped_mps = float(v_robot @ u), float(-peds.vel_mps[k] @ u)
                self.contacts.append(ContactEvent(self.t_s, int(peds.ids[k]), float(dist[k]), robot_mps, ped_mps,
                                                  robot_drove_in(robot_mps, ped_mps, self.robot_fault_mps)))

    @property
    def collisions_by_robot(self) -> int:
        """Contacts where the robot drove into the pedestrian (see :class:`ContactEvent`)."""
        return sum(c.by_robot for c in self.contacts)

    def pedestrians(self) -> PedestrianState:
        """Pedestrians present at ``t_s`` (world frame)."""
        return PedestrianState(*self.walkers.state())

    def render(self) -> tuple[np.ndarray, np.ndarray]:
        """Colour (H, W, 3) uint8 RGB and depth (H, W) float32 m from the robot's camera now."""
        peds = self.pedestrians()
        return self.renderer.render(self.pose, peds.xy_m, peds.ids, peds.radius_m, peds.height_m)

    def occupancy(self, resolution_m: float = 0.1) -> OccupancyGrid:
        """Static occupancy grid of the scene (pedestrians excluded)."""
        return occupancy_grid(self.scene, resolution_m)


def _inside_convex(p: np.ndarray, poly: np.ndarray) -> bool:
    e = np.roll(poly, -1, axis=0) - poly
    rel = p - poly
    cross = e[:, 0] * rel[:, 1] - e[:, 1] * rel[:, 0]
    return bool(np.all(cross >= 0) or np.all(cross <= 0))


def add_depth_noise(depth: np.ndarray, rng: np.random.Generator, *, noise_per_m2: float = 0.0,
                    dropout: float = 0.0) -> np.ndarray:
    """Kinect-like depth noise: sigma = ``noise_per_m2`` * z^2 (m), and a ``dropout`` fraction of holes (0)."""
    out = depth
    if noise_per_m2 > 0:
        out = out + (rng.standard_normal(depth.shape, np.float32) * np.float32(noise_per_m2)) * out * out
    if dropout > 0:
        out = np.where(rng.random(depth.shape, np.float32) < dropout, np.float32(0), out)
    return out.astype(np.float32, copy=False)


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    scene: str = "toward"              # bundled name (sim/scenes/crowd_<name>.yaml) or a YAML path
    rate_hz: float = 30.0              # physics; odom and pedestrians are published at this rate
    camera_hz: float = 15.0
    map_period_s: float = 2.0          # map and goal are re-published this often (late subscribers)
    map_resolution_m: float = 0.1
    watchdog_s: float = 0.5            # no cmd for this long -> the robot brakes to a stop
    wait_for_cmd_s: float = 10.0       # the world holds still until the first cmd, at most this long (0 = start at once)
    max_step_s: float = 1.0            # a clock jump longer than this is not simulated (logged)
    max_speed_mps: float = 1.0
    min_speed_mps: float = -0.3
    max_yaw_rate_radps: float = 1.2
    max_accel_mps2: float = 0.8
    max_yaw_accel_radps2: float = 2.5
    robot_radius_m: float = 0.35
    width_px: int = 640
    height_px: int = 480
    fx_px: float = 525.0
    fy_px: float = 525.0
    cx_px: float = -1.0                # < 0: image centre
    cy_px: float = -1.0
    camera_x_m: float = 0.3
    camera_z_m: float = 1.0
    min_range_m: float = 0.4
    max_range_m: float = 8.0
    depth_noise_per_m2: float = 0.0    # Kinect-like sigma = k z^2
    depth_dropout: float = 0.0         # fraction of depth pixels reported as 0
    seed: int = 0
    world_frame: str = "world"


def camera_from_config(cfg: Any) -> CameraModel:
    """The :class:`CameraModel` a ``Config`` describes (negative principal point = image centre)."""
    cx = cfg.cx_px if cfg.cx_px >= 0 else (cfg.width_px - 1) / 2.0
    cy = cfg.cy_px if cfg.cy_px >= 0 else (cfg.height_px - 1) / 2.0
    return CameraModel(width_px=cfg.width_px, height_px=cfg.height_px, fx_px=cfg.fx_px, fy_px=cfg.fy_px,
                       cx_px=cx, cy_px=cy, x_m=cfg.camera_x_m, z_m=cfg.camera_z_m,
                       min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m)


class CrowdSim(Node):
    """Crowd simulator node: input ``cmd``; outputs ``rgbd``, ``odom``, ``pedestrians``, ``goal``, ``map``."""

    Config = Config
    inputs = {"cmd": Input(Twist2D, depth=1, latest=True)}
    outputs = {"rgbd": RgbdFrame, "odom": Odometry2D, "pedestrians": Pedestrians, "goal": Goal2D, "map": Grid}
    timers = {"tick": "rate_hz", "camera": "camera_hz"}

    def setup(self) -> None:
        cfg = self.config
        limits = RobotLimits(cfg.max_speed_mps, cfg.min_speed_mps, cfg.max_yaw_rate_radps, cfg.max_accel_mps2,
                             cfg.max_yaw_accel_radps2, cfg.robot_radius_m)
        self.world = CrowdWorld(cfg.scene, camera=camera_from_config(cfg), limits=limits)
        cam = self.world.camera
        self._info = CameraInfo(width_px=cam.width_px, height_px=cam.height_px, fx_px=cam.fx_px, fy_px=cam.fy_px,
                                cx_px=cam.cx_px, cy_px=cam.cy_px)
        grid = self.world.occupancy(cfg.map_resolution_m)
        self._map = Grid(data=grid.data, resolution_m=grid.resolution_m, origin_x_m=grid.origin_x_m,
                         origin_y_m=grid.origin_y_m, frame_id=cfg.world_frame)
        self._rng = np.random.default_rng(cfg.seed)
        self._t0_ns: int | None = None
        self._cmd = (0.0, 0.0)
        self._cmd_ns: int | None = None
        self._next_map_ns = 0
        self._stopped_by_watchdog = False
        self._first_ns: int | None = None
        self._started = cfg.wait_for_cmd_s <= 0

    def on_cmd(self, msg: Twist2D) -> None:
        if not (np.isfinite(msg.vx_mps) and np.isfinite(msg.wz_radps)):
            self.log.error("dropped a non-finite cmd (vx=%s, wz=%s)", msg.vx_mps, msg.wz_radps)
            return
        self._cmd, self._cmd_ns = (float(msg.vx_mps), float(msg.wz_radps)), self.now_ns()

    def _advance(self, now_ns: int) -> None:
        if not self._started:
            self._first_ns = now_ns if self._first_ns is None else self._first_ns
            if self._cmd_ns is None and now_ns - self._first_ns < self.config.wait_for_cmd_s * 1e9:
                return
            self._started = True
            if self._cmd_ns is None:
                self.log.warning("no cmd within %.1f s: starting the world anyway", self.config.wait_for_cmd_s)
            else:
                self.log.info("first cmd after %.2f s: the world clock starts", (now_ns - self._first_ns) / 1e9)
        if self._t0_ns is None:
            self._t0_ns = now_ns - int(round(self.world.t_s * 1e9))
        dt = (now_ns - self._t0_ns) / 1e9 - self.world.t_s
        if dt > self.config.max_step_s:
            self.log.warning("clock jumped %.2f s; simulating only %.2f s", dt, self.config.max_step_s)
            self._t0_ns += int(round((dt - self.config.max_step_s) * 1e9))
            dt = self.config.max_step_s
        if dt <= 0:
            return
        fresh = self._cmd_ns is not None and now_ns - self._cmd_ns <= self.config.watchdog_s * 1e9
        if not fresh and self._cmd_ns is not None and not self._stopped_by_watchdog:
            self.log.warning("no cmd for %.2f s: stopping the robot", self.config.watchdog_s)
        self._stopped_by_watchdog = not fresh and self._cmd_ns is not None
        self.world.step(*(self._cmd if fresh else (0.0, 0.0)), dt)

    def _odom(self, now_ns: int) -> Odometry2D:
        (x, y, yaw), (v, w) = self.world.pose, self.world.twist
        return Odometry2D(stamp_ns=now_ns, frame_id=self.config.world_frame,
                          pose=Pose2D(x_m=x, y_m=y, yaw_rad=yaw), twist=Twist2D(vx_mps=v, wz_radps=w))

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        now = self.now_ns()
        self._advance(now)
        peds = self.world.pedestrians()
        out: list[tuple[str, Any]] = [
            ("odom", self._odom(now)),
            ("pedestrians", Pedestrians(stamp_ns=now, frame_id=self.config.world_frame, ids=peds.ids,
                                        positions_m=peds.xy_m, velocities_mps=peds.vel_mps,
                                        radius_m=float(peds.radius_m.mean()) if len(peds.ids) else 0.3))]
        if now >= self._next_map_ns:
            self._next_map_ns = now + int(self.config.map_period_s * 1e9)
            gx, gy, tol = self.world.goal
            out.append(("map", msgspec.structs.replace(self._map, stamp_ns=now)))
            out.append(("goal", Goal2D(stamp_ns=now, frame_id=self.config.world_frame, x_m=gx, y_m=gy,
                                       tolerance_m=tol)))
        return out

    def on_camera(self, tick: Any) -> list[tuple[str, Any]]:
        now = self.now_ns()
        self._advance(now)
        rgb, depth = self.world.render()
        if self.config.depth_noise_per_m2 > 0 or self.config.depth_dropout > 0:
            depth = add_depth_noise(depth, self._rng, noise_per_m2=self.config.depth_noise_per_m2,
                                    dropout=self.config.depth_dropout)
        frame = RgbdFrame(stamp_ns=now, frame_id="camera", rgb=rgb, depth_m=depth, info=self._info)
        return [("odom", self._odom(now)), ("rgbd", frame)]

    def teardown(self) -> None:
        w = self.world
        goal = "never" if w.goal_t_s is None else f"at {w.goal_t_s:.2f} s"
        self.log.info("crowd sim '%s' t=%.1f s: goal reached %s, collisions=%d (robot drove into %d), blocked steps=%d, "
                      "min clearance=%.2f m", w.scene.name, w.t_s, goal, w.collisions, w.collisions_by_robot,
                      w.blocked_steps, w.min_clearance_m)
        for c in w.contacts:
            self.log.info("contact t=%.2f s with %d at %.2f m: robot closing %.2f m/s, pedestrian closing %.2f m/s (%s)",
                          c.t_s, c.ped_id, c.distance_m, c.robot_closing_mps, c.ped_closing_mps,
                          "robot drove in" if c.by_robot else "pedestrian walked in")
