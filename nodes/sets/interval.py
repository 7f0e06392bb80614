"""Vectorised interval arithmetic with outward rounding, on numpy arrays of bounds.

codac is the project's interval engine (its ``Interval``, contractors and separators are
the reference in the tests and benches); this module is the small kernel the vectorised
paving and tubes of :mod:`nodes.sets` need, because codac works on one box per Python
call and a paving level here holds thousands. Every result stays guaranteed:

* ``+ - * / sqrt`` are correctly rounded in IEEE 754, so one ulp outward
  (:func:`outward`) encloses the exact result;
* numpy's ``sin``/``cos``/``arctan2`` are not correctly rounded (a few ulp), so their
  results are widened by :data:`TRIG_ABS` as well;
* decimal constants go through :func:`from_decimal` (0.1 is not a double: the interval
  holds the two doubles around it).

An interval is a pair of arrays ``(lo, hi)`` of the same shape; it is **empty** where
``not lo <= hi`` (NaN bounds count as empty). Operations propagate emptiness without raising:
an empty input gives an empty output ``(+inf, -inf)``. Unbounded bounds are allowed.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

Interval = tuple[np.ndarray, np.ndarray]

INF = math.inf
#: Absolute widening of trigonometric results (numpy's SIMD sin/cos/atan2 are within a few
#: ulp of 1; 1e-15 is about 4.5 ulp there).
TRIG_ABS = 1e-15


def interval(lo, hi=None) -> Interval:
    """``(lo, hi)`` as float64 arrays; ``hi`` defaults to ``lo`` (a degenerate interval)."""
    lo = np.asarray(lo, dtype=np.float64)
    return lo, (lo if hi is None else np.asarray(hi, dtype=np.float64))


def from_decimal(text: str) -> Interval:
    """The tightest interval of doubles around a decimal constant written as text:
    ``from_decimal("0.1")`` is ``[0.09999999999999999, 0.1000000000000000055]``."""
    exact = Fraction(text)
    near = float(exact)
    if Fraction(near) == exact:
        return interval(near)
    if Fraction(near) < exact:
        return interval(near, math.nextafter(near, INF))
    return interval(math.nextafter(near, -INF), near)


def is_empty(a: Interval) -> np.ndarray:
    return ~(a[0] <= a[1])


def empty_like(a: Interval) -> Interval:
    return np.full_like(a[0], INF), np.full_like(a[1], -INF)


def down(x: np.ndarray) -> np.ndarray:
    """One ulp toward -inf; infinities stay (nextafter(+inf, -inf) would be a finite 1.8e308)."""
    x = np.asarray(x, np.float64)
    with np.errstate(over="ignore"):
        return np.where(np.isinf(x), x, np.nextafter(x, -INF))


def up(x: np.ndarray) -> np.ndarray:
    """One ulp toward +inf; infinities stay."""
    x = np.asarray(x, np.float64)
    with np.errstate(over="ignore"):
        return np.where(np.isinf(x), x, np.nextafter(x, INF))


def outward(lo: np.ndarray, hi: np.ndarray, empty: np.ndarray | None = None) -> Interval:
    """Bounds moved one ulp outward (the enclosure of a correctly rounded operation);
    ``empty`` marks results that must stay empty."""
    lo, hi = down(lo), up(hi)
    if empty is not None and empty.any():
        lo, hi = np.where(empty, INF, lo), np.where(empty, -INF, hi)
    return lo, hi


def width(a: Interval) -> np.ndarray:
    return np.where(is_empty(a), 0.0, a[1] - a[0])


def inter(a: Interval, b: Interval) -> Interval:
    """Intersection (exact: no rounding)."""
    lo, hi = np.maximum(a[0], b[0]), np.minimum(a[1], b[1])
    bad = ~(lo <= hi)
    return np.where(bad, INF, lo), np.where(bad, -INF, hi)


def hull(a: Interval, b: Interval) -> Interval:
    """Smallest interval holding both (an empty side is ignored)."""
    ea, eb = is_empty(a), is_empty(b)
    lo = np.where(ea, b[0], np.where(eb, a[0], np.minimum(a[0], b[0])))
    hi = np.where(ea, b[1], np.where(eb, a[1], np.maximum(a[1], b[1])))
    return lo, hi


def add(a: Interval, b: Interval) -> Interval:
    with np.errstate(invalid="ignore"):
        return outward(a[0] + b[0], a[1] + b[1], is_empty(a) | is_empty(b))


def sub(a: Interval, b: Interval) -> Interval:
    with np.errstate(invalid="ignore"):
        return outward(a[0] - b[1], a[1] - b[0], is_empty(a) | is_empty(b))


def neg(a: Interval) -> Interval:
    return -a[1], -a[0]


def _mul_bounds(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Products of bounds with 0 * inf = 0 (a bound of a real set times zero is zero)."""
    with np.errstate(invalid="ignore"):
        p = x * y
    return np.where((x == 0) | (y == 0), 0.0, p)


