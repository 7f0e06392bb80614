"""Fast generalised winding numbers by a tree of dipole expansions (Barill et al., SIGGRAPH
2018), for triangle meshes in 3-D (solid angles) and segment soups in 2-D, vectorised over
queries one tree level at a time.

Each element (a segment or a triangle) has its area vector ``n`` (2-D: the segment turned
by -90 degrees, so outward for a counter-clockwise curve; 3-D: half the cross product of two
edges, outward for counter-clockwise faces seen from outside) and its centroid ``p``. Far
from a cluster of elements with centre ``c``, their winding number is the expansion of
``sum n_i . K(p_i - q)``, ``K(x) = x / (2 pi |x|**2)`` in 2-D and ``x / (4 pi |x|**3)`` in 3-D,
to second order: ``N . K(r) + sum_jk M_jk dK_j/dx_k(r)``, ``N = sum n_i``,
``M = sum n_i (p_i - c)^T`` (exact moments for flat elements), ``r = c - q``. A cluster is
used when ``|r| > beta * radius`` (``beta`` the accuracy knob; the truncation error of a
cluster falls as (radius / |r|)**3); otherwise its children are visited, and at the leaves
the elements are summed exactly. :func:`winding_mesh` is the exact 3-D sum (the solid angle
of each triangle by Van Oosterom and Strackee's formula).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class DipoleTree:
    dim: int
    elems: np.ndarray             # (E, dim, dim) element vertices (2 per segment, 3 per triangle), tree order
    centre: np.ndarray            # (T, dim)
    radius: np.ndarray            # (T,)
    n: np.ndarray                 # (T, dim) sum of area vectors
    m: np.ndarray                 # (T, dim, dim) sum of n_i (p_i - c)^T
    t: np.ndarray                 # (T, dim, dim, dim) sum of n_i (x)(x - c)(x - c) integrated (per area)
    child: np.ndarray             # (T, 2) children, -1 for a leaf
    start: np.ndarray             # (T,) leaf element range [start, stop)
    stop: np.ndarray


def _area_vectors(elems: np.ndarray) -> np.ndarray:
    if elems.shape[1] == 2:
        d = elems[:, 1] - elems[:, 0]
        return np.stack([d[:, 1], -d[:, 0]], -1)
    return 0.5 * np.cross(elems[:, 1] - elems[:, 0], elems[:, 2] - elems[:, 0])


def build_tree(elems: np.ndarray, *, leaf_size: int = 8) -> DipoleTree:
    """Tree over elements (E, k, dim): segments (k = 2, dim = 2) or triangles (k = 3, dim = 3);
    split at the median centroid along the widest side."""
    elems = np.asarray(elems, np.float64)
    if elems.ndim != 3 or elems.shape[1:] not in ((2, 2), (3, 3)):
        raise ValueError(f"elements must be (E, 2, 2) segments or (E, 3, 3) triangles, got {elems.shape}")
    keep = np.all(np.isfinite(elems.reshape(len(elems), -1)), axis=1)
    elems = elems[keep]
    area = _area_vectors(elems)
    elems, area = elems[np.any(area != 0, axis=1)], area[np.any(area != 0, axis=1)]   # degenerate: nothing
    dim = elems.shape[2]
    cent = elems.mean(axis=1)
    order = np.arange(len(elems))
    nodes: list[list] = []                            # [start, stop, left, right]
    stack = [(0, len(elems), -1, 0)]
    while stack:
        s, e, parent, side = stack.pop()
        k = len(nodes)
        nodes.append([s, e, -1, -1])
        if parent >= 0:
            nodes[parent][2 + side] = k
        if e - s > leaf_size:
            idx = order[s:e]
            ext = cent[idx].max(axis=0) - cent[idx].min(axis=0)
            axis = int(np.argmax(ext))
            mid = (e - s) // 2
            part = np.argpartition(cent[idx, axis], mid)
            order[s:e] = idx[part]
            stack.append((s + mid, e, k, 1))
            stack.append((s, s + mid, k, 0))
    elems, area, cent = elems[order], area[order], cent[order]
    info = np.array(nodes, dtype=np.int64).reshape(-1, 4)
    t = len(info)
    centre, radius = np.zeros((t, dim)), np.zeros(t)
    n, m, third = np.zeros((t, dim)), np.zeros((t, dim, dim)), np.zeros((t, dim, dim, dim))
    weight = np.linalg.norm(area, axis=1)
    # second central moment of each element per unit area: a segment's (b - a)(b - a)^T / 12,
    # a triangle's sum_k d_k d_k^T / 12 with d_k its vertices minus its centroid
    d = elems - cent[:, None]
    own = np.einsum("eki,ekj->eij", d, d) / 12 * (2.0 if dim == 2 else 1.0)
    for k, (s, e, _, _) in enumerate(info):
        w = weight[s:e]
        c = (w @ cent[s:e]) / w.sum() if w.sum() > 0 else cent[s:e].mean(axis=0)
        centre[k] = c
        radius[k] = np.sqrt(((elems[s:e] - c) ** 2).sum(axis=2).max()) if e > s else 0.0
        off = cent[s:e] - c
        n[k] = area[s:e].sum(axis=0)
        m[k] = area[s:e].T @ off
        third[k] = np.einsum("ej,ekl->jkl", area[s:e], np.einsum("ek,el->ekl", off, off) + own[s:e])
    return DipoleTree(dim, elems, centre, radius, n, m, third, info[:, 2:4].copy(), info[:, 0].copy(),
                      info[:, 1].copy())


def _exact(q: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Exact winding contribution of elements ``e`` (P, k, dim) at points ``q`` (P, dim), pairwise."""
    if e.shape[1] == 2:
        a, b = e[:, 0] - q, e[:, 1] - q
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        dot = (a * b).sum(axis=1)
        return np.where((cross == 0) & (dot <= 0), 0.0, np.arctan2(cross, dot)) / (2 * math.pi)
    a, b, c = e[:, 0] - q, e[:, 1] - q, e[:, 2] - q
    la, lb, lc = (np.sqrt((v * v).sum(axis=1)) for v in (a, b, c))
    det = (a * np.cross(b, c)).sum(axis=1)
    den = la * lb * lc + (a * b).sum(axis=1) * lc + (b * c).sum(axis=1) * la + (c * a).sum(axis=1) * lb
    return 2 * np.arctan2(det, den) / (4 * math.pi)


