"""Rectified stereo pair of an underwater cable (seed 05): the 3-D curve, its two images and
the ground truth, with only what the scene needs (cable colour and shading, water attenuation,
blur, noise, a textured background, optional occluders).

Frames: the left camera at the origin, x right, y down, z forward (OpenCV); the right camera at
``(baseline_m, 0, 0)``, same orientation, same intrinsics (a rectified pair). Pure module::

    rig = StereoRig()                                  # 640x480, 70 deg, 0.3 m baseline
    cable = make_cable("crossing", depth_m=2.0)        # (N, 3) points, left-camera frame
    pair = render_pair(rig, cable, rng=np.random.default_rng(0))
    pair.left, pair.right                              # (H, W, 3) uint8 BGR
    pair.truth_left_px                                 # (N, 2) projection of the curve
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

CABLE_SHAPES = ("catenary", "crossing", "epipolar", "exit", "occluded", "two", "red")


@dataclass(frozen=True)
class StereoRig:
    """A rectified pair: equal pinhole intrinsics, right camera displaced by +baseline along x."""

    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 70.0
    baseline_m: float = 0.3

    @property
    def f_px(self) -> float:
        return self.width_px / 2 / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.f_px, 0, (self.width_px - 1) / 2], [0, self.f_px, (self.height_px - 1) / 2], [0, 0, 1]])

    def project(self, pts_m: np.ndarray, *, right: bool = False) -> np.ndarray:
        """(N, 3) left-camera points -> (N, 2) pixels in the left (or right) image; z <= 0 gives NaN."""
        p = np.asarray(pts_m, float)
        x = p[:, 0] - (self.baseline_m if right else 0.0)
        z = np.where(p[:, 2] > 1e-6, p[:, 2], np.nan)
        K = self.K
        return np.stack([K[0, 0] * x / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]], axis=1)


@dataclass(frozen=True)
class Look:
    """Appearance: cable colour (BGR), diameter, water, blur and noise."""

    colour_bgr: tuple[int, int, int] = (0, 200, 230)        # a yellow tether
    diameter_m: float = 0.02
    water_bgr: tuple[int, int, int] = (90, 70, 20)           # what the far field fades to
    attenuation_per_m: tuple[float, float, float] = (0.05, 0.08, 0.25)   # red fades first
    blur_px: float = 0.8
    noise_grey: float = 3.0
    shading: float = 0.5           # brightness varies along the cable by up to this fraction


@dataclass
class StereoPair:
    left: np.ndarray
    right: np.ndarray
    cable_m: np.ndarray                  # (N, 3) the true curve, left-camera frame
    truth_left_px: np.ndarray            # (N, 2)
    truth_right_px: np.ndarray           # (N, 2)
    visible: np.ndarray                  # (N,) bool: in the left image and not occluded there
    occluders: list[tuple[np.ndarray, float]] = field(default_factory=list)
    others_m: tuple[np.ndarray, ...] = ()   # other cables in the scene (same colour)


def catenary(span_m: float = 2.4, sag_m: float = 0.5, *, depth_m: float = 2.0, yaw_deg: float = 30.0,
             n: int = 1200) -> np.ndarray:
    """A hanging cable: y = a cosh(u / a) in a vertical plane turned by ``yaw_deg`` about y."""
    u = np.linspace(-span_m / 2, span_m / 2, n)
    # solve a cosh(s/2a) - a = sag for a (monotone in a) by bisection
    lo, hi = 1e-3, 1e3
    for _ in range(80):
        a = math.sqrt(lo * hi)
        lo, hi = (a, hi) if a * math.cosh(span_m / 2 / a) - a > sag_m else (lo, a)
    y = a * np.cosh(u / a) - a - sag_m / 2          # y down: sags downwards in the image
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.stack([c * u, y, depth_m + s * u], axis=1)


def spline(control_m: np.ndarray, n: int = 1500) -> np.ndarray:
    """A Catmull-Rom curve through (K, 3) control points, ``n`` samples."""
    P = np.asarray(control_m, float)
    P = np.vstack([2 * P[0] - P[1], P, 2 * P[-1] - P[-2]])
    segs = len(P) - 3
    t = np.linspace(0, segs, n, endpoint=False)
    t = np.append(t, segs - 1e-9)
    i = np.minimum(t.astype(int), segs - 1)
    u = (t - i)[:, None]
    p0, p1, p2, p3 = P[i], P[i + 1], P[i + 2], P[i + 3]
    return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)


def make_cable(shape: str, *, depth_m: float = 2.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """The issue's scenes, scaled so the image footprint is about the same at every depth.

    ``crossing``: a free curve whose image crosses itself (a loop, seen at an angle);
    ``epipolar``: a long stretch nearly parallel to the image rows; ``exit``: leaves the image
    on the right and comes back; ``occluded``/``red``: the catenary (an occluder is added by
    :func:`occluders_for`; ``red`` is rendered red, hue near the wrap); ``two``: the first of
    two same-colour cables (the second is :func:`second_cable`).
    """
    if shape not in CABLE_SHAPES:
        raise ValueError(f"shape must be one of {CABLE_SHAPES}, got {shape!r}")
    s = depth_m / 2.0                 # footprint scale
    jitter = (rng.normal(0, 0.03, 3) * s) if rng is not None else np.zeros(3)
    if shape in ("catenary", "occluded", "red", "two"):
        return catenary(2.4 * s, 0.5 * s, depth_m=depth_m) + jitter
    if shape == "crossing":
        ctrl = np.array([[-1.4, -0.6, 0.3], [-0.5, -0.1, 0.1], [0.35, 0.3, -0.2], [0.5, -0.35, 0.25],
                         [-0.1, -0.3, 0.1], [0.0, 0.45, -0.25], [0.5, 0.75, 0.1]])
    elif shape == "epipolar":
        ctrl = np.array([[-1.4, -0.5, 0.1], [-0.6, -0.1, 0.0], [0.2, 0.02, -0.2], [0.8, 0.06, 0.2],
                         [1.2, 0.5, 0.1], [1.0, 0.8, -0.1]])
    else:                              # exit: out past the right edge (x/z > 0.7) and back
        ctrl = np.array([[-0.6, -0.8, 0.0], [0.4, -0.4, 0.0], [2.2, -0.15, 0.2], [2.0, 0.2, 0.1],
                         [0.5, 0.35, 0.0], [-0.4, 0.8, 0.0]])
    c = ctrl * s
    c[:, 2] += depth_m
    return spline(c) + jitter


def second_cable(depth_m: float = 2.0) -> np.ndarray:
    """The other cable of the ``two`` scene: same colour, hanging lower and further away."""
    s = depth_m / 2.0
    return catenary(2.2 * s, 0.35 * s, depth_m=depth_m * 1.15, yaw_deg=-20.0) + np.array([0.1, 0.45 * s, 0.0])


def occluders_for(shape: str, depth_m: float) -> list[tuple[np.ndarray, float]]:
    """(corners (4, 3) in the left-camera frame, unused) for scenes with something in front."""
    if shape != "occluded":
        return []
    s = depth_m / 2.0
    z = depth_m * 0.7
    x0, w = 0.05 * s, 0.12 * s
    return [(np.array([[x0, -1.5 * s, z], [x0 + w, -1.5 * s, z], [x0 + w, 1.5 * s, z], [x0, 1.5 * s, z]]), z)]


def _background(rig: StereoRig, rng: np.random.Generator, *, depth_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A seabed-like texture on a fronto-parallel plane behind the cable (so it has disparity),
    as the left and the right camera see it."""
    h, w = rig.height_px, rig.width_px
    z = depth_m + 1.5
    shift = rig.f_px * rig.baseline_m / z
    pad = int(math.ceil(shift)) + 2
    base = np.zeros((h // 8 + 2, (w + pad) // 8 + 2, 3), np.float32)
    base[:] = (70, 85, 75)
    # mostly brightness texture with a little colour, as on a seabed (not saturated confetti)
    lum = rng.normal(0, 20, base.shape[:2]).astype(np.float32)
    base += lum[..., None] + rng.normal(0, 5, base.shape).astype(np.float32)
    tex = cv2.resize(base, ((w + pad) // 8 * 8 + 16, h // 8 * 8 + 16), interpolation=cv2.INTER_CUBIC)
    tex += rng.normal(0, 6, tex.shape[:2]).astype(np.float32)[..., None]
    tex = cv2.GaussianBlur(tex, (0, 0), 1.2)
    return tuple(cv2.warpAffine(tex, np.float32([[1, 0, dx], [0, 1, 0]]), (w, h), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REFLECT) for dx in (0.0, shift))


def _draw_cable(img: np.ndarray, rig: StereoRig, cable_m: np.ndarray, look: Look, colour: np.ndarray,
                shade: np.ndarray, *, right: bool, zbuf: np.ndarray) -> None:
    """Segments drawn far to near, each into the z-buffer, so a self-crossing hides correctly."""
    px = rig.project(cable_m, right=right)
    z = cable_m[:, 2]
    water = np.array(look.water_bgr, np.float32)
    att = np.exp(-np.outer(z, look.attenuation_per_m))          # (N, 3)
    col = colour[None, :] * shade[:, None] * att + water[None, :] * (1 - att)
    order = np.argsort(-(z[:-1] + z[1:]) / 2)
    h, w = img.shape[:2]
    scale = 4                                                    # subpixel endpoints via the shift argument
    for i in order:
        a, b = px[i], px[i + 1]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            continue
        zm = (z[i] + z[i + 1]) / 2
        thick = max(1, int(round(rig.f_px * look.diameter_m / zm)))
        r = thick + 2
        x0 = max(int(min(a[0], b[0])) - r, 0)
        y0 = max(int(min(a[1], b[1])) - r, 0)
        x1 = min(int(max(a[0], b[0])) + r + 1, w)
        y1 = min(int(max(a[1], b[1])) + r + 1, h)
        if x1 <= x0 or y1 <= y0:
            continue
        pa = tuple(int(round(v * (1 << scale))) for v in (a[0] - x0, a[1] - y0))
        pb = tuple(int(round(v * (1 << scale))) for v in (b[0] - x0, b[1] - y0))
        seg = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.line(seg, pa, pb, 255, thick, cv2.LINE_AA, scale)
        zb = zbuf[y0:y1, x0:x1]
        m = (seg > 0) & (zm < zb)
        if not m.any():
            continue
        alpha = (seg[m].astype(np.float32) / 255)[:, None]
        roi = img[y0:y1, x0:x1]
        roi[m] = roi[m] * (1 - alpha) + col[i] * alpha
        zb[m & (seg > 127)] = zm


def render_pair(rig: StereoRig, cable_m: np.ndarray, *, look: Look = Look(),
                rng: np.random.Generator | None = None, extra_cables: tuple[np.ndarray, ...] = (),
                occluders: list[tuple[np.ndarray, float]] | None = None) -> StereoPair:
    """Both images of the scene and the ground truth. ``rng`` None: no noise, fixed texture."""
    rng = rng or np.random.default_rng(0)
    depth = float(np.median(cable_m[:, 2]))
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(cable_m, axis=0), axis=1))])
    shade = 1 - look.shading * 0.5 * (1 + np.sin(arc * 2.1 + rng.uniform(0, 6.28)))
    colour = np.array(look.colour_bgr, np.float32)
    occ = occluders or []
    out, zbufs = [], []
    backgrounds = _background(rig, np.random.default_rng(int(rng.integers(1 << 31))), depth_m=depth)  # one texture, both cameras
    for right in (False, True):
        img = backgrounds[right].copy()
        zbuf = np.full(img.shape[:2], np.inf, np.float32)
        _draw_cable(img, rig, cable_m, look, colour, shade, right=right, zbuf=zbuf)
        for other in extra_cables:
            _draw_cable(img, rig, other, look, colour, np.ones(len(other)), right=right, zbuf=zbuf)
        for corners, z in occ:
            poly = rig.project(corners, right=right)
            mask = np.zeros(img.shape[:2], np.uint8)
            cv2.fillConvexPoly(mask, np.round(poly * 16).astype(np.int32), 255, cv2.LINE_AA, 4)
            m = mask > 127
            img[m] = (40, 45, 50)
            zbuf[m] = np.minimum(zbuf[m], z)
        if look.blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), look.blur_px)
        img = img + rng.normal(0, look.noise_grey, img.shape).astype(np.float32)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
        zbufs.append(zbuf)
    tl, tr = rig.project(cable_m), rig.project(cable_m, right=True)
    inside = np.all(np.isfinite(tl), axis=1) & (tl[:, 0] >= 0) & (tl[:, 0] <= rig.width_px - 1) \
        & (tl[:, 1] >= 0) & (tl[:, 1] <= rig.height_px - 1)
    visible = inside.copy()
    for corners, _ in occ:
        poly = rig.project(corners).astype(np.float32)
        for k in np.flatnonzero(inside):
            if cv2.pointPolygonTest(poly, (float(tl[k, 0]), float(tl[k, 1])), False) >= 0:
                visible[k] = False
    return StereoPair(out[0], out[1], np.asarray(cable_m, float), tl, tr, visible, occ, tuple(extra_cables))


def scene_pair(shape: str, *, depth_m: float = 2.0, rig: StereoRig = StereoRig(), seed: int = 0,
               noise_grey: float = 3.0) -> StereoPair:
    """One of :data:`CABLE_SHAPES` rendered at ``depth_m`` (the bench's and the node's scenes)."""
    rng = np.random.default_rng(seed)
    cable = make_cable(shape, depth_m=depth_m, rng=rng)
    look = Look(noise_grey=noise_grey)
    if shape == "red":
        look = Look(colour_bgr=(40, 20, 210), noise_grey=noise_grey)
    extra = (second_cable(depth_m),) if shape == "two" else ()
    return render_pair(rig, cable, look=look, rng=rng, extra_cables=extra, occluders=occluders_for(shape, depth_m))
