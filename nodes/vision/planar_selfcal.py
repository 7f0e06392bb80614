"""Self-calibration from views of an unknown plane (Triggs 1998): correspondences between images
of a planar scene -- a chessboard whose size nobody wrote down, a floor, a wall -- give
homographies, not fundamental matrices, so the Kruppa equations do not apply; the plane's two
circular points do. Their images in view 0 lie on the image of the absolute conic w and on
the plane's vanishing line; mapped by each inter-view homography they must stay on w.

Unknowns: fx, fy, cx, cy (zero skew) and the plane's normal in view 0 (two angles). No metric
knowledge of the plane is used -- only which point is which in every view. Lens distortion is
estimated first from the same correspondences (a one-parameter division model chosen so that
the inter-view maps become homographies), since a wide lens bends the homographies otherwise.

    lam, centre, scale = estimate_division(views, (640, 480))     # views: list of (N, 2) pixel arrays
    Hs = homographies([undistort_division(v, lam, centre, scale) for v in views])
    cal = planar_selfcal(Hs, image_size=(640, 480))
"""
from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from nodes.vision.selfcal import Calibration, _K, _normaliser, _prior_K

__all__ = ["estimate_division", "homographies", "planar_selfcal", "undistort_division"]


def undistort_division(pts: np.ndarray, lam: float, centre: tuple[float, float], scale: float) -> np.ndarray:
    """Fitzgibbon's division model: x_u = c + (x_d - c) / (1 + lam r^2), r in units of ``scale`` px."""
    c = np.asarray(centre, float)
    d = (np.asarray(pts, float) - c) / scale
    r2 = (d ** 2).sum(axis=1, keepdims=True)
    return c + scale * d / (1 + lam * r2)


def homographies(views: list[np.ndarray]) -> list[np.ndarray]:
    """Least-squares (DLT, normalised) homographies from view 0 to every other view."""
    out = []
    for v in views[1:]:
        H, _ = cv2.findHomography(views[0], v, 0)
        out.append(H / H[2, 2])
    return out


def _homography_rms(views: list[np.ndarray]) -> float:
    err = []
    for v, H in zip(views[1:], homographies(views)):
        p = cv2.perspectiveTransform(views[0].reshape(-1, 1, 2), H).reshape(-1, 2)
        err.append(((p - v) ** 2).sum(axis=1))
    return float(np.sqrt(np.mean(np.concatenate(err))))


def estimate_division(views: list[np.ndarray], image_size: tuple[int, int]) -> tuple[float, tuple[float, float], float]:
    """The division-model parameter (about the image centre) that makes the views of a plane
    most exactly related by homographies; (lam, centre, scale) for :func:`undistort_division`."""
    w, h = image_size
    centre, scale = ((w - 1) / 2, (h - 1) / 2), (w + h) / 2
    cost = lambda lam: _homography_rms([undistort_division(v, lam, centre, scale) for v in views])   # noqa: E731
    res = minimize_scalar(cost, bounds=(-1.0, 1.0), method="bounded", options={"xatol": 1e-5})
    return float(res.x), centre, scale


def _circular_point(K: np.ndarray, n: np.ndarray) -> np.ndarray:
    """One image (complex 3-vector) of the circular points of the plane with normal n (view 0)."""
    Ki = np.linalg.inv(K)
    w = Ki.T @ Ki
    line = Ki.T @ n                           # the plane's vanishing line
    _, _, Vt = np.linalg.svd(line[None, :])
    a, b = Vt[1], Vt[2]                       # two points spanning the line
    A, B, C = b @ w @ b, a @ w @ b, a @ w @ a
    t = (-B + 1j * math.sqrt(max(A * C - B * B, 0.0))) / A
    x = a + t * b
    return x / np.linalg.norm(x)


def _normal(angles: np.ndarray) -> np.ndarray:
    ax, ay = angles
    return np.array([math.sin(ay) * math.cos(ax), -math.sin(ax), math.cos(ay) * math.cos(ax)])


