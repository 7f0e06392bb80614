"""Navigation messages: scene flow, crowd features, cost grids, pedestrian ground truth, plans."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class FlowPoints(Message, tag="nav.FlowPoints"):
    """Tracked 3D points and their velocities with the robot's own motion removed.

    ``points_m`` N x 3 and ``velocity_mps`` N x 3 in ``frame_id`` (robot frame: x ahead, y left, z up).
    """

    points_m: np.ndarray = const(np.zeros((0, 3), np.float32))
    velocity_mps: np.ndarray = const(np.zeros((0, 3), np.float32))


class FeatureGrid(Message, tag="nav.FeatureGrid"):
    """Per-cell binary crowd features over a local grid in front of the robot.

    ``features`` is rows x cols x K (uint8 0/1, K = 12 in the paper's layout).
    Cell (r, c) centre: x = origin_x_m + c * resolution_m, y = origin_y_m + r * resolution_m
    in ``frame_id``. ``names`` labels the K features.
    """

    features: np.ndarray = const(np.zeros((0, 0, 12), np.uint8))
    resolution_m: float = 0.25
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0
    names: list[str] = []


class CostGrid(Message, tag="nav.CostGrid"):
    """Strictly positive traversal cost per cell (inf = forbidden), same layout as FeatureGrid."""

    cost: np.ndarray = const(np.zeros((0, 0), np.float32))
    resolution_m: float = 0.25
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0


class Pedestrians(Message, tag="nav.Pedestrians"):
    """Ground-truth (or tracked) pedestrians: ids, N x 2 positions (m), N x 2 velocities (m/s), world frame."""

    ids: np.ndarray = const(np.zeros(0, np.int64))
    positions_m: np.ndarray = const(np.zeros((0, 2)))
    velocities_mps: np.ndarray = const(np.zeros((0, 2)))
    radius_m: float = 0.3


class Goal2D(Message, tag="nav.Goal2D"):
    """A navigation goal in ``frame_id``."""

    x_m: float = 0.0
    y_m: float = 0.0
    tolerance_m: float = 0.3


class PlanStatus(Message, tag="nav.PlanStatus"):
    """What a planner is doing: 'planning', 'following', 'replanned', 'reached', 'unreachable', 'stopped'."""

    state: str = ""
    reason: str = ""
    plan_ms: float = 0.0
