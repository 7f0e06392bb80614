"""Robust ICP of a sonar point cloud against a known structure model, with degeneracy and ambiguity checks.

Point-to-plane (default) or point-to-point Gauss-Newton on a KD-tree (``scipy.spatial.cKDTree``),
Huber or Cauchy weights, a shrinking correspondence gate (outlier rejection), and:

* **degeneracy**: the smallest eigenvalue of the point-to-plane normal matrix (translation in m,
  rotation scaled by the cloud's radius, per inlier) says which directions the geometry pins down.
  A flat seafloor leaves x, y and yaw free, one vertical cylinder its axis translation and the
  rotation about it. Updates are confined to the observable subspace, so free directions stay at
  the prior instead of wandering, and get a huge variance in the covariance.
* **ambiguity**: restarts over yaw about the model's vertical axis compare robust residuals. When a
  distinct pose near the prior fits as well as the chosen one (a 3-fold symmetric tripod seen 60 deg
  off), the result says so instead of claiming one with confidence.

Transforms are 4x4, cloud frame -> model frame. Covariance order (x, y, z, roll, pitch, yaw), a
left perturbation about the model-frame origin; the world is z-up.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

METHODS = ("point_to_plane", "point_to_point")
KERNELS = ("huber", "cauchy", "none")
UNOBSERVED_VARIANCE = 1e6       # m^2 or rad^2 for directions the geometry does not constrain


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
    """A model ready for matching: points, unit normals, their KD-tree and optionally a nearest grid."""

    points: np.ndarray
    normals: np.ndarray
    tree: cKDTree
    centroid: np.ndarray
    grid: NearestGrid | None = None

    @classmethod
    def build(cls, points: np.ndarray, normals: np.ndarray, *, grid_m: float = 0.0,
              grid_margin_m: float = 1.0) -> "IcpModel":
        """Build once per model. ``grid_m`` > 0 adds a :class:`NearestGrid` (faster matching, ~1 s to build)."""
        p, n = np.asarray(points, float), np.asarray(normals, float)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape or len(p) < 3:
            raise ValueError(f"model needs >= 3 points (K, 3) and normals of the same shape, got {p.shape}, {n.shape}")
        ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(n), axis=1) & (np.linalg.norm(n, axis=1) > 0)
        p, n = p[ok], n[ok] / np.linalg.norm(n[ok], axis=1, keepdims=True)
        tree = cKDTree(p, leafsize=16, balanced_tree=False)
        grid = NearestGrid.build(p, tree, grid_m, grid_margin_m) if grid_m > 0 else None
        return cls(p, n, tree, p.mean(axis=0), grid)

    def nearest(self, p: np.ndarray, gate: float, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``(distance, index)`` of each point's match; distance inf beyond ``gate`` or without one."""
        if exact or self.grid is None:
            return self.tree.query(p, k=1, distance_upper_bound=gate)
        idx = self.grid.lookup(p)
        d = np.linalg.norm(p - self.points[idx], axis=1)
        d[(idx < 0) | (d > gate)] = np.inf
        return d, idx


