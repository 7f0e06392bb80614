"""Contractors over a whole history: a tube of robot boxes chained by odometry, marker
boxes tied to it by ranges (set-membership SLAM, seed 03), and boxes tied by translation
constraints on a graph (the interval mosaic of seed 08, section VII).

The chain ``X[k+1] - X[k] in D[k]`` is contracted forward and backward in one vectorised
pass each: the forward lower bound is ``lo[k] = max_j<=k (lo[j] + sum_{j<=i<k} dlo[i])``,
i.e. a prefix sum plus a running maximum (``np.maximum.accumulate``), instead of K
sequential interval additions. The prefix sums are rounded; every bound is moved outward
by the classical error bound of recursive summation (Higham, eq. 4.4: k u sum |d_i| /
(1 - k u)), so the result still holds the true tube.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nodes.sets.contract import contract_sq_distance_boxes, range_sq_bounds
from nodes.sets.interval import down, up

U = 2.0 ** -53


def _margin(k: np.ndarray, abs_sum: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Outward margin for a bound built from a prefix sum of k terms with sum |d| = ``abs_sum``
    and bounds of magnitude ``scale``: two prefix sums (2 k u A) and three roundings (3 u (L + 2A))."""
    ku = k * U
    return ((2 * ku / (1 - ku)) * abs_sum + 3 * U * (scale + 2 * abs_sum)) * 1.01


def _prefix(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, A): S[k] = sum_{i<k} d[i], A[k] = sum_{i<k} |d[i]|, with S[0] = A[0] = 0; shapes (K+1, ...)."""
    zero = np.zeros((1,) + d.shape[1:])
    return np.concatenate([zero, np.cumsum(d, axis=0)]), np.concatenate([zero, np.cumsum(np.abs(d), axis=0)])


def contract_chain(lo: np.ndarray, hi: np.ndarray, dlo: np.ndarray, dhi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contract boxes ``[lo[k], hi[k]]`` (K+1, n) under ``X[k+1] - X[k] in [dlo[k], dhi[k]]``
    (K, n), forward then backward. The displacements must be finite; the boxes may be unbounded."""
    if not (np.all(np.isfinite(dlo)) and np.all(np.isfinite(dhi))):
        raise ValueError("odometry bounds must be finite (an unknown step splits the tube into two)")
    k = np.arange(len(lo), dtype=np.float64)[:, None]
    finite = np.concatenate([lo[np.isfinite(lo)], hi[np.isfinite(hi)]])
    scale = float(np.abs(finite).max()) if finite.size else 0.0
    s_lo, a_lo = _prefix(dlo)
    s_hi, a_hi = _prefix(dhi)
    with np.errstate(invalid="ignore"):
        # forward: lo[k] >= lo[j] + S_lo[k] - S_lo[j];  hi[k] <= hi[j] + S_hi[k] - S_hi[j]   (j <= k)
        f_lo = s_lo + np.maximum.accumulate(lo - s_lo, axis=0) - _margin(k, a_lo, scale)
        f_hi = s_hi + np.minimum.accumulate(hi - s_hi, axis=0) + _margin(k, a_hi, scale)
        lo, hi = np.maximum(lo, f_lo), np.minimum(hi, f_hi)
        # backward: lo[k] >= lo[j] - (S_hi[j] - S_hi[k]);  hi[k] <= hi[j] - (S_lo[j] - S_lo[k])   (j >= k)
        rmax = np.maximum.accumulate((lo - s_hi)[::-1], axis=0)[::-1]
        rmin = np.minimum.accumulate((hi - s_lo)[::-1], axis=0)[::-1]
        span = float(len(lo) - 1)               # a backward sum spans at most K terms
        b_lo = s_hi + rmax - _margin(span, a_hi[-1:], scale)
        b_hi = s_lo + rmin + _margin(span, a_lo[-1:], scale)
    lo, hi = np.maximum(lo, np.nan_to_num(b_lo, nan=-np.inf)), np.minimum(hi, np.nan_to_num(b_hi, nan=np.inf))
    return lo, hi


def contract_ranges(x: tuple[np.ndarray, np.ndarray], m: tuple[np.ndarray, np.ndarray], steps: np.ndarray,
                    markers: np.ndarray, r_lo: np.ndarray, r_hi: np.ndarray):
    """Contract robot boxes ``x`` (K+1, 2) and marker boxes ``m`` (M, 2) under every range
    observation ``|x[steps[i]] - m[markers[i]]| in [r_lo[i], r_hi[i]]``; several observations
    of one box are intersected."""
    s_lo, s_hi = range_sq_bounds(r_lo, r_hi)
    (xl, xh), (ml, mh) = contract_sq_distance_boxes((x[0][steps], x[1][steps]), (m[0][markers], m[1][markers]), s_lo, s_hi)
    x_lo, x_hi, m_lo, m_hi = x[0].copy(), x[1].copy(), m[0].copy(), m[1].copy()
    np.maximum.at(x_lo, steps, xl)
    np.minimum.at(x_hi, steps, xh)
    np.maximum.at(m_lo, markers, ml)
    np.minimum.at(m_hi, markers, mh)
    return (x_lo, x_hi), (m_lo, m_hi)


