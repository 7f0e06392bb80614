"""FLS scenes: seafloor, structures and a sonar on a moving boat; vectorised first-hit ray casting.

A scene is ``sim/scenes/fls_<name>.yaml`` (or a dict with the same keys)::

    name: tripod
    seafloor: {type: plane, z_m: -6.0, reflectivity: 0.3}
    #   or {type: heightfield, heights_m: [[...], ...], origin_m: [x0, y0], cell_m: 1.0}
    structures:
      - {type: cylinder, from_m: [0, 6, -6], to_m: [0, 0, -2], radius_m: 0.4, reflectivity: 0.9}
      - {type: box, center_m: [0, 6, -5.75], size_m: [2, 2, 0.5], yaw_deg: 0}
      - {type: mesh, obj: wreck.obj}          # or vertices_m: [[x, y, z], ...], faces: [[i, j, k], ...]
    sonar: {tilt_deg: 15, frequency: low, low: {...}, high: {...}, elevation_rays: 40, ...}
    platform: {start_m: [1, -30], end_m: [1, 30], depth_m: 1.0, speed_mps: 1.5}

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
import yaml

SCENE_DIR = Path(__file__).resolve().parent / "scenes"
_EPS = 1e-9


def _arr(v: Any, n: int | None = None) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if n is not None and a.shape != (n,):
        raise ValueError(f"expected {n} numbers, got {v!r}")
    return a


def _cells(size: float, spacing_m: float) -> np.ndarray:
    """Centres of ceil(size / spacing) equal cells across [-size/2, size/2] (no samples on edges)."""
    n = max(1, int(np.ceil(size / spacing_m)))
    return ((np.arange(n) + 0.5) / n - 0.5) * size


@dataclass(frozen=True)
class Plane:
    """Horizontal seafloor at ``z_m``."""

    z_m: float
    reflectivity: float = 0.3

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dz = dirs[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.z_m - origin[2]) / dz
        t = np.where((np.abs(dz) > _EPS) & (t > 0), t, np.inf)
        return t, np.broadcast_to(np.array([0.0, 0.0, 1.0 if origin[2] >= self.z_m else -1.0]), dirs.shape)

    def depth_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.full(np.broadcast(x, y).shape, self.z_m)


@dataclass(frozen=True)
class HeightField:
    """Seafloor z = h(x, y) on a grid (bilinear; clamped outside). For smooth terrain."""

    heights_m: np.ndarray          # (H, W), row = y index, col = x index
    origin_m: tuple[float, float]  # (x, y) of heights_m[0, 0]
    cell_m: float
    reflectivity: float = 0.3
    samples: int = 64              # samples along each ray's band between min and max height

    def depth_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        h = self.heights_m
        fx = np.clip((np.asarray(x) - self.origin_m[0]) / self.cell_m, 0, h.shape[1] - 1.000001)
        fy = np.clip((np.asarray(y) - self.origin_m[1]) / self.cell_m, 0, h.shape[0] - 1.000001)
        ix, iy = fx.astype(int), fy.astype(int)
        ax, ay = fx - ix, fy - iy
        top = h[iy, ix] * (1 - ax) + h[iy, ix + 1] * ax
        bottom = h[iy + 1, ix] * (1 - ax) + h[iy + 1, ix + 1] * ax
        return top * (1 - ay) + bottom * ay

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = float(self.heights_m.min()) - 1e-3, float(self.heights_m.max()) + 1e-3   # band strictly brackets
        dz = np.where(np.abs(dirs[:, 2]) > _EPS, dirs[:, 2], -_EPS)
        t_in = np.clip(np.minimum((hi - origin[2]) / dz, (lo - origin[2]) / dz), 0, None)
        t_out = np.maximum((hi - origin[2]) / dz, (lo - origin[2]) / dz)
        ok = (t_out > 0) & (dirs[:, 2] < 0)
        s = np.linspace(0.0, 1.0, self.samples)
        ts = t_in[:, None] + (t_out - t_in)[:, None] * s          # (N, S)
        f = origin[2] + ts * dirs[:, 2:3] - self.depth_at(origin[0] + ts * dirs[:, :1], origin[1] + ts * dirs[:, 1:2])
        below = f <= 0
        k = np.where(below.any(axis=1), below.argmax(axis=1), -1)
        ok &= k > 0
        rows = np.nonzero(ok)[0]
        a, b = ts[rows, k[rows] - 1], ts[rows, k[rows]]
        for _ in range(6):                                          # bisection on the bracket
            m = 0.5 * (a + b)
            p = origin + m[:, None] * dirs[rows]
            under = p[:, 2] <= self.depth_at(p[:, 0], p[:, 1])
            a, b = np.where(under, a, m), np.where(under, m, b)
        t = np.full(len(dirs), np.inf)
        t[rows] = 0.5 * (a + b)
        normals = np.zeros_like(dirs)
        normals[:, 2] = 1.0
        if rows.size:
            p = origin + t[rows, None] * dirs[rows]
            e = 0.25 * self.cell_m
            gx = (self.depth_at(p[:, 0] + e, p[:, 1]) - self.depth_at(p[:, 0] - e, p[:, 1])) / (2 * e)
            gy = (self.depth_at(p[:, 0], p[:, 1] + e) - self.depth_at(p[:, 0], p[:, 1] - e)) / (2 * e)
            n = np.stack([-gx, -gy, np.ones_like(gx)], axis=1)
            normals[rows] = n / np.linalg.norm(n, axis=1, keepdims=True)
        return t, normals


@dataclass(frozen=True)
class Cylinder:
    """Capped cylinder from ``p0`` to ``p1`` (m) of radius ``radius_m``."""

    p0: np.ndarray
    p1: np.ndarray
    radius_m: float
    reflectivity: float = 0.9
    name: str = ""

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        axis = self.p1 - self.p0
        length = float(np.linalg.norm(axis))
        a = axis / length
        w = origin - self.p0
        w_a = float(w @ a)
        w_perp = w - w_a * a
        d_a = dirs @ a
        qa = np.maximum(1.0 - d_a ** 2, _EPS)       # |d_perp|^2 for unit d
        qb = dirs @ w_perp
        disc = qb ** 2 - qa * (float(w_perp @ w_perp) - self.radius_m ** 2)
        t = (-qb - np.sqrt(np.maximum(disc, 0.0))) / qa
        s = w_a + t * d_a
        t = np.where((disc >= 0) & (t > _EPS) & (s >= 0) & (s <= length), t, np.inf)
        cap_hit = np.zeros(len(dirs), np.int8)
        r2 = self.radius_m ** 2
        for centre, code in ((self.p0, 1), (self.p1, 2)):
            wc = origin - centre                     # |wc + tc d|^2 <= r^2 on the cap's plane
            with np.errstate(divide="ignore", invalid="ignore"):
                tc = -float(wc @ a) / d_a
                inside = float(wc @ wc) + 2 * tc * (dirs @ wc) + tc ** 2 <= r2
            better = np.isfinite(tc) & (tc > _EPS) & inside & (tc < t)
            t = np.where(better, tc, t)
            cap_hit[better] = code
        normals = np.zeros_like(dirs)
        hit = np.isfinite(t)
        p = origin + t[hit, None] * dirs[hit] - self.p0
        radial = p - (p @ a)[:, None] * a
        normals[hit] = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), _EPS)
        normals[cap_hit == 1] = -a
        normals[cap_hit == 2] = a
        return t, normals

    def sphere(self) -> tuple[np.ndarray, float]:
        return 0.5 * (self.p0 + self.p1), 0.5 * float(np.linalg.norm(self.p1 - self.p0)) + self.radius_m

    def sample(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
        axis = self.p1 - self.p0
        length = float(np.linalg.norm(axis))
        a = axis / length
        u = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(a, u)
        n_around = max(6, int(np.ceil(2 * np.pi * self.radius_m / spacing_m)))
        ang = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
        radial = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v              # (A, 3)
        s = _cells(length, spacing_m) + length / 2
        pts = [(self.p0 + s[:, None, None] * a + self.radius_m * radial[None]).reshape(-1, 3)]
        nrm = [np.broadcast_to(radial[None], (s.size, n_around, 3)).reshape(-1, 3)]
        disk = [np.zeros((1, 3))]                                                 # the two end caps: rings
        for rr in np.arange(spacing_m, self.radius_m, spacing_m):
            ring = np.linspace(0, 2 * np.pi, max(6, int(np.ceil(2 * np.pi * rr / spacing_m))), endpoint=False)
            disk.append(rr * (np.cos(ring)[:, None] * u + np.sin(ring)[:, None] * v))
        disk = np.concatenate(disk)
        for centre, sign in ((self.p0, -1.0), (self.p1, 1.0)):
            pts.append(centre + disk)
            nrm.append(np.broadcast_to(sign * a, disk.shape))
        return np.concatenate(pts), np.concatenate(nrm).copy()

    def inside(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        a = (self.p1 - self.p0) / np.linalg.norm(self.p1 - self.p0)
        w = points - self.p0
        s = w @ a
        r2 = np.einsum("ij,ij->i", w, w) - s ** 2
        length = float(np.linalg.norm(self.p1 - self.p0))
        return (s > margin_m) & (s < length - margin_m) & (r2 < (self.radius_m - margin_m) ** 2)


@dataclass(frozen=True)
class Box:
    """Box of ``size_m`` centred at ``center_m``, turned by ``rotation`` (3x3, box -> world)."""

    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray
    reflectivity: float = 0.8
    name: str = ""

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o = self.rotation.T @ (origin - self.center)
        d = dirs @ self.rotation
        half = self.size / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / d, (half - o) / d
        t1 = np.where(np.isnan(t1), -np.inf, t1)
        t2 = np.where(np.isnan(t2), np.inf, t2)
        tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
        near, far = tmin.max(axis=1), tmax.min(axis=1)
        t = np.where((near <= far) & (near > _EPS), near, np.inf)
        face = tmin.argmax(axis=1)
        sign = -np.sign(d[np.arange(len(d)), face])
        return t, self.rotation[:, face].T * sign[:, None]

    def sphere(self) -> tuple[np.ndarray, float]:
        return self.center, 0.5 * float(np.linalg.norm(self.size))

    def inside(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        local = (points - self.center) @ self.rotation
        return np.all(np.abs(local) < self.size / 2 - margin_m, axis=1)

    def sample(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
        pts, nrm = [], []
        for k in range(3):
            i, j = [m for m in range(3) if m != k]
            a, b = np.meshgrid(_cells(self.size[i], spacing_m), _cells(self.size[j], spacing_m), indexing="ij")
            for sign in (-1.0, 1.0):
                local = np.zeros((a.size, 3))
                local[:, i], local[:, j], local[:, k] = a.ravel(), b.ravel(), sign * self.size[k] / 2
                n = np.zeros(3)
                n[k] = sign
                pts.append(local @ self.rotation.T + self.center)
                nrm.append(np.broadcast_to(self.rotation @ n, local.shape))
        return np.concatenate(pts), np.concatenate(nrm)


@dataclass(frozen=True)
class Mesh:
    """Triangle mesh: vertices (V, 3) m, faces (F, 3) vertex indices."""

    vertices: np.ndarray
    faces: np.ndarray
    reflectivity: float = 0.8
    name: str = ""
    chunk: int = 4096

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tri = self.vertices[self.faces]                                       # (F, 3, 3)
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        fn = np.cross(e1, e2)
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), _EPS)
        tvec = origin - tri[:, 0]                                             # (F, 3)
        qvec = np.cross(tvec, e1)                                             # (F, 3)
        t_all = np.full(len(dirs), np.inf)
        n_all = np.zeros_like(dirs)
        for start in range(0, len(dirs), self.chunk):                         # Moller-Trumbore, rays x faces
            d = dirs[start:start + self.chunk]
            pvec = np.cross(d[:, None, :], e2[None])                          # (n, F, 3)
            det = np.einsum("nfk,fk->nf", pvec, e1)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                u = np.einsum("nfk,fk->nf", pvec, tvec) * inv
                v = (d @ qvec.T) * inv
                t = np.einsum("fk,fk->f", qvec, e2)[None] * inv
            ok = (np.abs(det) > _EPS) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > _EPS)
            t = np.where(ok, t, np.inf)
            k = t.argmin(axis=1)
            t_all[start:start + len(d)] = t[np.arange(len(d)), k]
            n_all[start:start + len(d)] = fn[k]
        flip = np.einsum("ij,ij->i", n_all, dirs) > 0
        n_all[flip] *= -1
        return t_all, n_all

    def sphere(self) -> tuple[np.ndarray, float]:
        centre = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        return centre, float(np.linalg.norm(self.vertices - centre, axis=1).max())

    def sample(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
        tri = self.vertices[self.faces]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        cross = np.cross(e1, e2)
        area = 0.5 * np.linalg.norm(cross, axis=1)
        n = np.maximum(1, np.round(area / spacing_m ** 2).astype(int))
        idx = np.repeat(np.arange(len(tri)), n)
        r = np.random.default_rng(0).random((idx.size, 2))
        flip = r.sum(axis=1) > 1
        r[flip] = 1 - r[flip]
        pts = tri[idx, 0] + r[:, :1] * e1[idx] + r[:, 1:] * e2[idx]
        return pts, cross[idx] / np.maximum(np.linalg.norm(cross[idx], axis=1, keepdims=True), _EPS)


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
    """A boat running straight from ``start`` to ``end`` and back, the sonar ``depth_m`` below the surface."""

    start: np.ndarray
    end: np.ndarray
    depth_m: float = 1.0
    speed_mps: float = 1.5


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
        leg = p.end - p.start
        length = float(np.linalg.norm(leg))
        s = (p.speed_mps * t_s) % (2 * length) if length > 0 else 0.0
        forward = s <= length
        xy = p.start + leg * (s / length if forward else (2 * length - s) / length) if length > 0 else p.start
        heading = leg / length if length > 0 else np.array([1.0, 0.0])
        heading = heading if forward else -heading
        return sonar_frame(np.array([xy[0], xy[1], -p.depth_m]), float(np.arctan2(heading[1], heading[0])),
                           self.sonar.tilt_rad)


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
        base, scene = path.parent, yaml.safe_load(path.read_text())
    floor = scene.get("seafloor")
    seafloor: Plane | HeightField | None = None
    if floor and floor.get("type", "plane") == "plane":
        seafloor = Plane(float(floor["z_m"]), float(floor.get("reflectivity", 0.3)))
    elif floor:
        seafloor = HeightField(np.asarray(floor["heights_m"], float), tuple(floor.get("origin_m", (0.0, 0.0))),
                               float(floor["cell_m"]), float(floor.get("reflectivity", 0.3)))
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
    platform = Platform(_arr(p.get("start_m", (0.0, -30.0)), 2), _arr(p.get("end_m", (0.0, 30.0)), 2),
                        float(p.get("depth_m", 1.0)), float(p.get("speed_mps", 1.5)))
    return Scene(name=str(scene.get("name", "")), seafloor=seafloor,
                 structures=tuple(_structure(x, base) for x in scene.get("structures", [])),
                 sonar=sonar, platform=platform, description=str(scene.get("description", "")))
