"""Crowd features (Kim & Pineau 2016, Sec. 3.2): a local grid of 12-dim binary feature vectors from scene flow.

The grid lies in the robot frame (x ahead, y left), rows along y, columns along x; cell
(r, c) has its centre at ``x = origin_x_m + c * res``, ``y = origin_y_m + r * res``.
Every cell gets four features, each one-hot over the levels high / medium / low, so
exactly four of the 12 bits are set. Layout (index = 3 * group + level)::

    0 density_high    1 density_medium    2 density_low         points in the cell
    3 speed_high      4 speed_medium      5 speed_low           |mean velocity of its points|
    6 direction_high  7 direction_medium  8 direction_low       risk table of Figure 3
    9 goal_high      10 goal_medium      11 goal_low            distance from the cell to the goal

- density: ``count < density_points[0]`` low, ``< density_points[1]`` medium, else high.
  Every point counts, static ones too (walls are dense: that is how the planner sees them).
- speed: the norm of the mean (x, y) velocity of the cell's points, binned by ``speed_mps``;
  cells with fewer than ``density_points[0]`` points are low (too few to trust).
- direction (Figure 3): a point moving faster than ``moving_mps`` flows along its heading.
  With ``u = v / max(|vx|, |vy|)`` (its heading scaled to the Chebyshev unit square) it
  flows into the first-degree neighbour ``cell + round(u)`` and on into the second-degree
  neighbour ``cell + round(2 u)``. A cell is HIGH when at least ``flow_points`` points flow
  in from its first-degree neighbours, else MEDIUM when at least that many flow in from its
  second-degree neighbours, else LOW (its own points, if any, move out of it). Points up
  to two cells outside the grid still flow into the border cells; nothing wraps around.
- goal distance: Euclidean distance from the cell centre to the goal, binned by thirds of
  the grid's own range (nearest third low, farthest third high), so the local grid always
  has a gradient toward the goal however far away it is. Without a goal every cell is medium.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GROUPS = ("density", "speed", "direction", "goal")
LEVELS = ("high", "medium", "low")
FEATURE_NAMES = [f"{g}_{lvl}" for g in GROUPS for lvl in LEVELS]
HIGH, MEDIUM, LOW = 0, 1, 2


@dataclass(frozen=True)
class GridSpec:
    """Local grid extent in the robot frame (m); cells of ``resolution_m``."""

    x_min_m: float = -0.5
    x_max_m: float = 5.5
    y_min_m: float = -3.0
    y_max_m: float = 3.0
    resolution_m: float = 0.25

    def __post_init__(self) -> None:
        if not (self.resolution_m > 0 and self.x_max_m > self.x_min_m and self.y_max_m > self.y_min_m):
            raise ValueError(f"grid needs resolution > 0 and max > min on both axes, got {self}")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) = (cells along y, cells along x)."""
        return (int(np.ceil((self.y_max_m - self.y_min_m) / self.resolution_m - 1e-9)),
                int(np.ceil((self.x_max_m - self.x_min_m) / self.resolution_m - 1e-9)))

    @property
    def origin(self) -> tuple[float, float]:
        """Centre (x_m, y_m) of cell (0, 0)."""
        return self.x_min_m + 0.5 * self.resolution_m, self.y_min_m + 0.5 * self.resolution_m

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates: x (rows, cols) and y (rows, cols), metres."""
        rows, cols = self.shape
        ox, oy = self.origin
        return np.meshgrid(ox + self.resolution_m * np.arange(cols), oy + self.resolution_m * np.arange(rows))


@dataclass(frozen=True)
class Thresholds:
    """Bin edges: below the first is low, below the second medium, else high."""

    density_points: tuple[float, float] = (20.0, 150.0)
    speed_mps: tuple[float, float] = (0.3, 0.8)
    moving_mps: float = 0.25
    flow_points: int = 10

    def __post_init__(self) -> None:
        for name in ("density_points", "speed_mps"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must be (low_edge, high_edge) with 0 <= low <= high, got {(lo, hi)}")


@dataclass(frozen=True)
class FeatureResult:
    """Features (rows, cols, 12) uint8 and the raw per-cell quantities behind them."""

    features: np.ndarray
    density: np.ndarray          # (rows, cols) int: points per cell
    velocity_mps: np.ndarray     # (rows, cols, 2) mean (vx, vy) of the cell's points (0 where empty)
    inflow_first: np.ndarray     # (rows, cols) int: points flowing in from first-degree neighbours
    inflow_second: np.ndarray    # (rows, cols) int: ... from second-degree neighbours
    outflow: np.ndarray          # (rows, cols) int: moving points in the cell (they move out)
    goal_distance_m: np.ndarray  # (rows, cols) float, NaN without a goal


def level(values: np.ndarray, edges: tuple[float, float]) -> np.ndarray:
    """HIGH (0) / MEDIUM (1) / LOW (2) per value: < edges[0] low, < edges[1] medium, else high."""
    return np.where(values < edges[0], LOW, np.where(values < edges[1], MEDIUM, HIGH))


def _scatter_count(rows: int, cols: int, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    return np.bincount(r[inside] * cols + c[inside], minlength=rows * cols).reshape(rows, cols)


def extract_features(points_m: np.ndarray, velocity_mps: np.ndarray, goal_xy_m: tuple[float, float] | None,
                     grid: GridSpec = GridSpec(), thresholds: Thresholds = Thresholds(), *,
                     min_height_m: float = -np.inf, max_height_m: float = np.inf) -> FeatureResult:
    """Per-cell features from points (N, 3) m and velocities (N, 3) m/s in the robot frame.

    ``goal_xy_m`` is the goal in the same frame (or None). Points with a non-finite
    coordinate or velocity, or outside ``[min_height_m, max_height_m]``, are ignored.
    An empty cloud is fine: every cell is then density / speed / direction low.
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(velocity_mps, dtype=np.float64).reshape(-1, 3)
    if len(pts) != len(vel):
        raise ValueError(f"points ({len(pts)}) and velocities ({len(vel)}) must pair up")
    ok = np.all(np.isfinite(pts), axis=1) & np.all(np.isfinite(vel), axis=1)
    ok &= (pts[:, 2] >= min_height_m) & (pts[:, 2] <= max_height_m)
    pts, vel = pts[ok], vel[ok, :2]
    rows, cols = grid.shape
    c = np.floor((pts[:, 0] - grid.x_min_m) / grid.resolution_m).astype(np.int64)
    r = np.floor((pts[:, 1] - grid.y_min_m) / grid.resolution_m).astype(np.int64)
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    flat = r[inside] * cols + c[inside]
    density = np.bincount(flat, minlength=rows * cols).reshape(rows, cols)
    sums = np.stack([np.bincount(flat, weights=vel[inside, k], minlength=rows * cols) for k in (0, 1)], axis=1)
    mean_vel = (sums / np.maximum(density.reshape(-1, 1), 1)).reshape(rows, cols, 2)
    speed = np.hypot(mean_vel[..., 0], mean_vel[..., 1])
    speed = np.where(density < thresholds.density_points[0], 0.0, speed)

    near = (r >= -2) & (r < rows + 2) & (c >= -2) & (c < cols + 2)          # may flow into a border cell
    moving = near & (np.hypot(vel[:, 0], vel[:, 1]) >= thresholds.moving_mps)
    vm = vel[moving]
    u = vm / np.max(np.abs(vm), axis=1, keepdims=True) if len(vm) else np.zeros((0, 2))
    first = np.rint(u).astype(np.int64)
    second = np.rint(2 * u).astype(np.int64)
    rm, cm = r[moving], c[moving]
    inflow_first = _scatter_count(rows, cols, rm + first[:, 1], cm + first[:, 0])
    inflow_second = _scatter_count(rows, cols, rm + second[:, 1], cm + second[:, 0])
    outflow = _scatter_count(rows, cols, rm, cm)

    k = thresholds.flow_points
    direction = np.where(inflow_first >= k, HIGH, np.where(inflow_second >= k, MEDIUM, LOW))
    goal_level, goal_dist = _goal_levels(grid, goal_xy_m)
    feats = np.zeros((rows, cols, 12), np.uint8)
    for g, lv in enumerate((level(density, thresholds.density_points), level(speed, thresholds.speed_mps),
                            direction, goal_level)):
        np.put_along_axis(feats, (3 * g + lv)[..., None], 1, axis=2)
    return FeatureResult(feats, density, mean_vel.astype(np.float32), inflow_first, inflow_second, outflow,
                         goal_dist)


