"""Robust ICP of a sonar point cloud (or of elevation arcs) against a known structure model.

Point-to-plane (default) or point-to-point Gauss-Newton on a KD-tree (``scipy.spatial.cKDTree``)
or a nearest-point grid, Huber or Cauchy weights, a shrinking correspondence gate (outlier
rejection), and:

* **restricted degrees of freedom** (``dof``): ``"all"`` solves x, y, z, roll, pitch, yaw;
  ``"xyz_yaw"`` and ``"xy_yaw"`` hold roll and pitch (and z) at the initial transform, as a vehicle
  with an AHRS (and a depth sensor) measures them directly. Only the free columns of the Jacobian
  enter the normal equations, so degeneracy, steps and covariance live in that reduced space; the
  6x6 covariance has zero rows and columns for the held directions (known, not estimated).
* **elevation arcs**: a forward-looking sonar measures range and bearing, not elevation. A source
  may be given as arcs, (N, K, 3) samples across the vertical aperture at the measured range.
  Each arc's residual is taken at its sample with the smallest signed distance to the model
  surface (``n . (p - q)``): at the true pose the arc touches the surface where the first return
  came from and lies in free space elsewhere, so the smallest signed distance is 0; a gap pulls
  the model in, a penetration pushes it out. No elevation is ever guessed.

* **degeneracy**: the smallest eigenvalue of the point-to-plane normal matrix (translation in m,
  rotation scaled by the cloud's radius, per inlier) says which directions the geometry pins down.
  A flat seafloor leaves x, y and yaw free, one vertical cylinder its axis translation and the
  rotation about it. Updates are confined to the observable subspace, so free directions stay at
  the prior instead of wandering, and get a huge variance in the covariance.
* **ambiguity**: restarts over the whole circle of yaw about the model's vertical axis, and at the
  twins of the first fit under the model's own symmetries (found when the model is built,
  :mod:`nodes.sonar.symmetry`), compare robust residuals. When two distinct poses fit about as well
  (a four-fold pier, the tripod seen without its pylons) the result is ambiguous and lists both
  (``hypotheses``, with their costs) instead of claiming one. The final, refined pose must lie
  inside the prior window (the whole circle by default) and, when a restart won, next to the
  restart that was checked.

Transforms are 4x4, cloud frame -> model frame. Covariance order (x, y, z, roll, pitch, yaw), a
left perturbation about the model-frame origin; the world is z-up.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nodes.sonar.icp_model import IcpModel, NearestGrid

__all__ = ["DOFS", "IcpModel", "IcpOutcome", "IcpSettings", "NearestGrid", "align", "yaw_about"]

METHODS = ("point_to_plane", "point_to_point")
KERNELS = ("huber", "cauchy", "none")
# Free directions per setting, indices into (x, y, z, roll, pitch, yaw).
DOFS = {"all": (0, 1, 2, 3, 4, 5), "xyz_yaw": (0, 1, 2, 5), "xy_yaw": (0, 1, 5)}
UNOBSERVED_VARIANCE = 1e6       # m^2 or rad^2 for directions the geometry does not constrain


@dataclass(frozen=True)
class IcpSettings:
    """Tuning of :func:`align` (distances in m, angles in rad)."""

    method: str = "point_to_plane"
    dof: str = "all"                         # "all", "xyz_yaw" or "xy_yaw" (see the module docstring)
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
    yaw_hypotheses: int = 8                  # restarts over the whole circle of yaw (0 or 1: none)
    hypothesis_points: int = 200
    hypothesis_iterations: int = 8
    refine_ratio: float = 2.5                # restarts scoring within this factor of the best are finished
    ambiguity_ratio: float = 1.25            # another pose within this factor of the best score is "as good"
    distinct_yaw_rad: float = np.deg2rad(10.0)
    distinct_m: float = 0.5
    prior_window_rad: float = np.pi          # only poses this close to the prior's yaw can be chosen
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in METHODS or self.kernel not in KERNELS:
            raise ValueError(f"method must be one of {METHODS} and kernel one of {KERNELS}")
        if self.dof not in DOFS:
            raise ValueError(f"dof must be one of {tuple(DOFS)}, got {self.dof!r}")
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
    unobservable: np.ndarray                   # (6, k) basis of unconstrained free directions
    rmse_m: float
    inlier_ratio: float
    iterations: int
    cloud_size: int
    score: float = float("nan")
    # near-equal distinct optima of the yaw search (score, transform), best first; > 1: ambiguous
    hypotheses: list[tuple[float, np.ndarray]] = field(default_factory=list)
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


def _match(src: np.ndarray, model: IcpModel, transform: np.ndarray, gate: float,
           exact: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One matched point per source element: ``(p (k, 3) transformed, model index (k,), ok (N,))``.

    ``src`` is (N, K, 3): K = 1 for points; for arcs the sample with the smallest signed
    distance to its match's tangent plane represents the arc (see the module docstring).
    Samples without a model point within ``gate`` are ignored; an arc without any is unmatched.
    """
    n_src, k = src.shape[:2]
    p = src.reshape(-1, 3) @ transform[:3, :3].T + transform[:3, 3]
    d, idx = model.nearest(p, gate, exact)
    found = np.isfinite(d)
    if k == 1:
        return p[found], idx[found], found
    sd = np.full(len(p), np.inf)
    i = idx[found]
    sd[found] = np.einsum("ij,ij->i", p[found] - model.points[i], model.normals[i])
    sd = sd.reshape(n_src, k)
    pick = np.argmin(sd, axis=1)
    ok = np.isfinite(sd[np.arange(n_src), pick])
    flat = (np.flatnonzero(ok) * k + pick[ok])
    return p[flat], idx[flat], ok