def _residuals(p: np.ndarray, Hs: list[np.ndarray]) -> np.ndarray:
    K = _K(p[:4])
    Ki = np.linalg.inv(K)
    w = Ki.T @ Ki
    w = w / np.linalg.norm(w)
    x0 = _circular_point(K, _normal(p[4:]))
    out = []
    for H in Hs:
        x = H @ x0
        z = (x @ w @ x) / (np.vdot(x, x).real)
        out += [z.real, z.imag]
    # a weak prior that pixels are nearly square (a 10 % aspect costs as much as a residual of
    # 1e-3): without it an edge-on plane with a very flat w fits a few views as well
    out.append(1e-2 * math.log(p[0] / p[1]))
    return np.array(out)


def planar_selfcal(Hs: list[np.ndarray], image_size: tuple[int, int], *, bootstrap: int = 30,
                   max_rel_sigma: float = 0.03, seed: int = 0) -> Calibration:
    """Intrinsics from homographies H_j (view 0 -> view j) of one unknown plane.

    Flagged degenerate: fewer than three homographies (4 + 2 unknowns, 2 equations per view);
    views that barely tilt the plane (near-affine homographies: the circular points are then
    nearly fixed and the focal length free); a bootstrap sigma of fx or fy above
    ``max_rel_sigma`` of fx; a solution at the bounds.
    """
    rng = np.random.default_rng(seed)
    T = _normaliser(image_size)
    Ti = np.linalg.inv(T)
    s = sum(image_size) / 2
    reasons: list[str] = []
    if len(Hs) < 3:
        reasons.append(f"{len(Hs)} homographies: a plane needs at least four views (three homographies)")
        return Calibration(_prior_K(image_size), np.full(4, math.inf), "planar", True, reasons, len(Hs))
    Hn = [T @ H @ Ti for H in Hs]
    Hn = [H / np.cbrt(np.linalg.det(H)) for H in Hn]

    lo, hi = [0.1, 0.1, -1, -1, -1.3, -1.3], [20, 20, 1, 1, 1.3, 1.3]    # f >= 0.1: a 160-degree lens

    def refine(Hset, init):
        res = least_squares(lambda p: _residuals(p, Hset), init, max_nfev=200, bounds=(lo, hi))
        return res.x, float(np.sqrt(np.mean(res.fun ** 2)))

    def fit(Hset):
        starts = []
        for f in np.geomspace(0.3, 4.0, 12):
            for ax in np.radians(np.arange(-60, 61, 15)):
                for ay in np.radians(np.arange(-60, 61, 15)):
                    p = np.array([f, f, 0.0, 0.0, ax, ay])
                    starts.append((float(np.sum(_residuals(p, Hset) ** 2)), p))
        starts.sort(key=lambda c: c[0])
        # the cost has a degenerate basin (f -> 0, w flat): refine the five best starts, keep the best
        return min((refine(Hset, p) for _, p in starts[:5]), key=lambda r: r[1])

    p, rms = fit(Hn)
    boots = []
    for _ in range(bootstrap):
        pick = rng.integers(0, len(Hn), len(Hn))
        if len(set(pick.tolist())) >= 3:
            boots.append(refine([Hn[i] for i in pick], p)[0][:4])
    sigma = np.std(np.array(boots), axis=0) * s if len(boots) >= 5 else np.full(4, math.inf)
    K = Ti @ _K(p[:4])
    persp = [float(np.linalg.norm(H[2, :2])) for H in Hn]
    if max(persp) < 0.02:
        reasons.append("the plane barely tilts between views (near-affine homographies): the focal length is free")
    if p[0] >= 19.9 or p[1] >= 19.9 or p[0] <= 0.101 or p[1] <= 0.101:
        reasons.append("the solution ran to the bounds of the search")
    if max(sigma[0], sigma[1]) > max_rel_sigma * K[0, 0]:
        reasons.append(f"focal length not determined: bootstrap sigma {max(sigma[0], sigma[1]):.0f} px is more than "
                       f"{100 * max_rel_sigma:.0f} % of fx")
    return Calibration(K, sigma, "planar", bool(reasons), reasons, len(Hn),
                       details={"residual_rms": rms, "normal_view0": _normal(p[4:]).tolist()})
