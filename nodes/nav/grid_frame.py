"""Grids placed in the world, and what the planners do with a path: the map frame
(:class:`GridFrame`, cells <-> metres), robot <-> world transforms, obstacle inflation, a
global plan on an occupancy map, and following a path (sub-goal, densify, waypoint, steer).

The search itself is :mod:`nodes.nav.dijkstra`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nodes.nav.dijkstra import GridGraph, PlanResult, plan_dijkstra

@dataclass(frozen=True)
class GridFrame:
    """Where a ``shape = (rows, cols)`` grid lies: cell (r, c) centre at
    (origin_x_m + c * resolution_m, origin_y_m + r * resolution_m) in its frame."""

    shape: tuple[int, int]
    resolution_m: float
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.resolution_m > 0:
            raise ValueError(f"grid resolution must be > 0 m, got {self.resolution_m}")

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Nearest cells (n, 2) int (row, col) of points (n, 2) m; may lie outside the grid."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.rint(np.stack([(xy[:, 1] - self.origin_y_m), (xy[:, 0] - self.origin_x_m)], axis=1)
                       / self.resolution_m).astype(np.int64)

    def xy_of(self, cells: np.ndarray) -> np.ndarray:
        """Centres (n, 2) m of cells (n, 2) (row, col)."""
        cells = np.asarray(cells, float).reshape(-1, 2)
        return np.stack([self.origin_x_m + cells[:, 1] * self.resolution_m,
                         self.origin_y_m + cells[:, 0] * self.resolution_m], axis=1)

    def inside(self, cells: np.ndarray) -> np.ndarray:
        cells = np.asarray(cells).reshape(-1, 2)
        return (cells[:, 0] >= 0) & (cells[:, 0] < self.shape[0]) & (cells[:, 1] >= 0) & (cells[:, 1] < self.shape[1])

    def clamp(self, cells: np.ndarray) -> np.ndarray:
        """Cells moved onto the nearest border cell when outside (robot at the grid border)."""
        cells = np.asarray(cells, np.int64).reshape(-1, 2)
        return np.stack([np.clip(cells[:, 0], 0, self.shape[0] - 1), np.clip(cells[:, 1], 0, self.shape[1] - 1)], axis=1)


def to_world(pose: tuple[float, float, float], xy: np.ndarray) -> np.ndarray:
    """Robot-frame points (n, 2) -> world, for a robot at ``pose`` = (x_m, y_m, yaw_rad)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    xy = np.asarray(xy, float).reshape(-1, 2)
    return np.stack([pose[0] + c * xy[:, 0] - s * xy[:, 1], pose[1] + s * xy[:, 0] + c * xy[:, 1]], axis=1)


