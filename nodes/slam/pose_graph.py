"""SE(2) pose-graph optimisation: the back end of the sonar mosaic and of multi-robot SLAM.

A pose graph holds poses ``x_k = (x, y, theta)`` and relative measurements
``z_ij = (dx, dy, dtheta)`` of pose j in the frame of pose i, each with a 3x3 information
matrix. The residual is eq. (5) of seed 08 in g2o's convention,

    e_ij = t2v(Z_ij^-1 (X_i^-1 X_j)) = ( R_z^T (R_i^T (t_j - t_i) - t_z),  wrap(theta_j - theta_i - theta_z) ),

and the cost is chi2 = sum e^T Omega e (eq. 6-7). Seed 08 writes the angle residual without
wrapping; that is wrong as soon as a loop closes across +-pi, so it is wrapped here.

The solver is Levenberg-Marquardt (or Gauss-Newton) on the sparse normal equations with
the first vertex (or ``anchor``) held fixed. Jacobians are computed for every edge at once
with numpy; the sparse matrix's pattern is built once and refilled with one ``bincount``
per iteration. The linear solver is SuperLU in symmetric mode with a minimum-degree
ordering on the pattern of H (scipy has no CHOLMOD; on these SPD systems it performs
like a sparse Cholesky of the same ordering, see ``bench/pose_graph.py``).

Robust modes: Huber and Cauchy kernels (iteratively reweighted), and ``gnc`` --
graduated non-convexity with the truncated-least-squares surrogate (Yang et al., RA-L 2020)
applied to loop closures only (odometry edges, between consecutive ids, are trusted), which
rejects gross false loop closures that a convex kernel only down-weights.

Initialisation: the given vertices, the odometry chain (a spanning tree from the anchor),
or a chordal relaxation of the rotations followed by linear least squares for the
translations (Carlone et al., ICRA 2015), for graphs whose odometry start is far off.

>>> g = PoseGraph2D.from_edges([(0, 1, (1.0, 0.0, 0.0)), (1, 2, (1.0, 0.0, 0.0)), (0, 2, (2.0, 0.1, 0.0))])
>>> round(optimize(g).chi2, 6) > 0
True
"""
from __future__ import annotations

import collections
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

import numpy as np
import qdldl
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

log = logging.getLogger("nodes.slam.pose_graph")

ROBUST = (None, "huber", "cauchy", "gnc")
LINEAR_SOLVERS = ("ldl", "lu")
CHI2_3DOF_99 = 11.345          # 99 % quantile of chi2 with 3 degrees of freedom: an edge's outlier gate


class GraphError(ValueError):
    """A pose graph that cannot be optimised as given; the message says what to fix."""


def wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi if isinstance(angle, np.ndarray) \
        else (angle + math.pi) % (2 * math.pi) - math.pi


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a (+) b`` for (..., 3) poses: b expressed in a's frame, to the world."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     wrap(a[..., 2] + b[..., 2])], axis=-1)


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 (+) b`` for (..., 3) poses: b in a's frame."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])], axis=-1)


def adjoint(x: np.ndarray) -> np.ndarray:
    """SE(2) adjoint of (..., 3) poses, (..., 3, 3): Ad(X) = [[R, (y, -x)^T], [0, 1]] carries a right
    perturbation of X (the g2o residual's frame) to the left: X exp(e) = exp(Ad(X) e) X."""
    x = np.asarray(x, float)
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    out = np.zeros(x.shape[:-1] + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 0, 2], out[..., 1, 2], out[..., 2, 2] = x[..., 1], -x[..., 0], 1.0
    return out


@dataclass
class PoseGraph2D:
    """Vertices (``ids``, ``poses`` (N, 3)) and edges (``edges`` (M, 2) vertex *indices*,
    ``z`` (M, 3) measurements, ``info`` (M, 3, 3) information in (x, y, theta) order).

    ``known`` marks vertices whose pose came from the file (others are initialised from
    the edges). ``fixed`` holds indices of vertices held constant (g2o ``FIX``).
    """

    ids: np.ndarray
    poses: np.ndarray
    edges: np.ndarray
    z: np.ndarray
    info: np.ndarray
    known: np.ndarray
    fixed: set[int] = field(default_factory=set)

    @classmethod
    def from_edges(cls, edges: Iterable[tuple[int, int, Sequence[float]] | tuple[int, int, Sequence[float], np.ndarray]],
                   vertices: dict[int, Sequence[float]] | None = None) -> "PoseGraph2D":
        """Build from ``(i, j, (dx, dy, dtheta)[, info 3x3])`` tuples keyed by vertex id (info default identity)."""
        rows = list(edges)
        vertices = dict(vertices or {})
        order = list(vertices)
        for row in rows:
            for v in row[:2]:
                if v not in vertices and v not in order:
                    order.append(v)
        index = {v: k for k, v in enumerate(order)}
        n = len(order)
        poses = np.zeros((n, 3))
        known = np.zeros(n, bool)
        for v, pose in vertices.items():
            poses[index[v]] = pose
            known[index[v]] = True
        e = np.array([(index[r[0]], index[r[1]]) for r in rows], dtype=np.int64).reshape(-1, 2)
        z = np.array([r[2] for r in rows], dtype=float).reshape(-1, 3)
        info = np.array([np.asarray(r[3], float) if len(r) > 3 else np.eye(3) for r in rows]).reshape(-1, 3, 3)
        return cls(ids=np.array(order, dtype=np.int64), poses=poses, edges=e, z=z, info=info, known=known)

    @property
    def n(self) -> int:
        return len(self.ids)

    def odometry_mask(self) -> np.ndarray:
        """Edges between consecutive vertex ids (the trusted chain of a SLAM graph)."""
        return np.abs(self.ids[self.edges[:, 1]] - self.ids[self.edges[:, 0]]) == 1

    def index_of(self, vertex_id: int) -> int:
        hits = np.flatnonzero(self.ids == vertex_id)
        if not len(hits):
            raise KeyError(f"no vertex {vertex_id}")
        return int(hits[0])


