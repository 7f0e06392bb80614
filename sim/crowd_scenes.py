"""Crowd scenes: what exists (walls, obstacles, pedestrians, robot start, goal) and the static map.

A scene is a YAML file ``sim/scenes/crowd_<name>.yaml`` (or a dict with the same keys)::

    name: toward
    description: one pedestrian walks straight at the robot
    duration_s: 25                      # a sensible episode length for benchmarks
    bounds_m: [-2, -4, 14, 4]           # xmin ymin xmax ymax of the static map
    robot: {x_m: 0, y_m: 0, yaw_rad: 0}
    goal: {x_m: 10, y_m: 0, tolerance_m: 0.3}
    walls:                              # polylines, extruded to height_m
      - {points: [[-2, -4], [14, -4], [14, 4], [-2, 4], [-2, -4]], height_m: 2.5}
    obstacles:
      - {box: {x_m: 8, y_m: 1.2, length_m: 0.6, width_m: 0.6, yaw_rad: 0}, height_m: 1.0}
      - {cylinder: {x_m: 14, y_m: -1, radius_m: 0.3}, height_m: 2.5}
    pedestrian_model: social_force      # or "linear" (straight lines, no interaction)
    pedestrians_see_robot: false        # do simulated pedestrians avoid the robot?
    pedestrians:
      - {id: 1, waypoints: [[11, 0.15], [-1.5, 0.15]], speed_mps: 1.1, start_s: 0.0, at_goal: stop}
      - {id: 2, waypoints: [[3, 1]], speed_mps: 0}        # standing still
    replay:                             # optional: real ETH/UCY tracks (sim.pedestrian_data)
      {dataset: students003, t0_s: 40, x_m: 0, y_m: 0, yaw_rad: 0, exclude_ids: [129]}

``at_goal`` is ``stop`` (stand at the last waypoint), ``loop`` (walk the waypoints back and
forth) or ``respawn`` (reappear at the first waypoint). A pedestrian with ``speed_mps: 0``
is static: it never moves, even when pushed. World frame: x, y in metres, yaw
counter-clockwise from +x.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from tether.yamlsafe import load_yaml_file

SCENE_DIR = Path(__file__).resolve().parent / "scenes"
AT_GOAL = ("stop", "loop", "respawn")
MODELS = ("social_force", "linear")


@dataclass(frozen=True)
class PedestrianSpec:
    """A simulated pedestrian: walks its waypoints (first = start) at ``speed_mps`` from ``start_s``."""

    id: int
    waypoints: np.ndarray            # (K, 2) m
    speed_mps: float = 1.2
    start_s: float = 0.0
    radius_m: float = 0.3
    height_m: float = 1.75
    at_goal: str = "stop"
    unseen: bool = False             # the others do not react to this one (as to a robot they do not see)


@dataclass(frozen=True)
class ReplaySpec:
    """Real tracks from ``sim.pedestrian_data``: data time ``t0_s + t`` at sim time ``t``, moved by (x, y, yaw)."""

    dataset: str
    t0_s: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    radius_m: float = 0.3
    height_m: float = 1.75
    id_offset: int = 10000
    exclude_ids: tuple[int, ...] = ()    # data-set ids left out (the pedestrian whose place the robot takes)

    def __post_init__(self) -> None:
        object.__setattr__(self, "exclude_ids", tuple(int(i) for i in self.exclude_ids))

    def to_world(self, xy: np.ndarray) -> np.ndarray:
        """Data-set coordinates (N, 2) -> scene coordinates (N, 2) (rotate by yaw, then shift)."""
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        rot = np.array([[c, -s], [s, c]])
        return np.asarray(xy, float) @ rot.T + (self.x_m, self.y_m)


@dataclass(frozen=True)
class Scene:
    """Static geometry, agents and task of one scenario (see the module docstring for the file format)."""

    name: str
    description: str = ""
    duration_s: float = 30.0
    bounds_m: tuple[float, float, float, float] = (-5.0, -5.0, 5.0, 5.0)
    robot_start: tuple[float, float, float] = (0.0, 0.0, 0.0)       # x_m, y_m, yaw_rad
    goal: tuple[float, float, float] = (5.0, 0.0, 0.3)              # x_m, y_m, tolerance_m
    segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))   # (S, 2, 2) wall ends, m
    segment_heights_m: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (S,)
    cylinders: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))     # (C, 3) x, y, radius (m)
    cylinder_heights_m: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (C,)
    polygons: tuple[np.ndarray, ...] = ()        # filled footprints of boxes, each (4, 2), for the map
    pedestrians: tuple[PedestrianSpec, ...] = ()
    replay: ReplaySpec | None = None
    pedestrian_model: str = "social_force"
    pedestrians_see_robot: bool = True


def scene_names() -> list[str]:
    """Names of the bundled scenes (``crowd_<name>.yaml`` -> ``<name>``)."""
    return sorted(p.stem[len("crowd_"):] for p in SCENE_DIR.glob("crowd_*.yaml"))


def load_scene(source: str | Path | Mapping[str, Any]) -> Scene:
    """Load a scene from a bundled name (``"toward"``), a YAML path, or a dict of the file's keys."""
    if isinstance(source, Mapping):
        return scene_from_dict(source)
    path = Path(source)
    if not path.suffix:
        stem = str(source) if str(source).startswith("crowd_") else f"crowd_{source}"
        path = SCENE_DIR / f"{stem}.yaml"
    if not path.is_file():
        raise ValueError(f"no crowd scene {str(source)!r}: bundled scenes are {scene_names()}, or pass a YAML path")
    data = load_yaml_file(path)
    if not isinstance(data, Mapping):
        raise ValueError(f"{path}: a scene file is a YAML mapping (name, walls, pedestrians, ...)")
    return scene_from_dict(data)


