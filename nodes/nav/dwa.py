"""DWA baseline node: global path on the known map, Dynamic Window Approach on what the depth camera sees now.

The comparison planner of the paper (Sec. 6): a shortest-path local planner on current
obstacle positions (no crowd motion, no learnt cost). Obstacles are the depth camera's
points (floor excluded, thinned to one per 10 cm) placed in the world at the pose of the
frame, plus the known map's occupied cells near the robot (the camera's 57-ish degree
field of view would otherwise let it turn into walls it cannot see). It steers toward a
carrot ``lookahead_m`` along the global path and slows so that it stops on the goal.
With ``predict_s`` > 0 and an input ``points`` carrying velocities (the flow node's
``FlowPoints``), the moving points (``moving_mps`` and faster) also stand where they will be
over the next ``predict_s`` at constant velocity: the same prediction of people the collision
guard makes, so a comparison with the IRL planner measures the cost, not the prediction.
"""
from __future__ import annotations

from collections import deque

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Path2D, Twist2D
from msgs.nav import FlowPoints, Goal2D, PlanStatus
from msgs.sensor import Grid, RgbdFrame
from nodes.nav.dijkstra import GridGraph
from nodes.nav.grid_frame import GridFrame, extract_waypoint, inflate, plan_on_map, to_world
from nodes.nav.dwa_core import DwaParams, depth_to_robot, plan_dwa, thin_points
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    v_max_mps: float = 1.0
    w_max_radps: float = 1.2
    acc_v_mps2: float = 0.8
    acc_w_radps2: float = 2.5
    robot_radius_m: float = 0.35
    lookahead_m: float = 2.0
    map_range_m: float = 3.0
    camera_x_m: float = 0.3
    camera_y_m: float = 0.0
    camera_z_m: float = 1.0
    z_min_m: float = 0.1
    z_max_m: float = 2.0
    alpha: float = 0.6
    beta: float = 0.4
    gamma: float = 0.5
    predict_s: float = 0.0            # moving points are also obstacles where they will be this far ahead (0 = off)
    moving_mps: float = 0.3


