"""Cable in a rectified stereo pair (seed 05): the colour-distance valley, followed point by point
from the image border; left and right curves matched in tracked order; triangulation with a
per-point depth uncertainty.

Pure functions (numpy and OpenCV only)::

    P = colour_distance(bgr, reference_bgr)            # (H, W) float32 in [0, 2], low on the cable
    tracks = track_cable(P)                            # list of (K, 2) pixel polylines, in order
    cable = reconstruct(left_bgr, right_bgr, rig, reference_bgr=(0, 200, 230))
    cable.points_m, cable.sigma_m, cable.status        # (N, 3), (N, 3), "tracked"/"lost"/"ambiguous"
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from nodes.vision.cable_match import Match, match_in_order, match_row_nearest

__all__ = ["CableResult", "Rectified", "Track", "colour_distance", "reconstruct", "track_cable", "triangulate"]

_HUE = np.arange(180) * (2 * math.pi / 180)
_COS, _SIN = np.cos(_HUE).astype(np.float32), np.sin(_HUE).astype(np.float32)


@dataclass(frozen=True)
class Rectified:
    """What triangulation needs from a rectified pair: focal length and principal point of the
    (shared) rectified intrinsics, and the baseline (right camera at +baseline_m along x)."""

    f_px: float
    cx_px: float
    cy_px: float
    baseline_m: float


def colour_distance(bgr: np.ndarray, reference_bgr: tuple[float, float, float], *, blur_px: float = 1.0,
                    min_value: int = 25) -> np.ndarray:
    """Intensity-invariant distance of every pixel to a reference colour, seed 05 eq. (1)-(3).

    The seed takes the distance between (H, S, 0) vectors with the hue as a plain number, which
    puts a red at hue 179 as far as possible from a red at hue 1. We take the same two channels
    as a point of the chroma disc, (S cos H, S sin H), so the hue wraps and a pixel with no
    saturation (whose hue is noise) is at distance S_ref from the reference, whatever its hue.
    Value is dropped as in the seed (shading and attenuation change it along the cable).

    Parameters
    ----------
    bgr : (H, W, 3) uint8
    reference_bgr : the cable's colour (B, G, R), 0-255.
    blur_px : Gaussian sigma applied first (the seed's high-frequency filter); 0 = none.
    min_value : pixels darker than this (V channel) have no usable colour: distance 2.

    Returns
    -------
    (H, W) float32 in [0, 2]; the cable is a valley.
    """
    img = np.asarray(bgr)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"bgr must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    d = _distance_lut(tuple(int(round(v)) for v in reference_bgr))[hsv[..., 0], hsv[..., 1]]
    d[hsv[..., 2] < min_value] = 2.0
    return d


@lru_cache(maxsize=16)
def _distance_lut(reference_bgr: tuple[int, int, int]) -> np.ndarray:
    """(180, 256) float32: chroma-disc distance from every (hue, saturation) to the reference."""
    ref = cv2.cvtColor(np.uint8([[reference_bgr]]), cv2.COLOR_BGR2HSV)[0, 0]
    s = np.arange(256, dtype=np.float32)[None, :] / 255
    rs = ref[1] / 255
    dx = s * _COS[:, None] - rs * _COS[ref[0]]
    dy = s * _SIN[:, None] - rs * _SIN[ref[0]]
    return np.sqrt(dx * dx + dy * dy).astype(np.float32)


class Field:
    """The potential padded with "no cable" (2.0) all round, so sampling near or past the image
    border needs no clipping: the follower's inner loop is mostly this gather."""

    PAD = 24

    def __init__(self, P: np.ndarray) -> None:
        self.shape = P.shape
        self.padded = np.pad(P.astype(np.float32, copy=False), self.PAD, constant_values=2.0)
        self.flat = self.padded.ravel()
        self.stride = self.padded.shape[1]
        self.limit = np.array([self.padded.shape[1] - 1.001, self.padded.shape[0] - 1.001])

    def sample(self, xy: np.ndarray) -> np.ndarray:
        q = np.minimum(np.maximum(xy + self.PAD, 0.0), self.limit)
        i0 = q.astype(np.intp)
        f = q - i0
        i = i0[:, 1] * self.stride + i0[:, 0]
        flat, fx = self.flat, f[:, 0]
        top = flat[i] + (flat[i + 1] - flat[i]) * fx
        bot = flat[i + self.stride] + (flat[i + self.stride + 1] - flat[i + self.stride]) * fx
        return top + (bot - top) * f[:, 1]


def _sample(P: np.ndarray | Field, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of P at (N, 2) points; outside the image: 2 (no cable)."""
    return (P if isinstance(P, Field) else Field(P)).sample(xy)


def _local_grid(offsets_rad: np.ndarray, step_px: float, section_px: np.ndarray) -> np.ndarray:
    """(C * S, 2) candidate points with their normal sections, for a heading of zero."""
    c, s = np.cos(offsets_rad), np.sin(offsets_rad)
    cand = step_px * np.stack([c, s], axis=1)
    normal = np.stack([-s, c], axis=1)
    return (cand[:, None, :] + section_px[None, :, None] * normal[:, None, :]).reshape(-1, 2)


@dataclass
class Track:
    """One followed stretch of cable: (K, 2) pixel points in tracked order, and how it ended
    ("border", "end": the valley stopped, "gap": lost after bridging an occlusion, "steps")."""

    points_px: np.ndarray
    end: str


@dataclass(frozen=True)
class FollowParams:
    step_px: float = 6.0             # of the sequential follower; the output is refined at spacing_px
    spacing_px: float = 3.0
    max_turn_deg: float = 35.0
    turn_weight: float = 0.15        # potential units for a turn of max_turn (the seed's change of direction)
    valley_max: float = 0.45         # potential above this is not cable
    max_gap_px: float = 40.0         # bridged straight ahead (occluders, a blurred crossing)
    border_px: int = 2


def _border_starts(P: np.ndarray, prm: FollowParams) -> list[tuple[np.ndarray, float]]:
    """Local minima of P below valley_max along the image border: (point, inward angle)."""
    h, w = P.shape
    m = prm.border_px
    # walk the border clockwise: top, right, bottom, left
    xs = np.concatenate([np.arange(m, w - m), np.full(h - 2 * m, w - 1 - m), np.arange(w - 1 - m, m - 1, -1),
                         np.full(h - 2 * m, m)])
    ys = np.concatenate([np.full(w - 2 * m, m), np.arange(m, h - m), np.full(w - 2 * m, h - 1 - m),
                         np.arange(h - 1 - m, m - 1, -1)])
    inward = np.concatenate([np.full(w - 2 * m, math.pi / 2), np.full(h - 2 * m, math.pi),
                             np.full(w - 2 * m, -math.pi / 2), np.full(h - 2 * m, 0.0)])
    v = P[ys, xs]
    low = v < prm.valley_max
    if not low.any():
        return []
    # runs of low values along the (cyclic) border; one start per run, at its minimum
    starts = []
    idx = np.flatnonzero(low)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 3) + 1)
    if len(runs) > 1 and runs[0][0] == 0 and runs[-1][-1] == len(v) - 1:
        runs[0] = np.concatenate([runs[-1], runs[0]])
        runs.pop()
    for r in runs:
        k = r[np.argmin(v[r])]
        starts.append((np.array([xs[k], ys[k]], float), float(inward[k]), float(v[k])))
    starts.sort(key=lambda s: s[2])
    return [(p, a) for p, a, _ in starts]


def _centroid(values: np.ndarray, offsets: np.ndarray, valley_max: float) -> tuple[float, float]:
    """(centroid offset, width) of the valley in one normal section of samples."""
    wgt = valley_max - values
    wgt[wgt < 0] = 0.0
    s = float(wgt.sum())
    if s <= 1e-9:
        return 0.0, 0.0
    c = float(wgt @ offsets) / s
    return max(-2.0, min(2.0, c)), float(np.count_nonzero(wgt)) * float(offsets[1] - offsets[0])


def _section(P: np.ndarray | Field, p: np.ndarray, theta: float, valley_max: float,
             half_width_px: float = 8.0) -> tuple[float, float]:
    """The valley across the track at p: (offset of its centroid along the normal, its width).

    The cable is several pixels wide with a flat floor, so a three-point parabola would wander;
    the centroid of (valley_max - P) over a normal section is unbiased for a symmetric profile.
    The width is what tells a crossing (two cables side by side merge into one wide valley).
    """
    n = np.array([-math.sin(theta), math.cos(theta)])
    off = _OFFSETS * half_width_px
    return _centroid(_sample(P, p[None, :] + off[:, None] * n[None, :]), off, valley_max)


_OFFSETS = np.linspace(-1.0, 1.0, 17)        # a section every pixel over +-8 px


def _normal(theta: float) -> np.ndarray:
    return np.array([-math.sin(theta), math.cos(theta)])


def follow_valley(P: np.ndarray, start: np.ndarray, theta: float, prm: FollowParams = FollowParams(), *,
                  first_turn_deg: float = 80.0) -> Track:
    """Follow the valley of P from ``start`` heading ``theta`` (rad, image x right / y down).

    Each step picks, on an arc of radius step_px around the heading, the point minimising
    potential + turn_weight * (turn / max_turn)^2 (seed 05 section II: potential and change of
    direction), then centres it across the valley. Where the valley gets much wider than the
    cable has been (the cable crossing itself), the track coasts straight through without
    re-centring, so it leaves the crossing on the branch it came in on. Where no candidate is
    below valley_max (an occluder, a gap), it goes straight on for up to max_gap_px and picks
    the valley up again only where it is clearly there; bridged points are not kept. A track
    that comes back onto itself going the same way has closed a loop and stops.
    """
    field = P if isinstance(P, Field) else Field(P)
    P = field
    h, w = field.shape
    turns = np.radians(np.linspace(-prm.max_turn_deg, prm.max_turn_deg, 11))
    wide = np.radians(np.linspace(-first_turn_deg, first_turn_deg, 33))
    sec_off = _OFFSETS * 8.0
    grids = {False: _local_grid(turns, prm.step_px, sec_off), True: _local_grid(wide, prm.step_px, sec_off)}
    penalty_t = prm.turn_weight * (turns / turns[-1]) ** 2
    penalty_w = prm.turn_weight * (wide / turns[-1]) ** 2 * 0.25
    off, _ = _section(P, np.asarray(start, float), theta, prm.valley_max)
    p = np.asarray(start, float) + off * _normal(theta)
    pts, heads = [p], [theta]
    typical, seen = math.inf, 0                   # running cable width in the image
    own = np.full((h, w), -1, np.int32)          # index of the last point that passed each pixel
    gap = coast = 0.0
    inside = lambda q: 0 <= q[0] <= w - 1 and 0 <= q[1] <= h - 1      # noqa: E731
    for k in range(int(6 * (w + h) / prm.step_px)):
        ahead = np.array([math.cos(theta), math.sin(theta)])
        if coast > 0:                                            # inside a crossing: straight on
            q = p + prm.step_px * ahead
            coast -= prm.step_px
            if not inside(q):
                return Track(np.array(pts), "border")
            _, width = _section(P, q, theta, prm.valley_max)
            if width <= 1.3 * typical:
                coast = 0.0
            p = q
            pts.append(p)
            heads.append(theta)
            continue
        offs, pen = (wide, penalty_w) if k == 0 else (turns, penalty_t)
        ang = theta + offs
        # every candidate with its normal section in one sampling call (the loop's cost is calls)
        ct, st = math.cos(theta), math.sin(theta)
        grid = p + grids[k == 0] @ np.array([[ct, st], [-st, ct]])
        vals = field.sample(grid).reshape(len(offs), len(sec_off))
        v = vals[:, len(sec_off) // 2]
        cand = grid.reshape(len(offs), len(sec_off), 2)[:, len(sec_off) // 2]
        j = int(np.argmin(v + pen))
        q = cand[j]
        if not inside(q):
            return Track(np.array(pts), "border")
        if v[j] >= (prm.valley_max if gap == 0 else 0.7 * prm.valley_max):
            gap += prm.step_px
            if gap > prm.max_gap_px:
                return Track(np.array(pts), "gap" if gap > 2 * prm.step_px else "end")
            p = p + prm.step_px * ahead
            if not inside(p):
                return Track(np.array(pts), "border")
            continue
        off, width = _centroid(vals[j], sec_off, prm.valley_max)
        if width > 1.3 * typical:
            # a crossing (or the start of one): go straight on along the chord of the last
            # few points, not the heading the widening valley has already bent
            coast = 3 * typical
            if len(pts) > 8:
                chord = pts[-1] - pts[-8]
                theta = math.atan2(chord[1], chord[0])
            q = p + prm.step_px * np.array([math.cos(theta), math.sin(theta)])
        else:
            seen += 1
            typical = width if seen == 1 else (typical + 0.15 * (width - typical) if seen > 1 else width)
            if seen < 4:
                typical = max(typical, width)
            q = q + off * _normal(float(ang[j]))
            d = q - p
            new = math.atan2(d[1], d[0])
            theta = theta + 0.5 * math.remainder(new - theta, 2 * math.pi) if k else new
        gap = 0.0
        p = q
        pts.append(p)
        heads.append(theta)
        x, y = int(p[0]), int(p[1])
        prev = own[y, x]
        if prev >= 0 and len(pts) - prev > 20 and math.cos(theta - heads[prev]) > 0.7:
            return Track(np.array(pts[:-1]), "loop")
        own[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2] = len(pts) - 1
    return Track(np.array(pts), "steps")


_RAYS = np.linspace(0, math.pi, 16, endpoint=False)
_RAY_STEPS = np.arange(-12.0, 12.5, 1.0)


def _valley_direction(field: Field, p: np.ndarray) -> float:
    """The direction along the valley at p: of 16 lines through p (24 px), the one whose mean
    potential is lowest. (The gradient is useless here: p is a minimum, where it vanishes.)"""
    d = np.stack([np.cos(_RAYS), np.sin(_RAYS)], axis=1)
    pts = p + _RAY_STEPS[None, :, None] * d[:, None, :]
    means = field.sample(pts.reshape(-1, 2)).reshape(len(_RAYS), -1).mean(axis=1)
    return float(_RAYS[int(np.argmin(means))])


def _visited(mask: np.ndarray, pts: np.ndarray, radius: int) -> None:
    cv2.polylines(mask, [np.round(pts).astype(np.int32)], False, 1, 2 * radius + 1)


def track_cable(P: np.ndarray, prm: FollowParams = FollowParams(), *, min_length_px: float = 30.0) -> list[Track]:
    """Every stretch of cable in the image: followed from each border start not already on a
    track (a cable leaving the image and coming back gives two stretches), or, when the cable
    touches no border, from the deepest point of the valley in both directions."""
    visited = np.zeros(P.shape, np.uint8)
    tracks: list[Track] = []
    field = Field(P)
    for start, inward in _border_starts(P, prm):
        x, y = int(round(start[0])), int(round(start[1]))
        if visited[y, x]:
            continue
        t = follow_valley(field, start, inward, prm)
        t.points_px = refine_polyline(field, t.points_px, prm)
        _visited(visited, t.points_px, 8)
        if _length(t.points_px) >= min_length_px:
            tracks.append(t)
    # stretches with both ends inside the image (or missed from the border): start at the deepest
    # unvisited valley point and follow it both ways, until no deep valley is left
    # "deep": well inside the valley; a thin far cable (blurred into its background) never gets
    # as deep as a near one, so the bar follows the deepest point when that is shallow
    bar = min(0.9 * prm.valley_max, max(0.6 * prm.valley_max, float(P.min()) + 0.08))
    deep = ((P < bar) & (visited == 0)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(deep, connectivity=8)
    order = np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1
    for lab in order[:8]:
        if stats[lab, cv2.CC_STAT_AREA] < min_length_px:
            break
        comp = labels == lab
        if not (comp & (visited == 0)).any():
            continue
        flat = np.where(comp & (visited == 0), P, np.inf)
        y, x = np.unravel_index(int(np.argmin(flat)), P.shape)
        theta = _valley_direction(field, np.array([x, y], float))
        a = follow_valley(field, np.array([x, y], float), theta + math.pi, prm, first_turn_deg=20)
        b = follow_valley(field, np.array([x, y], float), theta, prm, first_turn_deg=20)
        pts = refine_polyline(field, np.vstack([a.points_px[::-1], b.points_px[1:]]), prm)
        _visited(visited, pts, 8)
        if _length(pts) >= min_length_px:
            tracks.append(Track(pts, b.end))
    return tracks


def refine_polyline(P: np.ndarray | Field, pts: np.ndarray, prm: FollowParams) -> np.ndarray:
    """Resample a followed track every ``spacing_px`` and centre every sample across the valley
    in one vectorised pass (the sequential follower only has to make the decisions). Jumps
    longer than 1.5 steps (bridged occlusions) stay jumps: nothing is invented behind them.
    Where the section is much wider than the cable (a crossing) the sample is not moved."""
    if len(pts) < 2:
        return pts
    jumps = np.flatnonzero(np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1.5 * prm.step_px) + 1
    pieces = []
    for piece in np.split(pts, jumps):
        if len(piece) < 2:
            pieces.append(piece)
            continue
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(piece, axis=0), axis=1))])
        s = np.arange(0, arc[-1] + 1e-9, prm.spacing_px)
        q = np.stack([np.interp(s, arc, piece[:, 0]), np.interp(s, arc, piece[:, 1])], axis=1)
        if len(q) >= 3:
            g = np.gradient(q, axis=0)
            g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
            n = np.stack([-g[:, 1], g[:, 0]], axis=1)
            off = _OFFSETS * 8.0
            vals = _sample(P, (q[:, None, :] + off[None, :, None] * n[:, None, :]).reshape(-1, 2)).reshape(len(q), -1)
            wgt = np.maximum(prm.valley_max - vals, 0.0)
            tot = wgt.sum(axis=1)
            shift = np.clip((wgt * off).sum(axis=1) / np.maximum(tot, 1e-9), -2.0, 2.0)
            width = (wgt > 0).sum(axis=1) * (off[1] - off[0])
            typical = np.median(width[tot > 0]) if (tot > 0).any() else 0.0
            move = (tot > 0) & (width <= 1.3 * typical)
            q = q + np.where(move, shift, 0.0)[:, None] * n
        pieces.append(q)
    return np.vstack(pieces)


def _length(pts: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) if len(pts) > 1 else 0.0


@dataclass
class CableResult:
    """A reconstructed cable. ``points_m`` (N, 3) left-camera frame in tracked order,
    ``sigma_m`` (N, 3) one-sigma per axis, ``segment`` (N,) which left track each point is on,
    ``left_px`` (N, 2) the tracked left-image points. ``status``: tracked / lost / ambiguous."""

    points_m: np.ndarray
    sigma_m: np.ndarray
    segment: np.ndarray
    left_px: np.ndarray
    status: str
    reason: str = ""
    tracks_left: list[Track] = field(default_factory=list)
    tracks_right: list[Track] = field(default_factory=list)
    usable_frac: float = 0.0


def triangulate(left_px: np.ndarray, disparity_px: np.ndarray, sigma_d_px: np.ndarray, rect: Rectified,
                *, sigma_px: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Seed 05 eq. (4)-(6) with principal point: z = b f / d, x = (u - cx) z / f, y = (v - cy) z / f.

    One-sigma per axis by first-order propagation: sigma_z = z^2 sigma_d / (b f); x and y get
    their share of sigma_z plus the image localisation ``sigma_px``. Non-positive disparities
    (a point at or beyond infinity) are refused with NaN rows, never a negative depth.
    """
    d = np.asarray(disparity_px, float)
    ok = d > 1e-6
    z = np.where(ok, rect.baseline_m * rect.f_px / np.where(ok, d, 1.0), np.nan)
    u = left_px[:, 0] - rect.cx_px
    v = left_px[:, 1] - rect.cy_px
    pts = np.stack([u * z / rect.f_px, v * z / rect.f_px, z], axis=1)
    sz = z * z * np.asarray(sigma_d_px, float) / (rect.baseline_m * rect.f_px)
    sx = np.hypot(np.abs(u) / rect.f_px * sz, sigma_px * z / rect.f_px)
    sy = np.hypot(np.abs(v) / rect.f_px * sz, sigma_px * z / rect.f_px)
    return pts, np.stack([sx, sy, sz], axis=1)


def _depth_jumps(pts: np.ndarray, sig: np.ndarray, seg: np.ndarray) -> int:
    """Depth steps between consecutive points of a stretch larger than 5 sigma and 0.15 m: a
    cable is continuous, so a stretch matched on the wrong branch starts and ends with one."""
    same = seg[1:] == seg[:-1]
    dz = np.abs(np.diff(pts[:, 2]))
    lim = np.maximum(5 * np.hypot(sig[1:, 2], sig[:-1, 2]), 0.15)
    return int(np.count_nonzero(same & (dz > lim)))


def reconstruct(left_bgr: np.ndarray, right_bgr: np.ndarray, rect: Rectified, *,
                reference_bgr: tuple[float, float, float], prm: FollowParams = FollowParams(),
                depth_range_m: tuple[float, float] = (0.5, 10.0), sigma_px: float = 0.3,
                min_angle_deg: float = 10.0, matching: str = "order", min_points: int = 20) -> CableResult:
    """Track the cable in both images, match the curves (``matching``: "order", the default, or
    "row" for the nearest-point-per-row baseline) and triangulate.

    Points where either curve runs within ``min_angle_deg`` of the image rows (the epipolar
    lines) get no depth: the row crossing that fixes the disparity is ill-conditioned there.
    """
    Pl = colour_distance(left_bgr, reference_bgr)
    Pr = colour_distance(right_bgr, reference_bgr)
    tl, tr = track_cable(Pl, prm), track_cable(Pr, prm)
    empty = CableResult(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros((0, 2)), "lost",
                        tracks_left=tl, tracks_right=tr)
    if not tl or not tr:
        empty.reason = f"no cable found in the {'left' if not tl else 'right'} image"
        return empty
    d_lo = rect.baseline_m * rect.f_px / depth_range_m[1]
    d_hi = rect.baseline_m * rect.f_px / depth_range_m[0]
    matches: list[Match] = []
    for i, t in enumerate(tl):
        if matching == "order":
            m = match_in_order(t.points_px, [r.points_px for r in tr], (d_lo, d_hi), sigma_px=sigma_px,
                               min_angle_deg=min_angle_deg)
        elif matching == "row":
            m = match_row_nearest(t.points_px, [r.points_px for r in tr], (d_lo, d_hi), sigma_px=sigma_px)
        else:
            raise ValueError(f"matching must be 'order' or 'row', got {matching!r}")
        m.segment = i
        matches.append(m)
    keep = [m for m in matches if m.ok.any()]
    total = sum(len(m.ok) for m in matches)
    usable = sum(int(m.ok.sum()) for m in matches)
    if usable < min_points:
        empty.status = "ambiguous" if total >= min_points else "lost"
        empty.reason = (f"only {usable} of {total} tracked points have a well-conditioned match"
                        " (cable along the epipolar lines, or no consistent right curve)")
        empty.usable_frac = usable / max(total, 1)
        return empty
    left = np.vstack([tl[m.segment].points_px[m.ok] for m in keep])
    disp = np.concatenate([m.disparity_px[m.ok] for m in keep])
    sd = np.concatenate([m.sigma_d_px[m.ok] for m in keep])
    seg = np.concatenate([np.full(int(m.ok.sum()), m.segment, np.int32) for m in keep])
    pts, sig = triangulate(left, disp, sd, rect, sigma_px=sigma_px)
    ambiguous = [m for m in keep if m.ambiguous]
    jumps = _depth_jumps(pts, sig, seg)
    status, reason = "tracked", ""
    if ambiguous or usable < 0.3 * total or jumps >= 2:
        status = "ambiguous"
        reason = ("another right curve fits as well" if ambiguous else
                  f"{usable} of {total} points usable (cable along the epipolar lines)" if usable < 0.3 * total else
                  f"the 3-D curve jumps in depth {jumps} times (the two images were followed differently)")
    return CableResult(pts, sig, seg, left, status, reason, tl, tr, usable / total)
