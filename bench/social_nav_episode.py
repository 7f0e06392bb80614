"""What a social-navigation run leaves to score: the episode record, the paper's metrics and
contact onsets. Shared by bench/social_nav.py (in-process runs) and bench/social_nav_live.py
(launched runs), which used to import each other for it."""
from __future__ import annotations

import dataclasses

import numpy as np

from sim.crowd import robot_drove_in

TURN_RADPS = 0.3          # a yaw rate above this near people counts as the avoidance manoeuvre
#: the collision guard's status reason (its first words) -> the rule that braked (``guard_why``)
GUARD_RULES = (("obstacle at", "stop"), ("obstacle predicted", "stop_few_predicted"),
               ("waiting for the path", "hold"), ("slowed", "slowed"))


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
    guard_ticks: int = 0                 # control ticks where the collision guard changed the planner's command
    ticks: int = 0                       # control ticks
    start_shift_s: float = 0.0           # the crowd walked this long before the robot appeared (clear start)
    guard_why: dict[str, int] = dataclasses.field(default_factory=dict)   # braked ticks by guard rule (social_nav.guarded)
    guard_ticks_other: int | None = None     # ticks the other-rule shadow guard would have braked (social_nav.shadow_guarded)
    planner_why: dict[str, int] | None = None   # IRL planner: ticks its speed profile waited / slowed (planner_paced)
    replans: int | None = None           # IRL planner: local plans it adopted (a re-plan event, not 'path kept')
    guard: str = "on"                    # 'on': the guard's command drove the robot; 'shadow': the planner's did, the
                                         # guard only counted (guard_ticks: the ticks it would have braked)


#: who was ahead when the guard braked (``guard_why`` keys ``ahead_*``): the nearest pedestrian centre in front of the
#: robot within AHEAD_M, by its velocity along / across the robot's heading (AHEAD_MPS apart from standing)
AHEAD_M = 1.8
AHEAD_MPS = 0.3


def ahead_kind(pose: tuple[float, float, float], xy_m: np.ndarray, vel_mps: np.ndarray) -> str:
    """'toward' (walking at the robot), 'same_way', 'crossing', 'standing' or 'nobody' (no centre ahead within AHEAD_M).

    Ground truth, for the bench's diagnosis of guard stops: the guard itself sees depth points, not people."""
    x, y, yaw = pose
    heading, left = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    rel = np.asarray(xy_m, float).reshape(-1, 2) - (x, y)
    ahead = (rel @ heading > 0) & (np.hypot(rel[:, 0], rel[:, 1]) < AHEAD_M)
    if not ahead.any():
        return "nobody"
    i = np.flatnonzero(ahead)[np.argmin(np.hypot(rel[ahead, 0], rel[ahead, 1]))]
    v = np.asarray(vel_mps, float).reshape(-1, 2)[i]
    along, across = float(v @ heading), float(v @ left)
    if along < -AHEAD_MPS:
        return "toward"
    if along > AHEAD_MPS:
        return "same_way"
    return "crossing" if abs(across) > AHEAD_MPS else "standing"


