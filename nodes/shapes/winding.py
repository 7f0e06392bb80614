"""Generalised winding numbers of 2-D polylines, open or closed (seed 17; Jacobson et al. 2013).

``w(q) = (1 / 2 pi) sum_s angle subtended at q by segment s`` -- the seed's formula: an
integer for closed curves (+1 inside a counter-clockwise curve, -1 inside a clockwise one,
2 inside a curve wound twice), a smooth fraction near the gaps of an open curve, so
``w > 1/2`` is a robust inside test for broken contours.

* :func:`winding_direct` sums the angles (``atan2`` of cross and dot), O(queries x segments):
  the reference, and the evaluator for points on the curve.
* :func:`winding_numbers` is exact and fast: each open curve is closed by its chord, the
  closed set's integer winding number is a signed count of crossings of the ray from q
  toward +x (only the segments of q's horizontal band are tested), and the chord's own
  angle is subtracted again -- one ``atan2`` per query and open curve instead of one per
  segment. No far-field approximation is needed in 2-D (Barill et al.'s tree is for 3-D; see
  :mod:`nodes.shapes.fast_winding`, which also has the 2-D dipole tree for comparison).

On the curve, ``w`` is defined as the mean of the two sides: the segment holding q
contributes no angle (``atan2(0, -x)`` would be +-pi depending on the sign of a zero), so
w = 1/2 on the edge of a simple closed curve and (interior angle / 2 pi) at a vertex.
Points 1e-12 off the curve get their side's value. Zero-length segments are dropped; a NaN
vertex cuts a polyline into open pieces; a curve of one point contributes nothing.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

TWO_PI = 2 * math.pi


def _pieces(curve: np.ndarray) -> list[np.ndarray]:
    """Split a polyline at NaN vertices; pieces of fewer than two points are dropped."""
    c = np.asarray(curve, np.float64).reshape(-1, 2)
    bad = ~np.all(np.isfinite(c), axis=1)
    if not bad.any():
        return [c] if len(c) >= 2 else []
    out, start = [], 0
    for k in np.flatnonzero(bad).tolist() + [len(c)]:
        if k - start >= 2:
            out.append(c[start:k])
        start = k + 1
    return out


def segments_of(curves: Sequence[np.ndarray], closed: bool | Sequence[bool] = True
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, chord_a, chord_b): segment starts and ends (S, 2) of every curve, closed ones
    with their closing segment, and the chords (end -> start) (C, 2) of the open ones.
    A curve cut by NaN becomes open pieces."""
    flags = [closed] * len(curves) if isinstance(closed, bool) else list(closed)
    if len(flags) != len(curves):
        raise ValueError(f"closed has {len(flags)} flags for {len(curves)} curves")
    a, b, ca, cb = [], [], [], []
    for curve, is_closed in zip(curves, flags):
        pieces = _pieces(curve)
        whole = len(pieces) == 1 and len(pieces[0]) == len(np.asarray(curve).reshape(-1, 2))
        for p in pieces:
            if is_closed and whole:
                p = np.vstack([p, p[:1]])
            elif not np.array_equal(p[0], p[-1]):
                ca.append(p[-1])
                cb.append(p[0])
            a.append(p[:-1])
            b.append(p[1:])
    if not a:
        z = np.zeros((0, 2))
        return z, z, z, z
    a, b = np.concatenate(a), np.concatenate(b)
    keep = np.any(a != b, axis=1)                           # zero-length segments subtend nothing
    two = lambda v: np.asarray(v, np.float64).reshape(-1, 2)   # noqa: E731
    return a[keep], b[keep], two(ca), two(cb)


