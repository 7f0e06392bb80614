"""Camera self-calibration from image correspondences alone (seed 12): the Kruppa equations in
Hartley's SVD form, Bougnoux's closed-form focal length, the infinite homography of a purely
rotating camera, a refinement on the essential-matrix constraint, bootstrap uncertainties,
and the critical motions detected and flagged rather than answered with a number.

The seed derives the Kruppa equations through H_inf = K R K^-1; two slips in it: its eq. (6)
reads R = K^-1 H_inf R (it is K^-1 H_inf K), and "two views determine H_inf" holds only for a
rotating camera -- with translation H_inf is not observable from two views, which is why the
Kruppa equations are written on the fundamental matrix instead (Hartley 1997; H&Z 19.3-19.4).

Pure functions (numpy, scipy, OpenCV)::

    pair = pair_geometry(pts1, pts2)                       # F or H by GRIC, inliers, checks
    cal = self_calibrate([pair, ...], image_size=(640, 480))
    cal.K, cal.sigma_px, cal.degenerate, cal.reasons
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

__all__ = ["Calibration", "PairGeometry", "bougnoux_focal", "kruppa_residuals", "pair_geometry",
           "rotation_selfcal", "self_calibrate"]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _K(theta: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = theta
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


@dataclass
class PairGeometry:
    """Two views' correspondences summarised: the model GRIC prefers ("F": the views see depth
    from a translation; "H": a homography explains them -- pure rotation, a planar scene or no
    baseline), both models and their inlier counts, and the motion checks."""

    n_matches: int
    model: str
    F: np.ndarray | None
    H: np.ndarray | None
    inliers_F: int
    inliers_H: int
    gric_F: float = math.inf
    gric_H: float = math.inf
    skew: float = math.nan            # ||F + F^T|| / ||F||: 0 for a pure translation


def _sampson(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Squared Sampson distances (px^2) of homogeneous (N, 3) correspondences to F."""
    Fx1 = x1 @ F.T
    Ftx2 = x2 @ F
    num = np.einsum("ij,ij->i", x2, Fx1) ** 2
    return num / np.maximum(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2, 1e-30)


