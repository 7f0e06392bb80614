"""Known structure models as oriented surface samples: cylinders, boxes, seabed patches, meshes (PLY/OBJ).

Everything returns ``(points, normals)``, both (K, 3) float64 in metres, normals unit and pointing
out of the solid. Sampling is deterministic (regular grids on each surface; meshes use a seeded
generator). The scene format is the ``structures`` list of ``sim/scenes/fls_*.yaml``::

    - {type: cylinder, from_m: [x, y, z], to_m: [x, y, z], radius_m: r}
    - {type: box, center_m: [x, y, z], size_m: [sx, sy, sz], yaw_deg: a}
    - {type: mesh, obj: file.obj}   (or ply: file.ply, or vertices_m: [...], faces: [...])
"""
from __future__ import annotations

import struct
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

Samples = tuple[np.ndarray, np.ndarray]


def sample_cylinder(p0: Sequence[float], p1: Sequence[float], radius_m: float, spacing_m: float = 0.1, *,
                    caps: bool = False) -> Samples:
    """Lateral surface of a finite cylinder, plus its two end discs with ``caps``.

    A cap that sits on the seabed or inside another part is removed by :func:`sample_structures`;
    an exposed one (a column's top below the surface) is often the first thing a sonar sees.
    """
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    if length <= 0 or radius_m <= 0 or spacing_m <= 0:
        raise ValueError("a cylinder needs distinct end points, radius_m > 0 and spacing_m > 0")
    w = axis / length
    u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    n_around = max(8, int(np.ceil(2 * np.pi * radius_m / spacing_m)))
    n_along = max(2, int(np.ceil(length / spacing_m)) + 1)
    ang = np.arange(n_around) * 2 * np.pi / n_around
    s = np.linspace(0.0, length, n_along)
    normals = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v             # (A, 3)
    pts = a + s[None, :, None] * w + radius_m * normals[:, None, :]            # (A, S, 3)
    out_p, out_n = [pts.reshape(-1, 3)], [np.repeat(normals, n_along, axis=0)]
    if caps:
        disc = [np.zeros((1, 3))]
        for rr in np.arange(spacing_m, radius_m, spacing_m):
            ring = np.arange(max(6, int(np.ceil(2 * np.pi * rr / spacing_m)))) * 2 * np.pi
            ring /= max(6, int(np.ceil(2 * np.pi * rr / spacing_m)))
            disc.append(rr * (np.cos(ring)[:, None] * u + np.sin(ring)[:, None] * v))
        disc = np.concatenate(disc)
        for centre, sign in ((a, -1.0), (b, 1.0)):
            out_p.append(centre + disc)
            out_n.append(np.tile(sign * w, (len(disc), 1)))
    return np.concatenate(out_p), np.concatenate(out_n)


def inside_structure(spec: Mapping[str, Any], points: np.ndarray, margin_m: float = 1e-3) -> np.ndarray:
    """(K,) bool: ``points`` strictly inside a cylinder or box spec (meshes: never), by ``margin_m``."""
    p = np.asarray(points, float)
    if spec.get("type") == "cylinder":
        a, b = np.asarray(spec["from_m"], float), np.asarray(spec["to_m"], float)
        length = float(np.linalg.norm(b - a))
        w = (b - a) / length
        rel = p - a
        s = rel @ w
        r2 = np.einsum("ij,ij->i", rel, rel) - s ** 2
        return (s > margin_m) & (s < length - margin_m) & (r2 < (float(spec["radius_m"]) - margin_m) ** 2)
    if spec.get("type") == "box":
        yaw = np.deg2rad(float(spec.get("yaw_deg", 0.0)))
        c, sn = np.cos(yaw), np.sin(yaw)
        local = (p - np.asarray(spec["center_m"], float)) @ np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
        return np.all(np.abs(local) < np.asarray(spec["size_m"], float) / 2 - margin_m, axis=1)
    return np.zeros(len(p), bool)


