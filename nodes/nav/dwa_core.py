"""Dynamic Window Approach (Fox, Burgard & Thrun 1997): choose (v, w) for a unicycle among obstacles.

Search space: the velocities reachable within one control period under the acceleration
limits (the dynamic window), sampled on a grid. Each sample is simulated as a circular
arc over a short horizon; it is admissible when the robot can still stop before the
nearest obstacle on that arc, v <= sqrt(2 d a_brake). Among admissible samples it
maximises

    G(v, w) = alpha * heading + beta * clearance + gamma * velocity,

each term scaled to [0, 1] (heading: 1 - |angle to goal| / pi at the end
of the arc; clearance: distance to the nearest obstacle, capped; velocity: v / v_max).
Obstacles are points as a laser would see them now, with no notion of their motion — the
property of DWA the paper's comparison is about.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class DwaParams:
    """Robot limits (SI units) and DWA tuning."""

    v_max_mps: float = 1.0
    v_min_mps: float = 0.0
    w_max_radps: float = 1.2
    acc_v_mps2: float = 1.0
    acc_w_radps2: float = 2.5
    dt_s: float = 0.2             # control period (size of the dynamic window)
    horizon_s: float = 2.0        # arc simulation length (clearance)
    heading_lookahead_s: float = 0.6   # where the heading term is measured along the arc
    sim_step_s: float = 0.1
    n_v: int = 11
    n_w: int = 21
    robot_radius_m: float = 0.4
    clearance_cap_m: float = 1.0
    alpha: float = 0.6
    beta: float = 0.4
    gamma: float = 0.5

    def __post_init__(self) -> None:
        if self.v_max_mps <= self.v_min_mps or self.w_max_radps <= 0 or self.acc_v_mps2 <= 0 or self.acc_w_radps2 <= 0:
            raise ValueError("DWA limits must satisfy v_max > v_min, w_max > 0, accelerations > 0")
        if self.dt_s <= 0 or self.horizon_s <= 0 or self.sim_step_s <= 0 or self.n_v < 1 or self.n_w < 1:
            raise ValueError("DWA dt_s, horizon_s, sim_step_s must be > 0 and n_v, n_w >= 1")


@dataclass(frozen=True)
class DwaResult:
    """Chosen command, its predicted arc (steps, 3) of (x, y, yaw), score and how many samples were admissible."""

    v_mps: float
    w_radps: float
    trajectory: np.ndarray
    score: float
    admissible: int
    reason: str = ""


def rollout(pose: np.ndarray, v: np.ndarray, w: np.ndarray, horizon_s: float, step_s: float) -> np.ndarray:
    """Exact constant-(v, w) arcs from ``pose`` (x, y, yaw): (S, steps, 3) for S samples."""
    t = np.arange(1, int(np.ceil(horizon_s / step_s)) + 1) * step_s
    v = np.asarray(v, float)[:, None]
    w = np.asarray(w, float)[:, None]
    yaw = pose[2] + w * t
    straight = np.abs(w) < 1e-6
    w_safe = np.where(straight, 1.0, w)
    dx = np.where(straight, v * t * np.cos(pose[2]), v / w_safe * (np.sin(yaw) - np.sin(pose[2])))
    dy = np.where(straight, v * t * np.sin(pose[2]), -v / w_safe * (np.cos(yaw) - np.cos(pose[2])))
    return np.stack([pose[0] + dx, pose[1] + dy, np.broadcast_to(yaw, dx.shape)], axis=-1)


def plan_dwa(pose: np.ndarray, velocity: tuple[float, float], goal: np.ndarray, obstacles: np.ndarray,
             params: DwaParams = DwaParams(), *, v_limit_mps: float | None = None) -> DwaResult:
    """One DWA step.

    Parameters
    ----------
    pose : (3,) x_m, y_m, yaw_rad of the robot.
    velocity : current (v_mps, w_radps).
    goal : (2,) x_m, y_m, same frame as ``pose``.
    obstacles : (N, 2) obstacle points (m), same frame; N may be 0. Non-finite rows are ignored.
    params : DwaParams.
    v_limit_mps : optional extra speed cap (e.g. to stop on a final goal).

    Returns
    -------
    DwaResult; ``v = w = 0`` with a reason when no sample is admissible.
    """
    pose = np.asarray(pose, float).reshape(3)
    goal = np.asarray(goal, float).reshape(2)
    if not (np.isfinite(pose).all() and np.isfinite(goal).all()):
        raise ValueError("DWA pose and goal must be finite")
    obstacles = np.asarray(obstacles, float).reshape(-1, 2)
    obstacles = obstacles[np.isfinite(obstacles).all(axis=1)]
    p = params
    v0, w0 = float(velocity[0]), float(velocity[1])
    v_hi = min(p.v_max_mps, v0 + p.acc_v_mps2 * p.dt_s, np.inf if v_limit_mps is None else max(v_limit_mps, p.v_min_mps))
    vs = np.linspace(max(p.v_min_mps, min(v0 - p.acc_v_mps2 * p.dt_s, v_hi)), v_hi, p.n_v)
    ws = np.linspace(max(-p.w_max_radps, w0 - p.acc_w_radps2 * p.dt_s), min(p.w_max_radps, w0 + p.acc_w_radps2 * p.dt_s), p.n_w)
    vv, ww = (a.ravel() for a in np.meshgrid(vs, ws, indexing="ij"))
    arcs = rollout(pose, vv, ww, p.horizon_s, p.sim_step_s)
    if len(obstacles):
        d, _ = cKDTree(obstacles).query(arcs[..., :2].reshape(-1, 2), distance_upper_bound=p.clearance_cap_m + p.robot_radius_m)
        gap = np.minimum(d.reshape(arcs.shape[:2]) - p.robot_radius_m, p.clearance_cap_m)
        clearance = gap.min(axis=1)
        hit = gap <= 0
        # free distance along the arc before the first colliding step (inf if none): the robot
        # must be able to brake within it, v <= sqrt(2 d a_brake)
        free = np.where(hit.any(axis=1), np.abs(vv) * hit.argmax(axis=1) * p.sim_step_s, np.inf)
        ok = vv <= np.sqrt(2.0 * free * p.acc_v_mps2) + 1e-9
    else:
        clearance = np.full(len(vv), p.clearance_cap_m)
        ok = np.ones(len(vv), dtype=bool)
    if not ok.any():
        return DwaResult(0.0, 0.0, np.tile(pose, (arcs.shape[1], 1)), 0.0, 0,
                         "no admissible velocity: obstacle too close on every arc")
    # Fox et al. measure heading where the robot is after one control interval plus braking,
    # not at the end of the whole arc (that would punish every turn as if held for seconds)
    k = min(arcs.shape[1], max(1, int(round(p.heading_lookahead_s / p.sim_step_s)))) - 1
    end = arcs[:, k]
    bearing = np.arctan2(goal[1] - end[:, 1], goal[0] - end[:, 0]) - end[:, 2]
    heading = 1.0 - np.abs(np.angle(np.exp(1j * bearing))) / np.pi
    score = p.alpha * heading + p.beta * clearance / p.clearance_cap_m + p.gamma * vv / p.v_max_mps
    score = np.where(ok, score, -np.inf)
    best = int(np.argmax(score))
    return DwaResult(float(vv[best]), float(ww[best]), arcs[best], float(score[best]), int(ok.sum()))


def depth_to_robot(depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float, *,
                   mount_xyz_m: tuple[float, float, float], stride: int = 4) -> tuple[np.ndarray, float]:
    """Valid depth pixels (every ``stride``-th) as robot-frame points (N, 3), and the valid fraction.

    Camera frame: x right, y down, z forward (optical axis level with the floor), mounted
    at ``mount_xyz_m`` (ahead, left, up) from the robot centre. Zero, negative and
    non-finite depths are holes.
    """
    d = np.asarray(depth_m, dtype=np.float32)[::stride, ::stride]
    if d.size == 0:
        return np.zeros((0, 3)), 0.0
    v, u = np.mgrid[0:depth_m.shape[0]:stride, 0:depth_m.shape[1]:stride]
    ok = np.isfinite(d) & (d > 0)
    z = d[ok].astype(np.float64)
    x_cam = (u[ok] - cx) * z / fx
    y_cam = (v[ok] - cy) * z / fy
    pts = np.stack([mount_xyz_m[0] + z, mount_xyz_m[1] - x_cam, mount_xyz_m[2] - y_cam], axis=1)
    return pts, float(ok.mean())


def thin_points(xy: np.ndarray, cell_m: float = 0.1, *, return_index: bool = False):
    """One point per ``cell_m`` square (the first seen), to keep the obstacle tree small: (M, 2),
    and with ``return_index`` also the indices (M,) of the kept points in ``xy``."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) == 0:
        return (xy, np.zeros(0, np.int64)) if return_index else xy
    _, keep = np.unique(np.floor(xy / cell_m).astype(np.int64), axis=0, return_index=True)
    keep = np.sort(keep)
    return (xy[keep], keep) if return_index else xy[keep]
