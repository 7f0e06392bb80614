"""The collision guard's 1 m rule asked of people: how often would it brake a real walker?

    python bench/guard_on_walkers.py [--json] [--sets biwi_eth ...] [--scenes toward ...] [--no-plot]

Issue 18 §1 asks that the guard brake the robot in < 5 % of control ticks. This bench measures what
the same rule says about people who walk among each other. Open loop (the guard's command is
recorded, never obeyed: the walker walks on, as the bench's shadow guard ``guard_other`` does),
deterministic (no random numbers), no rendering.

What is fed to the guard: a real :class:`nodes.nav.collision_guard.CollisionGuard` in a
``tether.testing.Harness`` with the bench's parameters (``launch/social_nav.yaml``: the defaults,
``stop_distance_m`` 1.0; the robot's radius 0.35 m and margin 0.1 m, so the walker is given the robot's
body), one guard per walker (per track segment), ticked at the bench's 15 Hz (``DT``). At each tick, in
this order:

- ``points``: a ``FlowPoints`` in the walker's frame (x along its heading): every other pedestrian
  present (ground truth, within ``REACH_M``, which is beyond anything the guard looks at) as the outline
  of a 0.3 m disc (the simulator's body radius), one point per 5 cm (the guard's thinning) at 1 m height,
  each with that person's velocity turned into the walker's frame (the flow node's convention: the
  world velocity, the observer's own motion removed), so the guard extrapolates them as it does for the
  robot (``predict_s``). No ``rgbd`` and no ``odom``: no field of view, no blind zone, no depth holes, no
  memory of unseen points and no walls (the recorded scenes have no map); the guard sees every person
  all around, as it never does on the robot.
- ``cmd``: the walker's own (v, yaw rate) at that moment: on the recorded sets, its speed and
  heading rate from central differences of its track (positions linearly interpolated between the
  annotated rows, as :meth:`sim.pedestrian_data.Tracks.state_at` gives the others); for the bench's
  human reference (:func:`episode_guard`), the speed of the recorded path and the bench's own
  ``Episode.yaw_rate``.

A tick counts when the walker moves faster than ``MOVING_MPS`` (0.3 m/s); it is braked when the guard's
command is slower than the walker's (as ``social_nav.guarded`` counts the robot's), split by the same
rules (``guard_why``: 'stop', 'stop_few_predicted', 'hold', 'slowed'; 'slowed' includes walkers faster
than the robot's 1 m/s whom the braking cap slows) and by who was ahead (``ahead_*``,
:func:`social_nav_episode.ahead_kind`). ``stop_frac`` leaves out 'slowed'. Beside it, the simpler
ground-truth rule (``gt_rule_frac``): another person's centre within 1.0 m of the walker's centre
whose 0.3 m body the walker's path (its 0.45 m disc, along the commanded arc, :func:`free_distance_m`)
would close in on: no prediction, no hold, no speed cap. ``without_companions``: the same with a second guard fed
everyone but the walker's companions at that tick (:func:`companions`: within 2 m, walking with a velocity within
0.5 m/s of the walker's; a heuristic): recorded people walk in groups shoulder to shoulder, inside the robot's
0.45 m disc corridor, and a robot walks with nobody.

JSON: ``walkers`` per recorded set (ticks, ``guard_frac``, ``stop_frac``, ``gt_rule_frac``, ``guard_why``),
``guard_frac_walkers`` (set -> share), ``human`` per bench scenario (its human reference, fed the
episode's ground-truth people; velocities by central differences of their positions), beside the
robot's ``guard_frac`` from ``out/bench/social_nav.json`` when present. Writes
``out/guard_on_walkers.png``. The recorded sets need ``../shared/data/pedestrians`` (skipped, and said,
when absent).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from msgs.geometry import Twist2D  # noqa: E402
from msgs.nav import FlowPoints  # noqa: E402
from nodes.nav.clearance import free_distance_m  # noqa: E402
from nodes.nav.collision_guard import CollisionGuard  # noqa: E402
from nodes.nav.grid_frame import to_robot  # noqa: E402
from social_nav_episode import GUARD_RULES, Episode, ahead_kind  # noqa: E402
from social_nav_humans import DT  # noqa: E402
from tether.testing import Harness  # noqa: E402

BODY_RADIUS_M = 0.3        # a pedestrian's body (sim.crowd_scenes.PedestrianSpec.radius_m)
OUTLINE_STEP_M = 0.05      # one outline point per 5 cm (the guard thins its points to one per 5 cm)
POINT_Z_M = 1.0            # the outline's height (inside the guard's z band)
MOVING_MPS = 0.3           # walker ticks slower than this are not counted
REACH_M = 8.0              # people farther than this are left out (the guard looks <= 3.85 m, + 0.7 s at 5 m/s)
GT_STOP_M = 1.0            # the ground-truth rule's centre distance
COMPANION_M = 2.0          # a companion: another walker within this centre distance ...
COMPANION_MPS = 0.5        # ... whose velocity differs from the walker's by less than this (both moving)
SETS = ["biwi_eth", "biwi_hotel", "crowds_zara03", "students003", "uni_examples"]


def guard_params() -> dict:
    """The bench's guard parameters: the ``guard`` node's params in ``launch/social_nav.yaml``."""
    import yaml
    launch = yaml.safe_load((ROOT / "launch" / "social_nav.yaml").read_text())
    return dict(next(n for n in launch["nodes"] if n["id"] == "guard").get("params") or {})


def outlines(xy: np.ndarray, vel: np.ndarray, *, radius_m: float = BODY_RADIUS_M,
             step_m: float = OUTLINE_STEP_M) -> tuple[np.ndarray, np.ndarray]:
    """Disc outlines of people at ``xy`` (P, 2) moving at ``vel`` (P, 2): points (P*K, 2) and their velocities."""
    k = max(int(np.ceil(2 * np.pi * radius_m / step_m)), 3)
    a = np.arange(k) * (2 * np.pi / k)
    ring = radius_m * np.column_stack([np.cos(a), np.sin(a)])
    xy, vel = np.asarray(xy, float).reshape(-1, 2), np.asarray(vel, float).reshape(-1, 2)
    return (xy[:, None, :] + ring[None]).reshape(-1, 2), np.repeat(vel, k, axis=0)


class WalkerGuard:
    """One guard fed one walker's ticks in order (see the module docstring); counts what it would brake."""

    def __init__(self, params: dict | None = None, *, companions: bool = True) -> None:
        self.companions = companions        # False: leave out the walker's companions (see :func:`companions`)
        self.harness = Harness(CollisionGuard, params=guard_params() if params is None else params, roundtrip=False,
                               node_id="guard")
        c = self.harness.node.config
        self.body_m = c.robot_radius_m + c.margin_m
        self.check_m = c.check_m
        self.t0: float | None = None
        self.ticks = self.braked = self.gt = 0
        self.why: dict[str, int] = {}

    def tick(self, t: float, pose: np.ndarray, v: float, w: float, xy: np.ndarray, vel: np.ndarray) -> bool:
        """The walker at ``pose`` (x, y, yaw) commanding (v, w), the others at ``xy`` (P, 2) with ``vel`` (P, 2),
        world frame. Returns whether the guard braked (counted only when v > MOVING_MPS)."""
        if self.t0 is None:
            self.t0 = t
        ts = t - self.t0
        xy, vel = np.asarray(xy, float).reshape(-1, 2), np.asarray(vel, float).reshape(-1, 2)
        if not self.companions:
            own = v * np.array([np.cos(pose[2]), np.sin(pose[2])])
            keep = ~companions(pose[:2], own, xy, vel)
            xy, vel = xy[keep], vel[keep]
        near = np.hypot(*(xy - pose[:2]).T) <= REACH_M if len(xy) else np.zeros(0, bool)
        rel, rel_v = to_robot(pose, xy[near]), to_robot((0.0, 0.0, pose[2]), vel[near])   # the walker's frame
        pts, pv = outlines(rel, rel_v)
        stamp = int(round(ts * 1e9))
        z = np.full((len(pts), 1), POINT_Z_M)
        flow = FlowPoints(stamp_ns=stamp, frame_id="base", points_m=np.hstack([pts, z]),
                          velocity_mps=np.hstack([pv, np.zeros_like(z)]))
        cmd = Twist2D(stamp_ns=stamp, frame_id="base", vx_mps=float(v), wz_radps=float(w))
        out = self.harness.feed([(ts, "points", flow), (ts, "cmd", cmd)])
        safe = [o.msg for o in out if o.output == "cmd"]
        reason = next((o.msg.reason for o in reversed(out) if o.output == "status"), "")
        self.harness.outputs.clear()
        braked = bool(safe) and v > 0 and safe[-1].vx_mps < v - 1e-6
        if v <= MOVING_MPS:
            return braked
        self.ticks += 1
        if braked:
            self.braked += 1
            rule = next((k for prefix, k in GUARD_RULES if reason.startswith(prefix)), "other")
            kind = "ahead_" + ahead_kind(tuple(pose), xy, vel)
            for key in (rule, kind):
                self.why[key] = self.why.get(key, 0) + 1
        self.gt += int(gt_rule(rel, v, w, body_m=self.body_m, check_m=self.check_m))
        return braked