def sample_box(center_m: Sequence[float], size_m: Sequence[float], yaw_rad: float = 0.0, spacing_m: float = 0.1,
               *, bottom: bool = False) -> Samples:
    """Faces of a box yawed about z; the bottom face (resting on the seabed) is left out unless asked."""
    c, size = np.asarray(center_m, float), np.asarray(size_m, float)
    if np.any(size <= 0) or spacing_m <= 0:
        raise ValueError("a box needs three positive sizes and spacing_m > 0")
    pts, nrm = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            if axis == 2 and sign < 0 and not bottom:
                continue
            i, j = [k for k in range(3) if k != axis]
            gi = np.linspace(-size[i] / 2, size[i] / 2, max(2, int(np.ceil(size[i] / spacing_m)) + 1))
            gj = np.linspace(-size[j] / 2, size[j] / 2, max(2, int(np.ceil(size[j] / spacing_m)) + 1))
            a, b = np.meshgrid(gi, gj, indexing="ij")
            face = np.zeros((a.size, 3))
            face[:, i], face[:, j], face[:, axis] = a.ravel(), b.ravel(), sign * size[axis] / 2
            n = np.zeros((a.size, 3))
            n[:, axis] = sign
            pts.append(face)
            nrm.append(n)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return np.concatenate(pts) @ rot.T + c, np.concatenate(nrm) @ rot.T


