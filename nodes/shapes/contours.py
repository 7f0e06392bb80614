"""Contours for winding numbers, from any segmentation (seed 17's steps).

Coordinates are pixel (x = column, y = row) of the image's pixel centres; a positive
shoelace area in these coordinates means w = +1 inside (y points down, so such a curve
runs clockwise on screen). OpenCV's ``findContours`` gives the raw curves; then:

* :func:`contours_from_mask`: closed region outlines, each oriented by its nesting depth
  (outer boundaries positive, holes negative, islands in holes positive);
* :func:`polylines_from_edges`: thin edge pixels (Canny, a skeleton) traced by OpenCV as a
  walk out and back along the line; the walk is cut at its turnarounds and one side kept,
  so an edge becomes one open polyline (closed when the walk has no turnaround);
* :func:`merge_close`: open polylines whose ends lie within ``tol`` are joined (reversed
  where needed), a polyline whose own ends meet is closed; the seed's merging of contours
  a detector split;
* :func:`orient_open`: an open polyline is turned so that, closed by its chord, its area is
  positive -- the seed's "trigonometric direction" by area rather than by three points.
"""
from __future__ import annotations

import cv2
import numpy as np


def signed_area(poly: np.ndarray) -> float:
    """Shoelace area of the polygon closed by its chord (pixel units)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def contours_from_mask(mask: np.ndarray) -> list[np.ndarray]:
    """Closed outlines (K, 2) float of the non-zero regions, oriented by nesting depth."""
    m = (np.asarray(mask) != 0).astype(np.uint8)
    found, hierarchy = cv2.findContours(m, cv2.RETR_TREE, cv2.CHAIN_APPROX_NONE)
    out = []
    for k, c in enumerate(found):
        depth, parent = 0, hierarchy[0][k][3]
        while parent >= 0:
            depth += 1
            parent = hierarchy[0][parent][3]
        poly = c[:, 0, :].astype(np.float64)
        if len(poly) < 3:
            continue                                  # a lone pixel or a 2-pixel run has no interior
        if (signed_area(poly) > 0) != (depth % 2 == 0):
            poly = poly[::-1]
        out.append(poly)
    return out


def _unfold(walk: np.ndarray) -> tuple[np.ndarray, bool]:
    """(polyline, closed) of one traced contour: a walk out and back along a thin line turns
    around where its previous and next points coincide; keep the walk between two turnarounds."""
    n = len(walk)
    if n < 3:
        return walk, False
    turn = np.flatnonzero(np.all(np.roll(walk, 1, axis=0) == np.roll(walk, -1, axis=0), axis=1))
    if len(turn) == 0:
        return walk, True
    a = int(turn[0])
    b = int(turn[1]) if len(turn) > 1 else a
    if b == a:
        return np.roll(walk, -a, axis=0), False
    return walk[a:b + 1], False


def polylines_from_edges(edges: np.ndarray, *, min_points: int = 3) -> tuple[list[np.ndarray], list[bool]]:
    """Open (and closed) polylines along thin edge pixels: (polylines, closed flags)."""
    e = (np.asarray(edges) != 0).astype(np.uint8)
    found, _ = cv2.findContours(e, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    lines, closed = [], []
    for c in found:
        walk = c[:, 0, :].astype(np.float64)
        poly, is_closed = _unfold(walk)
        if len(poly) >= min_points:
            lines.append(poly)
            closed.append(is_closed)
    return _drop_twins(lines, closed)


def _drop_twins(lines: list[np.ndarray], closed: list[bool], tol: float = 1.5) -> tuple[list[np.ndarray], list[bool]]:
    """A closed 1-pixel loop is traced twice (its outside and its inside, within a pixel of
    each other); keep the longer trace of each such pair."""
    from scipy.spatial import cKDTree

    keep = [True] * len(lines)
    loops = sorted((k for k in range(len(lines)) if closed[k]), key=lambda k: -len(lines[k]))
    trees = {k: cKDTree(lines[k]) for k in loops}
    for a_pos, a in enumerate(loops):
        if not keep[a]:
            continue
        for b in loops[a_pos + 1:]:
            if keep[b] and len(lines[b]) >= 0.5 * len(lines[a]):
                if trees[a].query(lines[b])[0].max() <= tol:
                    keep[b] = False
    return [p for p, k in zip(lines, keep) if k], [c for c, k in zip(closed, keep) if k]


def orient_open(poly: np.ndarray) -> np.ndarray:
    return poly if signed_area(poly) >= 0 else poly[::-1]


def merge_close(polylines: list[np.ndarray], closed: list[bool], tol: float) -> tuple[list[np.ndarray], list[bool]]:
    """Join open polylines end to end while two ends lie within ``tol``; close a polyline
    whose own ends do. Closed ones pass through."""
    done = [(p, True) for p, c in zip(polylines, closed) if c]
    pool = [p for p, c in zip(polylines, closed) if not c]
    while pool:
        cur = pool.pop()
        grown = True
        while grown:
            grown = False
            if len(cur) > 2 and np.hypot(*(cur[0] - cur[-1])) <= tol:
                break
            for k, other in enumerate(pool):
                joins = [(np.hypot(*(cur[-1] - other[0])), other, False), (np.hypot(*(cur[-1] - other[-1])), other[::-1], False),
                         (np.hypot(*(cur[0] - other[-1])), other, True), (np.hypot(*(cur[0] - other[0])), other[::-1], True)]
                dist, piece, before = min(joins, key=lambda j: j[0])
                if dist <= tol:
                    cur = np.vstack([piece, cur]) if before else np.vstack([cur, piece])
                    pool.pop(k)
                    grown = True
                    break
        is_closed = len(cur) > 2 and np.hypot(*(cur[0] - cur[-1])) <= tol
        done.append((cur, is_closed))
    return [p for p, _ in done], [c for _, c in done]


def orient_by_nesting(curves: list[np.ndarray]) -> list[np.ndarray]:
    """Orient each curve (closed by its chord) positive, then flip those nested in an odd
    number of others, so a ring's inner edge winds the other way and its hole reads w = 0.
    Nesting is read at each curve's middle vertex with every other curve's winding number."""
    from nodes.shapes.winding import winding_numbers

    curves = [orient_open(p) for p in curves]
    if len(curves) < 2:
        return curves
    mids = np.array([p[len(p) // 2] for p in curves])
    depth = np.zeros(len(curves), int)
    for j, other in enumerate(curves):
        w = winding_numbers(mids, [other], closed=True)
        inside = w >= 0.5
        inside[j] = False
        depth += inside
    return [p[::-1] if d % 2 else p for p, d in zip(curves, depth)]