def companions(at: np.ndarray, own_vel: np.ndarray, xy: np.ndarray, vel: np.ndarray) -> np.ndarray:
    """(P,) bool: the others (``xy``, ``vel``) walking with a walker at ``at`` moving at ``own_vel`` (world frame): both
    faster than MOVING_MPS, centres within COMPANION_M, velocities within COMPANION_MPS of each other. A heuristic for
    the people a walker goes with (a robot has none); each tick on its own."""
    if not len(xy) or np.hypot(*own_vel) <= MOVING_MPS:
        return np.zeros(len(xy), bool)
    return ((np.hypot(*(xy - at).T) < COMPANION_M) & (np.hypot(*vel.T) > MOVING_MPS)
            & (np.hypot(*(vel - own_vel).T) < COMPANION_MPS))


def gt_rule(rel_xy: np.ndarray, v: float, w: float, *, body_m: float = 0.45, check_m: float = 2.5,
            stop_m: float = GT_STOP_M) -> bool:
    """Another person's centre (walker frame, (P, 2)) nearer than ``stop_m`` whose body (BODY_RADIUS_M) the
    walker's disc (``body_m``) would close in on along the (v, w) arc within ``check_m``."""
    if not len(rel_xy) or v <= 0:
        return False
    close = rel_xy[np.hypot(rel_xy[:, 0], rel_xy[:, 1]) < stop_m]
    if not len(close):
        return False
    _, nearest = free_distance_m(close, v, w, radius_m=body_m + BODY_RADIUS_M, length_m=check_m)
    return bool(nearest < stop_m)


