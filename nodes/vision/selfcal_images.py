"""Self-calibration of a camera from a set of image files (what ``tether selfcal`` runs).

General scenes: features matched between neighbouring images -> F or H per pair -> Kruppa or
the infinite homography. A chessboard (or any plane whose points are found in the same order in
every view): its corners are correspondences, the plane's size is not used -> lens distortion
from the same correspondences, then the planar self-calibration (circular points).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.vision.features import detect, match
from nodes.vision.planar_selfcal import estimate_division, homographies, planar_selfcal, undistort_division
from nodes.vision.selfcal import Calibration, pair_geometry, self_calibrate

__all__ = ["calibrate_chessboard", "calibrate_images", "chessboard_views", "read_images"]


def read_images(paths: list[str | Path]) -> list[np.ndarray]:
    images = []
    for p in paths:
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{p}: not an image OpenCV can read")
        images.append(img)
    sizes = {im.shape for im in images}
    if len(sizes) > 1:
        raise ValueError(f"images of different sizes {sorted(sizes)}: one camera, one size")
    return images


def calibrate_images(images: list[np.ndarray], *, features: str = "sift", gap: int = 2, sigma_px: float = 1.0,
                     principal_point: tuple[float, float] | None = None) -> tuple[Calibration, list[dict]]:
    """Kruppa (or rotation) self-calibration from a sequence; returns the calibration and one
    summary per pair (views, matches, model, inliers)."""
    if len(images) < 3:
        raise ValueError(f"{len(images)} images: self-calibration needs at least three views")
    feats = [detect(im, method=features) for im in images]
    pairs, summary = [], []
    for i in range(len(images)):
        for j in range(i + 1, min(i + 1 + gap, len(images))):
            a, b = match(feats[i], feats[j])
            g = pair_geometry(a, b, sigma_px=sigma_px, seed=i * 1000 + j)
            pairs.append(g)
            summary.append({"views": [i, j], "matches": g.n_matches, "model": g.model,
                            "inliers_F": g.inliers_F, "inliers_H": g.inliers_H})
    h, w = images[0].shape[:2]
    return self_calibrate(pairs, (w, h), principal_point=principal_point), summary


def chessboard_views(images: list[np.ndarray], pattern: tuple[int, int]) -> tuple[list[np.ndarray], list[int]]:
    """Inner corners (N, 2) of each image where the whole pattern is found, sub-pixel refined,
    and the indices of those images. Only the order of the corners is used, never their spacing."""
    views, used = [], []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    for k, im in enumerate(images):
        try:
            found, corners = cv2.findChessboardCorners(im, pattern, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        except cv2.error:         # an image too small for OpenCV's thresholds holds no board: counted as not found
            found = False
        if not found:
            continue
        corners = cv2.cornerSubPix(im, corners, (11, 11), (-1, -1), crit)
        views.append(corners.reshape(-1, 2).astype(np.float64))
        used.append(k)
    return views, used


def calibrate_chessboard(images: list[np.ndarray], pattern: tuple[int, int], *,
                         distortion: bool = True) -> tuple[Calibration, dict]:
    """Planar self-calibration from the corners' correspondences alone (no square size, no
    board model): the division-model distortion first (``distortion``), then the circular points."""
    views, used = chessboard_views(images, pattern)
    if len(views) < 4:
        raise ValueError(f"the {pattern[0]}x{pattern[1]} pattern was found in {len(views)} images; at least 4 are needed")
    h, w = images[0].shape[:2]
    lam, centre, scale = estimate_division(views, (w, h)) if distortion else (0.0, ((w - 1) / 2, (h - 1) / 2), (w + h) / 2)
    undist = [undistort_division(v, lam, centre, scale) for v in views]
    cal = planar_selfcal(homographies(undist), (w, h))
    return cal, {"views_used": used, "division_lambda": lam, "division_scale_px": scale}