def _angles(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, S) signed angles subtended by segments a->b at points q; 0 where q is on a segment."""
    ax, ay = a[None, :, 0] - q[:, None, 0], a[None, :, 1] - q[:, None, 1]
    bx, by = b[None, :, 0] - q[:, None, 0], b[None, :, 1] - q[:, None, 1]
    cross = ax * by - ay * bx
    dot = ax * bx + ay * by
    on = (cross == 0) & (dot <= 0)
    return np.where(on, 0.0, np.arctan2(cross, dot))


def winding_direct(points: np.ndarray, curves: Sequence[np.ndarray], closed: bool | Sequence[bool] = True, *,
                   chunk: int = 2_000_000) -> np.ndarray:
    """Winding numbers (N,) of ``points`` (N, 2) by the sum of subtended angles (float64)."""
    q = np.asarray(points, np.float64).reshape(-1, 2)
    a, b, _, _ = segments_of(curves, closed)
    out = np.zeros(len(q))
    if not len(a):
        return out
    step = max(1, chunk // len(a))
    for i in range(0, len(q), step):
        out[i:i + step] = _angles(q[i:i + step], a, b).sum(axis=1) / TWO_PI
    return out


def winding_numbers(points: np.ndarray, curves: Sequence[np.ndarray], closed: bool | Sequence[bool] = True, *,
                    bands: int | None = None) -> np.ndarray:
    """Exact winding numbers (N,) of ``points`` (N, 2): crossing counts in horizontal bands
    plus the open curves' chord angles; points on a segment or a chord go to
    :func:`winding_direct`. NaN query points give NaN."""
    q = np.asarray(points, np.float64).reshape(-1, 2)
    a, b, ca, cb = segments_of(curves, closed)
    out = np.zeros(len(q))
    finite = np.all(np.isfinite(q), axis=1)
    out[~finite] = np.nan
    if not len(a) or not finite.any():
        return out
    sa, sb = np.concatenate([a, ca]), np.concatenate([b, cb])      # every curve closed by its chord
    idx = np.flatnonzero(finite)
    w, on = _banded_crossings(q[idx], sa, sb, bands)
    if len(ca):
        chord = _angles(q[idx], ca, cb)                                # (N, C), one atan2 per open curve
        w = w - chord.sum(axis=1) / TWO_PI
        on |= _on_segments(q[idx], ca, cb)
    out[idx] = w
    if on.any():
        out[idx[on]] = winding_direct(q[idx[on]], curves, closed)
    return out


def _on_segments(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay = a[None, :, 0] - q[:, None, 0], a[None, :, 1] - q[:, None, 1]
    bx, by = b[None, :, 0] - q[:, None, 0], b[None, :, 1] - q[:, None, 1]
    return np.any(((ax * by - ay * bx) == 0) & ((ax * bx + ay * by) <= 0), axis=1)


def _banded_crossings(q: np.ndarray, a: np.ndarray, b: np.ndarray, bands: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Signed count of segments crossed by the ray q -> +x (half-open in y, so a vertex on
    the ray counts once), and whether q lies on a segment; only the segments overlapping q's
    band in y are tested."""
    y0, y1 = float(q[:, 1].min()), float(q[:, 1].max())
    n_bands = bands or int(np.clip(np.sqrt(len(q)), 1, 4096))
    h = (y1 - y0) / n_bands if y1 > y0 else 1.0
    band_q = np.clip(((q[:, 1] - y0) / h).astype(np.int64), 0, n_bands - 1)
    lo_y, hi_y = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    first = np.clip(np.floor((lo_y - y0) / h), 0, n_bands - 1).astype(np.int64)
    last = np.clip(np.floor((hi_y - y0) / h), 0, n_bands - 1).astype(np.int64)
    live = (hi_y >= y0) & (lo_y <= y1)
    first, last, seg = first[live], last[live], np.flatnonzero(live)
    span = last - first + 1
    pair_band = np.repeat(first, span) + (np.arange(span.sum()) - np.repeat(np.cumsum(span) - span, span))
    pair_seg = np.repeat(seg, span)
    order = np.argsort(pair_band, kind="stable")
    pair_band, pair_seg = pair_band[order], pair_seg[order]
    seg_start = np.searchsorted(pair_band, np.arange(n_bands + 1))
    q_order = np.argsort(band_q, kind="stable")
    q_start = np.searchsorted(band_q[q_order], np.arange(n_bands + 1))
    w = np.zeros(len(q))
    on = np.zeros(len(q), bool)
    for k in np.flatnonzero(np.diff(q_start)):
        qs = q_order[q_start[k]:q_start[k + 1]]
        ss = pair_seg[seg_start[k]:seg_start[k + 1]]
        if not len(ss):
            continue
        px, py = q[qs, 0:1], q[qs, 1:2]
        ax, ay, bx, by = a[ss, 0], a[ss, 1], b[ss, 0], b[ss, 1]
        up = (ay <= py) & (py < by)
        down = (by <= py) & (py < ay)
        cross = (bx - ax) * (py - ay) - (by - ay) * (px - ax)      # > 0: q left of a->b
        # the ray crosses an upward segment right of q iff q is left of it (cross > 0), a
        # downward one iff q is right of it (cross < 0): no division, exact sign
        w[qs] = ((up & (cross > 0)).sum(axis=1) - (down & (cross < 0)).sum(axis=1))
        within = (np.minimum(ax, bx) <= px) & (px <= np.maximum(ax, bx)) & (np.minimum(ay, by) <= py) & (py <= np.maximum(ay, by))
        on[qs] = np.any((cross == 0) & within, axis=1)
    return w, on