def _system(src: np.ndarray, model: IcpModel, transform: np.ndarray, gate: float, cfg: IcpSettings,
            exact: bool = True) -> dict | None:
    """Correspondences within ``gate`` and the point-to-plane normal equations over the free directions.

    ``h``, ``g``, ``evals``, ``evecs`` and ``s`` are in the reduced space of ``cfg.dof`` (``sel``
    lists its directions); rotation is scaled to metres at the matched points' radius.
    """
    p, idx, ok = _match(src, model, transform, gate, exact)
    if len(p) < cfg.min_inliers:
        return None
    q, n = model.points[idx], model.normals[idx]
    c = p.mean(axis=0)
    scale = max(float(np.sqrt(((p - c) ** 2).sum(axis=1).mean())), 1e-3)
    r, j = _plane_system(p, q, n, c)
    sel = np.asarray(DOFS[cfg.dof])
    j = j[:, sel]
    w = _weights(r, cfg.kernel, cfg.kernel_scale_m)
    jw = j * w[:, None]
    h = jw.T @ j
    s = np.array([1.0, 1.0, 1.0, 1 / scale, 1 / scale, 1 / scale])[sel]
    evals, evecs = np.linalg.eigh((h * s[:, None] * s[None, :]) / max(float(w.sum()), 1e-9))
    return dict(p=p, q=q, r=r, w=w, h=h, g=jw.T @ r, c=c, scale=scale, s=s, sel=sel, evals=evals, evecs=evecs,
                n_in=len(p), n=len(src))


