"""Surfaces of an FLS scene: vectorised first-hit ray intersection and surface sampling (pure numpy).

Every surface has ``intersect(origin (3,), dirs (N, 3) unit) -> (t (N,) m, inf on a miss; normals
(N, 3))``; structures also have ``sphere()`` (bounding sphere, for culling), ``sample(spacing_m)``
(surface points and outward normals) and, for cylinders and boxes, ``inside(points)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_EPS = 1e-9


def _cells(size: float, spacing_m: float) -> np.ndarray:
    """Centres of ceil(size / spacing) equal cells across [-size/2, size/2] (no samples on edges)."""
    n = max(1, int(np.ceil(size / spacing_m)))
    return ((np.arange(n) + 0.5) / n - 0.5) * size


@dataclass(frozen=True, eq=False)
class Texture:
    """A reflectivity map on the seafloor: ``values`` (H, W) in [0, 1], cell (0, 0) centred at
    ``origin_m`` (x east, y north), ``cell_m`` apart; the mean maps to the surface's reflectivity."""

    values: np.ndarray
    origin_m: tuple[float, float]
    cell_m: float

    def factor_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear texture / its mean at world (x, y); 1 outside the map."""
        v = self.values
        fx = (np.asarray(x) - self.origin_m[0]) / self.cell_m
        fy = (np.asarray(y) - self.origin_m[1]) / self.cell_m
        inside = (fx >= 0) & (fy >= 0) & (fx < v.shape[1] - 1) & (fy < v.shape[0] - 1)
        ix, iy = np.clip(fx, 0, v.shape[1] - 2).astype(int), np.clip(fy, 0, v.shape[0] - 2).astype(int)
        ax, ay = np.clip(fx - ix, 0, 1), np.clip(fy - iy, 0, 1)
        top = v[iy, ix] * (1 - ax) + v[iy, ix + 1] * ax
        bottom = v[iy + 1, ix] * (1 - ax) + v[iy + 1, ix + 1] * ax
        return np.where(inside, (top * (1 - ay) + bottom * ay) / max(float(v.mean()), 1e-9), 1.0)


@dataclass(frozen=True)
class Plane:
    """Horizontal seafloor at ``z_m`` (with an optional reflectivity ``texture``)."""

    z_m: float
    reflectivity: float = 0.3
    texture: Texture | None = None

    def reflectivity_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.reflectivity * (self.texture.factor_at(x, y) if self.texture is not None else np.ones(np.shape(x)))

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
    texture: Texture | None = None

    def reflectivity_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.reflectivity * (self.texture.factor_at(x, y) if self.texture is not None else np.ones(np.shape(x)))

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

    def inside(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Inside by the generalised winding number (w >= 1/2), which holds for the open,
        cracked or doubled-up meshes OBJ files often are; with ``margin_m`` the point and its six
        neighbours at +-margin along the axes must all be inside (an erosion by a cube)."""
        from nodes.shapes.fast_winding import fast_winding, mesh_tree, winding_mesh

        pts = np.asarray(points, np.float64).reshape(-1, 3)
        offsets = np.zeros((1, 3)) if margin_m <= 0 else np.vstack([np.zeros(3), margin_m * np.eye(3), -margin_m * np.eye(3)])
        probe = (pts[:, None, :] + offsets[None]).reshape(-1, 3)
        if len(self.faces) * len(probe) <= 2e7:
            w = winding_mesh(probe, self.vertices, self.faces)
        else:
            w = fast_winding(mesh_tree(self.vertices, self.faces), probe, beta=2.0)
        return np.all(w.reshape(len(pts), len(offsets)) >= 0.5, axis=1)

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
