"""Demonstrations for learning the IRL cost from the simulator's side: real pedestrians carried
through the simulated RGB-D camera, and logs of an oracle driver on known weights; the full
learning command line (``nodes.nav.irl_learn`` learns from recorded logs alone).

    python -m sim.irl_demos --demos run1.mcap run2.mcap --tracks students003 crowds_zara03 \\
        --holdout biwi_hotel -o nodes/nav/weights/default.json

- real pedestrians (ETH/UCY): a chosen pedestrian is taken out of the replayed crowd and
  the simulated robot's RGB-D camera is carried along its recorded track through the very
  nodes of the live pipeline (``RgbdFlow`` -> ``CrowdFeatures``, in-process), so the
  features are what the robot itself would have seen; its next seconds of track are the
  expert path and its last position the goal;
- ``--record-oracle SCENE``: a sim scene driven by the three-layer planner on known weights
  (``ORACLE_WEIGHTS``), recorded, so the expected value difference of what is learnt from
  it can be measured.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from msgs.geometry import Odometry2D, Pose2D, Twist2D
from msgs.nav import Goal2D
from nodes.nav.grid_frame import GridFrame
from nodes.nav.irl import Demo, cell_costs
from nodes.nav.demos import CAMERA_FX_PX, PLANNER_PARAMS, DemoSet, FeaturePipeline, demos_from_poses
from nodes.nav.irl_learn import ORACLE_WEIGHTS, add_learning_arguments, learn_main
from nodes.nav.irl_learn import collect_demos as collect_logs
from nodes.nav.plan_geometry import predict_conflicts
from nodes.nav.social_planner import PlannerParams, SocialPlanner
from sim.crowd import CrowdWorld
from sim.crowd_render import CameraModel
from sim.pedestrian_data import ROW_PERIOD_S, Tracks, load_tracks
from tether.log import LogWriter

log = logging.getLogger("sim.irl_demos")


def sim_camera() -> object:
    """The simulator camera model used for learning and benchmarks (see CAMERA_FX_PX)."""
    return CameraModel(fx_px=CAMERA_FX_PX, fy_px=CAMERA_FX_PX)


def _expert_tracks(tracks: object, min_len_m: float, min_s: float) -> list[tuple[int, int]]:
    """(pedestrian index, segment index) of the walks long enough to demonstrate something; a track
    with gaps (:meth:`sim.pedestrian_data.Tracks.segments`) gives one walk per gapless piece."""
    out = []
    for i in range(len(tracks.ids)):  # type: ignore[attr-defined]
        for k, (t, xy) in enumerate(tracks.segments(i)):  # type: ignore[attr-defined]
            if len(t) > 3 and t[-1] - t[0] >= min_s and np.hypot(*(xy[-1] - xy[0])) >= min_len_m:
                out.append((i, k))
    return out


def pedestrian_demos(dataset: str | Tracks, n_peds: int, *, horizon_s: float = 3.0, every_s: float = 0.4,
                     seed: int = 0, rim_m: float = 0.0) -> list[Demo]:
    """Real pedestrians as experts: the robot's camera rides along each one's track (see the module docstring).

    ``dataset`` is a data set name or loaded :class:`Tracks`. A walker whose track has gaps
    demonstrates each gapless piece on its own (a path across a gap was never walked).
    """
    tracks = load_tracks(dataset) if isinstance(dataset, str) else dataset
    walks = _expert_tracks(tracks, 4.0, 5.0)
    rng = np.random.default_rng(seed)
    pick = sorted(rng.choice(len(walks), size=min(n_peds, len(walks)), replace=False).tolist()) if walks else []
    demos: list[Demo] = []
    for i, k in (walks[j] for j in pick):
        keep = [j for j in range(len(tracks.ids)) if j != i]
        others = Tracks(tracks.name, tracks.ids[keep], tuple(tracks.t_s[j] for j in keep),
                        tuple(tracks.xy_m[j] for j in keep), tracks.row_period_s, tracks.max_gap_s)
        t, xy = tracks.segments(i)[k]
        lo, hi = xy.min(axis=0) - 8.0, xy.max(axis=0) + 8.0
        scene = {"name": f"{tracks.name}-{tracks.ids[i]}", "bounds_m": [lo[0], lo[1], hi[0], hi[1]],
                 "robot": {"x_m": float(xy[0, 0]), "y_m": float(xy[0, 1])}, "goal": {"x_m": float(xy[-1, 0]), "y_m": float(xy[-1, 1])},
                 "replay": {"dataset": tracks.name, "t0_s": float(t[0])}}
        demos += _ride_along(CrowdWorld(scene, tracks=others, camera=sim_camera()), t - t[0], xy, horizon_s, every_s,
                             rim_m)
        log.info("%s pedestrian %d: %d demos so far", tracks.name, tracks.ids[i], len(demos))
    return demos


def body_points(xy: np.ndarray, vel: np.ndarray, rng: np.random.Generator, *, per_person: int = 100,
                radius_m: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and velocities (N, 3) on people's bodies (xy (P, 2), vel (P, 2), one frame): a
    ``radius_m`` column 0.2-1.7 m high each, as many points as the simulated camera gives a person at
    ~3 m (fx 149 px, stride 4)."""
    n = len(xy) * per_person
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    a, r = rng.uniform(0, 2 * np.pi, n), radius_m * np.sqrt(rng.uniform(0, 1, n))
    centre, v = np.repeat(xy, per_person, axis=0), np.repeat(vel, per_person, axis=0)
    pts = np.column_stack([centre[:, 0] + r * np.cos(a), centre[:, 1] + r * np.sin(a), rng.uniform(0.2, 1.7, n)])
    return pts, np.column_stack([v, np.zeros(n)])


