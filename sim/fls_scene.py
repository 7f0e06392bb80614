"""FLS scenes: seafloor, structures and a sonar on a moving boat; vectorised first-hit ray casting.

A scene is ``sim/scenes/fls_<name>.yaml`` (or a dict with the same keys)::

    name: tripod
    seafloor: {type: plane, z_m: -6.0, reflectivity: 0.3}
    #   + texture: {seed: 3, size_m: [80, 80], cell_m: 0.05, scales_m: [0.1, 0.3, 1.0]} (or image: floor.png)
    #   or {type: heightfield, heights_m: [[...], ...], origin_m: [x0, y0], cell_m: 1.0}
    structures:
      - {type: cylinder, from_m: [0, 6, -6], to_m: [0, 0, -2], radius_m: 0.4, reflectivity: 0.9}
      - {type: box, center_m: [0, 6, -5.75], size_m: [2, 2, 0.5], yaw_deg: 0}
      - {type: mesh, obj: wreck.obj}          # or vertices_m: [[x, y, z], ...], faces: [[i, j, k], ...]
    sonar: {tilt_deg: 15, frequency: low, low: {...}, high: {...}, elevation_rays: 40, ...}
    platform: {start_m: [1, -30], end_m: [1, 30], depth_m: 1.0, speed_mps: 1.5}
    #   or waypoints_m: [[x, y], ...] (a survey pattern), run out and back

World frame: x east, y north, z up, sea surface at z = 0. The sonar frame is FRD, as in the
paper's eq. (15)-(17): x along the boresight, y to starboard, z down; a return at range r,
bearing theta (positive to starboard) and elevation phi (positive downwards) lies at
``r * (cos phi cos theta, cos phi sin theta, sin phi)``. The boat runs straight from ``start_m``
to ``end_m`` and back at ``depth_m`` below the surface; the sonar looks ahead, tilted down by
``tilt_deg``. Only what the scene declares is modelled (no water surface, no multipath).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from sim.fls_shapes import Box, Cylinder, HeightField, Mesh, Plane, Texture
from tether.yamlsafe import load_yaml_file

__all__ = ["Box", "Cylinder", "HeightField", "Mesh", "Plane", "Platform", "Scene", "SonarModel", "cast_rays",
           "load_scene", "sample_structures", "sonar_frame"]

SCENE_DIR = Path(__file__).resolve().parent / "scenes"


def _arr(v: Any, n: int | None = None) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if n is not None and a.shape != (n,):
        raise ValueError(f"expected {n} numbers, got {v!r}")
    return a


@dataclass(frozen=True)
class SonarModel:
    """The FLS head: per-frequency apertures and the image model's constants."""

    tilt_rad: float = np.radians(15.0)
    frequency: str = "low"
    modes: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: {
        "low": {"frequency_hz": 1.2e6, "horizontal_aperture_deg": 130.0, "vertical_aperture_deg": 20.0,
                "max_range_m": 40.0, "absorption_db_per_m": 0.05},
        "high": {"frequency_hz": 2.1e6, "horizontal_aperture_deg": 80.0, "vertical_aperture_deg": 12.0,
                 "max_range_m": 10.0, "absorption_db_per_m": 0.1}})
    elevation_rays: int = 40
    max_ranges: int = 1024
    min_resolution_m: float = 0.0025
    speckle: float = 1.0              # 0 = none, 1 = fully developed (exponential intensity)
    noise_floor: float = 0.01         # mean of the additive noise, in level units (full scale = 1)
    level_scale: float = 60.0         # echo -> level (full scale = 1) before gain and gamma
    sound_speed_mps: float = 1500.0


@dataclass(frozen=True)
class Platform:
    """A boat running straight from ``start`` to ``end`` and back -- or along ``waypoints`` (a
    polyline, e.g. a lawn-mower survey) and back -- the sonar ``depth_m`` below the surface."""

    start: np.ndarray
    end: np.ndarray
    depth_m: float = 1.0
    speed_mps: float = 1.5
    waypoints: np.ndarray | None = None

    def path(self) -> np.ndarray:
        return self.waypoints if self.waypoints is not None else np.stack([self.start, self.end])

    def position_heading(self, t_s: float) -> tuple[np.ndarray, float]:
        """Position (2,) and heading (rad, CCW from +x) at ``t_s`` on the out-and-back run."""
        pts = self.path()
        seg = np.diff(pts, axis=0)
        lengths = np.linalg.norm(seg, axis=1)
        total = float(lengths.sum())
        if total <= 0:
            return pts[0].copy(), 0.0
        s = (self.speed_mps * t_s) % (2 * total)
        back = s > total
        s = 2 * total - s if back else s
        k = int(min(np.searchsorted(np.cumsum(lengths), s, side="right"), len(lengths) - 1))
        along = s - float(np.cumsum(lengths)[k] - lengths[k])
        direction = seg[k] / max(lengths[k], 1e-12)
        xy = pts[k] + direction * min(along, lengths[k])
        heading = -direction if back else direction
        return xy, float(np.arctan2(heading[1], heading[0]))