def _monomials(dim: int) -> list[tuple[int, ...]]:
    """Exponent tuples of the monomials of degree 1, 2 and 3 in ``dim`` variables."""
    from itertools import combinations_with_replacement as cwr
    return [c for deg in (1, 2, 3) for c in cwr(range(dim), deg)]


def far_coefficients(tree: DipoleTree) -> np.ndarray:
    """(T, 3, M) coefficients of the far field of every node as three polynomials in r = c - q,
    divided by |r|**p, |r|**(p+2) and |r|**(p+4) (p = dim), plus (T,) constants, packed as
    (T, 3, M + 1) with the constant first. The Taylor terms up to the Hessian of
    K(x) = x / |x|**p give: n.r + tr(M) over |r|**p; -p r^T M r - (p/2)(2 T_jjk + T_kjj) r_k
    over |r|**(p+2) (the latter written T_jkk x_j); p(p+2)/2 T_jkl r_j r_k r_l over |r|**(p+4)."""
    dim, p = tree.dim, tree.dim
    mono = _monomials(dim)
    col = {m: i + 1 for i, m in enumerate(mono)}
    t_count = len(tree.centre)
    out = np.zeros((t_count, 3, len(mono) + 1))
    out[:, 0, 0] = np.trace(tree.m, axis1=1, axis2=2)
    tjj = np.einsum("tjjk->tk", tree.t)
    tkk = np.einsum("tjkk->tj", tree.t)
    for j in range(dim):
        out[:, 0, col[(j,)]] += tree.n[:, j]
        out[:, 1, col[(j,)]] += -0.5 * p * (2 * tjj[:, j] + tkk[:, j])
        for k in range(dim):
            out[:, 1, col[tuple(sorted((j, k)))]] += -p * tree.m[:, j, k]
            for l in range(dim):
                out[:, 2, col[tuple(sorted((j, k, l)))]] += 0.5 * p * (p + 2) * tree.t[:, j, k, l]
    return out


