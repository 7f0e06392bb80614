"""Registration of a UAV's nadir frame to a geo-referenced map image (seed 11): features (SIFT,
ORB or AKAZE; SURF, the seed's choice, is patented: pip's opencv-contrib has
``xfeatures2d.SURF_create`` but it raises "not implemented" without the non-free build), Lowe's ratio test, a
RANSAC similarity (``cv2.estimateAffinePartial2D``), the seed's eq. (2.1)-(2.4) parameters
alpha, theta, b, and the checks that turn a bad match into no fix rather than a wrong one.

The frame is first scaled to the map's ground resolution from the altitude (a frame much finer
than the map otherwise fails: its features live at scales the map does not have). Localisation
mode matches against the map's features in a window around the predicted position; search mode
against the whole map, trying the frame at several scales (a pyramid) when the altitude or
the map's resolution is uncertain.

    mf = MapFeatures.of(map_bgr, method="sift")
    fix = register(frame_bgr, mf, prescale=0.4)               # prescale: map px per frame px
    fix.ok, fix.centre_px, fix.theta_rad, fix.alpha, fix.cov_px
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["GeoFix", "MapFeatures", "decompose", "register"]

METHODS = ("sift", "orb", "akaze")


def _detector(method: str, n: int):
    if method == "sift":
        return cv2.SIFT_create(nfeatures=n), cv2.NORM_L2
    if method == "orb":
        return cv2.ORB_create(nfeatures=n, fastThreshold=10), cv2.NORM_HAMMING
    if method == "akaze":           # OpenCV 5 moved it to xfeatures2d; 4.x has it at the top level
        make = getattr(cv2, "AKAZE_create", None) or cv2.xfeatures2d.AKAZE_create
        return make(), cv2.NORM_HAMMING
    raise ValueError(f"method must be one of {METHODS} (SURF is not in pip OpenCV), got {method!r}")


def _grey(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


@dataclass
class MapFeatures:
    """The map's keypoints (N, 2) px and descriptors, detected once."""

    points: np.ndarray
    descriptors: np.ndarray | None
    norm: int
    method: str
    shape: tuple[int, int]

    @classmethod
    def of(cls, map_img: np.ndarray, *, method: str = "sift", n_features: int = 20000) -> "MapFeatures":
        det, norm = _detector(method, n_features)
        kp, desc = det.detectAndCompute(_grey(map_img), None)
        return cls(np.array([k.pt for k in kp], np.float64).reshape(-1, 2), desc, norm, method, map_img.shape[:2])

    def window(self, box: tuple[float, float, float, float]) -> "MapFeatures":
        """The features inside (x0, y0, x1, y1) map px."""
        x0, y0, x1, y1 = box
        m = (self.points[:, 0] >= x0) & (self.points[:, 0] <= x1) & (self.points[:, 1] >= y0) & (self.points[:, 1] <= y1)
        return MapFeatures(self.points[m], None if self.descriptors is None else self.descriptors[m], self.norm,
                           self.method, self.shape)


@dataclass
class GeoFix:
    """A registration: ``T`` (2x3) maps frame px (original resolution) to map px; the frame
    centre in the map, theta (rad, image axes: y down, so positive turns clockwise on screen),
    alpha (map px per frame px), inliers, and a 2x2 covariance of the centre (map px^2).
    ``ok`` False: no fix, with ``reason``."""

    ok: bool
    reason: str = ""
    T: np.ndarray = field(default_factory=lambda: np.full((2, 3), np.nan))
    centre_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    theta_rad: float = math.nan
    alpha: float = math.nan
    inliers: int = 0
    matches: int = 0
    cov_px: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.inf))
    prescale: float = 1.0
    ms: float = 0.0