@dataclass(frozen=True)
class IcpSettings:
    """Tuning of :func:`align` (distances in m, angles in rad)."""

    method: str = "point_to_plane"
    kernel: str = "huber"
    kernel_scale_m: float = 0.2
    max_correspondence_m: float = 1.5        # first iteration's gate
    min_correspondence_m: float = 0.3        # the gate shrinks geometrically to this
    gate_decay: float = 0.6
    max_iterations: int = 30
    max_points: int = 800                    # random subsample of the cloud (seeded)
    coarse_fraction: float = 0.3             # share of the sample matched while the gate shrinks
    tolerance_m: float = 2e-3                # stop when a step moves less than this ...
    tolerance_rad: float = 5e-4              # ... and turns less than this, with the gate at its minimum
    polish_exact: bool = False               # after converging on the nearest grid, iterate on the KD-tree
    degeneracy_threshold: float = 0.02       # smallest normalised eigenvalue for a well-posed direction
    min_inliers: int = 12
    yaw_hypotheses: int = 6                  # restarts over yaw (0 or 1: none)
    hypothesis_points: int = 200
    hypothesis_iterations: int = 8
    refine_ratio: float = 2.5                # restarts scoring within this factor of the best are finished
    ambiguity_ratio: float = 1.25            # another pose within this factor of the best score is "as good"
    distinct_yaw_rad: float = np.deg2rad(10.0)
    distinct_m: float = 0.5
    prior_window_rad: float = np.deg2rad(90.0)   # alternatives further than this from the prior are dismissed
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in METHODS or self.kernel not in KERNELS:
            raise ValueError(f"method must be one of {METHODS} and kernel one of {KERNELS}")
        if not (0 < self.min_correspondence_m <= self.max_correspondence_m) or not (0 < self.gate_decay <= 1):
            raise ValueError("need 0 < min_correspondence_m <= max_correspondence_m and 0 < gate_decay <= 1")
        if self.max_iterations < 1 or self.max_points < 6 or self.kernel_scale_m <= 0:
            raise ValueError("need max_iterations >= 1, max_points >= 6 and kernel_scale_m > 0")


