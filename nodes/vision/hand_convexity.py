"""Finger counting the classic OpenCV way (seed 13, its reference [2]): skin segmentation
(YCrCb bounds, the Cr bound raised to Otsu's threshold), the largest contour, its convex hull
and convexity defects, the defects kept by their angle and their depth relative to the palm
radius (the distance transform's maximum).

The well-known failure modes are handled explicitly rather than by luck:

- the forearm is not a finger: the blob's pixels on the image border give the arm's direction
  from the palm centre, and hull points in that cone are never fingertips;
- 0 against 1: with no valid defect there is still one finger when a hull point outside the
  arm cone reaches ``tip_frac`` palm radii from the centre (a fist's knuckles do not);
- a defect counts only between two fingertip-like hull points (both beyond ``tip_frac``
  radii), so the valley between a pointing finger and the fist's knuckles is not a second
  finger.

Fingers held together (no valley between them) still count as one: the method cannot see them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["ConvexityResult", "count_fingers", "segment_skin"]


@dataclass(frozen=True)
class ConvexityResult:
    """``count`` fingers; ``present`` False when no blob is large enough (then count 0);
    ``tips_px`` (K, 2) fingertips, ``valleys_px`` (D, 2) accepted defects' deepest points,
    ``palm_px`` (2,) palm centre, ``palm_radius_px``; ``arm_dir`` (2,) unit vector or zeros;
    ``confidence`` in [0, 1] (a heuristic: how far the farthest reach outside the arm cone
    was from the fingertip threshold); ``reason`` when absent."""

    count: int
    present: bool
    tips_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    valleys_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    palm_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    palm_radius_px: float = 0.0
    arm_dir: np.ndarray = field(default_factory=lambda: np.zeros(2))
    confidence: float = 0.0
    reason: str = ""


def segment_skin(image: np.ndarray, *, cr: tuple[int, int] = (133, 180), cb: tuple[int, int] = (75, 135),
                 adaptive: bool = True) -> np.ndarray:
    """Skin mask (H, W) uint8 {0, 255} from YCrCb bounds, opened and closed.

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR. A mono image has no colour to segment: a ``ValueError``.
    cr, cb : inclusive bounds on the (blurred) Cr and Cb channels.
    adaptive : raise the lower Cr bound to Otsu's threshold of the Cr histogram when that is
        higher (a reddish background or a warm cast would otherwise flood the mask).
    """
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"segment_skin needs a BGR image (H, W, 3), got shape {image.shape}; pass mask= for mono")
    ycc = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)
    crc = cv2.GaussianBlur(ycc[..., 1], (5, 5), 0)
    lo = cr[0]
    if adaptive:
        otsu, _ = cv2.threshold(crc, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        lo = max(lo, int(otsu))
    mask = ((crc >= lo) & (crc <= cr[1]) & (ycc[..., 2] >= cb[0]) & (ycc[..., 2] <= cb[1])).astype(np.uint8) * 255
    k = np.ones((3, 3), np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, k)
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, k, iterations=2)


def _arm_direction(blob: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Unit vector from the palm centre toward the blob's pixels on the image border (zeros if none)."""
    h, w = blob.shape
    edge = np.zeros_like(blob, bool)
    edge[[0, -1], :] = True
    edge[:, [0, -1]] = True
    ys, xs = np.nonzero((blob > 0) & edge)
    if len(xs) < 3:
        return np.zeros(2)
    d = np.array([xs.mean(), ys.mean()]) - centre
    n = float(np.hypot(*d))
    return d / n if n > 0 else np.zeros(2)


def count_fingers(image: np.ndarray | None = None, *, mask: np.ndarray | None = None, min_area_frac: float = 0.02,
                  max_angle_deg: float = 95.0, depth_frac: float = 0.5, tip_frac: float = 1.9,
                  arm_cone_deg: float = 55.0) -> ConvexityResult:
    """Count raised fingers in ``image`` (BGR) or a given skin ``mask``.

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR, segmented by :func:`segment_skin`; or None with ``mask``.
    mask : (H, W) uint8, nonzero = hand (overrides the segmentation).
    min_area_frac : a blob smaller than this fraction of the image is no hand.
    max_angle_deg : a defect's angle (between its start and end, at its deepest point) must be below.
    depth_frac : a defect must be deeper than this many palm radii.
    tip_frac : a fingertip lies beyond this many palm radii from the palm centre.
    arm_cone_deg : half-angle of the cone around the arm's direction where no fingertip is looked for.

    Returns
    -------
    ConvexityResult
    """
    if mask is None:
        if image is None:
            raise ValueError("give an image or a mask")
        mask = segment_skin(image)
    mask = np.asarray(mask)
    h, w = mask.shape[:2]
    contours, _ = cv2.findContours((mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return ConvexityResult(0, False, reason="no skin-coloured pixels")
    cnt = max(contours, key=cv2.contourArea)
    if cv2.contourArea(cnt) < min_area_frac * h * w:
        return ConvexityResult(0, False, reason="largest skin blob too small for a hand")
    blob = np.zeros((h, w), np.uint8)
    cv2.drawContours(blob, [cnt], -1, 255, -1)
    dt = cv2.distanceTransform(blob, cv2.DIST_L2, 5)
    r = float(dt.max())
    cy, cx = np.unravel_index(int(np.argmax(dt)), dt.shape)
    centre = np.array([cx, cy], float)
    arm = _arm_direction(blob, centre)
    pts = cnt[:, 0, :].astype(float)
    rel = pts - centre
    dist = np.hypot(rel[:, 0], rel[:, 1])
    cos_arm = (rel @ arm) / np.maximum(dist, 1e-9)
    tipish = (dist > tip_frac * r) & (cos_arm < np.cos(np.radians(arm_cone_deg)))
    hull = cv2.convexHull(cnt, returnPoints=False)
    valleys, tips = [], []
    if len(hull) > 3:
        defects = None
        for order in (hull, hull[::-1]):                      # OpenCV wants the hull's own orientation
            try:
                defects = cv2.convexityDefects(cnt, order)
                break
            except cv2.error:
                continue
        for s, e, f, d in ([] if defects is None else defects.reshape(-1, 4)):
            a, b, c = pts[s], pts[e], pts[f]
            u, v = a - c, b - c
            cosang = float(u @ v / max(np.hypot(*u) * np.hypot(*v), 1e-9))
            if d / 256.0 < depth_frac * r or cosang < np.cos(np.radians(max_angle_deg)) or not (tipish[s] and tipish[e]):
                continue
            valleys.append(c)
            tips += [a, b]
    tips = _merge(np.array(tips).reshape(-1, 2), 0.8 * r)
    if len(tips) == 0 and tipish.any():                      # no valley: one finger, or none (0 vs 1)
        tips = pts[[int(np.argmax(np.where(tipish, dist, -1)))]]
    margin = float(np.max(dist[~(cos_arm > np.cos(np.radians(arm_cone_deg)))], initial=0.0)) / max(r, 1e-9)
    conf = float(np.clip(abs(margin - tip_frac) / tip_frac, 0.0, 1.0)) * 0.5 + 0.5
    return ConvexityResult(min(len(tips), 5), True, tips, np.array(valleys).reshape(-1, 2), centre, r, arm, conf)


def _merge(points: np.ndarray, radius: float) -> np.ndarray:
    """Points closer than ``radius`` merged into their first (greedy)."""
    kept: list[np.ndarray] = []
    for p in points:
        if all(np.hypot(*(p - q)) >= radius for q in kept):
            kept.append(p)
    return np.array(kept).reshape(-1, 2)
