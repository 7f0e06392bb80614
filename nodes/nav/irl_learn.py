"""Learn IRL cost weights from recorded logs and from real pedestrian tracks; write the weights file.

    python -m nodes.nav.irl_learn --demos run1.mcap run2.mcap --tracks students003 crowds_zara03 \\
        --holdout biwi_hotel -o nodes/nav/weights/default.json

A demonstration is a feature grid plus the path the expert then took across it:

- logs (a driven robot): every ``nav.FeatureGrid`` of the log, with the robot's odometry
  over the next ``--horizon-s`` seconds moved into that grid's frame;
- real pedestrians (ETH/UCY): a chosen pedestrian is taken out of the replayed crowd and
  the simulated robot's RGB-D camera is carried along its recorded track through the very
  nodes of the live pipeline (``RgbdFlow`` -> ``CrowdFeatures``, in-process), so the
  features are what the robot itself would have seen; its next seconds of track are the
  expert path and its last position the goal.

Held-out scenes (``--holdout`` data sets, or the last fifth of the log demos) are scored
by action agreement (expert moves that are optimal under the learnt cost) against the
shortest-path baseline (all weights 0); logs recorded by ``--record-oracle`` come from a
driver that plans on known weights, so their expected value difference is reported too.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nodes.nav.dijkstra import GridFrame, line_cells, to_robot
from nodes.nav.irl import CostWeights, Demo, action_agreement, expected_value_difference, learn
from nodes.nav.social_planner import on_rim

log = logging.getLogger("nodes.nav.irl_learn")

#: the robot's RGB-D camera in the simulator: 640x480 at 130 degrees horizontal field of view.
#: A pedestrian on a crossing collision course keeps a constant bearing - 50 to 60 degrees in
#: the paper's crossing scene - so a Kinect (57 degrees) or even a 100 degree camera never
#: sees it before contact (measured: both planners collide); see bench/social_nav.py.
CAMERA_FX_PX = 149.0
#: crowd feature thresholds for that camera: the defaults (20 / 150 points, 10 flowing) are
#: for fx = 525 px; a point count scales with fx^2, so they shrink by (149 / 525)^2 ~ 0.08
FEATURE_PARAMS = {"density_low_points": 2.0, "density_high_points": 12.0, "flow_points": 1}
#: the planner's view of that camera
PLANNER_PARAMS = {"fov_deg": 130.0}

#: the oracle driver of --record-oracle: the paper's table, each group shifted to >= 0
ORACLE_WEIGHTS = np.array([2.2, 0.7, 0.0, 0.0, 0.0, 0.0, 4.0, 3.5, 0.0, 0.7, 0.3, 0.0])


def demo_path(frame: GridFrame, pose: tuple[float, float, float], future_xy: np.ndarray) -> np.ndarray:
    """Expert cell path (n, 2) across a robot-frame grid: from the robot's (clamped) cell along
    ``future_xy`` (world, m) until it leaves the grid; 8-connected, no repeated cells."""
    start = frame.clamp(frame.cell_of(np.zeros(2)))[0]
    cells = frame.cell_of(to_robot(pose, future_xy)) if len(future_xy) else np.zeros((0, 2), np.int64)
    inside = frame.inside(cells)
    if len(cells) and not inside.all():
        cells = cells[:int(np.argmin(inside))]
    path, cur = [start[None, :]], tuple(start)
    for cell in cells:
        path.append(line_cells(cur, tuple(cell))[1:])
        cur = tuple(cell)
    out = np.vstack(path)
    keep = np.concatenate([[True], (np.diff(out, axis=0) != 0).any(axis=1)])
    return out[keep]


def exit_rim(frame: GridFrame, pose: tuple[float, float, float], goal_xy: np.ndarray, rim_m: float
             ) -> np.ndarray | None:
    """The local planner's exits on a robot-frame grid: cells on the rim ``rim_m`` ahead (two cells
    deep, as :meth:`nodes.nav.social_planner.SocialPlanner._local` scores them), each holding the
    straight-line distance (cells) still left from it to ``goal_xy`` (world, m); inf elsewhere.
    None when the goal lies within the rim: the planner then plans to the goal itself."""
    goal_rel = to_robot(pose, np.asarray(goal_xy, float))[0]
    if np.hypot(*goal_rel) <= rim_m:
        return None
    rr, cc = np.mgrid[:frame.shape[0], :frame.shape[1]]
    xy = frame.xy_of(np.stack([rr.ravel(), cc.ravel()], axis=1))
    r = np.hypot(xy[:, 0], xy[:, 1])
    rim = on_rim(r, rim_m, frame.resolution_m)
    left = np.hypot(xy[:, 0] - goal_rel[0], xy[:, 1] - goal_rel[1]) / frame.resolution_m
    return np.where(rim, left, np.inf).reshape(frame.shape)


def demos_from_poses(grids: list[tuple[float, np.ndarray, GridFrame]], poses: np.ndarray, *,
                     horizon_s: float = 3.0, goal_xy: np.ndarray | None = None, rim_m: float = 0.0) -> list[Demo]:
    """Demos from feature grids ``(t_s, features, frame)`` and a trajectory ``poses`` (T, 4) = t, x, y, yaw.

    With ``goal_xy`` (world, m) and ``rim_m`` > 0 a demo whose path reaches the rim of
    :func:`exit_rim` is cut there and leaves the grid from it (``Demo.exit_cells``); a path
    that does not reach it within ``horizon_s``, or a goal within the rim, gives a demo that
    ends at its last cell.
    """
    poses = np.asarray(poses, float).reshape(-1, 4)
    out = []
    for t, features, frame in grids:
        if len(poses) < 2 or not poses[0, 0] <= t <= poses[-1, 0]:
            continue
        k = int(np.searchsorted(poses[:, 0], t))
        near = poses[min(k, len(poses) - 1)]
        pose = (float(np.interp(t, poses[:, 0], poses[:, 1])), float(np.interp(t, poses[:, 0], poses[:, 2])), float(near[3]))
        ahead = (poses[:, 0] > t) & (poses[:, 0] <= t + horizon_s)
        path = demo_path(frame, pose, poses[ahead, 1:3])
        exits = exit_rim(frame, pose, goal_xy, rim_m) if goal_xy is not None and rim_m > 0 else None
        if exits is not None:
            on_rim = np.isfinite(exits[path[:, 0], path[:, 1]])
            if on_rim.any():
                path = path[:int(np.argmax(on_rim)) + 1]
            else:
                exits = None
        if len(path) >= 2:
            out.append(Demo(np.asarray(features), path, exit_cells=exits))
    return out


@dataclass
class DemoSet:
    """Demos by scene name (a log file or a data set)."""

    scenes: dict[str, list[Demo]]

    def pick(self, names: list[str]) -> list[Demo]:
        return [d for n in names for d in self.scenes.get(n, [])]


def read_log_demos(path: str | Path, *, horizon_s: float = 3.0, every_s: float = 0.4, rim_m: float = 0.0
                   ) -> list[Demo]:
    """Demos of one MCAP log holding ``nav.FeatureGrid`` and ``geometry.Odometry2D`` channels
    (and ``nav.Goal2D``, the world goal, for demos that leave by the rim; see :func:`demos_from_poses`)."""
    from tether.log import LogReader

    reader = LogReader(path)
    grids: list[tuple[float, np.ndarray, GridFrame]] = []
    poses: list[tuple[float, float, float, float]] = []
    last = -np.inf
    goal = None
    for rec in reader.messages():
        if rec.type_name == "nav.Goal2D":
            g = reader.decode(rec)
            goal = np.array([g.x_m, g.y_m])
        elif rec.type_name == "geometry.Odometry2D":
            m = reader.decode(rec)
            poses.append((m.stamp_ns * 1e-9, m.pose.x_m, m.pose.y_m, m.pose.yaw_rad))
        elif rec.type_name == "nav.FeatureGrid":
            m = reader.decode(rec)
            t = m.stamp_ns * 1e-9
            f = np.asarray(m.features)
            if f.ndim == 3 and f.size and t - last >= every_s - 1e-9:
                grids.append((t, f, GridFrame(f.shape[:2], m.resolution_m, m.origin_x_m, m.origin_y_m)))
                last = t
    p = np.array(sorted(set(poses)))
    return demos_from_poses(grids, p, horizon_s=horizon_s, goal_xy=goal, rim_m=rim_m)


def evaluate(weights: np.ndarray, step_cost: float, demos: list[Demo], *, oracle: bool = False) -> dict[str, float]:
    """Held-out scores of learnt weights next to the shortest-path baseline."""
    out = {"demos": len(demos), "moves": int(sum(len(d.path) - 1 for d in demos))}
    if not demos:
        return out
    out["action_agreement"] = round(action_agreement(demos, weights, step_cost=step_cost), 4)
    out["action_agreement_shortest_path"] = round(action_agreement(demos, np.zeros_like(weights)), 4)
    if oracle:
        out["evd"] = round(expected_value_difference(demos, weights, ORACLE_WEIGHTS, step_cost=step_cost), 4)
        out["evd_shortest_path"] = round(expected_value_difference(demos, np.zeros_like(weights), ORACLE_WEIGHTS), 4)
    return out


def widen_demo(demo: Demo, radius_cells: float, groups: tuple[int, ...] = (0, 3, 6)) -> Demo:
    """The planner's view of a demo: each crowd group's bins widened by the robot footprint.

    ``groups`` are the first columns of one-hot (high, medium, low) triples (density, speed,
    direction in :data:`nodes.nav.features.FEATURE_NAMES`); the goal-distance group is left as
    it is. A cell gets the highest bin found within ``radius_cells`` of it (high wins over
    medium, medium over low), as the planner's footprint dilation prices the robot's centre
    by the dearest cell under its disc. Features (rows, cols, K) stay one-hot per group.
    """
    from scipy.ndimage import grey_dilation

    if radius_cells <= 0:
        return demo
    r = int(np.ceil(radius_cells))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = np.hypot(yy, xx) <= radius_cells + 1e-9
    f = np.asarray(demo.features, float).copy()
    for g in groups:
        if g + 2 >= f.shape[2]:
            raise ValueError(f"group {g} needs columns {g}..{g + 2}, the features have {f.shape[2]}")
        hi = grey_dilation(f[..., g], footprint=disc, mode="constant", cval=0.0)
        med = np.maximum(grey_dilation(f[..., g + 1], footprint=disc, mode="constant", cval=0.0) - hi, 0.0)
        f[..., g], f[..., g + 1], f[..., g + 2] = hi, med, 1.0 - hi - med
    return Demo(f, demo.path, demo.blocked, demo.exit_cells)


def sim_camera() -> object:
    """The simulator camera model used for learning and benchmarks (see CAMERA_FX_PX)."""
    from sim.crowd_render import CameraModel
    return CameraModel(fx_px=CAMERA_FX_PX, fy_px=CAMERA_FX_PX)


class FeaturePipeline:
    """The live pipeline's ``RgbdFlow`` -> ``CrowdFeatures`` nodes, run in-process on simulator frames."""

    def __init__(self, flow_params: dict | None = None, feature_params: dict | None = None) -> None:
        from nodes.nav.crowd_features import CrowdFeatures
        from nodes.nav.rgbd_flow import RgbdFlow
        from tether.testing import Harness

        self.flow = Harness(RgbdFlow, params=flow_params or {}, roundtrip=False, node_id="flow")
        self.features = Harness(CrowdFeatures, params=FEATURE_PARAMS if feature_params is None else feature_params,
                                roundtrip=False, node_id="features")
        self._t = 0.0

    def set_goal(self, xy: tuple[float, float], t_s: float) -> None:
        from msgs.nav import Goal2D
        self._t = max(self._t, t_s)
        self.features.feed([(self._t, "goal", Goal2D(x_m=float(xy[0]), y_m=float(xy[1]), frame_id="world"))])

    def step(self, t_s: float, pose: tuple[float, float, float], twist: tuple[float, float], rgb: np.ndarray,
             depth: np.ndarray, camera: object) -> tuple[object, object | None]:
        """Feed one frame; returns (FlowPoints or None, FeatureGrid or None)."""
        from msgs.geometry import Odometry2D, Pose2D, Twist2D
        from msgs.sensor import CameraInfo, RgbdFrame
        self._t = max(self._t, t_s)
        stamp = int(round(self._t * 1e9))
        odom = Odometry2D(stamp_ns=stamp, frame_id="world", pose=Pose2D(x_m=pose[0], y_m=pose[1], yaw_rad=pose[2]),
                          twist=Twist2D(vx_mps=twist[0], wz_radps=twist[1]))
        info = CameraInfo(width_px=camera.width_px, height_px=camera.height_px, fx_px=camera.fx_px,  # type: ignore[attr-defined]
                          fy_px=camera.fy_px, cx_px=camera.cx_px, cy_px=camera.cy_px)  # type: ignore[attr-defined]
        frame = RgbdFrame(stamp_ns=stamp, frame_id="camera", rgb=rgb, depth_m=depth, info=info)
        flows = [o.msg for o in self.flow.feed([(self._t, "odom", odom), (self._t, "rgbd", frame)]) if o.output == "flow"]
        self.features.feed([(self._t, "odom", odom)])
        if not flows:
            return None, None
        grids = [o.msg for o in self.features.feed([(self._t, "flow", flows[-1])]) if o.output == "features"]
        return flows[-1], (grids[-1] if grids else None)