def track_demos(dataset: str | Tracks, n_peds: int, *, horizon_s: float = 8.0, every_s: float = 0.4, seed: int = 0,
                rim_m: float = 4.0, fov_deg: float = 130.0, range_m: float = 8.0, conflict_horizon_s: float = 6.0,
                own_speed: bool = False, hindsight: bool = False) -> list[Demo]:
    """Real pedestrians as experts over the others' recorded positions (no rendering, no flow): each
    other walker in the camera's view (``fov_deg``, ``range_m``) is a column of points moving at its
    recorded velocity, through the crowd-features node's own function. Perfect perception: what
    :func:`pedestrian_demos` sees through the simulated camera and optical flow, without their errors.
    ``own_speed``: the conflict feature assumes the walker's own mean speed (else the robot's 1 m/s).
    ``hindsight``: the conflict feature is asked of the others' recorded futures
    (:func:`nodes.nav.features.arrival_cells`) instead of their constant-velocity prediction:
    where somebody really was when the walker could have got there (perfect prediction in
    learning; the running robot can only predict). Measured (40 walkers per data set, own
    speed, cells within 4 m; expert / shortest path to the same exit): biwi_eth 13 / 65,
    biwi_hotel 7 / 29, crowds_zara03 71 / 142, uni_examples 24 / 26, students003 546 / 550.
    Walkers do avoid where others will really be, but MAP-BIRL prices such a cell at ~0.8
    against a step cost of 2 (0.27 from the constant-velocity feature on the same walkers):
    see nodes/nav/weights/default.json ``conflict_weight.hindsight_experiment``."""
    from nodes.nav.features import (CONFLICT, GridSpec, Thresholds, arrival_cells, conflict_cells, extract_features,
                                    goal_in_robot_frame)
    from nodes.nav.demos import FEATURE_PARAMS
    from nodes.nav.grid_frame import to_robot

    tracks = load_tracks(dataset) if isinstance(dataset, str) else dataset
    walks = _expert_tracks(tracks, 4.0, 5.0)
    rng = np.random.default_rng(seed)
    pick = sorted(rng.choice(len(walks), size=min(n_peds, len(walks)), replace=False).tolist()) if walks else []
    grid = GridSpec()
    th = Thresholds((FEATURE_PARAMS["density_low_points"], FEATURE_PARAMS["density_high_points"]), (0.3, 0.8), 0.25,
                    int(FEATURE_PARAMS["flow_points"]))
    demos: list[Demo] = []
    for i, k in (walks[j] for j in pick):
        t, xy = tracks.segments(i)[k]
        tt = np.arange(t[0], t[-1] + 1e-9, 0.1)
        px, py = np.interp(tt, t, xy[:, 0]), np.interp(tt, t, xy[:, 1])
        yaw = np.unwrap(np.arctan2(np.gradient(py), np.gradient(px)))
        poses = np.column_stack([tt, px, py, yaw])
        grids = []
        speed = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)) / (t[-1] - t[0])) if own_speed else 1.0
        for ts in np.arange(t[0], t[-1] - 1.0, every_s):
            pose = (float(np.interp(ts, tt, px)), float(np.interp(ts, tt, py)), float(np.interp(ts, tt, yaw)))
            ids, oxy, ovel = tracks.state_at(float(ts))
            keep = ids != tracks.ids[i]
            rel = to_robot(pose, oxy[keep]) if keep.any() else np.zeros((0, 2))
            c, s_ = np.cos(pose[2]), np.sin(pose[2])
            rvel = ovel[keep] @ np.array([[c, -s_], [s_, c]]) if keep.any() else np.zeros((0, 2))
            seen = (np.hypot(rel[:, 0], rel[:, 1]) <= range_m) & (np.abs(np.arctan2(rel[:, 1], rel[:, 0] - 0.3))
                                                                    <= np.radians(fov_deg) / 2)
            pts, vel = body_points(rel[seen], rvel[seen], rng)
            goal = goal_in_robot_frame(tuple(xy[-1]), pose)
            f = extract_features(pts, vel, goal, grid, th).features
            if hindsight:
                taus = np.arange(0.0, conflict_horizon_s + 1e-9, 0.25)
                paths = _futures(tracks, ids[keep][seen], float(ts), taus, pose)          # (P, T, 2)
                per = len(pts) // max(len(paths), 1)
                offsets = pts[:, :2] - np.repeat(rel[seen], per, axis=0)
                hit = arrival_cells(np.repeat(paths, per, axis=0) + offsets[:, None, :], taus, grid,
                                    min_points=th.density_points[0], robot_speed_mps=speed)
            else:
                hit = conflict_cells(pts, vel, grid, min_points=th.density_points[0], robot_speed_mps=speed,
                                     horizon_s=conflict_horizon_s)
            f = np.concatenate([f, hit[..., None].astype(np.uint8)], axis=2)
            ox, oy = grid.origin
            grids.append((float(ts), f, GridFrame(f.shape[:2], grid.resolution_m, ox, oy)))
        demos += demos_from_poses(grids, poses, horizon_s=horizon_s, goal_xy=xy[-1], rim_m=rim_m)
    log.info("%s: %d demos from %d walkers (recorded positions, %s feature)", tracks.name, len(demos), len(pick), CONFLICT)
    return demos