class Dwa(Node):
    """Inputs ``odom``, ``goal``, ``map`` and ``rgbd`` and/or ``points``; outputs ``cmd``, ``path`` (predicted arc), ``status``."""

    Config = Config
    inputs = {"odom": Odometry2D, "goal": Goal2D, "map": Grid, "rgbd": RgbdFrame, "points": FlowPoints}
    outputs = {"cmd": Twist2D, "path": Path2D, "status": PlanStatus}

    def setup(self) -> None:
        c = self.config
        self.params = DwaParams(v_max_mps=c.v_max_mps, w_max_radps=c.w_max_radps, acc_v_mps2=c.acc_v_mps2,
                                acc_w_radps2=c.acc_w_radps2, robot_radius_m=c.robot_radius_m,
                                alpha=c.alpha, beta=c.beta, gamma=c.gamma)
        self.goal: tuple[float, float, float] | None = None
        self.global_path: np.ndarray | None = None
        self._occupied: np.ndarray | None = None
        self._map_frame: GridFrame | None = None
        self._map_xy = np.zeros((0, 2))
        self._seen = np.zeros((0, 2))
        self._poses: deque[tuple[int, tuple[float, float, float]]] = deque(maxlen=64)
        self._graph: GridGraph | None = None
        self._occupied_raw: np.ndarray | None = None
        self._sensed = False
        self._rgbd = False
        self._movers = np.zeros((0, 2))           # world frame: predicted positions of moving points

    def on_goal(self, msg: Goal2D) -> None:
        self.goal = (msg.x_m, msg.y_m, msg.tolerance_m)
        self.global_path = None

    def on_map(self, msg: Grid) -> None:
        data = np.asarray(msg.data)
        if data.ndim != 2 or data.size == 0 or abs(msg.origin_yaw_rad) > 1e-9:
            self.log.error("malformed or rotated map ignored")
            return
        frame = GridFrame(data.shape, msg.resolution_m, msg.origin_x_m, msg.origin_y_m)
        occupied = data > 0.5
        if self._map_frame == frame and self._occupied is not None and np.array_equal(self._occupied_raw, occupied):
            return
        self._occupied_raw = occupied
        self._map_frame = frame
        self._map_xy = frame.xy_of(np.argwhere(occupied))
        self._occupied = inflate(occupied, (self.config.robot_radius_m + 0.1) / frame.resolution_m)
        self._graph = GridGraph.of(data.shape)
        self.global_path = None

    def _pose_at(self, stamp_ns: int) -> tuple[float, float, float] | None:
        return min(self._poses, key=lambda sp: abs(sp[0] - stamp_ns))[1] if self._poses else None

    def _see(self, points_robot: np.ndarray, stamp_ns: int) -> None:
        pose = self._pose_at(stamp_ns)
        if pose is None:
            return
        c = self.config
        p = points_robot[(points_robot[:, 2] >= c.z_min_m) & (points_robot[:, 2] <= c.z_max_m)]
        self._seen = to_world(pose, thin_points(p[:, :2]))
        self._sensed = True

    def on_rgbd(self, msg: RgbdFrame) -> None:
        i, c = msg.info, self.config
        if np.asarray(msg.depth_m).ndim != 2 or i.fx_px <= 0:
            self.log.error("RGB-D frame without depth or intrinsics ignored")
            return
        pts, _ = depth_to_robot(np.asarray(msg.depth_m), i.fx_px, i.fy_px, i.cx_px, i.cy_px, stride=6,
                                mount_xyz_m=(c.camera_x_m, c.camera_y_m, c.camera_z_m))
        self._rgbd = True
        self._see(pts, msg.stamp_ns)

    def on_points(self, msg: FlowPoints) -> None:
        pts = np.asarray(msg.points_m, float).reshape(-1, 3)
        vel = np.asarray(msg.velocity_mps, float).reshape(-1, 3)
        ok = np.isfinite(pts).all(axis=1)
        if not self._rgbd:                     # the depth image is the geometry when there is one
            self._see(pts[ok], msg.stamp_ns)
        c = self.config
        pose = self._pose_at(msg.stamp_ns)
        if c.predict_s <= 0 or len(vel) != len(pts) or pose is None:
            return
        ok &= (np.isfinite(vel).all(axis=1) & (pts[:, 2] >= c.z_min_m) & (pts[:, 2] <= c.z_max_m)
               & (np.hypot(vel[:, 0], vel[:, 1]) >= c.moving_mps))
        taus = np.arange(0.1, c.predict_s + 1e-9, 0.1)
        ahead = (pts[ok, None, :2] + vel[ok, None, :2] * taus[None, :, None]).reshape(-1, 2)
        self._movers = to_world(pose, thin_points(ahead)) if len(ahead) else np.zeros((0, 2))

    def _carrot(self, pose: tuple[float, float, float]) -> tuple[np.ndarray, bool]:
        assert self.goal is not None
        if self.global_path is None or np.hypot(*(self.global_path - pose[:2]).T).min() > 1.5:
            if self._occupied is not None and self._map_frame is not None and self._graph is not None:
                path, res = plan_on_map(self._occupied, self._map_frame, pose[:2], self.goal[:2], graph=self._graph)
                self.global_path = path if res.reachable else np.array([pose[:2], self.goal[:2]])
            else:
                self.global_path = np.array([pose[:2], self.goal[:2]])
        i = int(np.argmin(np.hypot(*(self.global_path - pose[:2]).T)))
        carrot = extract_waypoint(self.global_path[i:], self.config.lookahead_m)
        return carrot, bool(np.allclose(carrot, self.goal[:2]))

    def on_odom(self, msg: Odometry2D) -> list[tuple[str, object]] | None:
        pose = (msg.pose.x_m, msg.pose.y_m, msg.pose.yaw_rad)
        if not np.all(np.isfinite(pose)):
            self.log.error("odometry with a non-finite pose dropped")
            return None
        self._poses.append((msg.stamp_ns, pose))
        stop = Twist2D(stamp_ns=msg.stamp_ns, frame_id="base")
        if self.goal is None:
            return None         # no goal yet: say nothing, the robot waits
        dist = float(np.hypot(self.goal[0] - pose[0], self.goal[1] - pose[1]))
        if dist <= self.goal[2]:
            return [("cmd", stop), ("status", PlanStatus(stamp_ns=msg.stamp_ns, state="reached"))]
        if not self._sensed:
            return None         # nothing seen yet: the robot waits
        carrot, final = self._carrot(pose)
        near = self._map_xy[np.hypot(*(self._map_xy - pose[:2]).T) <= self.config.map_range_m] if len(self._map_xy) else self._map_xy
        obstacles = np.vstack([self._seen, near, self._movers])
        v_cap = np.sqrt(2 * self.params.acc_v_mps2 * max(dist - 0.5 * self.goal[2], 0.0)) if final else None
        r = plan_dwa(np.array(pose), (msg.twist.vx_mps, msg.twist.wz_radps), carrot, obstacles, self.params,
                     v_limit_mps=v_cap)
        out: list[tuple[str, object]] = [
            ("cmd", Twist2D(stamp_ns=msg.stamp_ns, frame_id="base", vx_mps=r.v_mps, wz_radps=r.w_radps)),
            ("path", Path2D(stamp_ns=msg.stamp_ns, frame_id="world", poses=r.trajectory))]
        if r.reason:
            out.append(("status", PlanStatus(stamp_ns=msg.stamp_ns, state="stopped", reason=r.reason)))
        return out