def _transfer(H: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Squared distance (px^2) of (N, 3) correspondences to H's manifold, approximated by a
    quarter of the two one-way transfer errors: a one-way transfer error carries the noise of
    both images (2 sigma^2 per coordinate), the distance to the manifold half of it -- so that,
    like the Sampson distance to F, it is comparable with sigma^2 in GRIC."""
    def one(A, a, b):
        p = a @ A.T
        p = p[:, :2] / np.where(np.abs(p[:, 2:]) > 1e-12, p[:, 2:], 1e-12)
        return ((p - b[:, :2]) ** 2).sum(axis=1)
    return 0.25 * (one(H, x1, x2) + one(np.linalg.inv(H), x2, x1))


def _gric(err2: np.ndarray, sigma: float, d: int, k: int, r: int = 4) -> float:
    """Torr's geometric robust information criterion (lower is better)."""
    n = len(err2)
    rho = np.minimum(err2 / sigma ** 2, 2.0 * (r - d))
    return float(rho.sum() + math.log(r) * d * n + math.log(r * n) * k)


def pair_geometry(pts1: np.ndarray, pts2: np.ndarray, *, sigma_px: float = 1.0, seed: int = 0) -> PairGeometry:
    """Fit F (rank 2, USAC/MAGSAC) and H to (N, 2) pixel correspondences; choose by GRIC.

    Fewer than 8 matches give model "none". The skew measure is taken on F in pixel units:
    a camera that only translates (same K) has a skew-symmetric F.
    """
    pts1, pts2 = np.asarray(pts1, np.float64), np.asarray(pts2, np.float64)
    n = len(pts1)
    if n < 8:
        return PairGeometry(n, "none", None, None, 0, 0)
    cv2.setRNGSeed(seed)
    thr = 3.0 * sigma_px
    F, mF = cv2.findFundamentalMat(pts1, pts2, cv2.USAC_MAGSAC, thr, 0.999, 20000)
    H, mH = cv2.findHomography(pts1, pts2, cv2.USAC_MAGSAC, thr * math.sqrt(2), maxIters=20000, confidence=0.999)
    if F is not None and F.shape != (3, 3):
        F = F[:3]                                  # several solutions from the 7-point case: keep one
    x1 = np.hstack([pts1, np.ones((n, 1))])
    x2 = np.hstack([pts2, np.ones((n, 1))])
    gF = _gric(_sampson(F, x1, x2), sigma_px, 3, 7) if F is not None else math.inf
    gH = _gric(_transfer(H, x1, x2), sigma_px, 2, 8) if H is not None else math.inf
    model = "F" if gF < gH else ("H" if H is not None else "none")
    skew = float(np.linalg.norm(F + F.T) / np.linalg.norm(F)) if F is not None else math.nan
    return PairGeometry(n, model, F, H, int(mF.sum()) if mF is not None else 0,
                        int(mH.sum()) if mH is not None else 0, gF, gH, skew)


def _normaliser(image_size: tuple[int, int]) -> np.ndarray:
    w, h = image_size
    s = (w + h) / 2
    return np.array([[1 / s, 0, -(w - 1) / 2 / s], [0, 1 / s, -(h - 1) / 2 / s], [0, 0, 1.0]])


def _normalise_F(F: np.ndarray, T: np.ndarray) -> np.ndarray:
    """F for normalised coordinates x_n = T x (x2^T F x1 = x2n^T T^-T F T^-1 x1n), unit norm,
    projected to rank 2 (a rank-3 F from noise is the nearest rank-2 one)."""
    Ti = np.linalg.inv(T)
    Fn = Ti.T @ F @ Ti
    U, S, Vt = np.linalg.svd(Fn)
    S = S / S[0]
    return U @ np.diag([S[0], S[1], 0.0]) @ Vt


def _svd_terms(Fs: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """What the Kruppa equations need of each F, which does not depend on K: (n, 3) u1, u2, v1,
    v2 scaled by the singular values as they appear."""
    U, S, Vt = np.linalg.svd(np.asarray(Fs))
    r, s = S[:, 0:1], S[:, 1:2]
    return U[:, :, 0], U[:, :, 1], Vt[:, 0] * r, Vt[:, 1] * s


def kruppa_residuals(theta: np.ndarray, Fs: list[np.ndarray] | tuple) -> np.ndarray:
    """Hartley's SVD form of the Kruppa equations for a constant camera (H&Z result 19.x).

    With F = U diag(r, s, 0) V^T and w = K K^T (the dual image of the absolute conic):
        u2'w u2 / (r^2 v1'w v1) = -u1'w u2 / (r s v1'w v2) = u1'w u1 / (s^2 v2'w v2).
    Written as two unit 3-vectors that must be parallel; the residual is their cross product
    (three numbers, two independent), so no ratio is ever taken of a number near zero.
    ``Fs`` may be the list of F or their precomputed :func:`_svd_terms`.
    """
    u1, u2, rv1, sv2 = Fs if isinstance(Fs, tuple) else _svd_terms(Fs)
    K = _K(theta)
    w = K @ K.T
    quad = lambda a, b: np.einsum("ni,ij,nj->n", a, w, b)          # noqa: E731
    p = np.stack([quad(rv1, rv1), quad(rv1, sv2), quad(sv2, sv2)], axis=1)
    q = np.stack([quad(u2, u2), -quad(u1, u2), quad(u1, u1)], axis=1)
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.cross(p, q).ravel()


def _essential_residuals(theta: np.ndarray, Fs: np.ndarray) -> np.ndarray:
    """Mendonca-Cipolla: E = K^T F K has two equal singular values; (s1 - s2) / (s1 + s2) per F."""
    K = _K(theta)
    s = np.linalg.svd(K.T @ np.asarray(Fs) @ K, compute_uv=False)
    return (s[:, 0] - s[:, 1]) / np.maximum(s[:, 0] + s[:, 1], 1e-30)


def bougnoux_focal(F: np.ndarray, principal_point: tuple[float, float]) -> float:
    """Bougnoux's closed form for f^2 of the first camera (square pixels, zero skew, known
    principal point p; both cameras alike):
        f^2 = -(p^T [e']x I~ F p p^T F^T p) / (p^T [e']x I~ F I~ F^T p),  I~ = diag(1, 1, 0).
    Returns f^2, which noise or a critical motion can make negative (an imaginary focal
    length) or huge (the optical axes meet: numerator and denominator both vanish)."""
    p = np.array([principal_point[0], principal_point[1], 1.0])
    U, _, _ = np.linalg.svd(F)
    ex = _skew(U[:, 2])
    It = np.diag([1.0, 1.0, 0.0])
    num = -(p @ ex @ It @ F @ np.outer(p, p) @ F.T @ p)
    den = p @ ex @ It @ F @ It @ F.T @ p
    return float(num / den) if abs(den) > 1e-300 else math.inf


def fixation_px(F: np.ndarray, principal_point: tuple[float, float]) -> float:
    """Distance (px) of the principal point in view 2 from the epipolar line of the principal
    point in view 1: zero when the optical axes meet (a fixating motion, a turntable), the
    configuration where a pair's F says nothing about the focal length."""
    p = np.array([principal_point[0], principal_point[1], 1.0])
    line = F @ p
    return float(abs(p @ line) / max(math.hypot(line[0], line[1]), 1e-300))


@dataclass
class Calibration:
    """Intrinsics K (3x3, zero skew), one-sigma ``sigma_px`` (fx, fy, cx, cy) by bootstrap over
    pairs, and whether the answer can be trusted: ``degenerate`` with ``reasons``."""

    K: np.ndarray
    sigma_px: np.ndarray
    method: str
    degenerate: bool
    reasons: list[str] = field(default_factory=list)
    pairs_used: int = 0
    f_bougnoux: float = math.nan
    details: dict = field(default_factory=dict)


def _solve(Fs: list[np.ndarray], init: np.ndarray, fix_pp: bool, fn) -> np.ndarray:
    """Least squares on residuals ``fn`` over (fx, fy, cx, cy) in normalised units."""
    if fix_pp:
        res = least_squares(lambda t: fn(np.array([t[0], t[1], init[2], init[3]]), Fs), init[:2],
                            loss="soft_l1", f_scale=0.05, bounds=([1e-3, 1e-3], [50, 50]), max_nfev=100)
        return np.array([res.x[0], res.x[1], init[2], init[3]])
    res = least_squares(lambda t: fn(t, Fs), init, loss="soft_l1", f_scale=0.05,
                        bounds=([1e-3, 1e-3, -2, -2], [50, 50, 2, 2]), max_nfev=100)   # a critical motion wanders
    return res.x


def _kruppa_solve(Fs: list[np.ndarray], pp_n: np.ndarray | None) -> np.ndarray:
    """Kruppa from a grid of focal lengths (pp at the centre or given), then the Mendonca-Cipolla
    refinement; the principal point is free unless ``pp_n`` (normalised) is given."""
    terms = _svd_terms(Fs)
    stack = np.asarray(Fs)
    pp = np.zeros(2) if pp_n is None else pp_n
    best, best_cost = None, math.inf
    for f in np.geomspace(0.2, 5.0, 25):
        r = kruppa_residuals(np.array([f, f, pp[0], pp[1]]), terms)
        c = float(np.sum(np.log1p((r / 0.05) ** 2)))
        if c < best_cost:
            best, best_cost = np.array([f, f, pp[0], pp[1]]), c
    theta = _solve(terms, best, pp_n is not None, kruppa_residuals)
    return _solve(stack, theta, pp_n is not None, _essential_residuals)


def self_calibrate(pairs: list[PairGeometry], image_size: tuple[int, int], *,
                   principal_point: tuple[float, float] | None = None, min_inliers: int = 20,
                   bootstrap: int = 30, max_rel_sigma: float = 0.03, seed: int = 0) -> Calibration:
    """Intrinsics from pairs of views of a rigid scene by one constant camera.

    Pairs whose correspondences a homography explains are used by the infinite-homography
    method when the camera only rotated (every usable pair is "H"); otherwise the "F" pairs go
    to the Kruppa equations (fx, fy, cx, cy; or fx, fy with ``principal_point`` given), refined
    on the essential-matrix constraint, with Bougnoux's f as a comparison.

    Flagged ``degenerate`` (never a NaN focal length):
      * fewer than two usable pairs (one motion gives two equations, four are unknown);
      * every F pair a pure translation (F skew-symmetric): the Kruppa equations hold for any K;
      * every F pair fixating (the optical axes meet): the orbit of a turntable;
      * a bootstrap sigma of fx or fy above ``max_rel_sigma`` of fx (small rotations, a single
        rotation axis, too much noise), or a solution at the bounds / not positive;
      * homographies that are not conjugate rotations (a planar scene seen while translating).
    """
    rng = np.random.default_rng(seed)
    w, h = image_size
    T = _normaliser(image_size)
    s = (w + h) / 2
    reasons: list[str] = []
    usable = [p for p in pairs if max(p.inliers_F, p.inliers_H) >= min_inliers and p.model in ("F", "H")]
    dropped = len(pairs) - len(usable)
    if dropped:
        reasons.append(f"{dropped} of {len(pairs)} pairs dropped: fewer than {min_inliers} inlier matches")
    rank1 = [p for p in usable if p.model == "F" and _rank_one(p.F)]
    if rank1:
        reasons.append(f"{len(rank1)} fundamental matrices of rank 1 dropped (no epipolar geometry)")
    f_pairs = [p for p in usable if p.model == "F" and not _rank_one(p.F)]
    h_pairs = [p for p in usable if p.model == "H"]
    pp0 = principal_point or ((w - 1) / 2, (h - 1) / 2)
    nan_K = _prior_K(image_size, pp0)

    if len(f_pairs) < 2 and len(h_pairs) >= 2 and len(f_pairs) == 0:
        return rotation_selfcal([p.H for p in h_pairs], image_size, reasons=reasons, bootstrap=bootstrap,
                                max_rel_sigma=max_rel_sigma, rng=rng)
    if len(f_pairs) < 2:
        reasons.append(f"{len(f_pairs)} pair(s) with depth (F): the Kruppa equations need at least two motions")
        return Calibration(nan_K, np.full(4, math.inf), "kruppa", True, reasons, len(f_pairs))

    Fs_px = [p.F / np.linalg.norm(p.F) for p in f_pairs]
    skews = np.array([_skew_ratio(_normalise_F(F, T)) for F in Fs_px])
    fixes = np.array([fixation_px(F, pp0) for F in Fs_px])
    translation = skews < 0.02
    details = {"pure_translation_pairs": int(translation.sum()), "fixating_pairs": int((fixes < 1.0).sum()),
               "pairs": len(f_pairs), "homography_pairs": len(h_pairs), "median_skew": float(np.median(skews)),
               "median_fixation_px": float(np.median(fixes))}
    f2 = np.array([bougnoux_focal(F, pp0) for F in Fs_px])
    details["bougnoux_negative"] = int((f2 <= 0).sum())
    f_boug = float(math.sqrt(np.median(f2[f2 > 0]))) if (f2 > 0).any() else math.nan
    if np.median(skews) < 0.02:
        reasons.append("the camera only translated (F skew-symmetric): the Kruppa equations hold for any K")
    elif np.median(fixes) < 0.002 * s:
        reasons.append("the optical axes meet (a fixating orbit, a turntable): the focal length is not observable")
    informative = [F for F, t in zip(Fs_px, translation) if not t]
    if len(informative) < 2:
        if not any("pure translation" in r for r in reasons):
            reasons.append("fewer than two pairs with rotation")
        return Calibration(nan_K, np.full(4, math.inf), "kruppa", True, reasons, len(f_pairs), f_boug, details)

    Fn = [_normalise_F(F, T) for F in informative]
    fix_pp = principal_point is not None
    init_pp = (T @ np.array([pp0[0], pp0[1], 1.0]))[:2]

    def solve(Fset):
        return _kruppa_solve(Fset, init_pp if fix_pp else None)

    theta = solve(Fn)
    boots = []
    stack = np.asarray(Fn)
    for _ in range(bootstrap):               # warm-started from the full solution: a resample moves it little
        pick = rng.integers(0, len(Fn), len(Fn))
        if len(set(pick.tolist())) >= 2:
            boots.append(_solve(stack[pick], theta, fix_pp, _essential_residuals))
    sig_n = np.std(np.array(boots), axis=0) if len(boots) >= 5 else np.full(4, math.inf)
    # pairs share views, so resampling them understates the spread when the cost is flat (small
    # rotations); the linearised covariance of the refinement is the other bound: keep the larger
    sig_n = np.maximum(sig_n, _linear_sigma(theta, stack))
    Kn = _K(theta)
    K = np.linalg.inv(T) @ Kn
    sigma = sig_n * s
    details["essential_rms"] = float(np.sqrt(np.mean(_essential_residuals(theta, np.asarray(Fn)) ** 2)))
    details["conditioning"] = cond = _conditioning(theta, Fn)
    if cond < 0.08:
        reasons.append(f"these motions leave a direction of K unconstrained (conditioning {cond:.1e}): a critical "
                       "sequence such as rotations about one axis or a fixating orbit")
    ok = np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0
    if not ok or theta[0] >= 49 or theta[1] >= 49 or theta[0] <= 2e-3 or theta[1] <= 2e-3:
        reasons.append("the solution ran to the bounds of the search (no finite positive focal length fits)")
    if ok and max(sigma[0], sigma[1]) > max_rel_sigma * K[0, 0]:
        reasons.append(f"focal length not determined: bootstrap sigma {max(sigma[0], sigma[1]):.0f} px is more than "
                       f"{100 * max_rel_sigma:.0f} % of fx (small or single-axis rotations, or noise)")
    degenerate = bool(reasons and any(not (r.endswith("inlier matches") or "rank 1" in r) for r in reasons))
    return Calibration(K, sigma, "kruppa", degenerate, reasons, len(Fn), f_boug, details)


def _rank_one(F: np.ndarray) -> bool:
    s = np.linalg.svd(F, compute_uv=False)
    return bool(s[1] <= 1e-6 * s[0])


def _prior_K(image_size: tuple[int, int], pp: tuple[float, float] | None = None) -> np.ndarray:
    """What is returned, flagged degenerate with infinite sigmas, when nothing can be solved: a
    90-degree camera centred on the image -- a finite placeholder, never a NaN in a message."""
    w, h = image_size
    cx, cy = pp or ((w - 1) / 2, (h - 1) / 2)
    return np.array([[w / 2, 0, cx], [0, w / 2, cy], [0, 0, 1.0]])


def _skew_ratio(F: np.ndarray) -> float:
    return float(np.linalg.norm(F + F.T) / np.linalg.norm(F))


def _linear_sigma(theta: np.ndarray, Fs: np.ndarray) -> np.ndarray:
    """One-sigma of (fx, fy, cx, cy) from the essential residuals' Jacobian and their spread."""
    e = _essential_residuals(theta, Fs)
    if len(e) <= 4:
        return np.full(4, math.inf)
    J = np.empty((len(e), 4))
    for k in range(4):
        d = np.zeros(4)
        d[k] = 1e-6 * max(1.0, abs(theta[k]))
        J[:, k] = (_essential_residuals(theta + d, Fs) - _essential_residuals(theta - d, Fs)) / (2 * d[k])
    s2 = float(e @ e) / (len(e) - 4)
    return np.sqrt(np.abs(np.diag(s2 * np.linalg.pinv(J.T @ J))))


def _conditioning(theta: np.ndarray, Fn: list[np.ndarray]) -> float:
    """Smallest over largest singular value of the Kruppa residuals' Jacobian in relative units
    (focal lengths by ratio, the principal point in image units): near zero when the motions
    leave some combination of the intrinsics free, whatever the noise."""
    terms = _svd_terms(Fn)
    J = np.empty((3 * len(Fn), 4))
    for k in range(4):
        d = np.zeros(4)
        d[k] = 1e-5 * max(1.0, abs(theta[k]))
        J[:, k] = (kruppa_residuals(theta + d, terms) - kruppa_residuals(theta - d, terms)) / (2 * d[k])
    sv = np.linalg.svd(J * np.array([theta[0], theta[1], 1.0, 1.0]), compute_uv=False)
    return float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0


def _rotation_residuals(theta: np.ndarray, Hs: list[np.ndarray]) -> np.ndarray:
    """K^-1 H K must be a rotation: the upper triangle of M M^T - I per homography."""
    K = _K(theta)
    Ki = np.linalg.inv(K)
    out = []
    for H in Hs:
        M = Ki @ H @ K
        M = M / np.cbrt(np.linalg.det(M))
        E = M @ M.T - np.eye(3)
        out.append(E[np.triu_indices(3)])
    return np.concatenate(out)


def _iac_from_homographies(Hs: list[np.ndarray]) -> np.ndarray | None:
    """Linear solution of w = H^T w H (w the image of the absolute conic, zero skew: w12 = 0)."""
    rows = []
    idx = [(0, 0), (0, 2), (1, 1), (1, 2), (2, 2)]          # w11 w13 w22 w23 w33 (w12 = 0)
    for H in Hs:
        Hn = H / np.cbrt(np.linalg.det(H))
        for a in range(3):
            for b in range(a, 3):
                row = []
                for i, j in idx:
                    E = np.zeros((3, 3))
                    E[i, j] = E[j, i] = 1.0
                    row.append((Hn.T @ E @ Hn - E)[a, b])
                rows.append(row)
    _, _, Vt = np.linalg.svd(np.array(rows))
    v = Vt[-1]
    W = np.array([[v[0], 0, v[1]], [0, v[2], v[3]], [v[1], v[3], v[4]]])
    if W[2, 2] < 0:
        W = -W
    try:
        L = np.linalg.cholesky(W)        # W = L L^T = K^-T K^-1  ->  K^-1 = L^T
    except np.linalg.LinAlgError:
        return None
    K = np.linalg.inv(L.T)
    return K / K[2, 2]


def rotation_selfcal(Hs: list[np.ndarray], image_size: tuple[int, int], *, reasons: list[str] | None = None,
                     bootstrap: int = 30, max_rel_sigma: float = 0.05,
                     rng: np.random.Generator | None = None) -> Calibration:
    """A purely rotating camera (Hartley 1994): each inter-image homography is the infinite
    homography K R K^-1, so w = K^-T K^-1 satisfies w = H^T w H; linear in w, then refined so
    that K^-1 H K is a rotation. Two rotations about different axes are needed."""
    reasons = list(reasons or [])
    rng = rng or np.random.default_rng(0)
    T = _normaliser(image_size)
    Ti = np.linalg.inv(T)
    s = sum(image_size) / 2
    Hn = [T @ H @ Ti for H in Hs]
    nan_K = _prior_K(image_size)

    def solve(Hset):
        K0 = _iac_from_homographies(Hset)
        init = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2]]) if K0 is not None and np.all(np.isfinite(K0)) \
            and K0[0, 0] > 0 and K0[1, 1] > 0 else np.array([1.0, 1.0, 0.0, 0.0])
        init = np.clip(init, [2e-3, 2e-3, -1.9, -1.9], [49, 49, 1.9, 1.9])
        res = least_squares(lambda t: _rotation_residuals(t, Hset), init, loss="soft_l1", f_scale=0.05,
                            bounds=([1e-3, 1e-3, -2, -2], [50, 50, 2, 2]))
        return res.x, float(np.sqrt(np.mean(res.fun ** 2)))

    if len(Hn) < 2:
        reasons.append("one rotation: the infinite homography method needs two about different axes")
        return Calibration(nan_K, np.full(4, math.inf), "rotation", True, reasons, len(Hn))
    theta, rms = solve(Hn)
    boots = [solve([Hn[i] for i in rng.integers(0, len(Hn), len(Hn))])[0] for _ in range(bootstrap)]
    sigma = np.std(np.array(boots), axis=0) * s
    K = Ti @ _K(theta)
    details = {"rotation_rms": rms, "pairs": len(Hn)}
    if rms > 0.02:
        reasons.append(f"the homographies are not conjugate rotations (rms {rms:.3f}): a planar scene seen while "
                       "translating, or a moving camera centre")
    if max(sigma[0], sigma[1]) > max_rel_sigma * K[0, 0]:
        reasons.append(f"focal length not determined: bootstrap sigma {max(sigma[0], sigma[1]):.0f} px is more than "
                       f"{100 * max_rel_sigma:.0f} % of fx (rotations about one axis, or too small)")
    degenerate = any(not r.endswith("inlier matches") for r in reasons)
    return Calibration(K, sigma, "rotation", degenerate, reasons, len(Hn), details=details)