def spacetime_demos(dataset: str | Tracks, n_demos: int, *, horizon_s: float = 6.0, slack: float = 1.5,
                    every_s: float = 2.0, seed: int = 0, cell_m: float = 0.25, pace: float = 0.75,
                    margin_m: float = 1.5,
                    radii_m: tuple[float, ...] = (0.5, 1.0), companions: str = "exclude",
                    companion_m: float = 1.5, companion_mps: float = 0.5, others: str = "recorded",
                    predictor: object | None = None) -> tuple[list, dict]:
    """Demonstrations of the space-time model (:mod:`nodes.nav.irl_spacetime`) from recorded walkers.

    Each demo is ``horizon_s`` of one walker's gapless track from a start time t0 (one every
    ``every_s`` along each walk, ``n_demos`` of them drawn with ``seed``), resampled at the
    walker's own pace, dt = ``pace`` x ``cell_m`` / its median speed (clipped to 0.1-0.5 s), so
    its usual walking is ``pace`` cells per step (below 1: a faster stretch rarely needs two cells
    in one step) and a repeated cell is a slow-down, a wait or the rounding of that pace.
    The model may take ``slack`` x as many steps as the walk did. Features: another walker
    (recorded position at t0 + k dt, exact) within each distance band of ``radii_m`` of the
    cell at step k. ``companions="exclude"`` leaves out the walkers who walk with it at t0
    (within ``companion_m`` and ``companion_mps`` of its velocity: a group, not people to
    avoid); ``"keep"`` keeps everybody. ``others="constant_velocity"`` asks the features of the
    others' positions at t0 moved on at their t0 velocity instead (the runtime conflict
    feature's prediction; people who appear after t0 are not seen; that velocity is
    :meth:`Tracks.state_at`'s, the recorded segment from t0 on, so one row of the future when t0
    falls on a sample: ``others="predicted"`` with ``BaselinePredictor()`` is constant velocity
    from the observed steps only). ``others="predicted"`` asks
    them of ``predictor.predict(hist)`` (:class:`nodes.nav.predict.MlpPredictor`, or
    :class:`nodes.nav.predict.BaselinePredictor`): each walker seen at t0 with its positions at
    t0 - 2.8 .. t0 s (8 steps of 0.4 s, NaN where unseen; what was observable at t0, never later),
    everybody seen at t0 its neighbours; its 12 predicted steps (4.8 s) are interpolated at the
    demo's steps and continued at the last predicted step's velocity beyond them.

    Returns the demos and counts (``windows``, ``clipped_steps``, ``companions_left_out``, ``windows_skipped``).
    """
    from nodes.nav.irl_spacetime import demo_from_track

    if companions not in ("exclude", "keep"):
        raise ValueError(f"companions must be 'exclude' or 'keep', got {companions!r}")
    if others not in ("recorded", "constant_velocity", "predicted"):
        raise ValueError(f"others must be 'recorded', 'constant_velocity' or 'predicted', got {others!r}")
    if others == "predicted" and not hasattr(predictor, "predict"):
        raise ValueError("others='predicted' needs predictor= an object with predict(hist (P, 8, 2)) -> (P, 12, 2)")
    tracks = load_tracks(dataset) if isinstance(dataset, str) else dataset
    windows = []
    for i in range(len(tracks.ids)):
        for t, xy in tracks.segments(i):
            if len(t) < 3:
                continue
            v = np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.diff(t)
            dt = float(np.clip(pace * cell_m / max(float(np.median(v)), 1e-3), 0.1, 0.5))
            for t0 in np.arange(t[0], t[-1] - horizon_s + 1e-9, every_s):
                windows.append((i, t, xy, float(t0), dt))
    rng = np.random.default_rng(seed)
    pick = sorted(rng.choice(len(windows), size=min(n_demos, len(windows)), replace=False).tolist())
    demos, counts = [], {"windows": len(windows), "clipped_steps": 0, "steps": 0, "companions_left_out": 0,
                         "windows_skipped": 0}
    for i, t, xy, t0, dt in (windows[j] for j in pick):
        n = int(round(horizon_s / dt))
        k_max = int(np.ceil(slack * n))
        times = t0 + dt * np.arange(k_max + 1)
        walker = np.column_stack([np.interp(times[:n + 1], t, xy[:, 0]), np.interp(times[:n + 1], t, xy[:, 1])])
        ids0, xy0, v0 = tracks.state_at(t0)
        me = np.flatnonzero(ids0 == tracks.ids[i])
        skip = set()
        if companions == "exclude" and len(me):
            near = (np.linalg.norm(xy0 - xy0[me[0]], axis=1) < companion_m) & \
                   (np.linalg.norm(v0 - v0[me[0]], axis=1) < companion_mps)
            skip = {int(p) for p in ids0[near]} - {int(tracks.ids[i])}
        counts["companions_left_out"] += len(skip)
        skip.add(int(tracks.ids[i]))
        slots: dict[int, int] = {}
        rows = []
        if others == "predicted":
            ahead = _predicted(tracks, t0, ids0, xy0, predictor, times - t0)
        for k, tk in enumerate(times):
            if others == "recorded":
                ids, pos, _ = tracks.state_at(float(tk))
            elif others == "predicted":
                ids, pos = ids0, ahead[:, k]
            else:
                ids, pos = ids0, xy0 + v0 * (tk - t0)
            rows.append({int(p): q for p, q in zip(ids, pos) if int(p) not in skip})
            for p in rows[-1]:
                slots.setdefault(p, len(slots))
        seen = np.full((len(times), len(slots), 2), np.nan)
        for k, row in enumerate(rows):
            for p, q in row.items():
                seen[k, slots[p]] = q
        try:
            demo, clipped = demo_from_track(walker, seen, cell_m=cell_m, margin_m=margin_m, radii_m=radii_m)
        except ValueError as exc:          # a walker standing still for the whole window demonstrates nothing
            if "demonstrates nothing" not in str(exc):
                raise                      # anything else is a bug in the windows above, not a quiet walker
            counts["windows_skipped"] += 1
            continue
        demos.append(demo)
        counts["clipped_steps"] += clipped
        counts["steps"] += len(demo.path) - 1
    log.info("%s: %d space-time demos of %d windows (%d drawn made no demo: the walker ended where it started)",
             tracks.name, len(demos), len(windows), counts["windows_skipped"])
    return demos, counts


