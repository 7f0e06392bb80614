"""Feature-expectation matching of the conflict price with the deployed planner in the loop.

Apprenticeship learning (Abbeel & Ng 2004; the feature matching of Kretzschmar et al. 2016)
on one weight: the planner's price of a conflict (the weights file's ``conflict`` weight, which
the IRL cost and the planner's speed profile both read). The robot takes the place of a
recorded walker among the others replayed (as the bench's real-crowd scenes do), the planner
node drives it from the walker's start to where the walker was ``window_s`` later, and the
feature the price controls is measured on both: the **encounter rate**, the fraction of the
walk's time with another walker's centre within 0.5 m of one's own (walkers who were the
walker's companions at the start are left out, for both: a robot walks with nobody). The
learnt price is where the planner's mean encounter rate over the training walkers crosses the
demonstrators' (:func:`match_price`, monotone interpolation over a log grid of prices).

Perception is ground truth, the way ``sim.irl_demos.track_demos`` learnt the 12 weights: each
other walker in the camera's view is a column of points moving at its recorded velocity
(no rendering, no optical flow), through the crowd-features, IRL-cost and planner nodes as the
launch file wires them. No collision guard: the price is the planner's to set.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ENCOUNTER_M = 0.5          # centre distance of an encounter (m)
COMPANION_M = 1.5          # a walker this near at the start ...
COMPANION_MPS = 0.5        # ... at a velocity this close is a companion (left out of the feature)
# ReactiveCrowd's social force: the bench's SocialForce but a milder keep-right side step, chosen (with the 1 s
# look-ahead) on the training sets biwi_eth, biwi_hotel, uni_examples so that a walker put back on his recorded
# track among the reactive others meets them as often as he met them recorded (bench/conflict_match.py --validate)
CROWD_FORCE = {"keep_right": 1.0}


@dataclass(frozen=True)
class Walk:
    """One demonstration: recorded walker ``pid`` of ``dataset`` over a gapless stretch of its track.

    ``t_s`` (n,) data-set seconds, ``xy_m`` (n, 2) metres; the goal is ``xy_m[-1]``.
    ``companions``: ids left out of the encounter feature."""

    dataset: str
    pid: int
    t_s: np.ndarray
    xy_m: np.ndarray
    companions: tuple[int, ...] = ()

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])


@dataclass
class Encounters:
    """The encounter feature of one walk: ``rate`` (fraction of ticks, 0-1), ``count`` (distinct encounters:
    a walker coming within ``ENCOUNTER_M``), ``time_s`` (to the goal, or the episode's length if not reached),
    ``reached``, ``closest_m`` (nearest non-companion centre); ``rate_self`` / ``count_self`` the same for the
    encounters whose onset the walk itself caused (``sim.crowd.robot_drove_in`` on the closing speeds): replayed
    people never make way for the robot, while the recorded walker's neighbours did make way for him."""

    rate: float
    count: int
    time_s: float
    reached: bool
    closest_m: float
    rate_self: float = 0.0
    count_self: int = 0
    xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)


def pick_walks(tracks, n: int, *, seed: int = 0, window_s: float = 8.0, min_len_m: float = 4.0,
               min_s: float = 4.0) -> list[Walk]:
    """A seeded choice of ``n`` demonstrations from ``tracks`` (``sim.pedestrian_data.Tracks``).

    Every gapless stretch of a track (:meth:`Tracks.segments`: a walker out of sight is cut there,
    never interpolated) gives its first ``window_s`` seconds; kept if it lasts ``min_s`` and ends
    ``min_len_m`` from where it began. Fewer than ``n`` candidates: all of them."""
    if n < 1:
        raise ValueError(f"n must be >= 1 walkers, got {n}")
    cands = []
    for i in range(len(tracks.ids)):
        for t, xy in tracks.segments(i):
            keep = t <= t[0] + window_s + 1e-9
            t, xy = t[keep], xy[keep]
            if len(t) >= 3 and t[-1] - t[0] >= min_s and np.hypot(*(xy[-1] - xy[0])) >= min_len_m:
                cands.append((i, t, xy))
                break                                   # one stretch per walker
    rng = np.random.default_rng(seed)
    pick = sorted(rng.choice(len(cands), size=min(n, len(cands)), replace=False).tolist()) if cands else []
    walks = []
    for j in pick:
        i, t, xy = cands[j]
        walks.append(Walk(tracks.name, int(tracks.ids[i]), t, xy, companions_at(tracks, int(tracks.ids[i]), t, xy)))
    return walks