def mul(a: Interval, b: Interval) -> Interval:
    p = np.stack([_mul_bounds(a[0], b[0]), _mul_bounds(a[0], b[1]), _mul_bounds(a[1], b[0]), _mul_bounds(a[1], b[1])])
    return outward(p.min(axis=0), p.max(axis=0), is_empty(a) | is_empty(b))


def sqr(a: Interval) -> Interval:
    """``a**2`` (tighter than ``mul(a, a)``: the range of x**2, not of x*y)."""
    lo2, hi2 = a[0] * a[0], a[1] * a[1]
    contains0 = (a[0] <= 0) & (a[1] >= 0)
    lo = np.where(contains0, 0.0, np.minimum(lo2, hi2))
    lo, hi = outward(lo, np.maximum(lo2, hi2), is_empty(a))
    return np.maximum(lo, 0.0), hi


def sqrt(a: Interval) -> Interval:
    """Square root of the non-negative part (empty where ``a`` is entirely negative)."""
    empty = is_empty(a) | (a[1] < 0)
    with np.errstate(invalid="ignore"):
        lo, hi = outward(np.sqrt(np.maximum(a[0], 0.0)), np.sqrt(np.maximum(a[1], 0.0)), empty)
    return np.where(empty, lo, np.maximum(lo, 0.0)), hi


def div_pieces(a: Interval, b: Interval) -> tuple[Interval, Interval]:
    """``a / b`` as two intervals whose union holds the exact result. Where ``b`` contains 0
    in its interior and ``a`` does not contain 0, the quotient is two half-lines
    ``(-inf, u] U [v, +inf)``; elsewhere the second piece is empty. Where both contain 0 the
    answer is the whole line; where ``b`` is exactly [0, 0] it is empty."""
    ea, eb = is_empty(a), is_empty(b)
    b_zero = (b[0] == 0) & (b[1] == 0)
    straddle = (b[0] < 0) & (b[1] > 0)
    a_has0 = (a[0] <= 0) & (a[1] >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # 1/b for b not straddling zero (an endpoint at 0 gives an infinite bound)
        inv_lo = np.where(b[1] == 0, -INF, 1.0 / np.where(b[1] == 0, 1.0, b[1]))
        inv_hi = np.where(b[0] == 0, INF, 1.0 / np.where(b[0] == 0, 1.0, b[0]))
        first = mul(a, outward(inv_lo, inv_hi))
        # straddling b: 1/b = (-inf, 1/b.lo] U [1/b.hi, +inf)
        left = mul(a, outward(np.full_like(b[0], -INF), 1.0 / np.where(straddle, b[0], -1.0)))
        right = mul(a, outward(1.0 / np.where(straddle, b[1], 1.0), np.full_like(b[1], INF)))
    lo1 = np.where(straddle, left[0], first[0])
    hi1 = np.where(straddle, left[1], first[1])
    lo2 = np.where(straddle, right[0], INF)
    hi2 = np.where(straddle, right[1], -INF)
    whole = straddle & a_has0 | (a_has0 & ((b[0] == 0) | (b[1] == 0)) & ~b_zero)
    lo1, hi1 = np.where(whole, -INF, lo1), np.where(whole, INF, hi1)
    lo2, hi2 = np.where(whole, INF, lo2), np.where(whole, -INF, hi2)
    empty = ea | eb | b_zero
    return (np.where(empty, INF, lo1), np.where(empty, -INF, hi1)), (np.where(empty, INF, lo2), np.where(empty, -INF, hi2))


def div(a: Interval, b: Interval) -> Interval:
    """``a / b`` as one interval: the **hull** of :func:`div_pieces` (the whole line when
    ``b`` straddles 0). Use :func:`div_pieces` and intersect each piece when the gap matters."""
    p, q = div_pieces(a, b)
    return hull(p, q)


def _trig(a: Interval, fn, phase: float) -> Interval:
    """Range of ``fn`` = sin or cos over ``a``: the bounds' values, plus +1 / -1 where a
    maximum / minimum (at ``phase + 2k pi`` / ``phase + pi + 2k pi``) lies inside."""
    empty = is_empty(a)
    lo, hi = np.where(empty, 0.0, a[0]), np.where(empty, 0.0, a[1])
    wide = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi - lo >= 2 * math.pi)
    lo_f, hi_f = np.where(wide, 0.0, lo), np.where(wide, 0.0, hi)
    f_lo, f_hi = fn(lo_f), fn(hi_f)
    two_pi = 2 * math.pi
    # a crest at phase + 2k pi lies in [lo, hi] iff ceil((lo - phase) / 2pi) <= floor((hi - phase) / 2pi);
    # the divisions are rounded, so a crest within 1e-12 rad of a bound counts as inside (wider, still safe).
    slack = 1e-12
    has_max = np.ceil((lo_f - phase - slack) / two_pi) <= np.floor((hi_f - phase + slack) / two_pi)
    has_min = np.ceil((lo_f - phase - math.pi - slack) / two_pi) <= np.floor((hi_f - phase - math.pi + slack) / two_pi)
    out_lo = np.where(has_min | wide, -1.0, np.minimum(f_lo, f_hi) - TRIG_ABS)
    out_hi = np.where(has_max | wide, 1.0, np.maximum(f_lo, f_hi) + TRIG_ABS)
    out_lo, out_hi = np.maximum(out_lo, -1.0), np.minimum(out_hi, 1.0)
    return np.where(empty, INF, out_lo), np.where(empty, -INF, out_hi)