def _predicted(tracks: Tracks, t0: float, ids0: np.ndarray, xy0: np.ndarray, predictor: object,
               taus_s: np.ndarray) -> np.ndarray:
    """Positions (P, T, 2) m of the walkers ``ids0`` seen at ``t0`` (at ``xy0``), ``taus_s`` after t0, as
    ``predictor`` foresees them from their last 8 positions (0.4 s apart, up to t0 only)."""
    from nodes.nav.predict import OBS_STEPS, STEP_S, positions_at

    if len(ids0) == 0:
        return np.zeros((0, len(taus_s), 2))
    hist = _futures(tracks, ids0, t0, -STEP_S * np.arange(OBS_STEPS - 1, -1, -1), (0.0, 0.0, 0.0))   # world frame
    return positions_at(xy0, predictor.predict(hist), taus_s)


def _futures(tracks: Tracks, ids: np.ndarray, t_s: float, taus_s: np.ndarray,
             pose: tuple[float, float, float]) -> np.ndarray:
    """Recorded places (P, T, 2) of pedestrians ``ids`` at ``t_s + taus_s``, in the robot frame of ``pose``;
    NaN where one is not in the data then (left, or inside a gap)."""
    from nodes.nav.grid_frame import to_robot

    out = np.full((len(ids), len(taus_s), 2), np.nan)
    where = {int(p): j for j, p in enumerate(ids)}
    for k, tau in enumerate(taus_s):
        now_ids, xy, _ = tracks.state_at(t_s + float(tau))
        for p, q in zip(now_ids, to_robot(pose, xy) if len(now_ids) else ()):
            if int(p) in where:
                out[where[int(p)], k] = q
    return out


