"""Structure models ready for ICP matching: points, normals, a KD-tree and an optional nearest-point grid."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from nodes.sonar.symmetry import ModelSymmetry


@dataclass(frozen=True)
class NearestGrid:
    """Precomputed nearest model point per voxel around the model (-1: none within the margin).

    A static model makes the nearest-neighbour search a table lookup: the match of a point is the
    model point nearest to its voxel's centre (at most ``voxel_m * sqrt(3) / 2`` from the exact one;
    the same surface patch, which is what the point-to-plane error needs). :func:`align` polishes
    the last iterations with the exact KD-tree.
    """

    origin: np.ndarray
    voxel_m: float
    dims: tuple[int, int, int]
    table: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, tree: cKDTree, voxel_m: float, margin_m: float) -> "NearestGrid":
        from scipy.ndimage import binary_dilation

        lo = points.min(axis=0) - margin_m
        dims = tuple(int(v) for v in np.ceil((points.max(axis=0) + margin_m - lo) / voxel_m))
        if int(np.prod(dims)) > 20_000_000:
            raise ValueError(f"nearest grid of {dims} voxels is too big; raise voxel_m or lower margin_m")
        occupied = np.zeros(dims, bool)
        occupied[tuple(((points - lo) / voxel_m).astype(int).T)] = True
        near = binary_dilation(occupied, iterations=int(np.ceil(margin_m / voxel_m)))
        cells = np.flatnonzero(near.ravel())
        centres = lo + (np.stack(np.unravel_index(cells, dims), axis=1) + 0.5) * voxel_m
        _, idx = tree.query(centres, k=1, distance_upper_bound=margin_m + voxel_m)
        table = np.full(int(np.prod(dims)), -1, np.int32)
        table[cells] = np.where(idx < len(points), idx, -1)
        return cls(lo, float(voxel_m), dims, table)

    def lookup(self, p: np.ndarray) -> np.ndarray:
        """Index of the model point matched to each of ``p`` (K, 3), -1 where none."""
        v = np.floor((p - self.origin) / self.voxel_m).astype(np.int64)
        d0, d1, d2 = self.dims
        inside = (v >= 0).all(axis=1) & (v[:, 0] < d0) & (v[:, 1] < d1) & (v[:, 2] < d2)
        out = np.full(len(p), -1, np.int32)
        vi = v[inside]
        out[inside] = self.table[(vi[:, 0] * d1 + vi[:, 1]) * d2 + vi[:, 2]]
        return out


@dataclass(frozen=True)
class IcpModel:
    """A model ready for matching: points, unit normals, their KD-tree, optionally a nearest grid and
    the model's own yaw symmetries (:mod:`nodes.sonar.symmetry`)."""

    points: np.ndarray
    normals: np.ndarray
    tree: cKDTree
    centroid: np.ndarray
    grid: NearestGrid | None = None
    symmetry: "ModelSymmetry | None" = None
    spacing_m: float = 0.0                 # median distance between neighbouring samples

    @classmethod
    def build(cls, points: np.ndarray, normals: np.ndarray, *, grid_m: float = 0.0,
              grid_margin_m: float = 1.0, symmetry: bool = False) -> "IcpModel":
        """Build once per model. ``grid_m`` > 0 adds a :class:`NearestGrid` (faster matching, ~1 s to build);
        ``symmetry`` finds the model's yaw twins (0.1-0.7 s), which :func:`nodes.sonar.icp.align` then tries."""
        p, n = np.asarray(points, float), np.asarray(normals, float)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape or len(p) < 3:
            raise ValueError(f"model needs >= 3 points (K, 3) and normals of the same shape, got {p.shape}, {n.shape}")
        ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(n), axis=1) & (np.linalg.norm(n, axis=1) > 0)
        p, n = p[ok], n[ok] / np.linalg.norm(n[ok], axis=1, keepdims=True)
        tree = cKDTree(p, leafsize=16, balanced_tree=False)
        grid = NearestGrid.build(p, tree, grid_m, grid_margin_m) if grid_m > 0 else None
        probe = p[:: max(1, len(p) // 2000)]
        spacing = float(np.median(tree.query(probe, k=2)[0][:, 1]))
        model = cls(p, n, tree, p.mean(axis=0), grid, spacing_m=spacing)
        if symmetry:
            from nodes.sonar.symmetry import find_symmetries

            model = replace(model, symmetry=find_symmetries(model))
        return model

    def nearest(self, p: np.ndarray, gate: float, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``(distance, index)`` of each point's match; distance inf beyond ``gate`` or without one."""
        if exact or self.grid is None:
            return self.tree.query(p, k=1, distance_upper_bound=gate)
        idx = self.grid.lookup(p)
        d = np.linalg.norm(p - self.points[idx], axis=1)
        d[(idx < 0) | (d > gate)] = np.inf
        return d, idx