def _point_to_point(sys_: dict, cfg: IcpSettings) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations of the point-to-point error, J_i = [I, -[a_i]x], in closed form (free directions)."""
    e, a = sys_["p"] - sys_["q"], sys_["p"] - sys_["c"]
    w = _weights(np.linalg.norm(e, axis=1), cfg.kernel, cfg.kernel_scale_m)
    wa = w @ a
    waa = (a * w[:, None]).T @ a
    h = np.zeros((6, 6))
    h[:3, :3] = w.sum() * np.eye(3)
    h[:3, 3:] = -_skew(wa)
    h[3:, :3] = _skew(wa)
    h[3:, 3:] = np.trace(waa) * np.eye(3) - waa
    sel = sys_["sel"]
    return h[np.ix_(sel, sel)], np.concatenate([w @ e, w @ np.cross(a, e)])[sel]


def _step(sys_: dict, cfg: IcpSettings) -> np.ndarray:
    """Gauss-Newton step [dt, dw] (6,) confined to the free directions the plane system observes."""
    s, evals, evecs = sys_["s"], sys_["evals"], sys_["evecs"]
    keep = evals > cfg.degeneracy_threshold
    if cfg.method == "point_to_plane":
        gs = sys_["g"] * s / max(float(sys_["w"].sum()), 1e-9)
        reduced = -(evecs[:, keep] @ ((evecs[:, keep].T @ gs) / evals[keep])) * s
    else:
        # Point-to-point matching "sticks" on a flat floor (nearest points are nearby), which would
        # hide the degeneracy: solve it, then drop what the plane system cannot see.
        h, g = _point_to_point(sys_, cfg)
        step_s = np.linalg.lstsq((h * s[:, None] * s[None, :]), -g * s, rcond=1e-9)[0]
        free = evecs[:, ~keep]
        reduced = (step_s - free @ (free.T @ step_s)) * s
    step = np.zeros(6)
    step[sys_["sel"]] = reduced
    return step


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
    """Truncated mean squared distance to the model: a fit measure comparable across restarts.

    Points: distance to the nearest model point. Arcs: distance of the sample that represents the arc.
    The distance is to the surface: its along-surface part counts only beyond the model's sample
    spacing, so that the score does not depend on how the samples fall (a model's symmetric twin,
    sampled with another phase on a brace, must score as the original does).
    """
    exact = model.grid is None          # the grid's match is on the same surface patch: good enough to rank
    if src.shape[1] == 1:
        p = src[:, 0] @ transform[:3, :3].T + transform[:3, 3]
        dist, idx = model.nearest(p, gate, exact)
        ok = np.isfinite(dist)
        p, idx = p[ok], idx[ok]
    else:
        p, idx, ok = _match(src, model, transform, gate, exact)
    e = p - model.points[idx]
    normal = np.abs(np.einsum("ij,ij->i", e, model.normals[idx]))
    along = np.sqrt(np.maximum(np.einsum("ij,ij->i", e, e) - normal ** 2, 0.0))
    d = np.full(len(src), gate)
    d[ok] = np.hypot(normal, np.maximum(along - model.spacing_m, 0.0))
    return float(np.mean(np.minimum(d, gate) ** 2))


def yaw_of(transform: np.ndarray) -> float:
    """Heading (rad, counter-clockwise from +x) of a transform's x axis."""
    return float(np.arctan2(transform[1, 0], transform[0, 0]))


def _off_prior(t: np.ndarray, prior: np.ndarray) -> float:
    """|yaw difference| (rad) of ``t`` from ``prior``."""
    return abs((yaw_of(t) - yaw_of(prior) + np.pi) % (2 * np.pi) - np.pi)


def _distinct(a: np.ndarray, b: np.ndarray, cfg: IcpSettings, pivot: np.ndarray) -> bool:
    dyaw = abs((yaw_of(a) - yaw_of(b) + np.pi) % (2 * np.pi) - np.pi)
    moved = np.linalg.norm((a[:3, :3] - b[:3, :3]) @ pivot + a[:3, 3] - b[:3, 3])
    return dyaw > cfg.distinct_yaw_rad or moved > cfg.distinct_m


def _finite_source(cloud: np.ndarray) -> np.ndarray:
    """(N, 3) points or (N, K, 3) arcs -> (N', K, 3) without non-finite elements (K = 1 for points)."""
    src = np.asarray(cloud, float)
    if src.size == 0:
        return np.zeros((0, 1, 3))
    if src.ndim == 2 and src.shape[1] == 3:
        src = src[:, None, :]
    if src.ndim != 3 or src.shape[2] != 3 or src.shape[1] < 1:
        raise ValueError(f"cloud must be (N, 3) points or (N, K, 3) arc samples in metres, got shape {src.shape}")
    return src[np.all(np.isfinite(src), axis=(1, 2))]


