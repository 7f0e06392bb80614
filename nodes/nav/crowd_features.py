"""Crowd features node: scene flow + goal + odometry -> 12-dim binary features per local grid cell (nav.FeatureGrid).

The layout of the 12 features is documented in :mod:`nodes.nav.features` and travels in
``FeatureGrid.names``: density, speed, direction (Figure 3 risk), goal distance, each
high / medium / low. With ``conflict`` (default) a 13th feature follows them: the cells
someone will occupy when the robot could be there (:func:`nodes.nav.features.conflict_cells`,
constant-velocity prediction at ``conflict_speed_mps``), the space-time occupancy the IRL
cost learns to avoid from real walkers.
"""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.geometry import Odometry2D
from msgs.nav import FeatureGrid, FlowPoints, Goal2D
from nodes.nav.features import (CONFLICT, FEATURE_NAMES, GridSpec, Thresholds, conflict_cells, extract_features,
                                goal_in_robot_frame)
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    x_min_m: float = -0.5            # grid extent in the robot frame (x ahead, y left)
    x_max_m: float = 5.5
    y_min_m: float = -3.0
    y_max_m: float = 3.0
    resolution_m: float = 0.25
    density_low_points: float = 20.0     # fewer points: density low (tuned for RgbdFlow's stride 4 at 640x480,
    density_high_points: float = 150.0   # fx 525): at least this many: density high
    speed_low_mps: float = 0.3
    speed_high_mps: float = 0.8
    moving_mps: float = 0.25         # slower points do not flow (Figure 3 direction feature)
    flow_points: int = 10            # points needed to call a cell's in-flow
    min_height_m: float = 0.15       # ignore floor points
    max_height_m: float = 2.2
    conflict: bool = True            # append the 'conflict' feature (space-time occupancy)
    conflict_speed_mps: float = 1.0  # the robot speed it assumes (the demos from walkers use the same)
    conflict_horizon_s: float = 6.0
    conflict_slack_m: float = 0.5


class CrowdFeatures(Node):
    """Inputs ``flow`` (latest only), ``goal``, ``odom``; output ``features`` in the flow's frame and stamp.

    A goal whose ``frame_id`` equals the flow's frame is used as is; any other goal is taken
    to be in the odometry's world frame and moved into the robot frame with the latest pose.
    """

    Config = Config
    inputs = {"flow": Input(FlowPoints, latest=True), "goal": Input(Goal2D, depth=4),
              "odom": Input(Odometry2D, latest=True)}
    outputs = {"features": FeatureGrid}

    def setup(self) -> None:
        cfg = self.config
        self.grid = GridSpec(cfg.x_min_m, cfg.x_max_m, cfg.y_min_m, cfg.y_max_m, cfg.resolution_m)
        self.thresholds = Thresholds((cfg.density_low_points, cfg.density_high_points),
                                     (cfg.speed_low_mps, cfg.speed_high_mps), cfg.moving_mps, cfg.flow_points)
        self._goal: Goal2D | None = None
        self._pose: tuple[float, float, float] | None = None
        self._warned: set[str] = set()

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.log.warning(text)

    def on_goal(self, msg: Goal2D) -> None:
        if not (np.isfinite(msg.x_m) and np.isfinite(msg.y_m)):
            self.log.error("dropped a non-finite goal (%s, %s)", msg.x_m, msg.y_m)
            return
        self._goal = msg

    def on_odom(self, msg: Odometry2D) -> None:
        pose = (msg.pose.x_m, msg.pose.y_m, msg.pose.yaw_rad)
        if np.all(np.isfinite(pose)):
            self._pose = pose

    def _goal_xy(self, flow_frame: str) -> tuple[float, float] | None:
        goal = self._goal
        if goal is None:
            self._warn_once("goal", "no goal yet: goal-distance features are all 'medium'")
            return None
        if goal.frame_id == flow_frame:
            return goal.x_m, goal.y_m
        if self._pose is None:
            self._warn_once("pose", f"goal is in {goal.frame_id!r} but no odometry yet: goal features 'medium'")
            return None
        return goal_in_robot_frame((goal.x_m, goal.y_m), self._pose)

    def on_flow(self, msg: FlowPoints) -> dict[str, FeatureGrid]:
        cfg = self.config
        result = extract_features(msg.points_m, msg.velocity_mps, self._goal_xy(msg.frame_id), self.grid,
                                  self.thresholds, min_height_m=cfg.min_height_m, max_height_m=cfg.max_height_m)
        ox, oy = self.grid.origin
        features, names = result.features, list(FEATURE_NAMES)
        if cfg.conflict:
            hit = conflict_cells(msg.points_m, msg.velocity_mps, self.grid, robot_speed_mps=cfg.conflict_speed_mps,
                                 horizon_s=cfg.conflict_horizon_s, slack_m=cfg.conflict_slack_m,
                                 moving_mps=cfg.moving_mps, min_points=cfg.density_low_points,
                                 min_height_m=cfg.min_height_m, max_height_m=cfg.max_height_m)
            features, names = np.concatenate([features, hit[..., None].astype(np.uint8)], axis=2), names + [CONFLICT]
        return {"features": FeatureGrid(stamp_ns=msg.stamp_ns, frame_id=msg.frame_id, features=features,
                                        resolution_m=cfg.resolution_m, origin_x_m=ox, origin_y_m=oy, names=names)}