def _ride_along(world: object, t: np.ndarray, xy: np.ndarray, horizon_s: float, every_s: float,
                rim_m: float = 0.0) -> list[Demo]:
    """Carry the camera along a track (t from 0, xy world); a demo every ``every_s``."""
    dt = 1.0 / 15.0
    pipe = FeaturePipeline({"max_gap_s": 1.5 * dt})
    pipe.flow.node.log.setLevel(logging.ERROR)        # every pair restarts the flow on purpose
    pipe.set_goal(tuple(xy[-1]), 0.0)
    tt = np.arange(0.0, t[-1] + 1e-9, 0.1)
    px, py = np.interp(tt, t, xy[:, 0]), np.interp(tt, t, xy[:, 1])
    yaw = np.unwrap(np.arctan2(np.gradient(py), np.gradient(px)))
    poses = np.column_stack([tt, px, py, yaw])
    grids = []
    for ts in np.arange(dt, t[-1] - 1.0, every_s):
        for tk in (ts - dt, ts):
            world.step(0.0, 0.0, max(tk - world.t_s, 0.0))          # type: ignore[attr-defined]
            pose = (float(np.interp(tk, tt, px)), float(np.interp(tk, tt, py)), float(np.interp(tk, tt, yaw)))
            speed = float(np.hypot(np.interp(tk + 0.05, tt, px) - np.interp(tk - 0.05, tt, px),
                                   np.interp(tk + 0.05, tt, py) - np.interp(tk - 0.05, tt, py)) / 0.1)
            world.pose, world.twist = pose, (speed, 0.0)             # type: ignore[attr-defined]
            rgb, depth = world.render()                             # type: ignore[attr-defined]
            _, grid = pipe.step(tk, pose, (speed, 0.0), rgb, depth, world.camera)   # type: ignore[attr-defined]
        if grid is not None:
            f = np.asarray(grid.features)
            grids.append((ts, f, GridFrame(f.shape[:2], grid.resolution_m, grid.origin_x_m, grid.origin_y_m)))
    return demos_from_poses(grids, poses, horizon_s=horizon_s, goal_xy=xy[-1], rim_m=rim_m)