def _far(r: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Far field at offsets r (P, dim) from the packed coefficients (P, 3, M + 1)."""
    dim = r.shape[1]
    mono = np.empty((len(r), coef.shape[2]))
    mono[:, 0] = 1.0
    for i, m in enumerate(_monomials(dim), start=1):
        if len(m) == 1:
            mono[:, i] = r[:, m[0]]
        elif len(m) == 2:
            np.multiply(r[:, m[0]], r[:, m[1]], out=mono[:, i])
        else:
            np.multiply(r[:, m[0]] * r[:, m[1]], r[:, m[2]], out=mono[:, i])
    poly = np.einsum("pgm,pm->pg", coef, mono)                            # (P, 3)
    inv2 = 1.0 / (r * r).sum(axis=1)
    inv_p = inv2 ** (dim / 2)
    scale = 1 / (2 * math.pi) if dim == 2 else 1 / (4 * math.pi)
    return scale * inv_p * (poly[:, 0] + inv2 * (poly[:, 1] + inv2 * poly[:, 2]))


def _morton_order(q: np.ndarray) -> np.ndarray:
    """Permutation sorting points along a Z-order curve (10 bits per axis), so runs of the
    sorted points are compact cells."""
    lo, hi = q.min(axis=0), q.max(axis=0)
    g = ((q - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023).astype(np.uint64)
    code = np.zeros(len(q), np.uint64)
    for bit in range(10):
        for axis in range(q.shape[1]):
            code |= ((g[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(bit * q.shape[1] + axis)
    return np.argsort(code, kind="stable")


def fast_winding(tree: DipoleTree, points: np.ndarray, *, beta: float = 2.0, chunk: int = 20_000,
                 threads: int = 2) -> np.ndarray:
    """Winding numbers (N,) at ``points`` (N, dim): dipole clusters beyond ``beta`` radii,
    exact sums at the leaves; NaN points give NaN. Points are walked in Z-order chunks
    (neighbours share nodes: the gathers stay in cache), ``threads`` chunks at a time
    (numpy releases the GIL in its loops)."""
    q_all = np.asarray(points, np.float64).reshape(-1, tree.dim)
    out = np.full(len(q_all), np.nan)
    good = np.flatnonzero(np.all(np.isfinite(q_all), axis=1))
    if len(tree.centre) == 0 or not len(good):
        out[good] = 0.0
        return out
    good = good[_morton_order(q_all[good])]
    coef = far_coefficients(tree)
    parts = [good[i:i + chunk] for i in range(0, len(good), chunk)]

    def run(idx: np.ndarray) -> None:
        out[idx] = _walk(tree, coef, q_all[idx], beta)

    if threads > 1 and len(parts) > 1:
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, parts))
    else:
        for idx in parts:
            run(idx)
    return out


def _walk(tree: DipoleTree, coef: np.ndarray, q: np.ndarray, beta: float) -> np.ndarray:
    w = np.zeros(len(q))
    sizes = tree.stop - tree.start
    reach2 = (beta * tree.radius) ** 2
    leaf_node = tree.child[:, 0] < 0
    qi, node = np.arange(len(q)), np.zeros(len(q), np.int64)
    while len(qi):
        r = tree.centre[node] - q[qi]
        far = np.einsum("ij,ij->i", r, r) > reach2[node]
        if far.any():
            w += np.bincount(qi[far], _far(r[far], coef[node[far]]), minlength=len(q))
            near = ~far
            qi, node = qi[near], node[near]
        leaf = leaf_node[node]
        if leaf.any():
            lq, ln = qi[leaf], node[leaf]
            cnt = sizes[ln]
            pq = np.repeat(lq, cnt)
            pe = np.repeat(tree.start[ln], cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            w += np.bincount(pq, _exact(q[pq], tree.elems[pe]), minlength=len(q))
            inner = ~leaf
            qi, node = qi[inner], node[inner]
        qi = np.repeat(qi, 2)
        node = tree.child[node].ravel()
    return w


def winding_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *, chunk: int = 4_000_000) -> np.ndarray:
    """Exact generalised winding numbers (N,) of a triangle soup at ``points`` (N, 3): the sum
    of the triangles' signed solid angles over 4 pi (open, non-manifold meshes allowed)."""
    q = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    out = np.zeros(len(q))
    if not len(tri):
        return out
    step = max(1, chunk // len(tri))
    for i in range(0, len(q), step):
        qq = q[i:i + step]
        a, b, c = (tri[None, :, k] - qq[:, None] for k in range(3))
        la, lb, lc = (np.sqrt((v * v).sum(axis=2)) for v in (a, b, c))
        det = (a * np.cross(b, c)).sum(axis=2)
        den = la * lb * lc + (a * b).sum(axis=2) * lc + (b * c).sum(axis=2) * la + (c * a).sum(axis=2) * lb
        out[i:i + step] = 2 * np.arctan2(det, den).sum(axis=1) / (4 * math.pi)
    return out


def mesh_tree(vertices: np.ndarray, faces: np.ndarray, **kw) -> DipoleTree:
    return build_tree(np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)], **kw)