def _expert_tracks(tracks: object, min_len_m: float, min_s: float) -> list[int]:
    """Indices of pedestrians that walk far enough for long enough to demonstrate something."""
    out = []
    for i, (t, xy) in enumerate(zip(tracks.t_s, tracks.xy_m)):  # type: ignore[attr-defined]
        if len(t) > 3 and t[-1] - t[0] >= min_s and np.hypot(*(xy[-1] - xy[0])) >= min_len_m:
            out.append(i)
    return out


def pedestrian_demos(dataset: str, n_peds: int, *, horizon_s: float = 3.0, every_s: float = 0.4,
                     seed: int = 0, rim_m: float = 0.0) -> list[Demo]:
    """Real pedestrians as experts: the robot's camera rides along each one's track (see the module docstring)."""
    from sim.crowd import CrowdWorld
    from sim.pedestrian_data import Tracks, load_tracks

    tracks = load_tracks(dataset)
    chosen = _expert_tracks(tracks, 4.0, 5.0)
    rng = np.random.default_rng(seed)
    chosen = sorted(rng.choice(chosen, size=min(n_peds, len(chosen)), replace=False).tolist())
    demos: list[Demo] = []
    for i in chosen:
        keep = [j for j in range(len(tracks.ids)) if j != i]
        others = Tracks(tracks.name, tracks.ids[keep], tuple(tracks.t_s[j] for j in keep),
                        tuple(tracks.xy_m[j] for j in keep), tracks.row_period_s)
        t, xy = tracks.t_s[i], tracks.xy_m[i]
        lo, hi = xy.min(axis=0) - 8.0, xy.max(axis=0) + 8.0
        scene = {"name": f"{dataset}-{tracks.ids[i]}", "bounds_m": [lo[0], lo[1], hi[0], hi[1]],
                 "robot": {"x_m": float(xy[0, 0]), "y_m": float(xy[0, 1])}, "goal": {"x_m": float(xy[-1, 0]), "y_m": float(xy[-1, 1])},
                 "replay": {"dataset": dataset, "t0_s": float(t[0])}}
        demos += _ride_along(CrowdWorld(scene, tracks=others, camera=sim_camera()), t - t[0], xy, horizon_s, every_s,
                             rim_m)
        log.info("%s pedestrian %d: %d demos so far", dataset, tracks.ids[i], len(demos))
    return demos


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
    from msgs.geometry import Odometry2D, Pose2D, Twist2D
    from msgs.nav import Goal2D
    from nodes.nav.social_planner import PlannerParams, SocialPlanner, predict_conflicts
    from nodes.nav.irl import cell_costs
    from sim.crowd import CrowdWorld
    from tether.log import LogWriter

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