@dataclass(frozen=True)
class Scene:
    name: str
    seafloor: Plane | HeightField | None
    structures: tuple[Cylinder | Box | Mesh, ...]
    sonar: SonarModel
    platform: Platform
    description: str = ""

    def surfaces(self) -> list:
        """Seafloor (label 0, if any) then structures (labels 1..n)."""
        return [self.seafloor] + list(self.structures)

    def sonar_pose(self, t_s: float) -> np.ndarray:
        """4x4 transform sonar (FRD head, tilted) -> world at time ``t_s`` on the back-and-forth run."""
        p = self.platform
        xy, yaw = p.position_heading(t_s)
        return sonar_frame(np.array([xy[0], xy[1], -p.depth_m]), yaw, self.sonar.tilt_rad)


def sonar_frame(position_m: np.ndarray, yaw_rad: float, tilt_rad: float) -> np.ndarray:
    """4x4 sonar(FRD) -> world(ENU) for a head at ``position_m`` heading ``yaw_rad`` (CCW from +x), tilted down."""
    f = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    starboard = np.array([np.sin(yaw_rad), -np.cos(yaw_rad), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    x = np.cos(tilt_rad) * f + np.sin(tilt_rad) * down
    z = np.cross(x, starboard)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, starboard, z], axis=1)
    out[:3, 3] = position_m
    return out


def cast_rays(scene: Scene, origin: np.ndarray, dirs: np.ndarray, *,
              max_range_m: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hit of each ray.

    Parameters
    ----------
    origin : (3,) m, world. dirs : (N, 3) unit vectors, world.
    max_range_m : structures whose bounding sphere lies beyond it are skipped.

    Returns
    -------
    t : (N,) range in m (inf on a miss). normals : (N, 3) unit surface normals at the hits.
    labels : (N,) int, index into :meth:`Scene.surfaces` (0 = seafloor), -1 on a miss.
    """
    t = np.full(len(dirs), np.inf)
    normals = np.zeros_like(dirs)
    labels = np.full(len(dirs), -1)
    for k, surface in enumerate(scene.surfaces()):
        if surface is None:
            continue
        rows = slice(None)
        if hasattr(surface, "sphere"):              # cull: only rays that pass the bounding sphere, nearer than the best
            centre, radius = surface.sphere()
            to_c = centre - origin
            dist = float(np.linalg.norm(to_c))
            if dist - radius > max_range_m:
                continue
            along = dirs @ to_c
            near = (along > -radius) & (dist ** 2 - along ** 2 < radius ** 2) & (t > dist - radius)
            rows = np.nonzero(near)[0]
            if rows.size == 0:
                continue
        tk, nk = surface.intersect(origin, dirs[rows])
        closer = tk < t[rows]
        idx = np.arange(len(dirs))[rows][closer]
        t[idx], normals[idx], labels[idx] = tk[closer], nk[closer], k
    return t, normals, labels


def sample_structures(scene: Scene, spacing_m: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 3) and outward normals (M, 3) on the structures' surfaces (not the seafloor), world m.

    Samples buried inside another structure (a leg's end inside a mud mat) or in the seabed are
    dropped; mesh
    samples are random on the faces (seeded), cylinders and boxes are on grids of ``spacing_m``.
    """
    if spacing_m <= 0:
        raise ValueError(f"spacing_m must be positive, got {spacing_m}")
    pts, nrm = [], []
    for k, structure in enumerate(scene.structures):
        p, n = structure.sample(spacing_m)
        buried = np.zeros(len(p), bool)              # drop samples inside another structure (joints, feet)
        for j, other in enumerate(scene.structures):
            if j != k and hasattr(other, "inside"):
                buried |= other.inside(p, margin_m=1e-3)
        if scene.seafloor is not None:               # and the faces lying on or under the seabed
            buried |= p[:, 2] <= scene.seafloor.depth_at(p[:, 0], p[:, 1]) + 1e-3
        pts.append(p[~buried])
        nrm.append(n[~buried])
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(pts), np.concatenate(nrm)


def _rotation(spec: Mapping[str, Any]) -> np.ndarray:
    roll, pitch, yaw = (np.radians(float(spec.get(k, 0.0))) for k in ("roll_deg", "pitch_deg", "yaw_deg"))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return (np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
            @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]]))


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    verts, faces = [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if parts[:1] == ["v"]:
            verts.append([float(x) for x in parts[1:4]])
        elif parts[:1] == ["f"]:
            idx = [int(p.split("/")[0]) - 1 for p in parts[1:]]
            faces += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]   # fan-triangulate
    return np.array(verts, float), np.array(faces, int)


