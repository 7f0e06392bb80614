"""IRL demonstrations: a feature grid plus the path the expert then took across it.

- from logs (a driven robot): every ``nav.FeatureGrid`` of the log, with the robot's odometry
  over the next seconds moved into that grid's frame (:func:`read_log_demos`);
- from real pedestrians (ETH/UCY, built in ``sim/irl_demos.py``): the simulated robot's RGB-D
  camera carried along a recorded track through the live pipeline's own nodes
  (:class:`FeaturePipeline`: ``RgbdFlow`` -> ``CrowdFeatures``, in-process).

Also the planner's view of a demo (:func:`widen_demo`) and demo files (npz, no pickles).
Learning and scoring are :mod:`nodes.nav.irl_learn`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nodes.nav.dijkstra import line_cells
from nodes.nav.grid_frame import GridFrame, to_robot
from nodes.nav.irl import Demo
from nodes.nav.plan_geometry import on_rim


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