def _xy(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: expected finite [x, y] points, got {value!r}")
    return arr


def _box_corners(box: Mapping[str, Any]) -> np.ndarray:
    c, s = np.cos(box.get("yaw_rad", 0.0)), np.sin(box.get("yaw_rad", 0.0))
    hl, hw = 0.5 * float(box["length_m"]), 0.5 * float(box["width_m"])
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    return local @ np.array([[c, -s], [s, c]]).T + (float(box["x_m"]), float(box["y_m"]))


def _pedestrian(raw: Mapping[str, Any]) -> PedestrianSpec:
    spec = PedestrianSpec(id=int(raw["id"]), waypoints=_xy(raw["waypoints"], f"pedestrian {raw.get('id')} waypoints"),
                          speed_mps=float(raw.get("speed_mps", 1.2)), start_s=float(raw.get("start_s", 0.0)),
                          radius_m=float(raw.get("radius_m", 0.3)), height_m=float(raw.get("height_m", 1.75)),
                          at_goal=str(raw.get("at_goal", "stop")), unseen=bool(raw.get("unseen", False)))
    if spec.at_goal not in AT_GOAL:
        raise ValueError(f"pedestrian {spec.id}: at_goal must be one of {AT_GOAL}, got {spec.at_goal!r}")
    if spec.speed_mps < 0 or spec.radius_m <= 0 or spec.height_m <= 0:
        raise ValueError(f"pedestrian {spec.id}: speed must be >= 0, radius and height > 0")
    return spec


def scene_from_dict(data: Mapping[str, Any]) -> Scene:
    """Build a :class:`Scene` from the keys of a scene file (see the module docstring)."""
    segs, seg_h, polys, cyls, cyl_h = [], [], [], [], []
    for wall in data.get("walls", []) or []:
        pts = _xy(wall["points"], "wall points")
        for a, b in zip(pts[:-1], pts[1:]):
            segs.append((a, b))
            seg_h.append(float(wall.get("height_m", 2.5)))
    for obs in data.get("obstacles", []) or []:
        height = float(obs.get("height_m", 1.0))
        if "box" in obs:
            corners = _box_corners(obs["box"])
            polys.append(corners)
            for k in range(4):
                segs.append((corners[k], corners[(k + 1) % 4]))
                seg_h.append(height)
        elif "cylinder" in obs:
            cyl = obs["cylinder"]
            cyls.append((float(cyl["x_m"]), float(cyl["y_m"]), float(cyl["radius_m"])))
            cyl_h.append(height)
        else:
            raise ValueError(f"obstacle {obs!r}: give a 'box' or a 'cylinder'")
    robot = data.get("robot", {}) or {}
    goal = data.get("goal", {}) or {}
    replay = data.get("replay")
    model = str(data.get("pedestrian_model", "social_force"))
    if model not in MODELS:
        raise ValueError(f"pedestrian_model must be one of {MODELS}, got {model!r}")
    peds = tuple(_pedestrian(p) for p in data.get("pedestrians", []) or [])
    if len({p.id for p in peds}) != len(peds):
        raise ValueError("pedestrian ids must be unique within a scene")
    bounds = tuple(float(v) for v in data.get("bounds_m", (-5, -5, 5, 5)))
    if len(bounds) != 4 or bounds[2] <= bounds[0] or bounds[3] <= bounds[1]:
        raise ValueError(f"bounds_m is [xmin, ymin, xmax, ymax] with max > min, got {bounds}")
    return Scene(
        name=str(data.get("name", "unnamed")), description=str(data.get("description", "")),
        duration_s=float(data.get("duration_s", 30.0)), bounds_m=bounds,  # type: ignore[arg-type]
        robot_start=(float(robot.get("x_m", 0.0)), float(robot.get("y_m", 0.0)), float(robot.get("yaw_rad", 0.0))),
        goal=(float(goal.get("x_m", 5.0)), float(goal.get("y_m", 0.0)), float(goal.get("tolerance_m", 0.3))),
        segments=np.asarray(segs, float).reshape(-1, 2, 2), segment_heights_m=np.asarray(seg_h, float),
        cylinders=np.asarray(cyls, float).reshape(-1, 3), cylinder_heights_m=np.asarray(cyl_h, float),
        polygons=tuple(polys), pedestrians=peds,
        replay=ReplaySpec(**replay) if replay else None,
        pedestrian_model=model, pedestrians_see_robot=bool(data.get("pedestrians_see_robot", True)))


@dataclass(frozen=True)
class OccupancyGrid:
    """Static occupancy: ``data`` (rows = y, cols = x) float32 1 = occupied; origin = centre of cell (0, 0)."""

    data: np.ndarray
    resolution_m: float
    origin_x_m: float
    origin_y_m: float


def occupancy_grid(scene: Scene, resolution_m: float = 0.1) -> OccupancyGrid:
    """Rasterise walls, boxes and cylinders of ``scene`` over its ``bounds_m``.

    A cell is occupied when any static geometry touches it (walls are drawn one cell
    thick at least). Pedestrians are not in the map.
    """
    if not resolution_m > 0:
        raise ValueError(f"resolution_m must be > 0, got {resolution_m}")
    xmin, ymin, xmax, ymax = scene.bounds_m
    cols = int(np.ceil((xmax - xmin) / resolution_m))
    rows = int(np.ceil((ymax - ymin) / resolution_m))
    img = np.zeros((rows, cols), np.uint8)
    shift = 4   # cv2 fixed-point sub-cell precision

    def px(xy: np.ndarray) -> np.ndarray:
        cells = (np.asarray(xy) - (xmin, ymin)) / resolution_m - 0.5     # cell-centre coordinates
        cells = np.clip(cells, 0, (cols - 1, rows - 1))                     # walls on the bounds stay in the map
        return np.round(cells * (1 << shift)).astype(np.int32)

    for a, b in scene.segments:
        cv2.line(img, tuple(px(a)), tuple(px(b)), 1, thickness=1, lineType=cv2.LINE_8, shift=shift)
    for poly in scene.polygons:
        cv2.fillPoly(img, [px(poly)], 1, lineType=cv2.LINE_8, shift=shift)
    for x, y, r in scene.cylinders:
        centre = tuple(px(np.array([x, y])))
        cv2.circle(img, centre, int(round(r / resolution_m * (1 << shift))), 1, thickness=-1, shift=shift)
    return OccupancyGrid(img.astype(np.float32), float(resolution_m), xmin + 0.5 * resolution_m,
                         ymin + 0.5 * resolution_m)


def segment_distances(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance (N, S) from each point (N, 2) to each segment (S, 2, 2), metres."""
    return np.linalg.norm(_closest_on_segments(points, segments)[0], axis=2)


def _closest_on_segments(points: np.ndarray, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectors (N, S, 2) from the closest point of each segment to each point, and that closest point."""
    a, e = segments[None, :, 0, :], (segments[:, 1, :] - segments[:, 0, :])[None]
    rel = points[:, None, :] - a
    lam = np.clip(np.sum(rel * e, axis=2) / np.maximum(np.sum(e * e, axis=2), 1e-12), 0.0, 1.0)
    closest = a + lam[..., None] * e
    return points[:, None, :] - closest, closest


@dataclass(frozen=True)
class SocialForce:
    """Helbing & Molnar (1995) social force, circular form with anisotropy (accelerations in m/s^2).

    Pedestrian i is driven toward its waypoint, ``(v0 e - v) / tau``, and pushed by every
    other agent j with ``A exp((r_i + r_j - d_ij) / B) n_ji w(phi)``, where
    ``w = lam + (1 - lam)(1 + cos phi) / 2`` weighs agents ahead more than behind, and by walls
    and obstacles with ``A_wall exp((r_i - d) / B_wall)`` along the wall normal. An agent
    ahead (cos phi > 0) that i closes in on at speed c also pushes i to its right with
    ``keep_right c exp((r_i + r_j - d) / B_side) cos phi``: without this evasive term two
    pedestrians meeting head-on only brake and bump (the circular model has none).
    """

    tau_s: float = 0.5
    a_mps2: float = 2.0
    b_m: float = 0.35
    anisotropy: float = 0.35
    keep_right: float = 2.0          # 1/s
    b_side_m: float = 1.0
    a_robot_mps2: float = 3.0
    b_robot_m: float = 0.5
    a_wall_mps2: float = 3.0
    b_wall_m: float = 0.15
    max_speed_factor: float = 1.3

    def acceleration(self, xy: np.ndarray, vel: np.ndarray, v0: np.ndarray, goal: np.ndarray, radius: np.ndarray,
                     others: np.ndarray, scene: Scene, robot: tuple[float, ...] | None) -> np.ndarray:
        """Acceleration (N, 2) of pedestrians ``xy`` (N, 2); ``others`` (M, 5) = x, y, radius, vx, vy of the other agents."""
        to_goal = goal - xy
        dist = np.linalg.norm(to_goal, axis=1, keepdims=True)
        e = np.where(dist > 1e-9, to_goal / np.maximum(dist, 1e-9), 0.0)
        acc = (v0[:, None] * e - vel) / self.tau_s
        agents = [(others, self.a_mps2, self.b_m)]
        if robot is not None:
            agents.append((np.array([[robot[0], robot[1], robot[4], robot[2], robot[3]]]), self.a_robot_mps2,
                           self.b_robot_m))
        right = np.stack([e[:, 1], -e[:, 0]], axis=1)
        for src, a, b in agents:
            if not len(src):
                continue
            diff = xy[:, None, :] - src[None, :, :2]                       # from j to i
            d = np.linalg.norm(diff, axis=2)
            same = d < 1e-6                                                 # itself (or exactly on top)
            n = diff / np.where(same, 1.0, d)[..., None]
            cos_phi = -np.sum(n * e[:, None, :], axis=2)
            w = self.anisotropy + (1 - self.anisotropy) * 0.5 * (1 + cos_phi)
            mag = np.where(same, 0.0, a * np.exp((radius[:, None] + src[None, :, 2] - d) / b) * w)
            closing = np.maximum(np.sum((vel[:, None, :] - src[None, :, 3:5]) * -n, axis=2), 0.0)
            side = np.where(same, 0.0, self.keep_right * closing * np.maximum(cos_phi, 0.0)
                            * np.exp((radius[:, None] + src[None, :, 2] - d) / self.b_side_m))
            acc += np.sum(mag[..., None] * n, axis=1) + np.sum(side, axis=1)[:, None] * right
        if len(scene.segments):
            away, _ = _closest_on_segments(xy, scene.segments)
            d = np.maximum(np.linalg.norm(away, axis=2), 1e-6)
            mag = self.a_wall_mps2 * np.exp((radius[:, None] - d) / self.b_wall_m)
            acc += np.sum((mag / d)[..., None] * away, axis=1)
        if len(scene.cylinders):
            diff = xy[:, None, :] - scene.cylinders[None, :, :2]
            dc = np.maximum(np.linalg.norm(diff, axis=2), 1e-6)
            mag = self.a_wall_mps2 * np.exp((radius[:, None] + scene.cylinders[None, :, 2] - dc) / self.b_wall_m)
            acc += np.sum((mag / dc)[..., None] * diff, axis=1)
        return acc


class Walkers:
    """The pedestrians of a scene: simulated ones (stepped) and replayed real tracks (sampled)."""

    def __init__(self, scene: Scene, *, tracks: Any = None, force: SocialForce = SocialForce(),
                 waypoint_tol_m: float = 0.4) -> None:
        self.scene, self.force, self.waypoint_tol_m = scene, force, waypoint_tol_m
        specs = scene.pedestrians
        self.ids = np.array([p.id for p in specs], np.int64)
        self.radius = np.array([p.radius_m for p in specs], float)
        self.height = np.array([p.height_m for p in specs], float)
        self.speed = np.array([p.speed_mps for p in specs], float)
        self.start_s = np.array([p.start_s for p in specs], float)
        self.unseen = np.array([p.unseen for p in specs], bool)
        self.tracks = tracks
        self.keep_clear: tuple[float, float, float] | None = None   # (x, y, radius) no respawn may land on
        if scene.replay is not None and tracks is None:
            from sim.pedestrian_data import load_tracks
            self.tracks = load_tracks(scene.replay.dataset)
        self.reset()

    def reset(self) -> None:
        specs = self.scene.pedestrians
        self.t_s = 0.0
        self.xy = np.array([p.waypoints[0] for p in specs], float).reshape(-1, 2)
        self.vel = np.zeros_like(self.xy)
        self.target = np.array([min(1, len(p.waypoints) - 1) for p in specs], int)
        self.direction = np.ones(len(specs), int)
        self.v0 = self.speed.copy()
        self.present = self.start_s <= 0.0
        self.static = self.speed == 0

    def step(self, t_s: float, dt: float, robot: tuple[float, ...] | None, *, goals: np.ndarray | None = None,
             v0: np.ndarray | None = None) -> None:
        """Advance from ``t_s`` by ``dt``; ``robot`` = (x, y, vx, vy, radius) when pedestrians should avoid it.

        ``goals`` (N, 2) m, optional: where each pedestrian heads this step instead of its current waypoint (a
        moving waypoint, e.g. a recorded track ahead; the waypoints are then not advanced); ``v0`` (N,) m/s,
        optional: each one's desired speed this step (default: its own, as set by the scene)."""
        self.t_s = t_s + dt
        self.present |= self.start_s <= self.t_s
        if v0 is not None:
            self.v0 = np.asarray(v0, float).reshape(len(self.ids))
        moving = self.present & ~self.static
        if not moving.any():
            return
        if goals is None:
            goal = np.array([p.waypoints[k] for p, k in zip(self.scene.pedestrians, self.target)]).reshape(-1, 2)
        else:
            goal = np.asarray(goals, float).reshape(-1, 2)
            if goal.shape != self.xy.shape:
                raise ValueError(f"goals must be one (x, y) per pedestrian, {self.xy.shape}, got {goal.shape}")
        if self.scene.pedestrian_model == "linear":
            to_goal = goal - self.xy
            dist = np.linalg.norm(to_goal, axis=1, keepdims=True)
            vel = self.v0[:, None] * to_goal / np.maximum(dist, 1e-9)
            vel = np.where(dist > self.v0[:, None] * dt, vel, to_goal / max(dt, 1e-9))   # land on the waypoint
        else:
            _, rep_xy, rep_vel, rep_r, _ = self.replayed()
            others = np.concatenate([np.column_stack([self.xy, self.radius, self.vel])[self.present & ~self.unseen],
                                     np.column_stack([rep_xy, rep_r, rep_vel])])
            acc = self.force.acceleration(self.xy, self.vel, self.v0, goal, self.radius, others, self.scene, robot)
            vel = self.vel + acc * dt
            to_goal = goal - self.xy
            e = to_goal / np.maximum(np.linalg.norm(to_goal, axis=1, keepdims=True), 1e-9)
            back = np.minimum(np.sum(vel * e, axis=1), 0.0)
            vel -= back[:, None] * e                  # people side-step or stop; they do not walk backwards
            cap = self.force.max_speed_factor * np.maximum(self.speed, 0.1)
            norm = np.linalg.norm(vel, axis=1)
            vel *= np.minimum(1.0, cap / np.maximum(norm, 1e-9))[:, None]
        self.vel = np.where(moving[:, None], vel, 0.0)
        self.xy = self._push_out_of_walls(self.xy + self.vel * dt)
        if goals is None:
            self._advance_waypoints(moving)

    def _push_out_of_walls(self, xy: np.ndarray) -> np.ndarray:
        """Hard constraint: a body never overlaps a wall or a pillar (the force alone can overshoot)."""
        if len(self.scene.segments):
            away, _ = _closest_on_segments(xy, self.scene.segments)
            d = np.maximum(np.linalg.norm(away, axis=2), 1e-9)
            depth = np.maximum(self.radius[:, None] - d, 0.0)
            xy = xy + np.sum((depth / d)[..., None] * away, axis=1)
        if len(self.scene.cylinders):
            diff = xy[:, None, :] - self.scene.cylinders[None, :, :2]
            d = np.maximum(np.linalg.norm(diff, axis=2), 1e-9)
            depth = np.maximum(self.radius[:, None] + self.scene.cylinders[None, :, 2] - d, 0.0)
            xy = xy + np.sum((depth / d)[..., None] * diff, axis=1)
        return np.where(self.static[:, None], self.xy, xy)

    def _advance_waypoints(self, moving: np.ndarray) -> None:
        for i in np.flatnonzero(moving):
            spec = self.scene.pedestrians[i]
            wps = spec.waypoints
            if np.linalg.norm(wps[self.target[i]] - self.xy[i]) > self.waypoint_tol_m:
                continue
            nxt = self.target[i] + self.direction[i]
            if 0 <= nxt < len(wps):
                self.target[i] = nxt
            elif spec.at_goal == "loop" and len(wps) > 1:
                self.direction[i] *= -1
                self.target[i] += self.direction[i]
            elif spec.at_goal == "respawn":
                if self._spawn_blocked(wps[0], self.radius[i]):
                    self.vel[i] = 0.0            # wait at the goal: nobody appears inside the robot
                    continue
                self.xy[i], self.vel[i] = wps[0], 0.0
                self.target[i], self.direction[i] = min(1, len(wps) - 1), 1
            else:
                self.v0[i], self.vel[i] = 0.0, 0.0        # stand at the goal, and stay there
                self.static[i] = True

    def _spawn_blocked(self, xy: np.ndarray, radius_m: float) -> bool:
        if self.keep_clear is None:
            return False
        x, y, r = self.keep_clear
        return bool(np.hypot(xy[0] - x, xy[1] - y) < r + radius_m + 0.5)

    def replayed(self) -> tuple[np.ndarray, ...]:
        """Replayed pedestrians inside the scene bounds now: ids, xy (M, 2), vel (M, 2), radius, height."""
        rep = self.scene.replay
        if rep is None or self.tracks is None:
            empty = np.zeros(0)
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), empty, empty
        ids, xy, vel = self.tracks.state_at(rep.t0_s + self.t_s)
        if rep.exclude_ids:
            keep = ~np.isin(ids, rep.exclude_ids)
            ids, xy, vel = ids[keep], xy[keep], vel[keep]
        xy = rep.to_world(xy)
        vel = rep.to_world(vel) - rep.to_world(np.zeros((1, 2)))
        x0, y0, x1, y1 = self.scene.bounds_m
        keep = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        n = int(keep.sum())
        return (ids[keep] + rep.id_offset, xy[keep], vel[keep], np.full(n, rep.radius_m), np.full(n, rep.height_m))

    def state(self) -> tuple[np.ndarray, ...]:
        """ids (N,), xy (N, 2), vel (N, 2), radius (N,), height (N,) of every pedestrian present."""
        p = self.present
        rep = self.replayed()
        return (np.concatenate([self.ids[p], rep[0]]), np.concatenate([self.xy[p], rep[1]]),
                np.concatenate([self.vel[p], rep[2]]), np.concatenate([self.radius[p], rep[3]]),
                np.concatenate([self.height[p], rep[4]]))