def _goal_levels(grid: GridSpec, goal_xy_m: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = grid.shape
    if goal_xy_m is None or not np.all(np.isfinite(goal_xy_m)):
        return np.full((rows, cols), MEDIUM), np.full((rows, cols), np.nan)
    x, y = grid.centres()
    dist = np.hypot(x - goal_xy_m[0], y - goal_xy_m[1])
    span = dist.max() - dist.min()
    if span <= 1e-9:                                  # a single cell: nothing to rank
        return np.full((rows, cols), LOW), dist
    q = (dist - dist.min()) / span
    return np.where(q < 1 / 3, LOW, np.where(q < 2 / 3, MEDIUM, HIGH)), dist


def goal_in_robot_frame(goal_xy: tuple[float, float], robot_pose: tuple[float, float, float]) -> tuple[float, float]:
    """World goal (x, y) -> robot frame, given the robot pose (x, y, yaw) in the world."""
    dx, dy = goal_xy[0] - robot_pose[0], goal_xy[1] - robot_pose[1]
    c, s = np.cos(robot_pose[2]), np.sin(robot_pose[2])
    return float(c * dx + s * dy), float(-s * dx + c * dy)


#: the feature the crowd-features node appends to the paper's 12 (``CrowdFeatures`` ``conflict``)
CONFLICT = "conflict"


def conflict_cells(points_m: np.ndarray, velocity_mps: np.ndarray, grid: GridSpec = GridSpec(), *,
                   robot_speed_mps: float = 1.0, horizon_s: float = 6.0, step_s: float = 0.25, slack_m: float = 0.5,
                   moving_mps: float = 0.25, min_points: float = 2.0, min_height_m: float = -np.inf,
                   max_height_m: float = np.inf) -> np.ndarray:
    """(rows, cols) bool: cells someone will occupy when a robot driving straight out at
    ``robot_speed_mps`` could be there, at constant velocity (a space-time occupancy feature).

    The paper's density feature marks where people are *now*. A walker following a flow
    crosses cells that were occupied when it looked and are empty when it gets there, so
    demonstrations in real crowds price density near zero (nodes/nav/weights/default.json:
    ``also_learnt_from_real_pedestrians``). This feature asks the question a walker answers:
    will someone be in this cell when I arrive? A point slower than ``moving_mps`` stays
    where it is (a standing person blocks its cell at every time); a moving one is
    extrapolated every ``step_s`` up to ``horizon_s`` and marks the cell it reaches at tau
    when the cell lies ``robot_speed_mps * tau`` (within ``slack_m``) from the robot. A cell
    needs ``min_points`` such points (a single flow outlier marks nothing). Every point moves with
    the median velocity of the grid cell it stands in (:func:`cell_velocity`): a few wrong flow
    vectors on a person (their edge during a fast turn) no longer throw cells ahead of them.
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(velocity_mps, dtype=np.float64).reshape(-1, 3)
    rows, cols = grid.shape
    if len(pts) != len(vel):
        raise ValueError(f"points ({len(pts)}) and velocities ({len(vel)}) must pair up")
    ok = np.all(np.isfinite(pts), axis=1) & np.all(np.isfinite(vel), axis=1)
    ok &= (pts[:, 2] >= min_height_m) & (pts[:, 2] <= max_height_m)
    if not ok.any():
        return np.zeros((rows, cols), bool)
    p = pts[ok, :2]
    v, _ = point_velocity(p, vel[ok, :2], grid.resolution_m, (grid.x_min_m, grid.y_min_m))
    still = np.hypot(v[:, 0], v[:, 1]) < moving_mps
    index = np.arange(len(p))
    pairs = [(index[still], *_cell_rc(grid, p[still]))]
    pm, vm, im = p[~still], v[~still], index[~still]
    if len(pm) and horizon_s > 0:
        for tau in np.arange(step_s, horizon_s + 1e-9, step_s):
            q = pm + vm * tau
            hit = np.abs(np.hypot(q[:, 0], q[:, 1]) - robot_speed_mps * tau) <= slack_m
            pairs.append((im[hit], *_cell_rc(grid, q[hit])))
    return _enough_points(pairs, grid, min_points)


def arrival_cells(paths_m: np.ndarray, taus_s: np.ndarray, grid: GridSpec = GridSpec(), *,
                  robot_speed_mps: float = 1.0, slack_m: float = 0.5, moving_mps: float = 0.25,
                  min_points: float = 2.0) -> np.ndarray:
    """(rows, cols) bool: :func:`conflict_cells` from where each point really goes, not from a constant velocity.

    ``paths_m`` (N, T, 2) holds each point's place at the times ``taus_s`` (T,) s after now, the
    first of them 0 (robot frame of now; NaN where it is not known, e.g. a walker who left the data). It is the
    same question (is a cell occupied when a robot driving straight out at ``robot_speed_mps``
    could be there, within ``slack_m``), the same still-point rule (a point whose mean speed over
    the horizon is below ``moving_mps`` blocks the cell it stands in now) and the same count
    (``min_points`` points per cell); only the motion differs. Learning (``sim.irl_demos``
    ``track_demos(hindsight=True)``) asks it of recorded walkers' real futures, a perfect prediction;
    the running robot asks :func:`conflict_cells`, its constant-velocity prediction.
    """
    q = np.asarray(paths_m, dtype=np.float64)
    taus = np.asarray(taus_s, dtype=np.float64).reshape(-1)
    rows, cols = grid.shape
    if q.ndim != 3 or q.shape[2] != 2 or q.shape[1] != len(taus):
        raise ValueError(f"paths_m must be (N, T, 2) with T = len(taus_s) = {len(taus)}, got {q.shape}")
    if len(taus) and taus[0] != 0:
        raise ValueError(f"taus_s must start at 0 (paths_m[:, 0] is where the points are now), got {taus[0]}")
    if not len(q) or not len(taus):
        return np.zeros((rows, cols), bool)
    now = q[:, 0]
    known = np.isfinite(q).all(axis=2)
    span = np.where(known.any(axis=1), taus[np.argmax(known * taus, axis=1)] - taus[0], 0.0)
    last = q[np.arange(len(q)), np.argmax(known * taus, axis=1)]
    speed = np.where(span > 0, np.hypot(*(last - now).T) / np.maximum(span, 1e-9), 0.0)
    still = np.isfinite(now).all(axis=1) & (speed < moving_mps)
    index = np.arange(len(q))
    pairs = [(index[still], *_cell_rc(grid, now[still]))]
    for k, tau in enumerate(taus):
        if tau <= 0:
            continue
        ok = ~still & known[:, k]
        hit = ok.copy()
        hit[ok] = np.abs(np.hypot(q[ok, k, 0], q[ok, k, 1]) - robot_speed_mps * tau) <= slack_m
        pairs.append((index[hit], *_cell_rc(grid, q[hit, k])))
    return _enough_points(pairs, grid, min_points)


def cell_motion(points_xy: np.ndarray, velocity_xy: np.ndarray, cell_m: float,
                corner_xy_m: tuple[float, float] = (0.0, 0.0)
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points grouped by the square cell (side ``cell_m``, lattice through ``corner_xy_m``) they stand in:
    per occupied cell the median position (K, 2) m, the median velocity (K, 2) m/s and the point count (K,),
    and per point the index (N,) of its cell.

    Dense flow is wrong on a minority of pixels (occlusion edges, a person leaving the image,
    fast turns); the median over a cell's points keeps the motion of what fills the cell.
    Inputs must be finite. The predictions need only the velocities: :func:`cell_velocity`.
    """
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    (x, y, vx, vy), n, of_point = _cell_medians(p, np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2),
                                                cell_m, corner_xy_m, with_points=True)
    return np.column_stack([x, y]), np.column_stack([vx, vy]), n, of_point


