"""Feature matches between two images (ORB or SIFT, ratio test, mutual best), for geometry.

SURF, the seed's third detector, is patented: pip's opencv-contrib build has
``cv2.xfeatures2d.SURF_create`` but it raises "not implemented" (non-free); ORB and SIFT (free
since 2020) are what is available."""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["Features", "detect", "match"]

METHODS = ("orb", "sift")


class Features:
    """Keypoints (N, 2) px and descriptors of one image, with the norm to compare them."""

    def __init__(self, points: np.ndarray, descriptors: np.ndarray | None, norm: int) -> None:
        self.points = points
        self.descriptors = descriptors
        self.norm = norm


def _grey(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        raise ValueError(f"images must be uint8, got {img.dtype}")
    return img


def detect(image: np.ndarray, *, method: str = "orb", n_features: int = 2000) -> Features:
    """Keypoints and descriptors; ``method`` "orb" (binary, fast) or "sift" (float, slower)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS} (SURF is not in pip OpenCV), got {method!r}")
    grey = _grey(image)
    if method == "orb":
        det, norm = cv2.ORB_create(nfeatures=n_features, fastThreshold=10), cv2.NORM_HAMMING
    else:
        det, norm = cv2.SIFT_create(nfeatures=n_features), cv2.NORM_L2
    kp, desc = det.detectAndCompute(grey, None)
    pts = np.array([k.pt for k in kp], np.float64).reshape(-1, 2)
    return Features(pts, desc, norm)


def match(a: Features, b: Features, *, ratio: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Correspondences (pts_a, pts_b), each (M, 2): Lowe's ratio test both ways, mutual best only."""
    if a.descriptors is None or b.descriptors is None or len(a.points) < 2 or len(b.points) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    bf = cv2.BFMatcher(a.norm)

    def one_way(x, y):
        best = {}
        for pair in bf.knnMatch(x.descriptors, y.descriptors, k=2):
            if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance:
                best[pair[0].queryIdx] = pair[0].trainIdx
        return best

    ab, ba = one_way(a, b), one_way(b, a)
    keep = [(i, j) for i, j in ab.items() if ba.get(j) == i]
    if not keep:
        return np.zeros((0, 2)), np.zeros((0, 2))
    ia, ib = np.array(keep).T
    return a.points[ia], b.points[ib]