def metrics(ep: Episode, radius_m: float = 0.65) -> dict:
    """The paper's metrics (centre distances, m; times, s) from an episode; when recorded, how often the
    other-rule guard would have braked (``guard_frac_other_rule``) and how often the IRL planner's own speed
    profile waited or slowed for predicted people (``planner_wait_frac``, and by ``planner_why``: 'wait',
    speed 0 where steering would drive, or 'slow'), as shares of control ticks. Weaving: ``heading_reversals``
    counts the turns that reverse the previous turn (sign changes of the yaw rate over the ticks turning faster than
    TURN_RADPS), ``replans`` (IRL planner) the local plans adopted."""
    d = np.full(len(ep.t), np.inf)
    for k, (_, xy) in enumerate(ep.peds):
        if len(xy):
            d[k] = np.hypot(*(xy - ep.pose[k, :2]).T).min()
    turning = np.flatnonzero((np.abs(ep.yaw_rate) > TURN_RADPS) & (ep.t > 0.5) & np.isfinite(d) & (d < 8.0))
    end = len(ep.t) if ep.goal_t is None else int(np.searchsorted(ep.t, ep.goal_t)) + 1
    length = float(np.sum(np.hypot(*np.diff(ep.pose[:end, :2], axis=0).T)))
    closest = float(d[:end].min()) if np.isfinite(d[:end]).any() else None
    stopped_at_closest = None
    if closest is not None and len(ep.t) >= 2:
        k = int(np.argmin(d[:end]))
        speed = np.hypot(*np.gradient(ep.pose[:, :2], ep.t, axis=0).T)
        stopped_at_closest = bool(speed[k] < STOPPED_MPS)
    m = {"closest_m": None if closest is None else round(closest, 3),
            "avoidance_m": round(float(d[turning[0]]), 3) if len(turning) else None,
            "time_s": None if ep.goal_t is None else round(ep.goal_t, 2), "path_m": round(length, 2),
            "collisions": int(ep.collisions),
            "collisions_robot": None if ep.by_robot is None else int(ep.by_robot),
            "collisions_pedestrian": None if ep.by_robot is None else int(ep.collisions - ep.by_robot),
            "success": bool(ep.goal_t is not None and ep.collisions == 0),
            **strict_contacts(ep),
            "guard_frac": round(ep.guard_ticks / ep.ticks, 4) if ep.ticks else None,
            "guard_why": {k: round(n / ep.ticks, 4) for k, n in sorted(ep.guard_why.items())} if ep.ticks else {},
            "stopped_at_closest": stopped_at_closest,
            "heading_reversals": heading_reversals(ep.yaw_rate[:end]),
            "start_shift_s": round(ep.start_shift_s, 2)}
    if ep.guard != "on":
        m["guard"] = ep.guard           # 'shadow': guard_frac / guard_why are what it would have braked
    if ep.guard_ticks_other is not None and ep.ticks:
        m["guard_frac_other_rule"] = round(ep.guard_ticks_other / ep.ticks, 4)
    if ep.replans is not None:
        m["replans"] = int(ep.replans)
    if ep.planner_why is not None and ep.ticks:
        m["planner_wait_frac"] = round(sum(ep.planner_why.values()) / ep.ticks, 4)
        m["planner_why"] = {k: round(n / ep.ticks, 4) for k, n in sorted(ep.planner_why.items())}
    return m


def heading_reversals(yaw_rate: np.ndarray, turn_radps: float = TURN_RADPS) -> int:
    """How often a turn (|yaw rate| above ``turn_radps``) goes the other way than the turn before it."""
    w = np.asarray(yaw_rate, float)
    sign = np.sign(w[np.abs(w) > turn_radps])
    return int(np.count_nonzero(np.diff(sign)))


#: the robot counts as stopped below this speed (m/s): a closest approach then is a person walking up to it
STOPPED_MPS = 0.1

#: bodies touch at this centre distance: 0.2 m personal radius each (issue 22, section 5)
TOUCH_M = 0.4


def strict_contacts(ep: Episode, *, touch_m: float = TOUCH_M, moving_mps: float = 0.05) -> dict:
    """Contacts at touching distance, blamed strictly: at the onset, whoever closes on the other is to
    blame, the robot first when both do (its closing speed above ``moving_mps`` is enough, whatever the
    person does); the person only when the robot was not closing. ``robot_contacts_strict`` counts the
    robot's; ``contacts_strict_moving`` the contacts while the robot moved at all."""
    t, xy = ep.t, ep.pose[:, :2]
    if len(t) < 2:
        return {"contacts_strict": 0, "robot_contacts_strict": 0, "contacts_strict_moving": 0}
    vel = np.gradient(xy, t, axis=0)
    n = robot = moving = 0
    touching: set[int] = set()
    for k, (ids, p) in enumerate(ep.peds):
        if ep.goal_t is not None and t[k] > ep.goal_t:
            break
        d = np.hypot(*(p - xy[k]).T) if len(ids) else np.zeros(0)
        now = {int(i) for i in ids[d < touch_m]} if len(ids) else set()
        for i in now - touching:
            j = int(np.flatnonzero(ids == i)[0])
            u = (p[j] - xy[k]) / max(d[j], 1e-9)
            n += 1
            robot += int(float(vel[k] @ u) > moving_mps)
            moving += int(float(np.hypot(*vel[k])) > moving_mps)
        touching = now
    return {"contacts_strict": n, "robot_contacts_strict": robot, "contacts_strict_moving": moving}


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