def _heading(vel: np.ndarray) -> np.ndarray:
    """Unwrapped heading (n,) of velocities (n, 2); where nearly standing, the last heading walked."""
    speed = np.hypot(vel[:, 0], vel[:, 1])
    h = np.arctan2(vel[:, 1], vel[:, 0])
    ok = speed >= 0.1
    if ok.any():
        idx = np.where(ok, np.arange(len(h)), 0)
        np.maximum.accumulate(idx, out=idx)
        first = int(np.argmax(ok))
        idx[:first] = first
        h = h[idx]
    return np.unwrap(h)


def walker_ticks(t: np.ndarray, xy: np.ndarray, grid_dt: float = DT):
    """A recorded walker's ticks on the global ``grid_dt`` grid within its segment: grid indices (n,), poses (n, 3)
    (positions linearly interpolated, heading of the interpolated central-difference velocity), speeds (n,)
    and yaw rates (n,) (central differences of the recorded heading)."""
    k = np.arange(int(np.ceil(t[0] / grid_dt - 1e-9)), int(np.floor(t[-1] / grid_dt + 1e-9)) + 1)
    tt = k * grid_dt
    vel = np.gradient(xy, t, axis=0)
    head = _heading(vel)
    rate = np.gradient(head, t)
    vx, vy = np.interp(tt, t, vel[:, 0]), np.interp(tt, t, vel[:, 1])
    pose = np.column_stack([np.interp(tt, t, xy[:, 0]), np.interp(tt, t, xy[:, 1]), np.interp(tt, t, head)])
    return k, pose, np.hypot(vx, vy), np.interp(tt, t, rate)


