"""SIVIA with separators, one whole level of boxes per step (vectorised), and the
inner / boundary / outside split of a paving.

``separator(lo, hi) -> ((out_lo, out_hi), (in_lo, in_hi))`` on (N, 2) box arrays: what the
outer contraction removes from a box is outside the set, what the inner one removes is
inside (see :mod:`nodes.sets.contract`). :func:`sivia` keeps both removed parts (as up to
four boxes each), bisects what is left along its widest side, and stops at width ``eps``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from nodes.sets.contract import Boxes, box_empty, box_hull, box_inter

Separator = Callable[[Boxes], tuple[Boxes, Boxes]]


@dataclass
class Paving:
    """``inner`` boxes lie inside the set, ``boundary`` boxes (width <= eps, or left when
    ``max_boxes`` was reached) may hold points of both; every point of the set lies in one of
    them. Boxes are (K, 2, 2): ``[k, 0]`` lower corner, ``[k, 1]`` upper corner."""

    inner: np.ndarray
    boundary: np.ndarray
    truncated: bool = False           # max_boxes stopped the bisection early (still guaranteed)

    @property
    def empty(self) -> bool:
        return len(self.inner) == 0 and len(self.boundary) == 0

    def hull(self) -> np.ndarray:
        """(2, 2) hull of the outer approximation (inner and boundary); NaN when empty."""
        boxes = np.concatenate([self.inner, self.boundary])
        if len(boxes) == 0:
            return np.full((2, 2), np.nan)
        return np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])

    def area(self) -> tuple[float, float]:
        """(inner area, outer area) in square units."""
        def a(b: np.ndarray) -> float:
            return float(np.prod(b[:, 1] - b[:, 0], axis=1).sum()) if len(b) else 0.0
        return a(self.inner), a(self.inner) + a(self.boundary)


def box_diff(x: Boxes, y: Boxes) -> Boxes:
    """``x \\ y`` for rows with ``y`` inside ``x`` (a contraction of it): up to four boxes per
    row (slabs below and above y in x, then left and right of y within y's x-range)."""
    (xl, xh), (yl, yh) = x, y
    gone = box_empty(y)
    yl = np.where(gone[:, None], xh, yl)              # y empty: all of x is removed (one slab)
    yh = np.where(gone[:, None], xh, yh)
    pieces_lo = [np.stack([xl[:, 0], xl[:, 1]], -1), np.stack([xl[:, 0], yh[:, 1]], -1),
                 np.stack([xl[:, 0], yl[:, 1]], -1), np.stack([yh[:, 0], yl[:, 1]], -1)]
    pieces_hi = [np.stack([xh[:, 0], yl[:, 1]], -1), np.stack([xh[:, 0], xh[:, 1]], -1),
                 np.stack([yl[:, 0], yh[:, 1]], -1), np.stack([xh[:, 0], yh[:, 1]], -1)]
    pieces_hi[0] = np.where(gone[:, None], xh, pieces_hi[0])  # the slab is the whole box
    lo, hi = np.concatenate(pieces_lo), np.concatenate(pieces_hi)
    keep = np.all(hi > lo, axis=1)                     # drop degenerate slivers of zero width
    if gone.any():
        drop = np.concatenate([np.zeros_like(gone), gone, gone, gone])
        keep &= ~drop
    return lo[keep], hi[keep]


def sivia(box: np.ndarray, separator: Separator, eps: float, *, max_boxes: int = 200_000) -> Paving:
    """Pave ``box`` (2, 2) (or (K, 2, 2) starting boxes) against ``separator`` down to width ``eps``."""
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps}")
    start = np.asarray(box, np.float64).reshape(-1, 2, 2)
    lo, hi = start[:, 0].copy(), start[:, 1].copy()
    ok = ~box_empty((lo, hi))
    lo, hi = lo[ok], hi[ok]
    inner: list[np.ndarray] = []
    boundary: list[np.ndarray] = []
    total, truncated = 0, False
    while len(lo):
        outer, inside = separator((lo, hi))
        kept = box_inter(outer, inside)                # neither proven outside nor inside
        il, ih = box_diff(box_inter((lo, hi), outer), box_inter(outer, inside))
        inner.append(np.stack([il, ih], 1))
        alive = ~box_empty(kept)
        kl, kh = kept[0][alive], kept[1][alive]
        w = kh - kl
        small = w.max(axis=1) <= eps
        total += len(il) + int(small.sum())
        boundary.append(np.stack([kl[small], kh[small]], 1))
        kl, kh = kl[~small], kh[~small]
        if total + 2 * len(kl) > max_boxes:
            boundary.append(np.stack([kl, kh], 1))
            truncated = True
            break
        # bisect along the widest side (an unbounded side is split at 0 or its finite end)
        axis = np.argmax(kh - kl, axis=1)
        rows = np.arange(len(kl))
        a, b = kl[rows, axis], kh[rows, axis]
        mid = np.where(np.isfinite(a) & np.isfinite(b), 0.5 * a + 0.5 * b,
                       np.where(np.isfinite(a), a + np.maximum(1.0, np.abs(a)),
                                np.where(np.isfinite(b), b - np.maximum(1.0, np.abs(b)), 0.0)))
        left_hi, right_lo = kh.copy(), kl.copy()
        left_hi[rows, axis] = mid
        right_lo[rows, axis] = mid
        lo, hi = np.concatenate([kl, right_lo]), np.concatenate([left_hi, kh])
    cat = (lambda parts: np.concatenate(parts) if parts else np.zeros((0, 2, 2)))
    return Paving(inner=cat(inner), boundary=cat(boundary), truncated=truncated)


def sep_inter(separators: Sequence[Separator], *, rounds: int = 2) -> Separator:
    """Separator of the intersection: the outer contractions applied in turn (``rounds``
    times, each using the last one's result), the inner ones joined by their hull."""
    def sep(b: Boxes) -> tuple[Boxes, Boxes]:
        outer = b
        inner = (np.full_like(b[0], np.inf), np.full_like(b[1], -np.inf))
        for r in range(rounds):
            for s in separators:
                o, i = s(outer)
                outer = o
                if r == 0:
                    inner = box_hull(inner, i)
        return outer, inner
    return sep
