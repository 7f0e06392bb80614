"""Forward-backward contractors and separators for range and bearing to known points, on
arrays of 2-D boxes.

A box array is ``(lo, hi)`` with shapes ``(N, 2)`` (x, y). A **contractor** returns boxes
inside the given ones that still hold every point of the box satisfying the constraint;
a **separator** returns a pair (outer, inner): the outer boxes hold every point of the
set, the inner boxes every point of its complement, so what the outer contraction removes
is proven outside and what the inner one removes is proven inside (Jaulin's separators,
as codac's ``SepInverse``).

* range: ``(x - mx)**2 + (y - my)**2 in [r]**2``, forward-backward on the expression tree;
* bearing: the direction from the robot to the marker, ``atan2(my - y, mx - x)``, in an
  interval of width below pi is the wedge of two half-planes through the marker, each
  a linear constraint contracted exactly (up to rounding, outward).
"""
from __future__ import annotations

import math

import numpy as np

from nodes.sets import interval as iv

Boxes = tuple[np.ndarray, np.ndarray]


def box_empty(b: Boxes) -> np.ndarray:
    """(N,) True where a box is empty in any coordinate."""
    return ~np.all(b[0] <= b[1], axis=-1)


def box_inter(a: Boxes, b: Boxes) -> Boxes:
    return iv.inter(a, b)


def box_hull(a: Boxes, b: Boxes) -> Boxes:
    """Per-row hull; an empty box (any coordinate) contributes nothing."""
    ea, eb = box_empty(a)[:, None], box_empty(b)[:, None]
    lo = np.where(ea, b[0], np.where(eb, a[0], np.minimum(a[0], b[0])))
    hi = np.where(ea, b[1], np.where(eb, a[1], np.maximum(a[1], b[1])))
    both = (ea & eb)[:, 0]
    lo[both], hi[both] = np.inf, -np.inf
    return lo, hi


def contract_sq_distance(b: Boxes, marker: np.ndarray, s_lo: np.ndarray, s_hi: np.ndarray) -> Boxes:
    """Contract boxes under ``|p - marker|**2 in [s_lo, s_hi]``.

    ``marker`` (N, 2) or (2,) points (or (N, 2, 2) marker boxes as ``(lo, hi)`` is handled by
    :func:`contract_sq_distance_boxes`); ``s_lo``, ``s_hi`` (N,), either may be infinite.
    """
    m = np.broadcast_to(np.asarray(marker, np.float64), b[0].shape)
    p, _ = contract_sq_distance_boxes(b, (m, m), s_lo, s_hi)
    return p


def contract_sq_distance_boxes(p: Boxes, m: Boxes, s_lo: np.ndarray, s_hi: np.ndarray) -> tuple[Boxes, Boxes]:
    """Contract robot boxes ``p`` and marker boxes ``m`` (both (N, 2) bounds) jointly under
    ``|p - m|**2 in [s_lo, s_hi]``: forward d = p - m, a = d**2, s = ax + ay; backward the same."""
    px, py = (p[0][:, 0], p[1][:, 0]), (p[0][:, 1], p[1][:, 1])
    mx, my = (m[0][:, 0], m[1][:, 0]), (m[0][:, 1], m[1][:, 1])
    dx, dy = iv.sub(px, mx), iv.sub(py, my)
    ax, ay = iv.sqr(dx), iv.sqr(dy)
    s = iv.inter(iv.add(ax, ay), (np.asarray(s_lo, np.float64), np.asarray(s_hi, np.float64)))
    ax, ay = iv.bwd_add(s, ax, ay)
    dx, dy = iv.bwd_sqr(ax, dx), iv.bwd_sqr(ay, dy)
    px, mx = iv.bwd_add(dx, px, iv.neg(mx))
    py, my = iv.bwd_add(dy, py, iv.neg(my))
    mx, my = iv.neg(mx), iv.neg(my)
    p_out = (np.stack([px[0], py[0]], -1), np.stack([px[1], py[1]], -1))
    m_out = (np.stack([mx[0], my[0]], -1), np.stack([mx[1], my[1]], -1))
    dead = box_empty(p_out) | box_empty(m_out)
    for box in (p_out, m_out):
        box[0][dead], box[1][dead] = np.inf, -np.inf
    return p_out, m_out