def decompose(T: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(alpha, theta, b) of a similarity [[a, -s, bx], [s, a, by]] (seed 11 eq. 2.2).

    The seed takes theta = arctan(T12 / mean(T11, T22)): T12 is -alpha sin(theta), so that is
    minus the angle, and an arctan of a ratio cannot tell theta from theta + 180 degrees (a
    frame upside down). atan2 of the averaged sine and cosine parts keeps sign and quadrant.
    """
    c = 0.5 * (T[0, 0] + T[1, 1])
    s = 0.5 * (T[1, 0] - T[0, 1])
    return float(math.hypot(c, s)), float(math.atan2(s, c)), T[:, 2].copy()


def _match(desc_a, desc_b, norm: int, ratio: float) -> list[tuple[int, int]]:
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return []
    bf = cv2.BFMatcher(norm)
    out = []
    for pair in bf.knnMatch(desc_a, desc_b, k=2):
        if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance:
            out.append((pair[0].queryIdx, pair[0].trainIdx))
    return out


def _register_once(frame: np.ndarray, mf: MapFeatures, prescale: float, *, ratio: float, min_inliers: int,
                   alpha_range: tuple[float, float], ransac_px: float, n_features: int) -> GeoFix:
    small = cv2.resize(frame, None, fx=prescale, fy=prescale, interpolation=cv2.INTER_AREA if prescale < 1
                       else cv2.INTER_LINEAR) if abs(prescale - 1) > 1e-3 else frame
    det, _ = _detector(mf.method, n_features)
    kp, desc = det.detectAndCompute(small, None)
    if len(kp) < 3:
        return GeoFix(False, f"{len(kp)} features in the frame (uniform texture?)", prescale=prescale)
    pts = np.array([k.pt for k in kp], np.float64)
    m = _match(desc, mf.descriptors, mf.norm, ratio)
    if len(m) < max(min_inliers, 3):
        return GeoFix(False, f"{len(m)} matches pass the ratio test (< {min_inliers})", matches=len(m), prescale=prescale)
    a = pts[[i for i, _ in m]]
    b = mf.points[[j for _, j in m]]
    S, inl = cv2.estimateAffinePartial2D(a, b, method=cv2.RANSAC, ransacReprojThreshold=ransac_px, maxIters=5000,
                                         confidence=0.999, refineIters=10)
    if S is None:
        return GeoFix(False, "RANSAC found no similarity", matches=len(m), prescale=prescale)
    inl = inl.ravel().astype(bool)
    n_in = int(inl.sum())
    alpha, theta, _ = decompose(S)
    # back to the frame's own pixels: x_map = S (prescale x_frame)
    T = S.copy()
    T[:, :2] *= prescale
    det_ = float(np.linalg.det(T[:, :2]))
    fix = GeoFix(False, "", T, inliers=n_in, matches=len(m), prescale=prescale, alpha=alpha, theta_rad=theta)
    if det_ <= 0:
        fix.reason = "mirror-image match (det <= 0)"
        return fix
    if n_in < min_inliers:
        fix.reason = f"{n_in} inliers (< {min_inliers})"
        return fix
    if not alpha_range[0] <= alpha <= alpha_range[1]:
        fix.reason = f"scale {alpha:.2f} outside {alpha_range} after prescaling (wrong altitude, or a false match)"
        return fix
    h, w = frame.shape[:2]
    centre = T @ np.array([(w - 1) / 2, (h - 1) / 2, 1.0])
    res = (a[inl] @ S[:, :2].T + S[:, 2]) - b[inl]
    sigma2 = float(np.mean(res ** 2)) / 2 if n_in > 2 else ransac_px ** 2
    spread = np.cov((a[inl] @ S[:, :2].T).T) if n_in > 2 else np.eye(2)
    # centre covariance: noise over the inliers, plus the lever arm of the rotation/scale error
    cov = sigma2 / n_in * (np.eye(2) + (h * w * prescale ** 2 / 12) / max(np.trace(spread), 1e-9) * np.eye(2))
    fix.ok, fix.centre_px, fix.cov_px = True, centre, cov
    return fix


def register(frame: np.ndarray, mf: MapFeatures, *, prescale: float = 1.0, window: tuple | None = None,
             pyramid: tuple[float, ...] = (1.0,), ratio: float = 0.8, min_inliers: int = 12,
             alpha_range: tuple[float, float] = (0.6, 1.6), ransac_px: float = 3.0, n_features: int = 3000) -> GeoFix:
    """Register a frame (grey or BGR) to the map: localisation mode with ``window`` (map px box
    around the predicted position), search mode without it; ``pyramid`` multiplies the prescale
    (search mode tries each and keeps the fix with most inliers)."""
    t0 = time.perf_counter()
    g = _grey(np.asarray(frame))
    if g.size == 0 or float(g.std()) < 1.0:
        return GeoFix(False, "uniform frame: nothing to match", ms=1000 * (time.perf_counter() - t0))
    feats = mf.window(window) if window is not None else mf
    best = None
    for k in pyramid:
        fix = _register_once(g, feats, prescale * k, ratio=ratio, min_inliers=min_inliers, alpha_range=alpha_range,
                             ransac_px=ransac_px, n_features=n_features)
        if best is None or (fix.ok and (not best.ok or fix.inliers > best.inliers)) or (not best.ok and fix.inliers > best.inliers):
            best = fix
    best.ms = 1000 * (time.perf_counter() - t0)
    return best
