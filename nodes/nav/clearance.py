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