def to_robot(pose: tuple[float, float, float], xy: np.ndarray) -> np.ndarray:
    """World points (n, 2) -> robot frame (x ahead, y left)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = np.asarray(xy, float).reshape(-1, 2) - (pose[0], pose[1])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def inflate(occupied: np.ndarray, radius_cells: float) -> np.ndarray:
    """Occupied mask grown by a disc of ``radius_cells`` (the robot's footprint)."""
    import cv2   # local: only the planner node needs it

    occupied = np.asarray(occupied, bool)
    r = int(np.ceil(radius_cells))
    if r <= 0 or not occupied.any():
        return occupied
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    kernel = (np.hypot(yy, xx) <= radius_cells + 1e-9).astype(np.uint8)
    return cv2.dilate(occupied.astype(np.uint8), kernel).astype(bool)


def plan_on_map(occupied: np.ndarray, frame: GridFrame, start_xy: tuple[float, float], goal_xy: tuple[float, float],
                *, graph: GridGraph | None = None) -> tuple[np.ndarray, PlanResult]:
    """Global path (n, 2) world metres over a (pre-inflated) occupancy mask; unit cost per cell length.

    A start inside an inflated obstacle is allowed (the robot is already there); a goal
    inside one is moved to the nearest free cell. The path ends exactly at ``goal_xy``.
    """
    cost = np.where(np.asarray(occupied, bool), np.inf, 1.0)
    start = frame.clamp(frame.cell_of(np.asarray(start_xy)))[0]
    goal = frame.clamp(frame.cell_of(np.asarray(goal_xy)))[0]
    if np.isinf(cost[goal[0], goal[1]]):
        free = np.argwhere(np.isfinite(cost))
        if len(free) == 0:
            return np.zeros((0, 2)), PlanResult(np.zeros((0, 2), np.int64), np.inf, False, "the map has no free cell")
        goal = free[np.argmin(np.hypot(*(free - goal).T))]
    result = plan_dijkstra(cost, tuple(start), tuple(goal), graph=graph)
    if not result.reachable:
        return np.zeros((0, 2)), result
    xy = frame.xy_of(result.cells)
    xy[0], xy[-1] = start_xy, goal_xy
    return xy, result


def pick_subgoal(path_xy: np.ndarray, robot_xy: np.ndarray, reach_m: float) -> int:
    """Index of the sub-goal on a global path (n, 2): from the path point closest to the robot,
    walk forward while points stay within ``reach_m`` of the robot; the last such point."""
    path_xy = np.asarray(path_xy, float).reshape(-1, 2)
    if len(path_xy) == 0:
        raise ValueError("the global path is empty; plan one first")
    d = np.hypot(*(path_xy - np.asarray(robot_xy, float).reshape(2)).T)
    i = int(np.argmin(d))
    beyond = np.flatnonzero(d[i + 1:] > reach_m)
    return i + int(beyond[0]) if len(beyond) else len(path_xy) - 1


def densify(path_xy: np.ndarray, step_m: float) -> np.ndarray:
    """A polyline (n, 2) resampled with points at most ``step_m`` apart (corners kept)."""
    path_xy = np.asarray(path_xy, float).reshape(-1, 2)
    out = [path_xy[:1]]
    for a, b in zip(path_xy[:-1], path_xy[1:]):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / step_m)))
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.vstack(out)


def extract_waypoint(path_xy: np.ndarray, distance_m: float) -> np.ndarray:
    """Point on a polyline (n, 2) at arc length ``distance_m`` from its start (its end if shorter)."""
    path_xy = np.asarray(path_xy, float).reshape(-1, 2)
    if len(path_xy) == 1:
        return path_xy[0].copy()
    seg = np.hypot(*np.diff(path_xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if distance_m >= s[-1]:
        return path_xy[-1].copy()
    k = int(np.searchsorted(s, distance_m, side="right") - 1)
    a = (distance_m - s[k]) / max(seg[k], 1e-12)
    return path_xy[k] + a * (path_xy[k + 1] - path_xy[k])


def steer(pose: tuple[float, float, float], target_xy: np.ndarray, *, v_max_mps: float, w_max_radps: float,
          k_heading: float = 2.0, turn_in_place_rad: float = 1.0, stop_at_m: float | None = None,
          decel_mps2: float = 0.8) -> tuple[float, float]:
    """Unicycle command (v, w) toward a target: turn rate proportional to the bearing error,
    speed v_max cos(error), zero beyond ``turn_in_place_rad``; if ``stop_at_m`` is given
    the target is a final goal and speed obeys v <= sqrt(2 a d) so the robot stops on it."""
    rel = to_robot(pose, target_xy)[0]
    err = float(np.arctan2(rel[1], rel[0]))
    w = float(np.clip(k_heading * err, -w_max_radps, w_max_radps))
    v = 0.0 if abs(err) > turn_in_place_rad else v_max_mps * max(0.0, np.cos(err))
    if stop_at_m is not None:
        dist = float(np.hypot(*rel))
        v = min(v, np.sqrt(2.0 * decel_mps2 * max(dist - 0.5 * stop_at_m, 0.0)))
    return float(v), w