def save_demos(path: str | Path, demos: DemoSet) -> None:
    """Demos to an npz (no pickles): features stacked per grid shape is not needed — all grids share one."""
    names, feats, paths, lens, exits = [], [], [], [], []
    for scene, ds in demos.scenes.items():
        for d in ds:
            names.append(scene), feats.append(d.features.astype(np.uint8)), paths.append(d.path), lens.append(len(d.path))
            exits.append(np.full(d.features.shape[:2], np.nan) if d.exit_cells is None else d.exit_cells)
    np.savez_compressed(path, names=np.array(names), features=np.stack(feats), paths=np.vstack(paths), lens=np.array(lens),
                        exits=np.stack(exits))


def load_demos(path: str | Path) -> DemoSet:
    with np.load(path, allow_pickle=False) as z:
        names, feats, paths, lens = z["names"], z["features"], z["paths"], z["lens"]
        exits = z["exits"] if "exits" in z else np.full(feats.shape[:3], np.nan)
    scenes: dict[str, list[Demo]] = {}
    for name, f, lo, n, ex in zip(names, feats, np.concatenate([[0], np.cumsum(lens)[:-1]]), lens, exits):
        # NaN marks "no exits" (a demo that ends at its last cell); inf is a cell one cannot leave from
        scenes.setdefault(str(name), []).append(Demo(f, paths[lo:lo + n], exit_cells=None if np.isnan(ex).any() else ex))
    return DemoSet(scenes)