@dataclass
class GraphCheck:
    """What :func:`check_graph` found that is legal but worth saying."""

    duplicates: int = 0            # edges whose (i, j) pair appears more than once (all are kept)


def check_graph(graph: PoseGraph2D) -> GraphCheck:
    """Refuse what no solver can answer; raise :class:`GraphError` naming the edge or vertices.

    Self edges, non-finite values, information that is not symmetric positive definite and
    a graph in pieces are errors (a piece has no anchor: its poses are not determined).
    Duplicate edges are legal (independent measurements) and counted.
    """
    if graph.n == 0:
        raise GraphError("the graph has no vertices")
    if not np.isfinite(graph.poses).all():
        bad = int(np.flatnonzero(~np.isfinite(graph.poses).all(axis=1))[0])
        raise GraphError(f"vertex {graph.ids[bad]} has a non-finite pose {graph.poses[bad].tolist()}")
    m = len(graph.edges)
    if m == 0:
        if graph.n > 1:
            raise GraphError(f"{graph.n} vertices and no edge: nothing relates them")
        return GraphCheck()
    ids = graph.ids
    self_edges = np.flatnonzero(graph.edges[:, 0] == graph.edges[:, 1])
    if len(self_edges):
        k = int(self_edges[0])
        raise GraphError(f"edge {k} ({ids[graph.edges[k, 0]]} -> {ids[graph.edges[k, 1]]}) joins a vertex to itself")
    finite = np.isfinite(graph.z).all(axis=1) & np.isfinite(graph.info).all(axis=(1, 2))
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise GraphError(f"edge {k} ({ids[graph.edges[k, 0]]} -> {ids[graph.edges[k, 1]]}) has a non-finite "
                         "measurement or information")
    asym = np.abs(graph.info - graph.info.transpose(0, 2, 1)).max(axis=(1, 2)) > 1e-9 * (1 + np.abs(graph.info).max(axis=(1, 2)))
    if asym.any():
        k = int(np.flatnonzero(asym)[0])
        raise GraphError(f"edge {k} ({ids[graph.edges[k, 0]]} -> {ids[graph.edges[k, 1]]}): information is not symmetric")
    eig = np.linalg.eigvalsh(graph.info)
    bad = eig[:, 0] <= 1e-12 * np.maximum(eig[:, -1], 1e-300)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise GraphError(f"edge {k} ({ids[graph.edges[k, 0]]} -> {ids[graph.edges[k, 1]]}): information is not "
                         f"positive definite (eigenvalues {eig[k].tolist()}); a zero information says nothing "
                         "about the pose: drop the edge, or give it a small positive weight")
    adj = sp.coo_matrix((np.ones(m), (graph.edges[:, 0], graph.edges[:, 1])), shape=(graph.n, graph.n))
    count, labels = connected_components(adj, directed=False)
    if count > 1:
        sizes = np.bincount(labels)
        parts = ", ".join(f"{sizes[c]} vertices from id {ids[np.flatnonzero(labels == c)[0]]}"
                          for c in np.argsort(-sizes)[:5])
        raise GraphError(f"the graph is in {count} disconnected components ({parts}"
                         f"{', ...' if count > 5 else ''}); only one can be anchored: optimise each apart "
                         "or add edges between them")
    pairs = np.sort(graph.edges, axis=1)
    _, counts = np.unique(pairs, axis=0, return_counts=True)
    return GraphCheck(duplicates=int((counts - 1).sum()))


# -- residuals and the normal equations ---------------------------------------------------------
def residuals(graph: PoseGraph2D, poses: np.ndarray) -> np.ndarray:
    """(M, 3) residuals e_ij in g2o's convention (angle wrapped)."""
    pred = between(poses[graph.edges[:, 0]], poses[graph.edges[:, 1]])
    return between(graph.z, pred)