def _summary(guards: list[WalkerGuard], extra: dict | None = None) -> dict:
    ticks = sum(g.ticks for g in guards)
    braked = sum(g.braked for g in guards)
    why: dict[str, int] = {}
    for g in guards:
        for k, n in g.why.items():
            why[k] = why.get(k, 0) + n
    stops = braked - why.get("slowed", 0)
    frac = (lambda n: round(n / ticks, 4) if ticks else None)
    return {"ticks": ticks, "guard_frac": frac(braked), "stop_frac": frac(stops),
            "gt_rule_frac": frac(sum(g.gt for g in guards)),
            "guard_why": {k: frac(n) for k, n in sorted(why.items())}, **(extra or {})}


def _both(pairs: list[tuple[WalkerGuard, WalkerGuard]], extra: dict | None = None) -> dict:
    """Summary of the guards fed everyone, with the same of those fed all but companions as ``without_companions``."""
    alone = _summary([b for _, b in pairs])
    alone.pop("ticks")
    return _summary([a for a, _ in pairs], {**(extra or {}), "without_companions": alone})


def dataset_guard(name: str, *, params: dict | None = None, tracks=None) -> dict:
    """Every walker of a recorded set (every track segment with >= 3 rows) through its own guard (module docstring)."""
    from sim.pedestrian_data import load_tracks
    tracks = tracks if tracks is not None else load_tracks(name)
    n_grid = int(np.floor(tracks.duration_s / DT + 1e-9)) + 1
    states = [tracks.state_at(k * DT) for k in range(n_grid)]
    guards = []
    for i, pid in enumerate(tracks.ids):
        for t, xy in tracks.segments(i):
            if len(t) < 3:
                continue
            pair = (WalkerGuard(params), WalkerGuard(params, companions=False))
            for k, pose, v, w in zip(*walker_ticks(t, xy)):
                ids, pos, vel = states[k]
                others = ids != pid
                for g in pair:
                    g.tick(k * DT, pose, v, w, pos[others], vel[others])
            guards.append(pair)
    return _both(guards, {"walkers": len(guards), "walkers_braked": sum(g.braked > 0 for g, _ in guards)})