def range_sq_bounds(r_lo: np.ndarray, r_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[r]**2 for ranges in [r_lo, r_hi] (a negative lower bound means 0)."""
    return iv.sqr((np.maximum(np.asarray(r_lo, np.float64), 0.0), np.asarray(r_hi, np.float64)))


def separate_range(b: Boxes, marker: np.ndarray, r_lo: np.ndarray, r_hi: np.ndarray) -> tuple[Boxes, Boxes]:
    """Separator of ``|p - marker| in [r_lo, r_hi]``: (outer, inner) contractions of ``b``.

    The complement of the annulus is the disc ``s <= r_lo**2`` union the outside ``s >= r_hi**2``;
    the inner contraction is the hull of the two contractions."""
    s_lo, s_hi = range_sq_bounds(r_lo, r_hi)
    outer = contract_sq_distance(b, marker, s_lo, s_hi)
    disc = contract_sq_distance(b, marker, np.full_like(s_lo, -np.inf), s_lo)
    beyond = contract_sq_distance(b, marker, s_hi, np.full_like(s_hi, np.inf))
    return outer, box_hull(disc, beyond)


# ---- bearing: linear half-planes -------------------------------------------------------------

def contract_halfplane(b: Boxes, a: np.ndarray, c: np.ndarray) -> Boxes:
    """Contract boxes under ``a[:, 0] x + a[:, 1] y <= c`` (a (N, 2), c (N,)), outward rounded.

    Backward on the sum: a_k x_k <= c - a_o x_o, whose largest value U bounds x_k above
    (a_k > 0) or below (a_k < 0); with a_k = 0 the box is empty when U < 0."""
    lo, hi = b[0].copy(), b[1].copy()
    c = np.asarray(c, np.float64)
    for k in (0, 1):
        o = 1 - k
        rest = iv.mul(iv.interval(a[:, o]), (lo[:, o], hi[:, o]))
        with np.errstate(invalid="ignore"):
            u = iv.sub(iv.interval(c), rest)[1]
            with np.errstate(divide="ignore"):
                q = u / np.where(a[:, k] == 0, 1.0, a[:, k])
        pos, neg = a[:, k] > 0, a[:, k] < 0
        hi[:, k] = np.where(pos, np.minimum(hi[:, k], iv.up(q)), hi[:, k])
        lo[:, k] = np.where(neg, np.maximum(lo[:, k], iv.down(q)), lo[:, k])
        dead = (a[:, k] == 0) & (u < 0)
        lo[dead], hi[dead] = np.inf, -np.inf
    dead = box_empty((lo, hi))
    lo[dead], hi[dead] = np.inf, -np.inf
    return lo, hi


def _side(theta: np.ndarray, marker: np.ndarray, ccw: bool) -> tuple[np.ndarray, np.ndarray]:
    """Half-plane ``a . p <= c`` of robots p whose direction to ``marker``, v = m - p, lies
    counter-clockwise of u = (cos theta, sin theta) (``ccw``: cross(u, v) >= 0) or clockwise.

    cross(u, m - p) = K - u_x p_y + u_y p_x with K = u_x m_y - u_y m_x, so ccw is
    (-u_y, u_x) . p <= K and cw is (u_y, -u_x) . p <= -K. The line passes through the marker
    for the float u used (K is bounded outward); u itself is a few 1e-16 rad off theta, which
    the callers' 1e-9 rad padding covers."""
    u = np.stack([np.cos(theta), np.sin(theta)], -1)
    k = iv.sub(iv.mul(iv.interval(u[:, 0]), iv.interval(marker[:, 1])), iv.mul(iv.interval(u[:, 1]), iv.interval(marker[:, 0])))
    if ccw:
        return np.stack([-u[:, 1], u[:, 0]], -1), k[1]
    return np.stack([u[:, 1], -u[:, 0]], -1), -k[0]


#: Angular padding of a bearing interval (rad) before its half-planes are built: covers the
#: rounding of cos/sin by seven orders of magnitude and is far below any sensor's error.
BEARING_PAD = 1e-9


def separate_bearing(b: Boxes, marker: np.ndarray, b_lo: np.ndarray, b_hi: np.ndarray) -> tuple[Boxes, Boxes]:
    """Separator of ``atan2(my - y, mx - x) in [b_lo, b_hi]`` (the world bearing from the
    robot to the marker, width < pi): outer = the wedge of two half-planes through the
    marker; inner = hull of the two complementary half-planes (each padded outward)."""
    n = len(b[0])
    b_lo = np.broadcast_to(np.asarray(b_lo, np.float64), (n,))
    b_hi = np.broadcast_to(np.asarray(b_hi, np.float64), (n,))
    if np.any(b_hi - b_lo >= math.pi - 2 * BEARING_PAD):
        raise ValueError("a bearing interval of width >= pi is not a wedge; drop the bearing "
                         "(use the range alone) or split the interval")
    m = np.broadcast_to(np.asarray(marker, np.float64), b[0].shape)
    outer = contract_halfplane(contract_halfplane(b, *_side(b_lo - BEARING_PAD, m, ccw=True)),
                               *_side(b_hi + BEARING_PAD, m, ccw=False))
    inner = box_hull(contract_halfplane(b, *_side(b_lo + BEARING_PAD, m, ccw=False)),
                     contract_halfplane(b, *_side(b_hi - BEARING_PAD, m, ccw=True)))
    return outer, inner