def edge_chi2(graph: PoseGraph2D, poses: np.ndarray, *, convention: str = "g2o") -> np.ndarray:
    """(M,) e^T Omega e per edge. ``convention``: 'g2o' (vector error) or 'gtsam' (Pose2 Logmap)."""
    e = residuals(graph, poses)
    if convention == "gtsam":
        e = _logmap_translation(e)
    elif convention != "g2o":
        raise ValueError("convention is 'g2o' or 'gtsam'")
    return np.einsum("mi,mij,mj->m", e, graph.info, e)


def chi2(graph: PoseGraph2D, poses: np.ndarray, *, convention: str = "g2o") -> float:
    """Sum of :func:`edge_chi2`; GTSAM's ``graph.error(values)`` is half of the 'gtsam' value."""
    return float(edge_chi2(graph, poses, convention=convention).sum())


def _logmap_translation(e: np.ndarray) -> np.ndarray:
    """GTSAM's Pose2 Logmap of (t, w): translation multiplied by V(w)^-1 = [[a, w/2], [-w/2, a]], a = (w/2) cot(w/2)."""
    w = e[:, 2]
    half = 0.5 * w
    small = np.abs(half) < 1e-4
    a = np.where(small, 1.0 - half ** 2 / 3.0, half / np.tan(np.where(small, 1.0, half)))
    return np.stack([a * e[:, 0] + half * e[:, 1], -half * e[:, 0] + a * e[:, 1], w], axis=1)