def companions_at(tracks, pid: int, t_s: np.ndarray, xy_m: np.ndarray) -> tuple[int, ...]:
    """Ids walking with ``pid`` at its start: within ``COMPANION_M`` and ``COMPANION_MPS`` of its velocity."""
    ids, pos, vel = tracks.state_at(float(t_s[0]))
    own = (xy_m[1] - xy_m[0]) / max(t_s[1] - t_s[0], 1e-9)
    near = ((ids != pid) & (np.hypot(*(pos - xy_m[0]).T) < COMPANION_M)
            & (np.hypot(*(vel - own).T) < COMPANION_MPS))
    return tuple(int(i) for i in ids[near])


class _Tally:
    """Running encounter feature of one walk (see :class:`Encounters`)."""

    def __init__(self, skip: set[int]) -> None:
        self.skip, self.inside = skip, {}            # id -> did we close the gap at its onset
        self.ticks = self.hits = self.hits_self = self.count = self.count_self = 0
        self.closest = np.inf

    def add(self, xy: np.ndarray, vel: np.ndarray, ids: np.ndarray, pos: np.ndarray, pvel: np.ndarray) -> None:
        from sim.crowd import robot_drove_in

        keep = np.array([int(i) not in self.skip for i in ids], bool) if len(ids) else np.zeros(0, bool)
        now = {}
        for i, q, v in zip(ids[keep], pos[keep], pvel[keep]):
            d = float(np.hypot(*(q - xy)))
            self.closest = min(self.closest, d)
            if d >= ENCOUNTER_M:
                continue
            if int(i) in self.inside:
                now[int(i)] = self.inside[int(i)]
                continue
            u = (q - xy) / max(d, 1e-9)
            now[int(i)] = robot_drove_in(float(vel @ u), float(-(v @ u)))
            self.count += 1
            self.count_self += int(now[int(i)])
        self.inside = now
        self.ticks += 1
        self.hits += bool(now)
        self.hits_self += any(now.values())

    def result(self, time_s: float, reached: bool, xy: np.ndarray) -> Encounters:
        n = max(self.ticks, 1)
        return Encounters(self.hits / n, self.count, time_s, reached, self.closest, self.hits_self / n,
                          self.count_self, xy)


def human_encounters(tracks, walk: Walk, *, dt_s: float = 1.0 / 15.0) -> Encounters:
    """The demonstrator's own encounter feature over its recorded walk (positions interpolated at ``dt_s``)."""
    tt = np.arange(walk.t_s[0], walk.t_s[-1] + 1e-9, dt_s)
    xy = np.column_stack([np.interp(tt, walk.t_s, walk.xy_m[:, 0]), np.interp(tt, walk.t_s, walk.xy_m[:, 1])])
    own = np.gradient(xy, dt_s, axis=0) if len(xy) > 1 else np.zeros_like(xy)
    tally = _Tally({walk.pid, *walk.companions})
    for tk, p, v in zip(tt, xy, own):
        tally.add(p, v, *tracks.state_at(float(tk)))
    return tally.result(walk.duration_s, True, xy)