def record_oracle(scene: str, path: str | Path, *, dt_s: float = 1.0 / 15.0, person_cost: float = 4.0,
                  predict_s: float = 2.0) -> Path:
    """Drive a sim scene with the three-layer planner on the known ORACLE_WEIGHTS cost; log features + odometry.

    A stand-in for a human driving the wheelchair: its cost is known, so the expected value
    difference of what is learnt from its log can be measured. It plans as the planner node
    does: with the floor on cells with people (``person_cost``, :class:`PlannerParams`) and
    the predicted crossings of moving points (``predict_s``). Measured without them (0, 0) it
    drove into the oncoming group three times in four contacts, on the paper's table alone
    and on that table x 2, 4, 8: not an expert worth learning from. With them its true cost
    is ``ORACLE_WEIGHTS`` plus those floors, so the expected value difference against
    ``ORACLE_WEIGHTS`` alone is an approximation.
    """
    world = CrowdWorld(scene, camera=sim_camera())
    pipe = FeaturePipeline()
    gx, gy, tol = world.goal
    pipe.set_goal((gx, gy), 0.0)
    planner = SocialPlanner(PlannerParams(**PLANNER_PARAMS, person_cost=person_cost))
    planner.set_goal((gx, gy), tol)
    occ = world.occupancy(0.1)
    planner.set_map(occ.data, GridFrame(occ.data.shape, occ.resolution_m, occ.origin_x_m, occ.origin_y_m))
    with LogWriter(path) as out:
        out.write("sim/goal", Goal2D(stamp_ns=0, frame_id="world", x_m=gx, y_m=gy, tolerance_m=tol), log_time_ns=0)
        while world.t_s < world.scene.duration_s and not world.goal_reached:
            t, pose, twist = world.t_s, world.pose, world.twist
            stamp = int(round(t * 1e9))
            out.write("sim/odom", Odometry2D(stamp_ns=stamp, frame_id="world", pose=Pose2D(x_m=pose[0], y_m=pose[1], yaw_rad=pose[2]),
                                             twist=Twist2D(vx_mps=twist[0], wz_radps=twist[1])), log_time_ns=stamp)
            rgb, depth = world.render()
            flow, grid = pipe.step(t, pose, twist, rgb, depth, world.camera)
            if grid is not None:
                out.write("features/features", grid, log_time_ns=stamp)
                f = np.asarray(grid.features)
                frame = GridFrame(f.shape[:2], grid.resolution_m, grid.origin_x_m, grid.origin_y_m)
                predicted = None
                if predict_s > 0 and flow is not None:     # as the planner node does with its flow input
                    predicted = predict_conflicts(flow.points_m, flow.velocity_mps, frame,
                                                  robot_speed_mps=planner.p.v_max_mps, horizon_s=predict_s)
                planner.update(pose, cell_costs(f, ORACLE_WEIGHTS), frame, f[..., 0] > 0, t, predicted)
            world.step(*planner.command(pose), dt_s)
    log.info("oracle drove %s in %.1f s (goal %s), closest %.2f m, contacts %d (robot drove in %d) -> %s", scene,
             world.t_s, world.goal_reached, world.min_clearance_m, world.collisions, world.collisions_by_robot, path)
    return Path(path)


def collect_demos(args: argparse.Namespace) -> tuple[DemoSet, set[str]]:
    """Demos from the cache, the logs, the oracle drives and the track data sets named on the command line."""
    def oracle_logs() -> list[str]:
        out = []
        for scene in args.record_oracle:
            path = Path(args.log_dir) / f"oracle-{scene}.mcap"
            record_oracle(scene, path)
            out.append(str(path))
        return out

    def pedestrians(scenes: dict) -> None:
        for k, dataset in enumerate(args.tracks + [h for h in args.holdout if h not in args.tracks and h in ROW_PERIOD_S]):
            scenes[dataset] = pedestrian_demos(dataset, args.peds, horizon_s=args.horizon_s, seed=k, rim_m=args.rim_m)

    return collect_logs(args, extra_logs=oracle_logs, more=pedestrians,
                        hint="give --demos logs, --tracks data sets or --record-oracle scenes")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Learn IRL cost weights from logs, real pedestrians (through the "
                                             "simulated camera) and oracle drives.")
    add_learning_arguments(ap)
    ap.add_argument("--tracks", nargs="*", default=[], help="ETH/UCY data sets whose pedestrians are experts")
    ap.add_argument("--peds", type=int, default=12, help="expert pedestrians per data set")
    ap.add_argument("--record-oracle", nargs="*", default=[], metavar="SCENE",
                    help="first drive these sim scenes with the oracle driver and record logs into --log-dir")
    ap.add_argument("--log-dir", default="out/irl_logs")
    return learn_main(ap.parse_args(argv), collect_demos)


if __name__ == "__main__":
    sys.exit(main())