def peds_velocity(t: np.ndarray, peds: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Velocities (per step, (P, 2)) of an episode's people by central differences of their positions (one-sided at
    their first and last step, 0 for one seen once)."""
    index = [{int(i): j for j, i in enumerate(ids)} for ids, _ in peds]
    out = []
    for k, (ids, xy) in enumerate(peds):
        vel = np.zeros((len(ids), 2))
        for j, i in enumerate(ids):
            a = k - 1 if k > 0 and int(i) in index[k - 1] else k
            b = k + 1 if k + 1 < len(peds) and int(i) in index[k + 1] else k
            if b > a:
                vel[j] = (peds[b][1][index[b][int(i)]] - peds[a][1][index[a][int(i)]]) / (t[b] - t[a])
        out.append(vel)
    return out


def episode_guard(ep: Episode, *, params: dict | None = None) -> dict:
    """The bench's human reference ``ep`` (its path until it arrives, its ``yaw_rate``) among the episode's ground-truth
    people, through one guard (module docstring)."""
    end = len(ep.t) if ep.goal_t is None else int(np.searchsorted(ep.t, ep.goal_t)) + 1
    t, xy = ep.t[:end], ep.pose[:end, :2]
    vel = np.gradient(xy, t, axis=0) if len(t) >= 2 else np.zeros((len(t), 2))
    pose = np.column_stack([xy, _heading(vel)])
    speed = np.hypot(vel[:, 0], vel[:, 1])
    pvel = peds_velocity(ep.t, ep.peds)
    pair = (WalkerGuard(params), WalkerGuard(params, companions=False))
    for k in range(end):
        for g in pair:
            g.tick(float(t[k]), pose[k], float(speed[k]), float(ep.yaw_rate[k]), ep.peds[k][1], pvel[k])
    return _both([pair])


def plot(walkers: dict, human: dict, robot: dict, filename: str = "guard_on_walkers.png") -> Path:
    """Braked share per recorded set (walkers) and per bench scenario (human reference vs robot)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [len(walkers) or 1, len(human) or 1]})
    ax = axes[0]
    names = list(walkers)
    x = np.arange(len(names))
    bars = ((lambda w: w["guard_frac"], "guard brakes or slows"),
            (lambda w: w["without_companions"]["guard_frac"], "... companions left out"),
            (lambda w: w["gt_rule_frac"], "person < 1 m on the path (ground truth, everyone)"))
    for off, (get, label) in zip((-0.27, 0.0, 0.27), bars):
        ax.bar(x + off, [100 * (get(walkers[n]) or 0) for n in names], 0.27, label=label)
    ax.set_xticks(x, names, rotation=20)
    ax.set_ylabel("share of moving walker ticks (%)")
    ax.set_title("the guard's rule on recorded walkers (ETH/UCY)")
    ax.axhline(5, color="k", ls="--", lw=0.8, label="issue goal for the robot (5 %)")
    ax.legend(fontsize=8)
    ax = axes[1]
    names = list(human)
    x = np.arange(len(names))
    ax.bar(x - 0.27, [100 * (human[n]["guard_frac"] or 0) for n in names], 0.27, label="human reference (open loop)")
    ax.bar(x, [100 * (human[n]["without_companions"]["guard_frac"] or 0) for n in names], 0.27,
           label="... companions left out")
    ax.bar(x + 0.27, [100 * (robot.get(n) or 0) for n in names], 0.27, label="IRL robot (social_nav.json guard_frac)")
    ax.set_xticks(x, names, rotation=20)
    ax.axhline(5, color="k", ls="--", lw=0.8)
    ax.set_ylabel("share of control ticks braked (%)")
    ax.set_title("bench scenarios: human reference vs robot")
    ax.legend(fontsize=8)
    return save_figure(fig, ROOT / "out" / filename, dpi=110)


def robot_guard_frac(path: Path = ROOT / "out" / "bench" / "social_nav.json") -> dict:
    """The IRL robot's ``guard_frac`` per scenario from the last full social_nav run (empty when absent)."""
    if not path.is_file():
        return {}
    return {n: r["irl"]["guard_frac"] for n, r in json.loads(path.read_text())["scenarios"].items()}