def contract_edges(lo: np.ndarray, hi: np.ndarray, i: np.ndarray, j: np.ndarray, dlo: np.ndarray, dhi: np.ndarray,
                   *, max_iter: int = 1000, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, int]:
    """Contract node boxes (N, n) under ``X[j[e]] - X[i[e]] in [dlo[e], dhi[e]]`` for every
    edge, all edges at once per sweep, to a fixpoint (no bound moves by more than ``tol``).
    Returns (lo, hi, sweeps). Linear constraints: a sweep is exact up to outward rounding."""
    lo, hi = lo.astype(np.float64).copy(), hi.astype(np.float64).copy()
    for sweep in range(1, max_iter + 1):
        with np.errstate(invalid="ignore"):
            fj_lo, fj_hi = down(lo[i] + dlo), up(hi[i] + dhi)
            fi_lo, fi_hi = down(lo[j] - dhi), up(hi[j] - dlo)
        new_lo, new_hi = lo.copy(), hi.copy()
        np.maximum.at(new_lo, j, np.nan_to_num(fj_lo, nan=-np.inf))
        np.minimum.at(new_hi, j, np.nan_to_num(fj_hi, nan=np.inf))
        np.maximum.at(new_lo, i, np.nan_to_num(fi_lo, nan=-np.inf))
        np.minimum.at(new_hi, i, np.nan_to_num(fi_hi, nan=np.inf))
        settled = _settled(np.concatenate([lo, hi]), np.concatenate([new_lo, new_hi]), tol)
        lo, hi = new_lo, new_hi
        if np.any(lo > hi):
            bad = np.any(lo > hi, axis=1)
            lo[bad], hi[bad] = np.inf, -np.inf
            return lo, hi, sweep
        if settled:
            return lo, hi, sweep
    return lo, hi, max_iter


def _settled(before: np.ndarray, after: np.ndarray, tol: float) -> bool:
    """No bound became finite and no finite bound moved by more than ``tol``."""
    finite = np.isfinite(before) & np.isfinite(after)
    if not np.array_equal(np.isfinite(before), np.isfinite(after)):
        return False
    return not finite.any() or float(np.abs(after[finite] - before[finite]).max()) <= tol


@dataclass
class SetSlam:
    """Set-membership SLAM over the whole history: robot tube ``x`` (K+1, 2) from a known
    start box, markers ``m`` (M, 2) unknown (unbounded) until ranges bound them.

    :meth:`add_step` appends one odometry box and the step's range observations;
    :meth:`contract` runs the chain and range contractors to a fixpoint over all of it, so
    a marker seen again late contracts the whole past of the tube."""

    start: np.ndarray                              # (2, 2) box of x[0]
    n_markers: int
    x_lo: np.ndarray = field(init=False)
    x_hi: np.ndarray = field(init=False)
    m_lo: np.ndarray = field(init=False)
    m_hi: np.ndarray = field(init=False)
    d_lo: list = field(default_factory=list)
    d_hi: list = field(default_factory=list)
    obs: list = field(default_factory=list)       # (step, marker, r_lo, r_hi)

    def __post_init__(self) -> None:
        self.x_lo, self.x_hi = self.start[0][None].astype(float), self.start[1][None].astype(float)
        self.m_lo = np.full((self.n_markers, 2), -np.inf)
        self.m_hi = np.full((self.n_markers, 2), np.inf)

    def add_step(self, step_box: np.ndarray, observations: list[tuple[int, float, float]]) -> None:
        """``step_box`` (2, 2) displacement; observations (marker index, r_lo, r_hi) at the new step."""
        self.d_lo.append(np.asarray(step_box[0], float))
        self.d_hi.append(np.asarray(step_box[1], float))
        self.x_lo = np.vstack([self.x_lo, np.full(2, -np.inf)])
        self.x_hi = np.vstack([self.x_hi, np.full(2, np.inf)])
        k = len(self.x_lo) - 1
        for j, r0, r1 in observations:
            if not 0 <= j < self.n_markers:
                raise ValueError(f"marker index {j} outside 0..{self.n_markers - 1}")
            self.obs.append((k, j, r0, r1))

    def contract(self, *, max_iter: int = 50, tol: float = 1e-6) -> int:
        """Chain and ranges to a fixpoint; returns the sweeps used. Empty boxes mean the bounds
        failed somewhere (check :attr:`consistent`); an empty tube stays empty."""
        if not self.consistent:
            return 0
        dlo, dhi = np.array(self.d_lo).reshape(-1, 2), np.array(self.d_hi).reshape(-1, 2)
        ob = np.array(self.obs, dtype=np.float64).reshape(-1, 4)
        steps, markers = ob[:, 0].astype(int), ob[:, 1].astype(int)
        x, m = (self.x_lo, self.x_hi), (self.m_lo, self.m_hi)
        for sweep in range(1, max_iter + 1):
            before = np.concatenate([x[0], x[1], m[0], m[1]])
            x = contract_chain(x[0], x[1], dlo, dhi) if len(dlo) else x
            if len(ob):
                x, m = contract_ranges(x, m, steps, markers, ob[:, 2], ob[:, 3])
            after = np.concatenate([x[0], x[1], m[0], m[1]])
            self.x_lo, self.x_hi, self.m_lo, self.m_hi = x[0], x[1], m[0], m[1]
            if not self.consistent:
                return sweep
            if _settled(before, after, tol):
                return sweep
        return max_iter

    @property
    def consistent(self) -> bool:
        return bool(np.all(self.x_lo <= self.x_hi) and np.all(self.m_lo <= self.m_hi))
