"""What a social-navigation run leaves to score: the episode record, the paper's metrics and
contact onsets. Shared by bench/social_nav.py (in-process runs) and bench/social_nav_live.py
(launched runs), which used to import each other for it."""
from __future__ import annotations

import dataclasses

import numpy as np

from sim.crowd import robot_drove_in

TURN_RADPS = 0.3          # a yaw rate above this near people counts as the avoidance manoeuvre


@dataclasses.dataclass
class Episode:
    """One run: times (n,), poses (n, 3), yaw rates (n,), pedestrians per step [(ids, xy)], outcome."""

    t: np.ndarray
    pose: np.ndarray
    yaw_rate: np.ndarray
    peds: list[tuple[np.ndarray, np.ndarray]]
    goal_t: float | None
    collisions: int
    stage_ms: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    by_robot: int | None = None          # contacts where the robot drove into the person (None = not known)


def metrics(ep: Episode, radius_m: float = 0.65) -> dict:
    """The paper's metrics (centre distances, m; times, s) from an episode."""
    d = np.full(len(ep.t), np.inf)
    for k, (_, xy) in enumerate(ep.peds):
        if len(xy):
            d[k] = np.hypot(*(xy - ep.pose[k, :2]).T).min()
    turning = np.flatnonzero((np.abs(ep.yaw_rate) > TURN_RADPS) & (ep.t > 0.5) & np.isfinite(d) & (d < 8.0))
    end = len(ep.t) if ep.goal_t is None else int(np.searchsorted(ep.t, ep.goal_t)) + 1
    length = float(np.sum(np.hypot(*np.diff(ep.pose[:end, :2], axis=0).T)))
    closest = float(d[:end].min()) if np.isfinite(d[:end]).any() else None
    return {"closest_m": None if closest is None else round(closest, 3),
            "avoidance_m": round(float(d[turning[0]]), 3) if len(turning) else None,
            "time_s": None if ep.goal_t is None else round(ep.goal_t, 2), "path_m": round(length, 2),
            "collisions": int(ep.collisions),
            "collisions_robot": None if ep.by_robot is None else int(ep.by_robot),
            "collisions_pedestrian": None if ep.by_robot is None else int(ep.collisions - ep.by_robot),
            "success": bool(ep.goal_t is not None and ep.collisions == 0)}


def contact_onsets(t: np.ndarray, xy: np.ndarray, robot_vel: np.ndarray, peds: list[tuple[np.ndarray, np.ndarray]], *,
                   radius_m: float = 0.65, fault_mps: float = 0.1) -> list[tuple[float, int, bool]]:
    """Contacts (t_s, pedestrian id, robot drove in) from a sampled episode, as ``sim.crowd`` attributes them:
    at the onset the robot's velocity (n, 2) toward the person exceeds ``fault_mps`` -> the robot drove in."""
    out, touching = [], set()
    prev: dict[int, tuple[float, np.ndarray]] = {}
    for k, (ids, p) in enumerate(peds):
        d = np.hypot(*(p - xy[k]).T) if len(ids) else np.zeros(0)
        now = {int(i) for i in ids[d < radius_m]}
        for j in np.flatnonzero(d < radius_m):
            if int(ids[j]) not in touching:
                u = (p[j] - xy[k]) / max(d[j], 1e-9)
                t_prev, p_prev = prev.get(int(ids[j]), (t[k], p[j]))
                ped_vel = (p[j] - p_prev) / (t[k] - t_prev) if t[k] > t_prev else np.zeros(2)
                out.append((float(t[k]), int(ids[j]), robot_drove_in(float(robot_vel[k] @ u), float(-ped_vel @ u), fault_mps)))
        touching = now
        prev = {int(i): (t[k], q) for i, q in zip(ids, p)}
    return out