def cell_velocity(points_xy: np.ndarray, velocity_xy: np.ndarray, cell_m: float,
                  corner_xy_m: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cell_motion` without the median positions: (median velocity (K, 2), count (K,), cell of each point (N,))."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    (vx, vy), n, of_point = _cell_medians(p, np.asarray(velocity_xy, dtype=np.float64).reshape(-1, 2),
                                          cell_m, corner_xy_m, with_points=False)
    return np.column_stack([vx, vy]), n, of_point


def point_velocity(points_xy: np.ndarray, velocity_xy: np.ndarray, cell_m: float,
                   corner_xy_m: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Each point's predicted velocity, the median velocity (N, 2) m/s of the cell it stands in
    (:func:`cell_velocity`), and that cell's point count (N,): a few wrong flow vectors do not move a cell."""
    cell_v, n, of_point = cell_velocity(points_xy, velocity_xy, cell_m, corner_xy_m)
    return cell_v[of_point], n[of_point]


def _cell_medians(p: np.ndarray, v: np.ndarray, cell_m: float, corner_xy_m: tuple[float, float], *,
                  with_points: bool) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Per occupied cell the median of each column (x, y, then vx, vy; or vx, vy only), counts, cell of each point."""
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    columns = (p[:, 0], p[:, 1], v[:, 0], v[:, 1]) if with_points else (v[:, 0], v[:, 1])
    if len(p) == 0:
        return [np.zeros(0) for _ in columns], np.zeros(0, np.int64), np.zeros(0, np.int64)
    ij = np.floor((p - np.asarray(corner_xy_m, float)) / cell_m).astype(np.int64)
    ij -= ij.min(axis=0)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]          # one integer per cell
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.r_[True, sorted_key[1:] != sorted_key[:-1]]
    first = np.flatnonzero(starts)
    of_point = np.empty(len(key), np.int64)
    of_point[order] = np.cumsum(starts) - 1
    n = np.diff(np.r_[first, len(key)])
    mid_lo, mid_hi = first + (n - 1) // 2, first + n // 2
    out = []
    for col in columns:
        lo, span = col.min(), np.ptp(col) * 1.001 + 1e-9
        s = col[np.argsort(key + (col - lo) / span)]   # by cell, then by value (the fraction never crosses a cell)
        out.append(0.5 * (s[mid_lo] + s[mid_hi]))
    return out, n, of_point


def _enough_points(pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], grid: GridSpec,
                   min_points: float) -> np.ndarray:
    """(rows, cols) bool: cells reached by at least ``min_points`` distinct points; ``pairs`` are
    (point index, row, col) arrays, a point counted once per cell however often it reaches it."""
    rows, cols = grid.shape
    i, r, c = (np.concatenate(a) for a in zip(*pairs))
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    flat = np.unique(i[inside] * (rows * cols) + r[inside] * cols + c[inside]) % (rows * cols)
    counts = np.bincount(flat, minlength=rows * cols).reshape(rows, cols)
    return counts >= max(min_points, 1)


def _cell_rc(grid: GridSpec, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.floor((xy[:, 0] - grid.x_min_m) / grid.resolution_m).astype(np.int64)
    r = np.floor((xy[:, 1] - grid.y_min_m) / grid.resolution_m).astype(np.int64)
    return r, c