@dataclass
class IcpOutcome:
    """Result of :func:`align`. ``transform`` maps the cloud onto the model (apply to correct the cloud)."""

    transform: np.ndarray
    covariance: np.ndarray
    converged: bool
    degenerate: bool
    ambiguous: bool
    min_eigenvalue: float
    eigenvalues: np.ndarray
    unobservable: np.ndarray                   # (6, k) basis of unconstrained directions
    rmse_m: float
    inlier_ratio: float
    iterations: int
    cloud_size: int
    score: float = float("nan")
    hypotheses: list[tuple[float, np.ndarray]] = field(default_factory=list)   # (score, transform) per restart
    reason: str = ""


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp_so3(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    k = _skew(w)
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th ** 2 * (k @ k)


def yaw_about(transform: np.ndarray, yaw_rad: float, pivot: np.ndarray) -> np.ndarray:
    """``transform`` followed by a yaw of ``yaw_rad`` about the vertical line through ``pivot``."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    rz = np.eye(4)
    rz[:2, :2] = [[c, -s], [s, c]]
    rz[:3, 3] = pivot - rz[:3, :3] @ pivot
    return rz @ transform


def _weights(r: np.ndarray, kernel: str, k: float) -> np.ndarray:
    a = np.abs(r)
    if kernel == "huber":
        return np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))
    if kernel == "cauchy":
        return 1.0 / (1.0 + (a / k) ** 2)
    return np.ones_like(a)


def _plane_system(p: np.ndarray, q: np.ndarray, n: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (K,) and Jacobian rows (K, 6) of point-to-plane error for a left perturbation about c."""
    r = np.einsum("ij,ij->i", p - q, n)
    return r, np.hstack([n, np.cross(p - c, n)])


def _eig_scaled(h: np.ndarray, scale: float, norm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-decomposition of the per-point normal matrix with rotation scaled to metres at ``scale``."""
    s = np.array([1.0, 1.0, 1.0, 1 / scale, 1 / scale, 1 / scale])
    evals, evecs = np.linalg.eigh((h * s[:, None] * s[None, :]) / norm)
    return evals, evecs, s


def _system(src: np.ndarray, model: IcpModel, transform: np.ndarray, gate: float, cfg: IcpSettings,
            exact: bool = True) -> dict | None:
    """Correspondences within ``gate`` and the point-to-plane normal equations at ``transform``."""
    p = src @ transform[:3, :3].T + transform[:3, 3]
    d, idx = model.nearest(p, gate, exact)
    ok = np.isfinite(d)
    if ok.sum() < cfg.min_inliers:
        return None
    p, q, n = p[ok], model.points[idx[ok]], model.normals[idx[ok]]
    c = p.mean(axis=0)
    scale = max(float(np.sqrt(((p - c) ** 2).sum(axis=1).mean())), 1e-3)
    r, j = _plane_system(p, q, n, c)
    w = _weights(r, cfg.kernel, cfg.kernel_scale_m)
    jw = j * w[:, None]
    h = jw.T @ j
    evals, evecs, s = _eig_scaled(h, scale, max(float(w.sum()), 1e-9))
    return dict(p=p, q=q, r=r, w=w, h=h, g=jw.T @ r, c=c, scale=scale, s=s, evals=evals, evecs=evecs,
                n_in=int(ok.sum()), n=len(src))


def _point_to_point(sys_: dict, cfg: IcpSettings) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations of the point-to-point error, J_i = [I, -[a_i]x], in closed form."""
    e, a = sys_["p"] - sys_["q"], sys_["p"] - sys_["c"]
    w = _weights(np.linalg.norm(e, axis=1), cfg.kernel, cfg.kernel_scale_m)
    wa = w @ a
    waa = (a * w[:, None]).T @ a
    h = np.zeros((6, 6))
    h[:3, :3] = w.sum() * np.eye(3)
    h[:3, 3:] = -_skew(wa)
    h[3:, :3] = _skew(wa)
    h[3:, 3:] = np.trace(waa) * np.eye(3) - waa
    return h, np.concatenate([w @ e, w @ np.cross(a, e)])


def _step(sys_: dict, cfg: IcpSettings) -> np.ndarray:
    """Gauss-Newton step [dt, dw] confined to the directions the plane system observes."""
    s, evals, evecs = sys_["s"], sys_["evals"], sys_["evecs"]
    keep = evals > cfg.degeneracy_threshold
    if cfg.method == "point_to_plane":
        gs = sys_["g"] * s / max(float(sys_["w"].sum()), 1e-9)
        return -(evecs[:, keep] @ ((evecs[:, keep].T @ gs) / evals[keep])) * s
    # Point-to-point matching "sticks" on a flat floor (nearest points are nearby), which would
    # hide the degeneracy: solve it, then drop what the plane system cannot see.
    h, g = _point_to_point(sys_, cfg)
    step_s = np.linalg.lstsq((h * s[:, None] * s[None, :]), -g * s, rcond=1e-9)[0]
    free = evecs[:, ~keep]
    return (step_s - free @ (free.T @ step_s)) * s


def _iterate(src: np.ndarray, model: IcpModel, transform: np.ndarray, cfg: IcpSettings, iterations: int,
             *, polish: bool | None = None) -> tuple[np.ndarray, int, bool, dict | None]:
    """Gauss-Newton ICP from ``transform``; returns the final transform, iterations, converged, last system.

    While the gate is still shrinking only the first ``coarse_fraction`` of ``src`` (a random
    subsample already) is matched: coarse steps need few points, the final ones get them all.
    With a nearest grid, matching uses it until converged, then (``polish_exact``) the exact KD-tree.
    """
    gate = cfg.max_correspondence_m
    n_coarse = max(cfg.min_inliers * 4, int(len(src) * cfg.coarse_fraction))
    exact = model.grid is None
    polish = cfg.polish_exact if polish is None else polish
    sys_ = None
    for it in range(1, iterations + 1):
        pts = src if gate <= cfg.min_correspondence_m else src[:n_coarse]
        sys_ = _system(pts, model, transform, gate, cfg, exact)
        if sys_ is None:
            return transform, it, False, None
        step = _step(sys_, cfg)
        c = sys_["c"]
        delta = np.eye(4)
        delta[:3, :3] = _exp_so3(step[3:])
        delta[:3, 3] = c + step[:3] - delta[:3, :3] @ c
        transform = delta @ transform
        small = np.linalg.norm(step[:3]) < cfg.tolerance_m and np.linalg.norm(step[3:]) < cfg.tolerance_rad
        if small and gate <= cfg.min_correspondence_m:
            if exact or not polish:
                return transform, it, True, sys_
            exact = True
        gate = max(cfg.min_correspondence_m, gate * cfg.gate_decay)
    return transform, iterations, False, sys_


def _score(src: np.ndarray, model: IcpModel, transform: np.ndarray, gate: float) -> float:
    """Truncated mean squared distance to the model: a fit measure comparable across restarts."""
    p = src @ transform[:3, :3].T + transform[:3, 3]
    d, _ = model.tree.query(p, k=1, distance_upper_bound=gate)
    return float(np.mean(np.minimum(np.nan_to_num(d, posinf=gate), gate) ** 2))


def _yaw_of(transform: np.ndarray) -> float:
    return float(np.arctan2(transform[1, 0], transform[0, 0]))


def _distinct(a: np.ndarray, b: np.ndarray, cfg: IcpSettings, pivot: np.ndarray) -> bool:
    dyaw = abs((_yaw_of(a) - _yaw_of(b) + np.pi) % (2 * np.pi) - np.pi)
    moved = np.linalg.norm((a[:3, :3] - b[:3, :3]) @ pivot + a[:3, 3] - b[:3, 3])
    return dyaw > cfg.distinct_yaw_rad or moved > cfg.distinct_m


def _finite_points(cloud: np.ndarray) -> np.ndarray:
    pts = np.asarray(cloud, float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        if pts.size == 0:
            return np.zeros((0, 3))
        raise ValueError(f"cloud must be (N, 3) points in metres, got shape {pts.shape}")
    return pts[np.all(np.isfinite(pts), axis=1)]


def _subsample(pts: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return pts if len(pts) <= n else pts[rng.choice(len(pts), n, replace=False)]


def _failed(init: np.ndarray, n: int, reason: str) -> IcpOutcome:
    return IcpOutcome(init, np.full((6, 6), np.nan), False, True, False, 0.0, np.zeros(6), np.eye(6), float("nan"),
                      0.0, 0, n, reason=reason)


def _covariance(sys_: dict, cfg: IcpSettings) -> tuple[np.ndarray, np.ndarray]:
    """6x6 covariance about the model origin, and the (6, k) unobservable basis (unscaled)."""
    s, evals, evecs, w, r = sys_["s"], sys_["evals"], sys_["evecs"], sys_["w"], sys_["r"]
    keep = evals > cfg.degeneracy_threshold
    dof = max(float(w.sum()) - 6.0, 1.0)
    sigma2 = float((w * r ** 2).sum()) / dof
    inv = evecs[:, keep] @ np.diag(1.0 / evals[keep]) @ evecs[:, keep].T * (sigma2 / max(float(w.sum()), 1e-9))
    inv += UNOBSERVED_VARIANCE * evecs[:, ~keep] @ evecs[:, ~keep].T
    cov_c = inv * s[:, None] * s[None, :]
    a = np.eye(6)
    a[:3, 3:] = _skew(sys_["c"])           # about c -> about the origin: dt_o = dt + c x dw
    free = evecs[:, ~keep] * s[:, None]
    return a @ cov_c @ a.T, free / np.maximum(np.linalg.norm(free, axis=0), 1e-12)


def align(cloud: np.ndarray, model: IcpModel, init: np.ndarray | None = None,
          settings: IcpSettings = IcpSettings()) -> IcpOutcome:
    """Align ``cloud`` (N, 3, m) to ``model`` starting from ``init`` (4x4 cloud -> model).

    Non-finite points are dropped; a cloud with too few points gives ``converged=False`` and
    ``reason`` rather than an exception. See the module docstring for degeneracy and ambiguity.

    Returns
    -------
    IcpOutcome
    """
    cfg = settings
    t0 = np.eye(4) if init is None else np.asarray(init, float)
    if t0.shape != (4, 4) or not np.all(np.isfinite(t0)):
        raise ValueError("init must be a finite 4x4 transform (cloud -> model)")
    pts = _finite_points(cloud)
    if len(pts) < cfg.min_inliers:
        return _failed(t0, len(pts), f"cloud has {len(pts)} finite points, need >= {cfg.min_inliers}")
    rng = np.random.default_rng(cfg.seed)
    src = _subsample(pts, cfg.max_points, rng)
    best, iters, converged, sys_ = _iterate(src, model, t0, cfg, cfg.max_iterations)
    if sys_ is None:
        return _failed(t0, len(pts), "no model point within the correspondence gate of the cloud")
    hypotheses: list[tuple[float, np.ndarray]] = []
    ambiguous = False
    if cfg.yaw_hypotheses > 1:
        best, ambiguous, hypotheses = _resolve_yaw(src, model, t0, best, cfg, rng)
        if hypotheses and best is not hypotheses[0][1]:      # a restart won: refine it on the full sample
            best, iters, converged, sys_ = _iterate(src, model, best, cfg, cfg.max_iterations)
            if sys_ is None:
                return _failed(t0, len(pts), "the best yaw hypothesis lost its correspondences")
    cov, free = _covariance(sys_, cfg)
    gate_score = 2.0 * cfg.min_correspondence_m
    return IcpOutcome(best, cov, converged, bool(free.shape[1] > 0), ambiguous, float(sys_["evals"][0]),
                      sys_["evals"], free, float(np.sqrt(np.mean(sys_["r"] ** 2))), sys_["n_in"] / sys_["n"],
                      iters, len(pts), _score(src, model, best, gate_score), hypotheses)


def _resolve_yaw(src: np.ndarray, model: IcpModel, prior: np.ndarray, first: np.ndarray, cfg: IcpSettings,
                 rng: np.random.Generator) -> tuple[np.ndarray, bool, list[tuple[float, np.ndarray]]]:
    """Restart at yaw offsets about the model's vertical axis; pick the best fit nearest the prior.

    Returns the chosen transform (``first`` itself if it stays), whether a distinct pose within the
    prior window fits as well, and every (score, transform).
    """
    small = _subsample(src, cfg.hypothesis_points, rng)
    gate = 2.0 * cfg.min_correspondence_m
    pivot = model.centroid
    hyps = [(_score(small, model, first, gate), first)]
    for k in range(1, cfg.yaw_hypotheses):
        start = yaw_about(first, 2 * np.pi * k / cfg.yaw_hypotheses, pivot)
        t, _, _, _ = _iterate(small, model, start, cfg, cfg.hypothesis_iterations, polish=False)
        hyps.append((_score(small, model, t, gate), t))
    floor = (0.02 * cfg.min_correspondence_m) ** 2          # scores this small are all "perfect"
    top = min(score for score, _ in hyps)
    # Short restarts can stop half-way: finish the contenders before comparing them.
    for i, (score, t) in enumerate(hyps[1:], start=1):
        if score <= cfg.refine_ratio * max(top, floor):
            t, _, _, _ = _iterate(small, model, t, cfg, cfg.max_iterations, polish=False)
            hyps[i] = (_score(small, model, t, gate), t)
    top = min(score for score, _ in hyps)
    good = [(sc, t) for sc, t in hyps if sc <= cfg.ambiguity_ratio * max(top, floor)]

    def off_prior(t: np.ndarray) -> float:
        return abs((_yaw_of(t) - _yaw_of(prior) + np.pi) % (2 * np.pi) - np.pi)

    chosen = min(good, key=lambda h: (off_prior(h[1]), h[0]))[1]
    if any(h[1] is first for h in good) and not _distinct(first, chosen, cfg, pivot):
        chosen = first
    rivals = [t for _, t in good if _distinct(t, chosen, cfg, pivot) and off_prior(t) <= cfg.prior_window_rad]
    return chosen, bool(rivals), hyps