class ReactiveCrowd:
    """The walkers of ``tracks`` (but ``exclude``) from data time ``t0_s`` as social-force agents.

    ``sim.crowd_scenes.Walkers`` steps them with ``force`` (``SocialForce``, default ``CROWD_FORCE``: each other and the
    agent in the replaced walker's place repel them; no walls, the data sets have no maps). Each
    gapless stretch of a track (:meth:`Tracks.segments`) that overlaps ``[t0_s, t0_s + span_s]``
    is one agent, reported under the walker's id: it appears where and how fast the walker was at
    the window start (or when first seen), heads for its **recorded position** ``lookahead_s``
    ahead (a moving waypoint) at the speed that would get it there on time, capped at
    ``force.max_speed_factor`` x the stretch's fastest recorded speed, and leaves when its recorded
    stretch ends. With nobody pushing, an agent on its track keeps to it; pushed off, it is drawn
    back. ``radius_m``: body radius of the agents (m); ``substep_s``: the longest force step (s).
    Same interface as ``Tracks.state_at`` through :meth:`state`; advance with :meth:`step`."""

    def __init__(self, tracks, t0_s: float, span_s: float, *, exclude: tuple[int, ...] = (),
                 force=None, lookahead_s: float = 1.0, radius_m: float = 0.3, substep_s: float = 1.0 / 30.0) -> None:
        from sim.crowd_scenes import PedestrianSpec, Scene, SocialForce, Walkers

        if not (lookahead_s > 0 and radius_m > 0 and substep_s > 0 and span_s > 0):
            raise ValueError(f"lookahead_s, radius_m, substep_s and span_s must be > 0, got {lookahead_s}, "
                             f"{radius_m}, {substep_s}, {span_s}")
        self.t0_s, self.span_s, self.lookahead_s, self.substep_s = float(t0_s), float(span_s), lookahead_s, substep_s
        skip = {int(i) for i in exclude}
        pids, stretches, specs = [], [], []
        for i, pid in enumerate(tracks.ids):
            if int(pid) in skip:
                continue
            for t, xy in tracks.segments(i):
                if t[-1] < t0_s or t[0] > t0_s + span_s or len(t) < 2:
                    continue
                a = max(float(t[0]), t0_s)
                fastest = float(np.max(np.hypot(*np.diff(xy, axis=0).T) / np.diff(t)))
                specs.append(PedestrianSpec(id=len(specs), waypoints=self._at(t, xy, a)[None], radius_m=radius_m,
                                            speed_mps=max(fastest, 0.1), start_s=a - t0_s))
                pids.append(int(pid))
                stretches.append((t, xy))
        self.pids, self.stretches = np.array(pids, np.int64), stretches
        self.end_s = np.array([t[-1] - t0_s for t, _ in stretches])
        scene = Scene(name=f"{tracks.name}@{t0_s:g}", pedestrians=tuple(specs), pedestrian_model="social_force")
        self.walkers = Walkers(scene, force=force if force is not None else SocialForce(**CROWD_FORCE))
        self.t_s = 0.0
        self.walkers.present[:] = False               # Walkers starts them still: _enter gives their recorded velocity
        self._enter(0.0)

    @staticmethod
    def _at(t: np.ndarray, xy: np.ndarray, when: float) -> np.ndarray:
        return np.array([np.interp(when, t, xy[:, 0]), np.interp(when, t, xy[:, 1])])

    def _vel(self, k: int, when: float) -> np.ndarray:
        t, xy = self.stretches[k]
        j = int(np.clip(np.searchsorted(t, when, side="right") - 1, 0, len(t) - 2))
        return (xy[j + 1] - xy[j]) / (t[j + 1] - t[j])

    def _enter(self, upto_s: float) -> None:
        """Agents appearing by ``upto_s`` (s since t0) start at their recorded velocity."""
        w = self.walkers
        new = ~w.present & (w.start_s <= upto_s + 1e-9)
        for k in np.flatnonzero(new):
            w.vel[k] = self._vel(int(k), self.t0_s + w.start_s[k])
        w.present |= new

    def recorded(self, k: int, t_s: float) -> np.ndarray:
        """Where agent ``k`` was recorded at ``t_s`` (s since t0; clamped to its stretch), (2,) m."""
        t, xy = self.stretches[k]
        return self._at(t, xy, self.t0_s + t_s)

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Agents present now: ids (M,), positions (M, 2) m, velocities (M, 2) m/s."""
        p = self.walkers.present & (self.end_s >= self.t_s - 1e-9)
        return self.pids[p], self.walkers.xy[p].copy(), self.walkers.vel[p].copy()

    def drift(self) -> np.ndarray:
        """Distance (M,) m of each present agent from where it was recorded now."""
        p = np.flatnonzero(self.walkers.present & (self.end_s >= self.t_s - 1e-9))
        if not len(p):
            return np.zeros(0)
        rec = np.array([self.recorded(int(k), self.t_s) for k in p])
        return np.hypot(*(self.walkers.xy[p] - rec).T)

    def step(self, dt_s: float, robot: tuple[float, ...] | None = None) -> None:
        """Advance ``dt_s`` seconds; ``robot`` = (x, y, vx, vy, radius) of whoever is in the replaced walker's
        place (m, m/s; ``None``: nobody), held over the sub-steps."""
        w = self.walkers
        n = max(1, int(np.ceil(dt_s / self.substep_s - 1e-9)))
        h = dt_s / n
        for _ in range(n):
            self._enter(self.t_s + h)
            goals, v0 = w.xy.copy(), np.zeros(len(self.pids))
            for k in np.flatnonzero(w.present):
                ahead = min(self.lookahead_s, max(self.end_s[k] - self.t_s, h))
                goals[k] = self.recorded(int(k), self.t_s + ahead)
                v0[k] = min(np.hypot(*(goals[k] - w.xy[k])) / ahead, w.force.max_speed_factor * w.speed[k])
            if len(self.pids):
                w.step(self.t_s, h, robot, goals=goals, v0=v0)
            self.t_s += h
            gone = w.present & (self.end_s < self.t_s - 1e-9)
            w.present &= ~gone
            w.start_s[gone] = np.inf                  # Walkers.step would bring them back
            w.vel[gone] = 0.0


def human_among_reactive(tracks, walk: Walk, *, dt_s: float = 1.0 / 15.0, robot_radius_m: float = 0.35,
                         **crowd) -> tuple[Encounters, np.ndarray]:
    """The demonstrator walking its recorded track exactly (not reacting) among the others as a
    :class:`ReactiveCrowd` (``crowd``: its keywords) that sees him as it would see the robot (the
    ``robot`` agent of the social force, ``robot_radius_m``). The check of the reactive crowd: if it
    is calibrated, his encounter feature here agrees with :func:`human_encounters` (the recorded crowd).
    Returns his :class:`Encounters` and the others' drift from their recorded positions (m, one entry
    per agent and tick)."""
    tt = np.arange(walk.t_s[0], walk.t_s[-1] + 1e-9, dt_s)
    xy = np.column_stack([np.interp(tt, walk.t_s, walk.xy_m[:, 0]), np.interp(tt, walk.t_s, walk.xy_m[:, 1])])
    own = np.gradient(xy, dt_s, axis=0) if len(xy) > 1 else np.zeros_like(xy)
    rc = ReactiveCrowd(tracks, float(walk.t_s[0]), walk.duration_s + dt_s, exclude=(walk.pid,), **crowd)
    tally, drift = _Tally({walk.pid, *walk.companions}), []
    for p, v in zip(xy, own):
        tally.add(p, v, *rc.state())
        drift.append(rc.drift())
        rc.step(dt_s, (float(p[0]), float(p[1]), float(v[0]), float(v[1]), robot_radius_m))
    return tally.result(walk.duration_s, True, xy), np.concatenate(drift) if drift else np.zeros(0)


def crowd_drift(tracks, walk: Walk, *, span_s: float | None = None, dt_s: float = 1.0 / 15.0, **crowd) -> np.ndarray:
    """How far the others of ``walk`` (a :class:`ReactiveCrowd`, ``crowd`` its keywords) drift from their
    recorded positions with nobody in the walker's place: distances (m), one per agent and tick over
    ``span_s`` (default the walk's duration) from the walk's start."""
    span = walk.duration_s if span_s is None else float(span_s)
    rc = ReactiveCrowd(tracks, float(walk.t_s[0]), span + dt_s, exclude=(walk.pid,), **crowd)
    out = []
    for _ in range(int(round(span / dt_s)) + 1):
        out.append(rc.drift())
        rc.step(dt_s, None)
    return np.concatenate(out) if out else np.zeros(0)


def weights_with_price(src: str | Path, price: float, dst: str | Path) -> Path:
    """Copy the weights file ``src`` to ``dst`` with its ``conflict`` weight set to ``price`` (cost units, as
    the step cost). Raises ValueError when ``src`` has no conflict feature (learn one with conflict on)."""
    data = json.loads(Path(src).read_text(encoding="utf-8"))
    if "conflict" not in data.get("names", []):
        raise ValueError(f"{src} has no 'conflict' weight: use weights learnt with the conflict feature "
                         "(nodes/nav/weights/default.json)")
    if not np.isfinite(price) or price < 0:
        raise ValueError(f"price must be finite and >= 0, got {price}")
    data["weights"][data["names"].index("conflict")] = float(price)
    Path(dst).write_text(json.dumps(data), encoding="utf-8")
    return Path(dst)


def replace_walker(tracks, walk: Walk, weights_path: str | Path, *, dt_s: float = 1.0 / 15.0,
                   timeout_factor: float = 2.5, slack_s: float = 8.0, goal_tol_m: float = 0.5,
                   fov_deg: float = 130.0, range_m: float = 8.0, planner_params: dict | None = None,
                   seed: int = 0, reactive: dict | None = None) -> Encounters:
    """Drive the planner node from ``walk``'s start to its goal among the other walkers replayed.

    ``reactive``: ``None`` replays the others as recorded (they never make way for the robot); a dict
    (:class:`ReactiveCrowd`'s keywords, ``{}`` for its defaults) makes them a reactive crowd seeded from
    their tracks, which sees the robot (its disc, ``RobotLimits.radius_m``) as :func:`human_among_reactive`
    sees the demonstrator.

    The robot (``sim.crowd.RobotLimits``, unicycle) starts at the walker's first position facing
    its first step; the episode ends at the goal (``goal_tol_m``) or after ``timeout_factor`` x
    the walker's time + ``slack_s``. Each tick (``dt_s``) the others in the camera's view
    (``fov_deg`` from a camera 0.3 m ahead, ``range_m``) become body points with their recorded
    velocities (``sim.irl_demos.body_points``) -> CrowdFeatures -> IrlCost -> DijkstraPlanner
    (``nodes.nav.demos.PLANNER_PARAMS`` + ``planner_params``; person_cost at its default 0)."""
    from msgs.geometry import Odometry2D, Pose2D, Twist2D
    from msgs.nav import FlowPoints, Goal2D
    from msgs.sensor import Grid
    from nodes.nav.crowd_features import CrowdFeatures
    from nodes.nav.demos import FEATURE_PARAMS, PLANNER_PARAMS
    from nodes.nav.dijkstra_planner import DijkstraPlanner
    from nodes.nav.grid_frame import to_robot
    from nodes.nav.irl_cost import IrlCost
    from sim.crowd import RobotLimits, unicycle_step
    from sim.irl_demos import body_points
    from tether.testing import Harness

    rng = np.random.default_rng(seed)
    feats = Harness(CrowdFeatures, params=FEATURE_PARAMS, roundtrip=False, node_id="features")
    cost = Harness(IrlCost, params={"weights_path": str(weights_path)}, roundtrip=False, node_id="cost")
    plan = Harness(DijkstraPlanner, params={**PLANNER_PARAMS, "weights_path": str(weights_path), **(planner_params or {})},
                   roundtrip=False, node_id="planner")
    for h in (feats, cost, plan):
        h.node.log.setLevel(logging.ERROR)
    goal_xy = walk.xy_m[-1]
    lo, hi = np.minimum(walk.xy_m.min(0), goal_xy) - 10.0, np.maximum(walk.xy_m.max(0), goal_xy) + 10.0
    shape = tuple(np.ceil((hi - lo) / 0.1).astype(int)[::-1])
    goal = Goal2D(x_m=float(goal_xy[0]), y_m=float(goal_xy[1]), tolerance_m=goal_tol_m, frame_id="world")
    feats.feed([(0.0, "goal", goal)])
    plan.feed([(0.0, "goal", goal), (0.0, "map", Grid(data=np.zeros(shape, np.uint8), resolution_m=0.1,
                                                        origin_x_m=float(lo[0]), origin_y_m=float(lo[1]), frame_id="world"))])
    k = int(np.argmax(np.hypot(*(walk.xy_m - walk.xy_m[0]).T) > 0.3)) or 1
    heading = np.arctan2(*(walk.xy_m[k] - walk.xy_m[0])[::-1])
    pose, twist, limits = (float(walk.xy_m[0, 0]), float(walk.xy_m[0, 1]), float(heading)), (0.0, 0.0), RobotLimits()
    tally, path = _Tally({walk.pid, *walk.companions}), []
    max_s, t, cmd, reached = timeout_factor * walk.duration_s + slack_s, 0.0, (0.0, 0.0), False
    crowd = None if reactive is None else ReactiveCrowd(tracks, float(walk.t_s[0]), max_s + dt_s,
                                                         exclude=(walk.pid,), **reactive)
    while t <= max_s:
        ids, pos, vel = tracks.state_at(float(walk.t_s[0] + t)) if crowd is None else crowd.state()
        tally.add(np.array(pose[:2]), twist[0] * np.array([np.cos(pose[2]), np.sin(pose[2])]), ids, pos, vel)
        path.append(pose[:2])
        if np.hypot(pose[0] - goal_xy[0], pose[1] - goal_xy[1]) <= goal_tol_m:
            reached = True
            break
        others = ids != walk.pid
        rel = to_robot(pose, pos[others])
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rvel = vel[others] @ np.array([[c, -s], [s, c]])
        seen = ((np.hypot(rel[:, 0], rel[:, 1]) <= range_m)
                & (np.abs(np.arctan2(rel[:, 1], rel[:, 0] - 0.3)) <= np.radians(fov_deg) / 2))
        pts, pvel = body_points(rel[seen], rvel[seen], rng)
        stamp = int(round(t * 1e9))
        odom = Odometry2D(stamp_ns=stamp, frame_id="world", pose=Pose2D(x_m=pose[0], y_m=pose[1], yaw_rad=pose[2]),
                          twist=Twist2D(vx_mps=twist[0], wz_radps=twist[1]))
        flow = FlowPoints(stamp_ns=stamp, frame_id="base", points_m=pts.astype(np.float32),
                          velocity_mps=pvel.astype(np.float32))
        cmds = [o.msg for o in plan.feed([(t, "odom", odom)]) if o.output == "cmd"]
        feats.feed([(t, "odom", odom)])
        grids = [o.msg for o in feats.feed([(t, "flow", flow)]) if o.output == "features"]
        if grids:
            costs = [o.msg for o in cost.feed([(t, "features", grids[-1])])]
            out = plan.feed([(t, "flow", flow), (t, "features", grids[-1])] + [(t, "costs", cg) for cg in costs])
            cmds += [o.msg for o in out if o.output == "cmd"]
        if cmds:
            cmd = (cmds[-1].vx_mps, cmds[-1].wz_radps)
        pose, twist = unicycle_step(pose, twist, cmd, dt_s, limits)
        if crowd is not None:
            crowd.step(dt_s, (pose[0], pose[1], twist[0] * np.cos(pose[2]), twist[0] * np.sin(pose[2]),
                              limits.radius_m))
        t += dt_s
    return tally.result(t if reached else max_s, reached, np.array(path))


@dataclass(frozen=True)
class Match:
    """A matched price (cost units) and whether it lies outside the grid searched: ``censored`` is
    '' (inside), 'below' (the planner meets fewer than the demonstrators even at the lowest price) or
    'above' (more even at the highest)."""

    price: float
    censored: str = ""


def match_price(prices: np.ndarray, planner: np.ndarray, human: float) -> Match:
    """The price at which the planner's feature equals the demonstrators' ``human``.

    ``prices`` (P,) increasing, > 0; ``planner`` (P,) the planner's mean feature at each price. The
    curve is made non-increasing (running minimum: a dearer conflict never buys more encounters,
    wiggles are noise) and crossed by linear interpolation in log price. Outside the curve's range
    the nearest end is returned, ``censored``."""
    prices, planner = np.asarray(prices, float), np.asarray(planner, float)
    if prices.ndim != 1 or prices.shape != planner.shape or len(prices) < 2:
        raise ValueError(f"give >= 2 prices and one planner feature per price, got {prices.shape} and {planner.shape}")
    if not (np.all(prices > 0) and np.all(np.diff(prices) > 0)):
        raise ValueError("prices must be > 0 and increasing (a log grid, e.g. np.geomspace(0.1, 40, 7))")
    if not (np.isfinite(human) and np.all(np.isfinite(planner))):
        raise ValueError("features must be finite: drop walkers with no samples before averaging")
    f = np.minimum.accumulate(planner)
    if human >= f[0]:
        return Match(float(prices[0]), "below" if human > f[0] else "")
    if human < f[-1]:
        return Match(float(prices[-1]), "above")
    j = int(np.flatnonzero(f <= human)[0])          # first price at or under the demonstrators
    lp = np.log(prices)
    if f[j - 1] == f[j]:
        return Match(float(prices[j]))
    a = (f[j - 1] - human) / (f[j - 1] - f[j])
    return Match(float(np.exp(lp[j - 1] + a * (lp[j] - lp[j - 1]))))


def bootstrap_prices(prices: np.ndarray, planner: np.ndarray, human: np.ndarray, *, n_boot: int = 1000,
                     seed: int = 0) -> np.ndarray:
    """Matched prices over walkers resampled with replacement: ``planner`` (W, P) per walker and price,
    ``human`` (W,). Returns (n_boot,) prices (censored ones at the grid's ends)."""
    planner, human = np.asarray(planner, float), np.asarray(human, float)
    if planner.ndim != 2 or planner.shape[0] != len(human) or len(human) < 2:
        raise ValueError(f"planner must be (walkers, prices) and human (walkers,), >= 2 walkers; got "
                         f"{planner.shape} and {human.shape}")
    rng = np.random.default_rng(seed)
    out = np.empty(n_boot)
    for b in range(n_boot):
        k = rng.integers(0, len(human), len(human))
        out[b] = match_price(prices, planner[k].mean(0), float(human[k].mean())).price
    return out


def loso_prices(prices: np.ndarray, per_scene: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, Match]:
    """Leave-one-scene-out: for each scene, the price matched on the others' walkers pooled.

    ``per_scene`` maps a scene name to (planner (W, P), human (W,)). Raises ValueError with fewer than
    two scenes (nothing is left to learn from: use :func:`bootstrap_prices` over walkers instead)."""
    if len(per_scene) < 2:
        raise ValueError(f"leave-one-scene-out needs >= 2 scenes, got {list(per_scene)}: add a data set, or "
                         "give an interval with bootstrap_prices over the walkers")
    out = {}
    for name in per_scene:
        rest = [v for k, v in per_scene.items() if k != name]
        pm = np.concatenate([np.asarray(p, float).reshape(-1, len(prices)) for p, _ in rest])
        hm = np.concatenate([np.asarray(h, float).ravel() for _, h in rest])
        out[name] = match_price(prices, pm.mean(0), float(hm.mean()))
    return out