def collect_demos(args: argparse.Namespace) -> tuple[DemoSet, set[str]]:
    """Demos from the cache, the logs and the track data sets named on the command line."""
    if args.cache and Path(args.cache).is_file():
        log.info("reusing demos from %s", args.cache)
        demos = load_demos(args.cache)
        return demos, {n for n in demos.scenes if n.startswith("oracle-")}
    scenes: dict[str, list[Demo]] = {}
    oracle: set[str] = set()
    logs = list(args.demos)
    for scene in args.record_oracle:
        path = Path(args.log_dir) / f"oracle-{scene}.mcap"
        record_oracle(scene, path)
        logs.append(str(path))
    for path in logs:
        name = Path(path).stem
        scenes[name] = read_log_demos(path, horizon_s=args.horizon_s, rim_m=args.rim_m)
        oracle |= {name} if name.startswith("oracle-") else set()
        log.info("%s: %d demos", path, len(scenes[name]))
    from sim.pedestrian_data import ROW_PERIOD_S
    for k, dataset in enumerate(args.tracks + [h for h in args.holdout if h not in args.tracks and h in ROW_PERIOD_S]):
        scenes[dataset] = pedestrian_demos(dataset, args.peds, horizon_s=args.horizon_s, seed=k, rim_m=args.rim_m)
    demos = DemoSet({k: v for k, v in scenes.items() if v})
    if not demos.scenes:
        raise ValueError("no demonstrations: give --demos logs, --tracks data sets or --record-oracle scenes")
    if args.cache:
        save_demos(args.cache, demos)
    return demos, oracle


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Learn IRL cost weights (MAP-BIRL or MaxEnt) from logs and real tracks.")
    ap.add_argument("--demos", nargs="*", default=[], help="MCAP logs with FeatureGrid + Odometry2D")
    ap.add_argument("--tracks", nargs="*", default=[], help="ETH/UCY data sets whose pedestrians are experts")
    ap.add_argument("--holdout", nargs="*", default=[], help="data sets / log files kept for scoring")
    ap.add_argument("--peds", type=int, default=12, help="expert pedestrians per data set")
    ap.add_argument("--method", choices=("birl", "maxent"), default="birl")
    ap.add_argument("--prior", choices=("laplace", "gaussian"), default="laplace")
    ap.add_argument("--lam", type=float, default=0.5)
    ap.add_argument("--horizon-s", type=float, default=8.0, help="expert path length (s) after each feature grid")
    ap.add_argument("--rim-m", type=float, default=4.0,
                    help="demos leave the grid by the local planner's rim this far ahead (its subgoal_m; 0 = "
                         "a demo ends at its own last cell)")
    ap.add_argument("--record-oracle", nargs="*", default=[], metavar="SCENE",
                    help="first drive these sim scenes with the oracle driver and record logs into --log-dir")
    ap.add_argument("--log-dir", default="out/irl_logs")
    ap.add_argument("--cache", default="", help="npz file to save / reuse the extracted demos")
    ap.add_argument("--use", nargs="*", default=[], help="only these scenes (log stems / data sets) of the cache")
    ap.add_argument("--widen-m", type=float, default=0.0,
                    help="learn on crowd features widened by this radius (the planner's footprint view; 0 = as seen)")
    ap.add_argument("--cell-m", type=float, default=0.25, help="feature grid cell size (for --widen-m)")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--debug", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.INFO, format="%(message)s")
    try:
        demos, oracle_scenes = collect_demos(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"irl_learn: {exc}", file=sys.stderr)
        return 2
    if args.use:
        demos = DemoSet({k: v for k, v in demos.scenes.items() if k in set(args.use) | set(args.holdout)})
    if args.widen_m > 0:
        demos = DemoSet({k: [widen_demo(d, args.widen_m / args.cell_m) for d in v] for k, v in demos.scenes.items()})
    held = set(args.holdout) or {n for n in list(demos.scenes)[-max(1, len(demos.scenes) // 5):]}
    train_names = [n for n in demos.scenes if n not in held]
    train = demos.pick(train_names)
    if not train:
        print("irl_learn: no training demonstrations (everything is held out?)", file=sys.stderr)
        return 2
    res = learn(train, method=args.method, prior=args.prior, lam=args.lam)
    report = {"train": evaluate(res.weights, res.step_cost, train)}
    for name in sorted(held & set(demos.scenes)):
        report[name] = evaluate(res.weights, res.step_cost, demos.scenes[name], oracle=name in oracle_scenes)
    from nodes.nav.features import FEATURE_NAMES
    extra = {"method": args.method, "prior": args.prior, "lam": args.lam, "widen_m": args.widen_m, "trained_on": train_names,
             "held_out": sorted(held), "converged": res.converged, "scores": report}
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(CostWeights(tuple(FEATURE_NAMES), res.weights, res.step_cost, extra).to_json() + "\n")
    print(json.dumps({"weights": dict(zip(FEATURE_NAMES, np.round(res.weights, 3).tolist())),
                      "step_cost": round(res.step_cost, 3), "scores": report}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