def _jacobians(graph: PoseGraph2D, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (M, 3) and their Jacobians with respect to pose i and pose j, (M, 3, 3) each."""
    xi, xj = poses[graph.edges[:, 0]], poses[graph.edges[:, 1]]
    ci, si = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    u0, u1 = ci * dx + si * dy, -si * dx + ci * dy                  # R_i^T (t_j - t_i)
    cz, sz = np.cos(graph.z[:, 2]), np.sin(graph.z[:, 2])
    w0, w1 = u0 - graph.z[:, 0], u1 - graph.z[:, 1]
    e = np.stack([cz * w0 + sz * w1, -sz * w0 + cz * w1, wrap(xj[:, 2] - xi[:, 2] - graph.z[:, 2])], axis=1)
    cp, sp_ = np.cos(xi[:, 2] + graph.z[:, 2]), np.sin(xi[:, 2] + graph.z[:, 2])
    m = len(e)
    ji = np.zeros((m, 3, 3))
    jj = np.zeros((m, 3, 3))
    ji[:, 0, 0], ji[:, 0, 1], ji[:, 1, 0], ji[:, 1, 1] = -cp, -sp_, sp_, -cp
    ji[:, 0, 2] = cz * u1 - sz * u0                                  # R_z^T d(R_i^T d)/dtheta_i
    ji[:, 1, 2] = -sz * u1 - cz * u0
    ji[:, 2, 2] = -1.0
    jj[:, 0, 0], jj[:, 0, 1], jj[:, 1, 0], jj[:, 1, 1] = cp, sp_, -sp_, cp
    jj[:, 2, 2] = 1.0
    return e, ji, jj


class _System:
    """The sparse pattern of H for one graph and anchor set, built once, refilled per iteration."""

    def __init__(self, graph: PoseGraph2D, fixed: set[int], linear_solver: str = "ldl") -> None:
        if linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver is one of {LINEAR_SOLVERS}")
        n = graph.n
        free = np.ones(n, bool)
        free[list(fixed)] = False
        if not free.any():
            raise GraphError("every vertex is fixed: nothing to optimise")
        col_of = np.full(n, -1, np.int64)
        col_of[free] = np.arange(int(free.sum()))
        self.free, self.col_of, self.size = free, col_of, 3 * int(free.sum())
        i, j = graph.edges[:, 0], graph.edges[:, 1]
        k3 = np.arange(3)
        # Entries of the four 3x3 blocks of every edge, row-major: (M, 4, 3, 3) -> flat.
        blocks = [(i, i), (i, j), (j, i), (j, j)]
        rows = np.stack([3 * col_of[a][:, None, None] + k3[None, :, None] + 0 * k3[None, None, :] for a, _ in blocks], 1)
        cols = np.stack([3 * col_of[b][:, None, None] + 0 * k3[None, :, None] + k3[None, None, :] for _, b in blocks], 1)
        ok = np.stack([(col_of[a] >= 0) & (col_of[b] >= 0) for a, b in blocks], 1)[:, :, None, None]
        ok = np.broadcast_to(ok, rows.shape)
        self.entry_keep = ok.reshape(-1)
        r, c = rows.reshape(-1)[self.entry_keep], cols.reshape(-1)[self.entry_keep]
        diag = np.arange(self.size)
        r_all, c_all = np.concatenate([r, diag]), np.concatenate([c, diag])   # the diagonal is always present
        pattern = sp.csc_matrix((np.ones(len(r_all)), (r_all, c_all)), shape=(self.size, self.size))
        pattern.sum_duplicates()
        pattern.sort_indices()
        self.indptr, self.indices = pattern.indptr, pattern.indices
        # Position in the CSC data array of every kept entry (and of every diagonal element).
        key = c_all * self.size + r_all
        csc_key = np.repeat(np.arange(self.size), np.diff(self.indptr)) * self.size + self.indices
        pos = np.searchsorted(csc_key, key)
        self.entry_pos, self.diag_pos = pos[:len(r)], pos[len(r):]
        self.nnz = len(self.indices)
        # The upper triangle's pattern, for the LDL^T factorisation (qdldl reads only that).
        cols_of = np.repeat(np.arange(self.size), np.diff(self.indptr))
        self.upper = self.indices <= cols_of
        self.upper_indptr = np.concatenate([[0], np.cumsum(np.bincount(cols_of[self.upper], minlength=self.size))])
        self.upper_indices = self.indices[self.upper]
        self.linear_solver = linear_solver
        self._ldl = None
        self._upper_matrix: sp.csc_matrix | None = None
        self.bi_rows = np.where(col_of[i] >= 0, 3 * col_of[i], -1)
        self.bj_rows = np.where(col_of[j] >= 0, 3 * col_of[j], -1)

    def assemble(self, e: np.ndarray, ji: np.ndarray, jj: np.ndarray, info_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CSC data of H = J^T W J and the gradient b = J^T W e (free variables only).

        Relies on the structure of :func:`_jacobians` (J_j a rotation block, J_i = -J_j + C)."""
        # J_i = -J_j + C with C nonzero only in column theta, rows x, y (q = C[:, :2, 2]): the four
        # blocks follow from P = Omega J_j with two batched products instead of eight.
        p = info_w @ jj
        a = jj.transpose(0, 2, 1) @ p                                    # J_j^T Omega J_j
        q0, q1 = ji[:, 0, 2], ji[:, 1, 2]
        r = q0[:, None] * p[:, 0, :] + q1[:, None] * p[:, 1, :]          # q^T Omega J_j
        s = q0 * q0 * info_w[:, 0, 0] + 2 * q0 * q1 * info_w[:, 0, 1] + q1 * q1 * info_w[:, 1, 1]
        blocks = np.empty((len(e), 4, 3, 3))
        blocks[:, 3] = a                                                 # (j, j)
        blocks[:, 1] = -a                                                # (i, j) = J_i^T Omega J_j
        blocks[:, 1, 2, :] += r
        blocks[:, 2] = blocks[:, 1].transpose(0, 2, 1)                   # (j, i)
        blocks[:, 0] = a                                                 # (i, i)
        blocks[:, 0, 2, :] -= r
        blocks[:, 0, :, 2] -= r
        blocks[:, 0, 2, 2] += s
        data = np.bincount(self.entry_pos, weights=blocks.reshape(-1)[self.entry_keep], minlength=self.nnz)
        gj = (p * e[:, :, None]).sum(axis=1)                             # J_j^T Omega e
        u = (info_w * e[:, None, :]).sum(axis=2)                         # Omega e
        gi = -gj
        gi[:, 2] += q0 * u[:, 0] + q1 * u[:, 1]
        b = np.zeros(self.size)
        for rows, g in ((self.bi_rows, gi), (self.bj_rows, gj)):
            keep = rows >= 0
            np.add.at(b, (rows[keep][:, None] + np.arange(3)).reshape(-1), g[keep].reshape(-1))
        return data, b

    def solve(self, data: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        return self.factor(data).solve(rhs)

    def factor(self, data: np.ndarray):
        """Factorise H (CSC ``data`` on this pattern): LDL^T with an AMD ordering computed once
        (qdldl), or SuperLU in symmetric mode. Raises RuntimeError when H is singular."""
        if self.linear_solver == "lu":
            h = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))
            return splu(h, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        if self._upper_matrix is None:
            self._upper_matrix = sp.csc_matrix((data[self.upper], self.upper_indices, self.upper_indptr),
                                               shape=(self.size, self.size))
        upper = self._upper_matrix
        upper.data = data[self.upper]          # same pattern: no re-validation of indices per iteration
        try:
            if self._ldl is None:
                self._ldl = qdldl.Solver(upper, upper=True)
            else:
                self._ldl.update(upper, upper=True)
        except ValueError as exc:          # a zero pivot
            self._ldl = None
            raise RuntimeError(f"LDL^T factorisation failed: {exc}") from None
        return self._ldl

    def update(self, poses: np.ndarray, delta: np.ndarray) -> np.ndarray:
        out = poses.copy()
        out[self.free] += delta.reshape(-1, 3)
        out[:, 2] = wrap(out[:, 2])
        return out


# -- robust kernels ------------------------------------------------------------------------------
def _kernel(robust: str | None, s: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """(rho(s), rho'(s)) of a kernel on the squared Mahalanobis error ``s``."""
    if robust is None:
        return s, np.ones_like(s)
    k2 = width * width
    if robust == "huber":
        root = np.sqrt(s)
        inside = s <= k2
        return np.where(inside, s, 2 * width * root - k2), np.where(inside, 1.0, width / np.maximum(root, 1e-300))
    if robust == "cauchy":
        return k2 * np.log1p(s / k2), 1.0 / (1.0 + s / k2)
    raise ValueError(f"robust kernel {robust!r}: choose one of {ROBUST}")


# -- optimisation ------------------------------------------------------------------------------
@dataclass
class OptimizeResult:
    """What :func:`optimize` returns. ``chi2`` values are in g2o's convention, without kernel."""

    poses: np.ndarray
    chi2_initial: float
    chi2: float
    cost: float                    # what was minimised (with the robust kernel / GNC weights)
    iterations: int
    converged: bool
    time_s: float
    weights: np.ndarray            # final per-edge weight (1 without robust mode)
    outliers: np.ndarray           # edge indices rejected by gnc (empty otherwise)
    message: str = ""


def optimize(graph: PoseGraph2D, *, initial: np.ndarray | str | None = None, method: str = "lm",
             robust: str | None = None, kernel_width: float | None = None, anchor: int | None = None,
             max_iterations: int = 100, rel_tol: float = 1e-10, lambda_init: float = 1e-5,
             linear_solver: str = "ldl", progress: Callable[[int, float, float], None] | None = None,
             trusted: np.ndarray | None = None) -> OptimizeResult:
    """Minimise chi2 over the poses of ``graph``.

    Parameters
    ----------
    initial : (N, 3) poses, or 'given' (the graph's own, default when every vertex has one),
        'odometry' (composing edges along a spanning tree from the anchor; the default when
        some vertex has none) or 'chordal' (rotations by chordal relaxation, then translations).
    method : 'lm' (Levenberg-Marquardt, damping lambda * diag(H)) or 'gn' (Gauss-Newton).
    robust : None, 'huber', 'cauchy' (kernels on e^T Omega e, width ``kernel_width`` in
        Mahalanobis units, default 1.345 / 2.3849) or 'gnc' (reject false loop closures;
        ``kernel_width`` is the squared-error gate, default the 99 % chi2 quantile, 11.345).
    anchor : vertex *id* held fixed (default: the g2o FIX vertices, else the first vertex).
    rel_tol : stop when an accepted step lowers the cost by less than this fraction.
    linear_solver : 'ldl' (sparse LDL^T, qdldl, AMD ordering reused) or 'lu' (SuperLU).
    progress : called as ``progress(iteration, cost, lambda)`` after each accepted step.
    trusted : (M,) bool, the edges 'gnc' never rejects (default: odometry, between consecutive ids).
    """
    t0 = time.process_time()
    check_graph(graph)
    if method not in ("lm", "gn"):
        raise ValueError("method is 'lm' or 'gn'")
    if robust not in ROBUST:
        raise ValueError(f"robust kernel {robust!r}: choose one of {ROBUST}")
    fixed = set(graph.fixed) if anchor is None and graph.fixed else {graph.index_of(anchor) if anchor is not None else 0}
    poses = initial_poses(graph, initial, fixed=fixed)
    system = _System(graph, fixed, linear_solver)
    chi2_initial = chi2(graph, poses)
    if robust == "gnc":
        poses, weights, iterations, converged, message = _gnc(graph, system, poses, method, kernel_width,
                                                              max_iterations, rel_tol, lambda_init, progress, trusted)
        outliers = np.flatnonzero(weights == 0.0)
        cost = float((edge_chi2(graph, poses) * weights).sum())
    else:
        width = kernel_width if kernel_width is not None else {"huber": 1.345, "cauchy": 2.3849}.get(robust or "", 1.0)
        poses, cost, iterations, converged, message, weights = _solve(
            graph, system, poses, method, robust, width, None, max_iterations, rel_tol, lambda_init, progress)
        outliers = np.zeros(0, np.int64)
    return OptimizeResult(poses=poses, chi2_initial=chi2_initial, chi2=chi2(graph, poses), cost=cost,
                          iterations=iterations, converged=converged, time_s=time.process_time() - t0,
                          weights=weights, outliers=outliers, message=message)


def _solve(graph: PoseGraph2D, system: _System, poses: np.ndarray, method: str, robust: str | None, width: float,
           fixed_weights: np.ndarray | None, max_iterations: int, rel_tol: float, lambda_init: float,
           progress: Callable[[int, float, float], None] | None
           ) -> tuple[np.ndarray, float, int, bool, str, np.ndarray]:
    """LM / GN with IRLS weights (kernel) or fixed per-edge weights (GNC's inner problem)."""

    def evaluate(p: np.ndarray) -> tuple[float, np.ndarray]:
        s = edge_chi2(graph, p)
        if fixed_weights is not None:
            return float((fixed_weights * s).sum()), fixed_weights
        rho, w = _kernel(robust, s, width)
        return float(rho.sum()), w

    cost, w = evaluate(poses)
    lam, nu = lambda_init, 2.0
    converged, message = False, "iteration limit"
    it = 0
    for it in range(1, max_iterations + 1):
        e, ji, jj = _jacobians(graph, poses)
        data, b = system.assemble(e, ji, jj, graph.info * w[:, None, None])
        diag = data[system.diag_pos].copy()
        accepted = False
        while not accepted:
            damped = data.copy()
            if method == "lm":
                damped[system.diag_pos] += lam * np.maximum(diag, 1e-9)
            try:
                delta = system.solve(damped, -b)
            except RuntimeError as exc:             # singular: SuperLU names the pivot
                if method == "gn":
                    raise GraphError(f"the normal equations are singular ({exc}); the graph does not "
                                     "determine every pose (anchor it, or use method='lm')") from None
                lam, nu = lam * nu, nu * 2
                continue
            if not np.isfinite(delta).all():
                raise GraphError("the linear solve gave non-finite steps: the information is too ill-conditioned")
            candidate = system.update(poses, delta)
            new_cost, new_w = evaluate(candidate)
            if method == "gn":
                accepted = True
                break
            predicted = float(-delta @ b + lam * (np.maximum(diag, 1e-9) * delta * delta).sum())
            ratio = (cost - new_cost) / predicted if predicted > 0 else -1.0
            if ratio > 0:
                accepted = True
                # A good model: trust it ten times more (Nielsen's gentler rule, lam *= max(1/3, ...),
                # keeps enough damping on the long lever arms' rotations to make the tail linear).
                lam = lam / 10.0 if ratio > 0.25 else lam * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                nu = 2.0
            else:
                lam, nu = lam * nu, nu * 2
                if lam > 1e16:
                    return poses, cost, it, True, "no step lowers the cost (local minimum)", w
        improvement = cost - new_cost
        poses, w = candidate, new_w
        old_cost, cost = cost, new_cost
        if progress is not None:
            progress(it, cost, lam)
        if abs(improvement) <= rel_tol * max(old_cost, 1e-300) or np.abs(delta).max() < 1e-12:
            converged, message = True, "converged"
            break
    return poses, cost, it, converged, message, w


def _gnc(graph: PoseGraph2D, system: _System, poses: np.ndarray, method: str, gate: float | None,
         max_iterations: int, rel_tol: float, lambda_init: float, progress, trusted: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, int, bool, str]:
    """Graduated non-convexity with the truncated-least-squares surrogate (GNC-TLS, Yang et al.,
    RA-L 2020) on loop closures; odometry edges are trusted.

    Starting from a convex surrogate (mu small), each round solves the weighted problem and
    re-weights: w = 1 below mu/(mu+1) c^2, 0 above (mu+1)/mu c^2, c sqrt(mu(mu+1)/s) - mu between;
    mu grows by 1.4 until the weights are binary. (The Geman-McClure surrogate was tried first:
    at mu = 1 it still halves the weight of an inlier at s = 0.41 c^2, and on a grid with one
    180-degree closure it drifted two good closures out with it.)
    """
    c2 = gate if gate is not None else CHI2_3DOF_99
    trusted = graph.odometry_mask() if trusted is None else np.asarray(trusted, bool)
    s = edge_chi2(graph, poses)
    s_max = float(s[~trusted].max(initial=0.0))
    mu = c2 / max(2.0 * s_max - c2, 1e-12) if 2.0 * s_max > c2 else math.inf
    weights = np.ones(len(s))
    total = 0
    for _ in range(1000):
        if not math.isfinite(mu):
            break                                   # every closure is within the gate: plain least squares
        lo, hi = mu / (mu + 1.0) * c2, (mu + 1.0) / mu * c2
        new = np.where(s <= lo, 1.0, np.where(s >= hi, 0.0,
                                              np.sqrt(c2 * mu * (mu + 1.0) / np.maximum(s, 1e-300)) - mu))
        new[trusted] = 1.0
        binary = bool(np.all((new == 0.0) | (new == 1.0)))
        unchanged = float(np.abs(new - weights).max()) < 1e-6
        weights = new
        if binary and unchanged:
            break
        poses, _, its, _, _, _ = _solve(graph, system, poses, method, None, 1.0, weights, max(5, max_iterations // 10),
                                        max(rel_tol, 1e-8), lambda_init, progress)
        total += its
        s = edge_chi2(graph, poses)
        mu *= 1.4
    final = np.where(trusted | (weights >= 0.5), 1.0, 0.0)
    poses, _, its, converged, message, _ = _solve(graph, system, poses, method, None, 1.0, final, max_iterations,
                                                  rel_tol, lambda_init, progress)
    return poses, final, total + its, converged, message


# -- initialisation ------------------------------------------------------------------------------
def initial_poses(graph: PoseGraph2D, initial: np.ndarray | str | None = None, *,
                  fixed: set[int] | None = None) -> np.ndarray:
    """Starting poses (see :func:`optimize`'s ``initial``)."""
    fixed = fixed if fixed is not None else {0}
    if isinstance(initial, np.ndarray):
        if initial.shape != graph.poses.shape or not np.isfinite(initial).all():
            raise GraphError(f"initial poses must be finite, shape {graph.poses.shape}")
        return initial.astype(float).copy()
    mode = initial or ("given" if graph.known.all() else "odometry")
    if mode == "given":
        if not graph.known.all():
            raise GraphError(f"{int((~graph.known).sum())} vertices have no pose in the file: "
                             "use initial='odometry' or 'chordal'")
        return graph.poses.copy()
    if mode == "odometry":
        return spanning_tree_poses(graph, root=min(fixed))
    if mode == "chordal":
        return chordal_poses(graph, root=min(fixed))
    raise ValueError("initial is an (N, 3) array, 'given', 'odometry' or 'chordal'")


def spanning_tree_poses(graph: PoseGraph2D, *, root: int = 0, known: Sequence[int] = ()) -> np.ndarray:
    """Compose measurements along a tree from ``root`` that uses as few loop closures as it can.

    A 0-1 breadth-first search (odometry edges cost 0, others 1): on a SLAM graph this is
    exactly the odometry chain, and vertices the chain does not reach hang off the
    fewest loop closures. ``known`` vertices keep their ``graph.poses`` and seed the search
    too (a warm start: only the others are composed); vertices reached from nowhere keep
    theirs.
    """
    n = graph.n
    odometry = graph.odometry_mask()
    neighbours: list[list[tuple[int, int, bool]]] = [[] for _ in range(n)]
    for k, (a, b) in enumerate(graph.edges.tolist()):
        neighbours[a].append((b, k, True))
        neighbours[b].append((a, k, False))
    poses = graph.poses.tolist()
    if not graph.known[root] and root not in known:
        poses[root] = [0.0, 0.0, 0.0]
    z = graph.z.tolist()
    inverse = between(graph.z, np.zeros_like(graph.z)).tolist()     # z^-1: the edge walked backwards
    odometry = odometry.tolist()
    cost = [math.inf] * n
    seeds = [root, *[int(k) for k in known if k != root]]
    for k in seeds:
        cost[k] = 0
    queue = collections.deque(seeds)
    done = [False] * n
    while queue:                       # scalar math: one vertex at a time, numpy per call would dominate
        v = queue.popleft()
        if done[v]:
            continue
        done[v] = True
        x, y, t = poses[v]
        c, s = math.cos(t), math.sin(t)
        for w, k, forward in neighbours[v]:
            step = 0 if odometry[k] else 1
            if cost[v] + step < cost[w]:
                cost[w] = cost[v] + step
                dx, dy, dt = z[k] if forward else inverse[k]
                poses[w] = [x + c * dx - s * dy, y + s * dx + c * dy, (t + dt + math.pi) % (2 * math.pi) - math.pi]
                (queue.appendleft if step == 0 else queue.append)(w)
    return np.array(poses, dtype=float)


def chordal_poses(graph: PoseGraph2D, *, root: int = 0) -> np.ndarray:
    """Rotations by chordal relaxation, then translations by linear least squares (both anchored at ``root``)."""
    theta0 = graph.poses[root, 2] if graph.known[root] else 0.0
    t_root = graph.poses[root, :2] if graph.known[root] else np.zeros(2)
    r = chordal_rotations(graph, {root: np.array([math.cos(theta0), math.sin(theta0)])})
    theta = np.arctan2(r[:, 1], r[:, 0])
    theta[root] = theta0
    t = chordal_translations(graph, theta, {root: t_root})
    return np.column_stack([t, wrap(theta)])


def chordal_rotations(graph: PoseGraph2D, known: dict[int, np.ndarray]) -> np.ndarray:
    """(N, 2) rotation vectors r = (cos, sin), unnormalised, minimising sum kappa |r_j - M(z) r_i|^2.

    ``known`` maps vertex indices to fixed r (an anchor, or a neighbour's estimate in a
    distributed solve). Raises RuntimeError when some free vertex is not tied to a known one.
    """
    i, j, m = graph.edges[:, 0], graph.edges[:, 1], len(graph.edges)
    eq = np.arange(m)
    kappa = np.sqrt(np.maximum(graph.info[:, 2, 2], 1e-12))
    cz, sz = np.cos(graph.z[:, 2]), np.sin(graph.z[:, 2])
    terms = []
    for c, (m0, m1) in enumerate(((cz, -sz), (sz, cz))):
        terms += [(2 * eq + c, j, c, kappa), (2 * eq + c, i, 0, -kappa * m0), (2 * eq + c, i, 1, -kappa * m1)]
    return _anchored_lsq(graph.n, known, terms, np.zeros(2 * m))


def chordal_translations(graph: PoseGraph2D, theta: np.ndarray, known: dict[int, np.ndarray]) -> np.ndarray:
    """(N, 2) translations minimising sum w |t_j - t_i - R(theta_i) t_z|^2 for given headings."""
    i, j, m = graph.edges[:, 0], graph.edges[:, 1], len(graph.edges)
    eq = np.arange(m)
    ci, si = np.cos(theta[i]), np.sin(theta[i])
    d = np.stack([ci * graph.z[:, 0] - si * graph.z[:, 1], si * graph.z[:, 0] + ci * graph.z[:, 1]], axis=1)
    wt = np.sqrt(np.maximum(np.minimum(graph.info[:, 0, 0], graph.info[:, 1, 1]), 1e-12))
    terms = [(2 * eq + c, v, c, sign * wt) for c in range(2) for v, sign in ((j, 1.0), (i, -1.0))]
    rhs = np.empty(2 * m)
    rhs[0::2], rhs[1::2] = wt * d[:, 0], wt * d[:, 1]
    return _anchored_lsq(graph.n, known, terms, rhs)


def _anchored_lsq(n: int, known: dict[int, np.ndarray], terms: list, rhs: np.ndarray) -> np.ndarray:
    """Least squares for a 2-vector per vertex; ``terms`` are (equation, vertex, component, coefficient)
    arrays; the ``known`` vertices' values are moved to the right-hand side. Returns (n, 2)."""
    eq, vert, comp, coef = (np.concatenate([np.broadcast_to(np.asarray(t[k]), np.shape(t[0])) for t in terms])
                            for k in range(4))
    vert, comp = vert.astype(np.int64), comp.astype(np.int64)
    value = np.zeros((n, 2))
    is_known = np.zeros(n, bool)
    for k, v in known.items():
        value[k], is_known[k] = v, True
    fixed = is_known[vert]
    rhs = rhs - np.bincount(eq[fixed], weights=coef[fixed] * value[vert[fixed], comp[fixed]], minlength=len(rhs))
    free = ~is_known
    if not free.any():
        return value
    col = np.cumsum(free) - 1                                         # free vertices, known ones removed
    a = sp.csr_matrix((coef[~fixed], (eq[~fixed], 2 * col[vert[~fixed]] + comp[~fixed])),
                      shape=(len(rhs), 2 * int(free.sum())))
    value[free] = _least_squares(a, rhs).reshape(-1, 2)
    return value


def _least_squares(a: sp.csr_matrix, rhs: np.ndarray) -> np.ndarray:
    normal = (a.T @ a).tocsc()
    return splu(normal, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True}).solve(a.T @ rhs)


# -- covariances ----------------------------------------------------------------------------------
def joint_covariance(graph: PoseGraph2D, poses: np.ndarray, index: Sequence[int], *, fixed: set[int]) -> np.ndarray:
    """(3K, 3K) joint covariance of the vertices at ``index`` (indices, not ids) at ``poses``,
    the ``fixed`` vertices held (their rows are zero): blocks of H^-1, one factorisation,
    one solve per free row."""
    system = _System(graph, fixed)
    e, ji, jj = _jacobians(graph, poses)
    data, _ = system.assemble(e, ji, jj, graph.info)
    lu = system.factor(data)
    index = np.asarray(index, np.int64)
    cols = system.col_of[index]
    out = np.zeros((3 * len(index), 3 * len(index)))
    rows = (3 * cols[:, None] + np.arange(3)).reshape(-1)
    free = np.repeat(cols >= 0, 3)
    for a in np.flatnonzero(free):
        unit = np.zeros(system.size)
        unit[rows[a]] = 1.0
        out[free, a] = lu.solve(unit)[rows[free]]
    return 0.5 * (out + out.T)


def marginal_covariances(graph: PoseGraph2D, poses: np.ndarray, vertex_ids: Iterable[int], *,
                         anchor: int | None = None) -> np.ndarray:
    """(K, 3, 3) marginal covariances of the given vertices at ``poses`` (the anchor's is zero).

    The blocks of H^-1 (Laplace approximation at the optimum), from one factorisation and
    three solves per vertex.
    """
    fixed = set(graph.fixed) if anchor is None and graph.fixed else {graph.index_of(anchor) if anchor is not None else 0}
    system = _System(graph, fixed)
    e, ji, jj = _jacobians(graph, poses)
    data, _ = system.assemble(e, ji, jj, graph.info)
    lu = system.factor(data)
    out = []
    for vid in vertex_ids:
        k = graph.index_of(vid)
        if system.col_of[k] < 0:
            out.append(np.zeros((3, 3)))
            continue
        first = 3 * system.col_of[k]
        cov = np.empty((3, 3))
        for c in range(3):
            unit = np.zeros(system.size)
            unit[first + c] = 1.0
            cov[:, c] = lu.solve(unit)[first:first + 3]
        out.append(0.5 * (cov + cov.T))
    return np.array(out).reshape(-1, 3, 3)