def sample_seabed(z_m: float, center_xy: Sequence[float] = (0.0, 0.0), radius_m: float = 10.0,
                  spacing_m: float = 0.25) -> Samples:
    """A horizontal disc of seabed (normal +z)."""
    g = np.arange(-radius_m, radius_m + 1e-9, spacing_m)
    x, y = np.meshgrid(g, g, indexing="ij")
    keep = x ** 2 + y ** 2 <= radius_m ** 2
    pts = np.stack([x[keep] + center_xy[0], y[keep] + center_xy[1], np.full(keep.sum(), float(z_m))], axis=1)
    return pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1))


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, spacing_m: float = 0.1, *, seed: int = 0) -> Samples:
    """Area-weighted random samples of a triangle mesh (about one per spacing^2), face normals.

    Normals follow the faces' winding (counter-clockwise seen from outside, as PLY/OBJ exporters write).
    """
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or f.size == 0:
        raise ValueError("a mesh needs (V, 3) vertices and (F, 3) triangle indices")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError("mesh face indices out of range")
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    ok = area > 1e-12
    a, b, c, cross, area = a[ok], b[ok], c[ok], cross[ok], area[ok]
    rng = np.random.default_rng(seed)
    count = max(len(area), int(np.ceil(area.sum() / spacing_m ** 2)))
    tri = rng.choice(len(area), size=count, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    pts = (1 - r1)[:, None] * a[tri] + (r1 * (1 - r2))[:, None] * b[tri] + (r1 * r2)[:, None] * c[tri]
    return pts, cross[tri] / (2 * area[tri])[:, None]


def load_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3), faces (F, 3))`` from an OBJ or a PLY (ascii or binary little/big endian).

    Polygons are fanned into triangles.
    """
    p = Path(path)
    if p.suffix.lower() == ".obj":
        return _read_obj(p)
    if p.suffix.lower() == ".ply":
        return _read_ply(p)
    raise ValueError(f"{p}: unknown mesh format; give a .obj or .ply file")


def _triangulate(polys: list[list[int]]) -> np.ndarray:
    tris = [(poly[0], poly[k], poly[k + 1]) for poly in polys for k in range(1, len(poly) - 1)]
    return np.asarray(tris, np.int64).reshape(-1, 3)


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    verts, polys = [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(tok.split("/")[0]) for tok in parts[1:]]
            polys.append([i - 1 if i > 0 else len(verts) + i for i in idx])    # 1-based, or negative = relative
    if not verts or not polys:
        raise ValueError(f"{path}: no vertices or faces in this OBJ")
    return np.asarray(verts, float), _triangulate(polys)


_PLY_TYPES = {"char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h",
              "ushort": "H", "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I",
              "float": "f", "float32": "f", "double": "d", "float64": "d"}


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' magic or 'end_header')")
    header = data[:end].decode("ascii", "replace").splitlines()
    body = data[data.index(b"\n", end) + 1:]
    fmt = next((ln.split()[1] for ln in header if ln.startswith("format")), "")
    elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
    for ln in header:
        tok = ln.split()
        if tok[:1] == ["element"]:
            elements.append((tok[1], int(tok[2]), []))
        elif tok[:1] == ["property"] and elements:
            elements[-1][2].append(tuple(tok[1:]))
    if fmt == "ascii":
        return _ply_ascii(body.decode("ascii", "replace").split(), elements, path)
    if fmt in ("binary_little_endian", "binary_big_endian"):
        return _ply_binary(body, "<" if fmt == "binary_little_endian" else ">", elements, path)
    raise ValueError(f"{path}: unsupported PLY format {fmt!r}")


def _ply_ascii(tokens: list[str], elements, path: Path) -> tuple[np.ndarray, np.ndarray]:
    pos, verts, polys = 0, [], []
    for name, count, props in elements:
        for _ in range(count):
            row: dict[str, Any] = {}
            for prop in props:
                if prop[0] == "list":
                    n = int(tokens[pos])
                    row[prop[-1]] = [int(t) for t in tokens[pos + 1:pos + 1 + n]]
                    pos += 1 + n
                else:
                    row[prop[-1]] = float(tokens[pos])
                    pos += 1
            if name == "vertex":
                verts.append([row["x"], row["y"], row["z"]])
            elif name == "face":
                polys.append(row.get("vertex_indices", row.get("vertex_index", [])))
    return _ply_result(verts, polys, path)


def _ply_binary(body: bytes, order: str, elements, path: Path) -> tuple[np.ndarray, np.ndarray]:
    pos, verts, polys = 0, [], []
    for name, count, props in elements:
        if not any(p[0] == "list" for p in props):      # fixed-size rows: read them in one go
            dtype = np.dtype([(p[-1], order + _PLY_TYPES[p[0]]) for p in props])
            rows = np.frombuffer(body, dtype, count, pos)
            pos += dtype.itemsize * count
            if name == "vertex":
                verts = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(float).tolist()
            continue
        for _ in range(count):
            row: dict[str, Any] = {}
            for prop in props:
                if prop[0] == "list":
                    cfmt, ifmt = order + _PLY_TYPES[prop[1]], order + _PLY_TYPES[prop[2]]
                    (n,) = struct.unpack_from(cfmt, body, pos)
                    pos += struct.calcsize(cfmt)
                    row[prop[-1]] = list(struct.unpack_from(f"{order}{n}{ifmt[-1]}", body, pos))
                    pos += n * struct.calcsize(ifmt)
                else:
                    f = order + _PLY_TYPES[prop[0]]
                    (row[prop[-1]],) = struct.unpack_from(f, body, pos)
                    pos += struct.calcsize(f)
            if name == "vertex":
                verts.append([row["x"], row["y"], row["z"]])
            elif name == "face":
                polys.append(row.get("vertex_indices", row.get("vertex_index", [])))
    return _ply_result(verts, polys, path)


def _ply_result(verts, polys, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if len(verts) == 0 or not polys:
        raise ValueError(f"{path}: PLY without vertices or faces (a point-only PLY is not a surface)")
    return np.asarray(verts, float), _triangulate([list(p) for p in polys])


def sample_structures(structures: Sequence[Mapping[str, Any]], spacing_m: float = 0.1, *,
                      base: str | Path = ".", seabed_z_m: float | None = None) -> Samples:
    """Samples of a scene's ``structures`` list (see the module docstring).

    Cylinders are capped; samples buried inside another cylinder or box (joints, feet) or, with
    ``seabed_z_m``, on or under the seabed are dropped: a sonar cannot see them, and a model point
    there would pull ICP towards a surface that does not exist.
    """
    pts, nrm = [], []
    for k, spec in enumerate(structures):
        kind = spec.get("type")
        if kind == "cylinder":
            p, n = sample_cylinder(spec["from_m"], spec["to_m"], float(spec["radius_m"]), spacing_m, caps=True)
        elif kind == "box":
            p, n = sample_box(spec["center_m"], spec["size_m"], np.deg2rad(float(spec.get("yaw_deg", 0.0))),
                              spacing_m)
        elif kind == "mesh":
            if "vertices_m" in spec:
                v, f = np.asarray(spec["vertices_m"], float), np.asarray(spec["faces"], np.int64)
            else:
                v, f = load_mesh(Path(base) / str(spec.get("obj") or spec.get("ply")))
            p, n = sample_mesh(v, f, spacing_m)
        else:
            raise ValueError(f"unknown structure type {kind!r}; use cylinder, box or mesh")
        buried = np.zeros(len(p), bool)
        for j, other in enumerate(structures):
            if j != k:
                buried |= inside_structure(other, p)
        if seabed_z_m is not None:
            buried |= p[:, 2] <= seabed_z_m + 1e-3
        pts.append(p[~buried])
        nrm.append(n[~buried])
    if not pts:
        raise ValueError("no structures to sample")
    return np.concatenate(pts), np.concatenate(nrm)


def tripod_structures(*, pylons: bool = True, seabed_z_m: float = -6.0) -> list[dict[str, Any]]:
    """The paper's windmill tripod, as in ``sim/scenes/fls_tripod.yaml``.

    Three feet with mud mats on a 6 m circle (90, 210, 330 deg), inclined legs to an apex 2.5 m
    below the surface, a central column, braces between the feet, and (``pylons``) two pylons on
    the south-west and south-east feet breaking the surface. Without the pylons it is 3-fold
    symmetric about the z axis.
    """
    z0 = seabed_z_m
    feet = [(6.0 * np.cos(np.deg2rad(a)), 6.0 * np.sin(np.deg2rad(a))) for a in (90.0, 210.0, 330.0)]
    out: list[dict[str, Any]] = []
    for (x, y), yaw in zip(feet, (0.0, 30.0, -30.0)):
        out.append({"type": "box", "center_m": [x, y, z0 + 0.2], "size_m": [1.8, 1.8, 0.4], "yaw_deg": yaw})
        out.append({"type": "cylinder", "from_m": [x, y, z0 + 0.4], "to_m": [0.0, 0.0, -2.5], "radius_m": 0.4})
    out.append({"type": "cylinder", "from_m": [0.0, 0.0, z0], "to_m": [0.0, 0.0, -2.0], "radius_m": 0.6})
    for (xa, ya), (xb, yb) in ((feet[1], feet[2]), (feet[1], feet[0]), (feet[2], feet[0])):
        out.append({"type": "cylinder", "from_m": [xa, ya, z0 + 0.7], "to_m": [xb, yb, z0 + 0.7], "radius_m": 0.25})
    if pylons:
        for x, y in feet[1:]:
            out.append({"type": "cylinder", "from_m": [x, y, z0 + 0.4], "to_m": [x, y, 2.0], "radius_m": 0.6})
    return out


def tripod_model(*, pylons: bool = True, spacing_m: float = 0.1, seabed_radius_m: float = 0.0,
                 seabed_z_m: float = -6.0) -> Samples:
    """Surface samples of :func:`tripod_structures`, plus a seabed disc when ``seabed_radius_m`` > 0."""
    pts, nrm = sample_structures(tripod_structures(pylons=pylons, seabed_z_m=seabed_z_m), spacing_m,
                                 seabed_z_m=seabed_z_m)
    if seabed_radius_m > 0:
        sp, sn = sample_seabed(seabed_z_m, (0.0, 0.0), seabed_radius_m, max(spacing_m, 0.25))
        pts, nrm = np.concatenate([pts, sp]), np.concatenate([nrm, sn])
    return pts, nrm
