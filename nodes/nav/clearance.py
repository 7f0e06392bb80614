"""Swept-path clearance for a disc robot: how far it can drive along an arc before touching a point, and how fast.

Used by the collision guard (:mod:`nodes.nav.collision_guard`). Robot frame: x ahead,
y left, metres; the robot is a disc of radius ``radius_m`` centred at the origin.
"""
from __future__ import annotations

import numpy as np


def arc_samples(v_mps: float, w_radps: float, length_m: float, step_m: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Points (S, 2) along the arc the robot centre follows with (v, w) held, every ``step_m`` of travel,
    starting at the origin, and their arc lengths (S,) in m. Curvature is w / v (a straight line
    when |w| is negligible); only the path's shape matters, not the speed."""
    if not (np.isfinite(v_mps) and np.isfinite(w_radps) and length_m >= 0 and step_m > 0):
        raise ValueError(f"arc needs finite v, w, length >= 0 and step > 0; got {v_mps}, {w_radps}, {length_m}, {step_m}")
    s = np.arange(0.0, length_m + 1e-9, step_m)
    k = w_radps / max(abs(v_mps), 1e-3)
    if abs(k) * max(length_m, step_m) < 1e-6:
        return np.column_stack([s, np.zeros_like(s)]), s
    return np.column_stack([np.sin(k * s) / k, (1.0 - np.cos(k * s)) / k]), s


def free_distance_m(points_xy: np.ndarray, v_mps: float, w_radps: float, *, radius_m: float,
                    length_m: float = 2.5, step_m: float = 0.05) -> tuple[float, float]:
    """Travel along the (v, w) arc before a disc of ``radius_m`` closes in on any point.

    A point conflicts at an arc sample when it is inside the disc there and nearer than it
    is now (moving along the arc brings it closer): a wall beside the robot that the path
    moves away from does not block it, a wall the path runs into does.

    Parameters
    ----------
    points_xy : (N, 2) obstacle points, robot frame (m). Non-finite rows are ignored.
    v_mps, w_radps : the motion whose path is checked (its curvature w / v).
    radius_m : robot radius plus the safety margin (m).
    length_m : how far ahead to check (m); beyond it the path counts as free.

    Returns
    -------
    (free_m, nearest_on_path_m): arc length (m) to the first conflicting sample (``inf`` when
    none within ``length_m``), and the distance (m) from the robot centre now to the nearest
    conflicting point (``inf`` when none).
    """
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    now = np.hypot(p[:, 0], p[:, 1])
    p, now = p[now <= length_m + radius_m], now[now <= length_m + radius_m]
    if len(p) == 0:
        return float("inf"), float("inf")
    path, s = arc_samples(v_mps, w_radps, length_m, step_m)
    d = np.hypot(path[:, None, 0] - p[None, :, 0], path[:, None, 1] - p[None, :, 1])      # (S, N)
    conflict = (d < radius_m) & (d < now[None, :] - 1e-9)
    hit = conflict.any(axis=1)
    if not hit.any():
        return float("inf"), float("inf")
    first = int(np.argmax(hit))
    # the contact lies between the previous sample and this one: count only the part known free
    return float(max(s[first] - step_m, 0.0)), float(now[conflict.any(axis=0)].min())


def conflicting(points_xy: np.ndarray, v_mps: float, w_radps: float, *, radius_m: float, length_m: float = 2.5,
                step_m: float = 0.05) -> np.ndarray:
    """(N,) bool: the points that conflict somewhere along the (v, w) arc, as :func:`free_distance_m` counts them
    (inside the disc there and nearer than now). Non-finite points never conflict."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    out = np.zeros(len(p), bool)
    now = np.hypot(p[:, 0], p[:, 1])
    idx = np.flatnonzero(np.isfinite(now) & (now <= length_m + radius_m))
    if len(idx) == 0:
        return out
    path, _ = arc_samples(v_mps, w_radps, length_m, step_m)
    d = np.hypot(path[:, None, 0] - p[None, idx, 0], path[:, None, 1] - p[None, idx, 1])
    out[idx] = ((d < radius_m) & (d < now[None, idx] - 1e-9)).any(axis=0)
    return out


def braking_speed_mps(free_m: float, *, decel_mps2: float, latency_s: float) -> float:
    """Largest speed from which the robot still stops within ``free_m``: v * latency + v^2 / (2 a) = free."""
    if not free_m > 0:
        return 0.0
    if not np.isfinite(free_m):
        return float("inf")
    a, lat = float(decel_mps2), max(float(latency_s), 0.0)
    return float(a * (-lat + np.sqrt(lat * lat + 2.0 * free_m / a)))


def unseen_mask(points_xy: np.ndarray, *, camera_x_m: float, half_fov_rad: float, min_range_m: float) -> np.ndarray:
    """(N,) bool: robot-frame points the camera (at ``camera_x_m`` ahead, looking along x) cannot see now."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    rel_x = p[:, 0] - camera_x_m
    bearing = np.arctan2(p[:, 1], rel_x)
    return (np.abs(bearing) > half_fov_rad) | (np.hypot(rel_x, p[:, 1]) < min_range_m)


def cleared_by_depth(points_xy: np.ndarray, depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float, *,
                     mount_xyz_m: tuple[float, float, float], z_min_m: float, z_max_m: float, max_range_m: float,
                     margin_m: float = 0.05, spread_m: float = 0.2, row_stride: int = 4) -> np.ndarray:
    """(N,) bool: robot-frame points (N, 2) that the depth image shows to be empty space (ray-trace clearing).

    A point the camera cannot measure (nearer than its minimum range, where it reports holes) is
    cleared when every downward ray of its image column that passes over it at a height in
    [``z_min_m``, camera height] returns a valid depth beyond it: the camera saw the floor or a
    wall through that place. Whatever stands there (a person, a bench, a post) blocks those rays
    and leaves holes, so it is kept. Rays that would meet the floor beyond ``max_range_m`` are
    not used (their holes may just be distance). The same must hold ``spread_m`` to either side
    of the point (across the view): a person who shifted a little within the blind zone still
    blocks some of those rays and keeps the point. Points outside the image, behind the camera,
    or with no such ray are not cleared. Camera frame as :func:`nodes.nav.dwa_core.depth_to_robot`
    (x right, y down, z forward, level), mounted at ``mount_xyz_m`` (ahead, left, up) of the robot centre.
    """
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth_m, dtype=np.float64)
    if len(p) == 0 or depth.ndim != 2 or not (fx > 0 and fy > 0):
        return np.zeros(len(p), bool)
    if spread_m > 0:
        out = np.ones(len(p), bool)
        for dy in (-spread_m, 0.0, spread_m):       # the point and its neighbours across the view
            out &= cleared_by_depth(p + [0.0, dy], depth, fx, fy, cx, cy, mount_xyz_m=mount_xyz_m, z_min_m=z_min_m,
                                    z_max_m=z_max_m, max_range_m=max_range_m, margin_m=margin_m, spread_m=0.0,
                                    row_stride=row_stride)
        return out
    out = np.zeros(len(p), bool)
    rays = _column_rays(p, depth, fx, fy, cx, cy, mount_xyz_m=mount_xyz_m, z_min_m=z_min_m, z_max_m=z_max_m,
                        max_range_m=max_range_m, row_stride=row_stride)
    if rays is None:
        return out
    idx, zc, d, relevant = rays
    free = np.isfinite(d) & (d > zc[:, None] + margin_m)
    out[idx] = relevant.any(axis=1) & (free | ~relevant).all(axis=1)
    return out


