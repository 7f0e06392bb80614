"""Three-layer social planner node: messages <-> :class:`nodes.nav.social_planner.SocialPlanner`.

The planning itself (global path, Algorithm 2's local Dijkstra on the IRL cost, waypoints,
re-plan events) is the pure module :mod:`nodes.nav.social_planner`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import fields

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Path2D, Twist2D
from msgs.nav import CostGrid, FeatureGrid, FlowPoints, Goal2D, PlanStatus
from msgs.sensor import Grid
from nodes.nav.features import CONFLICT
from nodes.nav.grid_frame import GridFrame
from nodes.nav.irl_cost import load_weights
from nodes.nav.plan_geometry import predict_conflicts
from nodes.nav.social_planner import PlannerParams, SocialPlanner
from tether import Node


_DEFAULT = PlannerParams()


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    safe_zone_m: float = _DEFAULT.safe_zone_m
    obstacle_radius_m: float = _DEFAULT.obstacle_radius_m
    subgoal_m: float = _DEFAULT.subgoal_m
    waypoint_m: float = _DEFAULT.waypoint_m
    waypoint_min_m: float = _DEFAULT.waypoint_min_m
    corner_people_only: bool = _DEFAULT.corner_people_only
    waypoint_timeout_s: float = _DEFAULT.waypoint_timeout_s
    stray_m: float = _DEFAULT.stray_m
    robot_radius_m: float = _DEFAULT.robot_radius_m
    inflate_margin_m: float = _DEFAULT.inflate_margin_m
    v_max_mps: float = _DEFAULT.v_max_mps
    w_max_radps: float = _DEFAULT.w_max_radps
    crowd_margin_m: float = _DEFAULT.crowd_margin_m
    person_cost: float = _DEFAULT.person_cost
    commitment: float = _DEFAULT.commitment
    replan_margin_m: float = _DEFAULT.replan_margin_m
    side_hold_m: float = _DEFAULT.side_hold_m
    side_near_m: float = _DEFAULT.side_near_m
    side_ray_m: float = _DEFAULT.side_ray_m
    side_motion: bool = _DEFAULT.side_motion
    turn_near_radps: float = _DEFAULT.turn_near_radps
    turn_near_m: float = _DEFAULT.turn_near_m
    memory_s: float = _DEFAULT.memory_s
    predict_s: float = 2.0        # 0 = plan on the features alone (no flow input needed)
    fov_deg: float = _DEFAULT.fov_deg
    camera_x_m: float = _DEFAULT.camera_x_m
    min_range_m: float = _DEFAULT.min_range_m
    conflict_price: float = -1.0  # the speed profile's price of a conflict; < 0: the weights file's 'conflict' weight
    weights_path: str = ""        # the IRL cost's weights file ("" = the shipped default; as IrlCost's)
    speed_horizon_s: float = _DEFAULT.speed_horizon_s   # 0 = no speed profile (steering's speed only)
    headway_s: float = _DEFAULT.headway_s
    accel_mps2: float = _DEFAULT.accel_mps2
    people_timeout_s: float = _DEFAULT.people_timeout_s
    density_feature: str = "density_high"   # the FeatureGrid feature that flags an obstacle (Algorithm 2)
    density_index: int = 0                  # used when the grid carries no feature names


def conflict_weight(weights_path: str = "") -> float:
    """The learnt cost's price of a conflict cell (its 'conflict' weight) in a weights file ("" = the shipped one);
    0 when the file has no such feature (the speed profile is then off)."""
    w = load_weights(weights_path)
    return float(w.weights[list(w.names).index(CONFLICT)]) if CONFLICT in w.names else 0.0


def high_density_mask(grid: FeatureGrid, name: str, index: int) -> np.ndarray:
    """(rows, cols) bool: cells whose ``name`` feature (or column ``index`` if unnamed) is set."""
    f = np.asarray(grid.features)
    if f.ndim != 3 or f.shape[2] == 0:
        return np.zeros(f.shape[:2] if f.ndim >= 2 else (0, 0), bool)
    k = list(grid.names).index(name) if name in grid.names else index
    if not 0 <= k < f.shape[2]:
        raise ValueError(f"feature {name!r} / index {index} not in a grid of {f.shape[2]} features {list(grid.names)}")
    return f[..., k] > 0


class DijkstraPlanner(Node):
    """Inputs ``odom``, ``goal``, ``map`` (occupancy, world), ``features`` and ``costs`` (robot frame),
    optionally ``flow`` (moving points: their predicted positions join the cost, ``predict_s``).

    Outputs ``cmd`` (velocity toward the waypoint, on every odom and decision, from the first decision on), ``path`` (the path being
    followed, world frame) and ``status`` (mode, re-plan event, plan time) on every cost grid.
    """

    Config = Config
    inputs = {"odom": Odometry2D, "goal": Goal2D, "map": Grid, "features": FeatureGrid, "costs": CostGrid,
              "flow": FlowPoints}
    outputs = {"cmd": Twist2D, "path": Path2D, "status": PlanStatus}

    def setup(self) -> None:
        c = self.config
        params = {f.name: getattr(c, f.name) for f in fields(PlannerParams)}
        if c.conflict_price < 0:
            params["conflict_price"] = conflict_weight(c.weights_path)
        self.planner = SocialPlanner(PlannerParams(**params))
        self._v_now = 0.0
        self._poses: deque[tuple[int, tuple[float, float, float]]] = deque(maxlen=64)
        self._high: np.ndarray | None = None
        self._map: np.ndarray | None = None
        self._flow: FlowPoints | None = None
        self.bad_inputs = 0

    def _pose_at(self, stamp_ns: int) -> tuple[float, float, float] | None:
        if not self._poses:
            return None
        return min(self._poses, key=lambda sp: abs(sp[0] - stamp_ns))[1]

    def on_odom(self, msg: Odometry2D) -> dict[str, Twist2D] | None:
        pose = (msg.pose.x_m, msg.pose.y_m, msg.pose.yaw_rad)
        if not np.all(np.isfinite(pose)):
            self.bad_inputs += 1
            self.log.error("odometry with a non-finite pose dropped (%d so far)", self.bad_inputs)
            return None
        self._poses.append((msg.stamp_ns, pose))
        self._v_now = float(msg.twist.vx_mps) if np.isfinite(msg.twist.vx_mps) else 0.0
        if self.planner.mode == "idle":
            return None         # nothing decided yet (no goal or no cost grid): say nothing, the robot waits
        v, w = self.planner.command(pose, msg.stamp_ns * 1e-9, self._v_now)
        return {"cmd": Twist2D(stamp_ns=msg.stamp_ns, frame_id="base", vx_mps=v, wz_radps=w)}

    def on_goal(self, msg: Goal2D) -> None:
        self.planner.set_goal((msg.x_m, msg.y_m), msg.tolerance_m)

    def on_map(self, msg: Grid) -> None:
        if abs(msg.origin_yaw_rad) > 1e-9:
            self.log.error("map with a rotated origin is not supported; ignored")
            return
        data = np.asarray(msg.data)
        if data.ndim != 2 or data.size == 0 or not msg.resolution_m > 0:
            self.log.error("empty or malformed map ignored (shape %s)", data.shape)
            return
        frame = GridFrame(data.shape, msg.resolution_m, msg.origin_x_m, msg.origin_y_m)
        if self.planner.map_frame != frame or not np.array_equal(self._map, data):   # maps are re-sent periodically
            self._map = data.copy()
            self.planner.set_map(data, frame)

    def on_flow(self, msg: FlowPoints) -> None:
        self._flow = msg
        pose = self._pose_at(msg.stamp_ns)
        if pose is not None and len(msg.points_m) == len(msg.velocity_mps):
            self.planner.set_people(pose, msg.points_m, msg.velocity_mps, msg.stamp_ns * 1e-9)

    def on_features(self, msg: FeatureGrid) -> None:
        self._high = high_density_mask(msg, self.config.density_feature, self.config.density_index)

    def on_costs(self, msg: CostGrid) -> list[tuple[str, object]] | None:
        pose = self._pose_at(msg.stamp_ns)
        cost = np.asarray(msg.cost, dtype=np.float64)
        if pose is None or cost.ndim != 2 or cost.size == 0:
            return None
        if np.isnan(cost).any() or (cost <= 0).any():
            self.bad_inputs += 1
            self.log.error("cost grid with NaN or non-positive cells dropped (%d so far)", self.bad_inputs)
            return None
        frame = GridFrame(cost.shape, msg.resolution_m, msg.origin_x_m, msg.origin_y_m)
        high = self._high if self._high is not None and self._high.shape == cost.shape else np.zeros(cost.shape, bool)
        predicted = None
        if self._flow is not None and self.config.predict_s > 0 and abs(self._flow.stamp_ns - msg.stamp_ns) < 0.3e9:
            predicted = predict_conflicts(self._flow.points_m, self._flow.velocity_mps, frame,
                                          robot_speed_mps=self.config.v_max_mps, horizon_s=self.config.predict_s)
        d = self.planner.update(pose, cost, frame, high, msg.stamp_ns * 1e-9, predicted)
        status = PlanStatus(stamp_ns=msg.stamp_ns, state=_STATE[d.mode] if d.event or d.mode != "local" else "following",
                            reason="/".join(x for x in (d.mode, d.event, d.reason) if x), plan_ms=d.plan_ms)
        stamp, now = self._poses[-1]
        v, w = self.planner.command(now, stamp * 1e-9, self._v_now)       # steer on the fresh decision right away
        out: list[tuple[str, object]] = [("status", status),
                                         ("cmd", Twist2D(stamp_ns=msg.stamp_ns, frame_id="base", vx_mps=v, wz_radps=w))]
        if len(d.path_xy) >= 2:
            step = np.diff(d.path_xy, axis=0)
            yaw = np.arctan2(step[:, 1], step[:, 0])
            poses = np.column_stack([d.path_xy, np.append(yaw, yaw[-1])])
            out.append(("path", Path2D(stamp_ns=msg.stamp_ns, frame_id="world", poses=poses)))
        return out


#: planner mode -> PlanStatus.state
_STATE = {"idle": "planning", "global": "following", "local": "replanned", "hold": "stopped",
          "reached": "reached", "unreachable": "unreachable"}