def sin(a: Interval) -> Interval:
    return _trig(a, np.sin, math.pi / 2)


def cos(a: Interval) -> Interval:
    return _trig(a, np.cos, 0.0)


def atan2(y: Interval, x: Interval) -> Interval:
    """Range of ``atan2(y, x)`` in [-pi, pi]. Where the box touches the negative x-axis
    (the branch cut) the answer is the whole [-pi, pi] (one interval cannot hold both
    sides of the cut); where it holds the origin, also [-pi, pi]."""
    empty = is_empty(y) | is_empty(x)
    ylo, yhi, xlo, xhi = (np.where(empty, 1.0, v) for v in (y[0], y[1], x[0], x[1]))
    corners = np.stack([np.arctan2(yy, xx) for yy in (ylo, yhi) for xx in (xlo, xhi)])
    lo, hi = corners.min(axis=0) - TRIG_ABS, corners.max(axis=0) + TRIG_ABS
    # the angle is monotone on each side of the axes; extremes lie at corners unless the box
    # crosses the cut (x < 0, y spans 0) or holds the origin
    cut = (xlo < 0) & (ylo <= 0) & (yhi >= 0)
    lo, hi = np.where(cut, -math.pi, np.maximum(lo, -math.pi)), np.where(cut, math.pi, np.minimum(hi, math.pi))
    # a box straddling the positive x-axis: corners still bound the angle (monotone in y)
    return np.where(empty, INF, lo), np.where(empty, -INF, hi)


# ---- backward (projection) operators used by the contractors -------------------------------

def bwd_add(z: Interval, x: Interval, y: Interval) -> tuple[Interval, Interval]:
    """Contract ``x`` and ``y`` under ``z = x + y``."""
    x = inter(x, sub(z, y))
    y = inter(y, sub(z, x))
    return x, y


def bwd_sqr(z: Interval, x: Interval) -> Interval:
    """Contract ``x`` under ``z = x**2``: ``x`` within the hull of its parts in +-sqrt(z)."""
    r = sqrt(z)
    pos = inter(x, r)
    negp = inter(x, neg(r))
    return hull(pos, negp)