def _column_rays(p: np.ndarray, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, *,
                 mount_xyz_m: tuple[float, float, float], z_min_m: float, z_max_m: float, max_range_m: float,
                 row_stride: int):
    """For robot-frame points (N, 2): the indices of those with rays, their optical depth, the depth the rays
    of their image column read (n, R) and which of those rays pass over them at a relevant height (n, R)."""
    mx, my, mz = mount_xyz_m
    zc = p[:, 0] - mx                                  # optical depth of each point
    xc = -(p[:, 1] - my)
    ok = zc > 0.02
    u = np.full(len(p), -1)
    u[ok] = np.round(cx + fx * xc[ok] / zc[ok]).astype(int)
    ok &= (u >= 0) & (u < depth.shape[1])
    rows = np.arange(0, depth.shape[0], max(1, int(row_stride)))
    slope = (rows - cy) / fy                           # downward ray: height drops by slope per metre of depth
    down = (slope > 0) & (mz / np.maximum(slope, 1e-9) <= max_range_m)
    rows, slope = rows[down], slope[down]
    if not len(rows) or not ok.any():
        return None
    idx = np.flatnonzero(ok)
    height = mz - slope[None, :] * zc[idx, None]                       # (n, R) height of each ray over the point
    relevant = (height >= z_min_m) & (height <= min(z_max_m, mz))
    return idx, zc[idx], depth[rows[None, :], u[idx, None]], relevant


def measured_through(points_xy: np.ndarray, depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float, *,
                     mount_xyz_m: tuple[float, float, float], z_min_m: float, z_max_m: float, max_range_m: float,
                     row_stride: int = 4) -> np.ndarray:
    """(N,) bool: robot-frame points (N, 2) whose image column has at least one valid depth among the rays that
    pass over them at a height in [``z_min_m``, camera height] (what :func:`cleared_by_depth` looks at). False
    where those rays all read holes: something nearer than the camera's minimum range may stand there."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth_m, dtype=np.float64)
    out = np.zeros(len(p), bool)
    if len(p) == 0 or depth.ndim != 2 or not (fx > 0 and fy > 0):
        return out
    rays = _column_rays(p, depth, fx, fy, cx, cy, mount_xyz_m=mount_xyz_m, z_min_m=z_min_m, z_max_m=z_max_m,
                        max_range_m=max_range_m, row_stride=row_stride)
    if rays is None:
        return out
    idx, _, d, relevant = rays
    out[idx] = (relevant & np.isfinite(d) & (d > 0)).any(axis=1)
    return out