def _subsample(pts: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return pts if len(pts) <= n else pts[rng.choice(len(pts), n, replace=False)]


def _failed(init: np.ndarray, n: int, reason: str) -> IcpOutcome:
    return IcpOutcome(init, np.full((6, 6), np.nan), False, True, False, 0.0, np.zeros(6), np.eye(6), float("nan"),
                      0.0, 0, n, reason=reason)


def _covariance(sys_: dict, cfg: IcpSettings) -> tuple[np.ndarray, np.ndarray]:
    """6x6 covariance about the model origin, and the (6, k) unobservable basis (unscaled).

    Directions held by ``cfg.dof`` have zero variance (known from other sensors); free directions
    the geometry does not constrain get :data:`UNOBSERVED_VARIANCE`.
    """
    s, evals, evecs, w, r, sel = sys_["s"], sys_["evals"], sys_["evecs"], sys_["w"], sys_["r"], sys_["sel"]
    keep = evals > cfg.degeneracy_threshold
    dof = max(float(w.sum()) - len(sel), 1.0)
    sigma2 = float((w * r ** 2).sum()) / dof
    inv = evecs[:, keep] @ np.diag(1.0 / evals[keep]) @ evecs[:, keep].T * (sigma2 / max(float(w.sum()), 1e-9))
    inv += UNOBSERVED_VARIANCE * evecs[:, ~keep] @ evecs[:, ~keep].T
    cov_c = np.zeros((6, 6))
    cov_c[np.ix_(sel, sel)] = inv * s[:, None] * s[None, :]
    a = np.eye(6)
    a[:3, 3:] = _skew(sys_["c"])           # about c -> about the origin: dt_o = dt + c x dw
    free = np.zeros((6, int((~keep).sum())))
    free[sel] = evecs[:, ~keep] * s[:, None]
    return a @ cov_c @ a.T, free / np.maximum(np.linalg.norm(free, axis=0), 1e-12)


def align(cloud: np.ndarray, model: IcpModel, init: np.ndarray | None = None,
          settings: IcpSettings = IcpSettings()) -> IcpOutcome:
    """Align ``cloud`` to ``model`` starting from ``init`` (4x4 cloud -> model).

    Parameters
    ----------
    cloud : (N, 3) points or (N, K, 3) elevation-arc samples, metres
        Non-finite points (arcs with a non-finite sample) are dropped; too few gives
        ``converged=False`` and ``reason`` rather than an exception.
    model : IcpModel
    init : (4, 4), optional
        Prior; directions held by ``settings.dof`` keep its values.
    settings : IcpSettings

    Returns
    -------
    IcpOutcome
        See the module docstring for degeneracy, ambiguity and the covariance layout.
    """
    cfg = settings
    t0 = np.eye(4) if init is None else np.asarray(init, float)
    if t0.shape != (4, 4) or not np.all(np.isfinite(t0)):
        raise ValueError("init must be a finite 4x4 transform (cloud -> model)")
    pts = _finite_source(cloud)
    if len(pts) < cfg.min_inliers:
        return _failed(t0, len(pts), f"cloud has {len(pts)} finite points, need >= {cfg.min_inliers}")
    rng = np.random.default_rng(cfg.seed)
    src = _subsample(pts, cfg.max_points, rng)
    best, iters, converged, sys_ = _iterate(src, model, t0, cfg, cfg.max_iterations)
    if sys_ is None:
        return _failed(t0, len(pts), "no model point within the correspondence gate of the cloud")
    first = best
    hypotheses: list[tuple[float, np.ndarray]] = []
    ambiguous = False
    if cfg.yaw_hypotheses > 1:
        best, ambiguous, hypotheses = _resolve_yaw(src, model, t0, best, cfg, rng)
        if best is not first:                                # a restart won: refine it on the full sample
            chosen = best
            best, iters, converged, sys_ = _iterate(src, model, best, cfg, cfg.max_iterations)
            if sys_ is None:
                return _failed(t0, len(pts), "the best yaw hypothesis lost its correspondences")
            # The window and the rivals were judged at the restart's pose; the refinement on the full
            # sample can slide on (a partial view of the 3-fold tripod: from 56 deg to 104 deg off
            # the prior). A result the check did not see is not trusted.
            ambiguous = ambiguous or _distinct(best, chosen, cfg, model.centroid)
        ambiguous = ambiguous or _off_prior(best, t0) > cfg.prior_window_rad
    cov, free = _covariance(sys_, cfg)
    gate_score = 2.0 * cfg.min_correspondence_m
    return IcpOutcome(best, cov, converged, bool(free.shape[1] > 0), ambiguous, float(sys_["evals"][0]),
                      sys_["evals"], free, float(np.sqrt(np.mean(sys_["r"] ** 2))), sys_["n_in"] / sys_["n"],
                      iters, len(pts), _score(src, model, best, gate_score), hypotheses)


def _resolve_yaw(src: np.ndarray, model: IcpModel, prior: np.ndarray, first: np.ndarray, cfg: IcpSettings,
                 rng: np.random.Generator) -> tuple[np.ndarray, bool, list[tuple[float, np.ndarray]]]:
    """Search the whole circle of yaw; keep every distinct local optimum near the best.

    Restarts at ``yaw_hypotheses`` evenly spaced yaws about the model's vertical axis and at every
    twin of ``first`` under the model's own symmetries (``model.symmetry``), each refined and
    scored; distinct optima whose score is within ``ambiguity_ratio`` of the best are the
    near-equal hypotheses. More than one makes the fit ambiguous. Among them the one nearest the
    prior is returned (``first`` itself if it is one); only poses within ``prior_window_rad`` of the
    prior's yaw can be chosen (default: the whole circle), and if none is, the fit is ambiguous too.
    Returns the chosen transform, whether ambiguous, and the near-equal (score, transform), best first.
    """
    small = _subsample(src, cfg.hypothesis_points, rng)
    gate = 2.0 * cfg.min_correspondence_m
    pivot = model.centroid
    starts = [yaw_about(first, 2 * np.pi * k / cfg.yaw_hypotheses, pivot) for k in range(1, cfg.yaw_hypotheses)]
    if model.symmetry is not None:
        starts += [twin.transform @ first for twin in model.symmetry.twins]
    hyps = [(_score(small, model, first, gate), first)]
    for start in starts:
        t, _, _, _ = _iterate(small, model, start, cfg, cfg.hypothesis_iterations, polish=False)
        hyps.append((_score(small, model, t, gate), t))
    floor = (0.02 * cfg.min_correspondence_m) ** 2          # scores this small are all "perfect"
    top = min(score for score, _ in hyps)
    # Short restarts can stop half-way: finish the contenders before comparing them.
    for i, (score, t) in enumerate(hyps[1:], start=1):
        if score <= cfg.refine_ratio * max(top, floor):
            t, _, _, _ = _iterate(small, model, t, cfg, cfg.max_iterations, polish=False)
            hyps[i] = (_score(small, model, t, gate), t)
    optima: list[tuple[float, np.ndarray]] = []
    for score, t in sorted(hyps, key=lambda h: h[0]):
        if all(_distinct(t, o, cfg, pivot) for _, o in optima):
            optima.append((score, t))
    top = optima[0][0]
    near = [(sc, t) for sc, t in optima if sc <= cfg.ambiguity_ratio * max(top, floor)]
    # An exact twin of the model fits exactly as well as the original whatever the view: scoring it
    # would only measure how the model's samples happen to fall (up to 2x on a braced square pier).
    exact = model.symmetry.exact if model.symmetry is not None else ()
    for sc, t in list(near):
        for twin in exact:
            mirror = twin.transform @ t
            if all(_distinct(mirror, o, cfg, pivot) for _, o in near):
                near.append((sc, mirror))
    inside = [(sc, t) for sc, t in near if _off_prior(t, prior) <= cfg.prior_window_rad]
    if not inside:
        return first, True, near
    chosen = min(inside, key=lambda h: (_off_prior(h[1], prior), h[0]))[1]
    if not _distinct(first, chosen, cfg, pivot):
        chosen = first
    continuous = model.symmetry is not None and model.symmetry.continuous
    return chosen, len(near) > 1 or continuous, near