def _structure(spec: Mapping[str, Any], base: Path) -> Cylinder | Box | Mesh:
    kind, refl, name = spec.get("type"), float(spec.get("reflectivity", 0.9)), str(spec.get("name", ""))
    if kind == "cylinder":
        return Cylinder(_arr(spec["from_m"], 3), _arr(spec["to_m"], 3), float(spec["radius_m"]), refl, name)
    if kind == "box":
        return Box(_arr(spec["center_m"], 3), _arr(spec["size_m"], 3), _rotation(spec), refl, name)
    if kind == "mesh":
        verts, faces = (_read_obj(base / spec["obj"]) if "obj" in spec
                        else (_arr(spec["vertices_m"]), np.asarray(spec["faces"], int)))
        return Mesh(verts, faces, refl, name)
    raise ValueError(f"structure type must be cylinder, box or mesh, got {kind!r} in {dict(spec)}")


def _texture(spec: Mapping[str, Any] | None, base: Path) -> Texture | None:
    """``{seed, size_m: [w, h], cell_m, origin_m}`` (procedural, sim.subimages.seafloor) or ``{image: file.png, ...}``."""
    if not spec:
        return None
    cell = float(spec.get("cell_m", 0.05))
    if cell <= 0:
        raise ValueError(f"texture cell_m must be positive, got {cell}")
    if "image" in spec:
        import cv2

        values = cv2.imread(str(base / spec["image"]), cv2.IMREAD_GRAYSCALE)
        if values is None:
            raise ValueError(f"texture image {spec['image']!r} cannot be read")
        values = values.astype(np.float32) / 255.0
    else:
        from sim.subimages import seafloor as procedural

        w, h = (float(v) for v in spec.get("size_m", (100.0, 100.0)))
        rows, cols = int(round(h / cell)), int(round(w / cell))
        if rows * cols > 50_000_000:
            raise ValueError(f"texture of {rows} x {cols} cells is too large; raise cell_m")
        values = procedural(np.random.default_rng(int(spec.get("seed", 0))), rows, cols,
                            scales_px=tuple(float(s) / cell for s in spec.get("scales_m", (0.1, 0.3, 1.0))))
    origin = spec.get("origin_m", (-values.shape[1] * cell / 2, -values.shape[0] * cell / 2))
    return Texture(values.astype(np.float32), (float(origin[0]), float(origin[1])), cell)


def load_scene(scene: str | Path | Mapping[str, Any]) -> Scene:
    """A :class:`Scene` from a name (``sim/scenes/fls_<name>.yaml``), a YAML path, or a dict."""
    base = SCENE_DIR
    if not isinstance(scene, Mapping):
        path = Path(scene)
        if not path.suffix:
            path = SCENE_DIR / f"fls_{scene}.yaml"
        if not path.is_file():
            known = sorted(p.stem[4:] for p in SCENE_DIR.glob("fls_*.yaml"))
            raise ValueError(f"no FLS scene {str(scene)!r}: give a YAML path or one of {known}")
        base, scene = path.parent, load_yaml_file(path)
    floor = scene.get("seafloor")
    seafloor: Plane | HeightField | None = None
    texture = _texture(floor.get("texture"), base) if floor else None
    if floor and floor.get("type", "plane") == "plane":
        seafloor = Plane(float(floor["z_m"]), float(floor.get("reflectivity", 0.3)), texture)
    elif floor:
        seafloor = HeightField(np.asarray(floor["heights_m"], float), tuple(floor.get("origin_m", (0.0, 0.0))),
                               float(floor["cell_m"]), float(floor.get("reflectivity", 0.3)), texture=texture)
    s = dict(scene.get("sonar", {}))
    modes = {k: {n: float(v) for n, v in {**SonarModel().modes[k], **s.pop(k, {})}.items()} for k in ("low", "high")}
    tilt = np.radians(float(s.pop("tilt_deg", 15.0)))
    try:
        sonar = SonarModel(tilt_rad=tilt, modes=modes, **s)
    except TypeError as exc:
        raise ValueError(f"scene {scene.get('name')!r} sonar: {exc}") from None
    if sonar.frequency not in modes:
        raise ValueError(f"sonar frequency must be 'low' or 'high', got {sonar.frequency!r}")
    p = scene.get("platform", {})
    waypoints = None
    if "waypoints_m" in p:
        waypoints = np.asarray(p["waypoints_m"], float)
        if waypoints.ndim != 2 or waypoints.shape[1] != 2 or len(waypoints) < 2 or not np.isfinite(waypoints).all():
            raise ValueError(f"platform waypoints_m: a list of at least two [x, y] points, got {p['waypoints_m']!r}")
    platform = Platform(_arr(p.get("start_m", (0.0, -30.0)), 2), _arr(p.get("end_m", (0.0, 30.0)), 2),
                        float(p.get("depth_m", 1.0)), float(p.get("speed_mps", 1.5)), waypoints)
    return Scene(name=str(scene.get("name", "")), seafloor=seafloor,
                 structures=tuple(_structure(x, base) for x in scene.get("structures", [])),
                 sonar=sonar, platform=platform, description=str(scene.get("description", "")))