def readme_row(d: dict) -> tuple[str, str, str, str]:
    """The README table row (bench, result, baseline, goal) from this bench's JSON (for bench/readme.py)."""
    pct = (lambda x: "-" if x is None else f"{100 * x:.0f}")
    w, h = d["walkers"], d["human"]
    alone = [v["without_companions"]["guard_frac"] for v in w.values()]
    gt = [v["gt_rule_frac"] for v in w.values()]
    span = (lambda v: f"{pct(min(v))}-{pct(max(v))} %" if v else "-")
    return (f"`guard_on_walkers.py` the guard's 1 m rule asked of people, open loop: every ETH/UCY walker "
            f"({len(w)} sets) and the social_nav human references, each fed as the robot's guard is (its own (v, w) as the "
            f"command, the others as disc outlines with velocities, all around: no field of view)",
            "recorded walkers braked or slowed in " + span([v["guard_frac"] for v in w.values()]) + " of moving ticks ("
            + ", ".join(f"{n} {pct(v['guard_frac'])}" for n, v in w.items()) + " %); leaving out companions (within "
            f"{COMPANION_M:g} m, velocity within {COMPANION_MPS:g} m/s) {span(alone)}; a person's centre within "
            f"{GT_STOP_M:g} m on the path (no prediction) {span(gt)}",
            "human references in the bench's scenarios: " + ", ".join(
                f"{n} {pct(v['guard_frac'])} %" + (f" ({pct(v['without_companions']['guard_frac'])} % without companions)"
                                                   if v["without_companions"]["guard_frac"] != v["guard_frac"] else "")
                for n, v in h.items()) + "; the robot (social_nav.json): " + ", ".join(
                f"{n} {pct(v['robot_guard_frac'])} %" for n, v in h.items()),
            "no goal (calibrates issue 18's guard < 5 %: "
            + ("no recorded set and no human reference is below it)" if min(alone + [v["guard_frac"] for v in h.values()],
                                                                          default=1) >= 0.05 else "some people are below it)"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--sets", nargs="*", default=None, help=f"recorded sets (default: {' '.join(SETS)})")
    ap.add_argument("--scenes", nargs="*", default=None, help="bench scenarios for the human reference (default: all six)")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--param", action="append", default=[],
                    help="guard parameter KEY=VALUE over the bench's (a sensitivity check, e.g. robot_radius_m=0.2)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    from social_nav_humans import SCENES, clear_start_s, human_reference
    from sim.crowd_scenes import load_scene
    from sim.pedestrian_data import default_root
    import yaml
    params = guard_params()
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"guard_on_walkers: --param wants KEY=VALUE, got {item!r}")
        params[key] = yaml.safe_load(value)
    out: dict = {"guard_params": params, "moving_mps": MOVING_MPS, "dt_s": round(DT, 4)}
    walkers, skipped = {}, []
    t0 = time.perf_counter()
    for name in (SETS if args.sets is None else args.sets):
        try:
            walkers[name] = dataset_guard(name, params=params)
        except FileNotFoundError:
            skipped.append(name)
            continue
        print(f"{name}: {walkers[name]}", file=sys.stderr, flush=True)
    out["walkers"] = walkers
    out["guard_frac_walkers"] = {n: w["guard_frac"] for n, w in walkers.items()}
    out["guard_frac_walkers_without_companions"] = {n: w["without_companions"]["guard_frac"] for n, w in walkers.items()}
    if skipped:
        out["walkers_skipped"] = f"{', '.join(skipped)}: no tracks under {default_root()}"
    human = {}
    for name in (SCENES if args.scenes is None else args.scenes):
        scene = load_scene(name)
        if scene.replay is not None and not (default_root() / "eth_ucy_sgan_format").is_dir():
            continue
        shift = clear_start_s(scene)
        human[name] = episode_guard(human_reference(scene, shift), params=params)
        print(f"{name} human: {human[name]}", file=sys.stderr, flush=True)
    robot = robot_guard_frac()
    out["human"] = {n: {**h, "robot_guard_frac": robot.get(n)} for n, h in human.items()}
    fr = [h["guard_frac"] for h in human.values() if h["guard_frac"] is not None]
    out["guard_frac_human"] = round(float(np.max(fr)), 4) if fr else None
    out["guard_frac_human_median"] = round(float(np.median(fr)), 4) if fr else None
    out["seconds"] = round(time.perf_counter() - t0, 1)
    if not args.no_plot:
        out["plot"] = str(plot(walkers, human, robot).relative_to(ROOT))
    if args.json:
        print(json.dumps(out))
        return
    for n, w in walkers.items():
        print(f"{n:14s} walkers {w['walkers']:4d} ticks {w['ticks']:6d}: guard brakes {w['guard_frac']}, stops "
              f"{w['stop_frac']}, person < 1 m on the path {w['gt_rule_frac']}, companions left out "
              f"{w['without_companions']['guard_frac']}; {w['guard_why']}")
    for n, h in out["human"].items():
        print(f"{n:12s} human {h['guard_frac']} (stops {h['stop_frac']}, gt {h['gt_rule_frac']}, companions left out "
              f"{h['without_companions']['guard_frac']}) "
              f"robot {h['robot_guard_frac']}; {h['guard_why']}")
    print(f"plot {out.get('plot')}")


if __name__ == "__main__":
    main()
