"""Hand scenes (seed 13): the articulated hand of :mod:`sim.hand` drawn with OpenCV as a palm
polygon and shaded capsules, on a plain, cluttered, noisy or skin-coloured background, under a
lighting gradient with noise and blur; ground-truth keypoints, finger count and gesture.

Hard cases on request (:class:`SceneSpec`): no hand, two hands, a hand touching or cut by the
border, the forearm in view (it is not a finger), a skin-coloured background, the spread V,
a fist against a single finger.

    rng = np.random.default_rng(0)
    img, truth = render_scene(rng, SceneSpec(gesture="victory", spread=True, arm=True))
    truth.keypoints_px, truth.count, truth.gesture          # (21, 2), 2, "victory"
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from sim.hand import RADII, HandPose, count_of, finger_chains, forward_kinematics, gesture_of, project, sample_pose

__all__ = ["BACKGROUNDS", "FRAMINGS", "HandTruth", "SceneSpec", "draw_hand", "render_scene", "skin_colour"]

BACKGROUNDS = ("plain", "clutter", "noise", "skin")
FRAMINGS = ("inside", "bottom", "border")

_PALM = np.array([[0.27, 0.0], [0.36, 0.32], [0.40, 0.93], [0.30, 1.04], [0.10, 1.08], [-0.10, 1.04], [-0.28, 0.97],
                  [-0.38, 0.85], [-0.36, 0.35], [-0.25, 0.0]])


@dataclass(frozen=True)
class SceneSpec:
    """What a scene holds. None: drawn at random. ``framing``: "inside" (whole hand in view),
    "bottom" (upright, wrist on the bottom edge, as a signer), "border" (touching or cut by an
    edge). ``hands``: 0, 1 or 2 (the second is smaller and behind; the truth is the first)."""

    gesture: str | None = None
    spread: bool | None = None
    hands: int = 1
    framing: str | None = None
    arm: bool | None = None
    background: str | None = None
    width_px: int = 128
    height_px: int = 128
    mono: bool = False


@dataclass(frozen=True)
class HandTruth:
    """Ground truth of a scene's (first) hand: ``keypoints_px`` (21, 2) (NaN without a hand),
    ``count``, ``gesture``, ``palm_px`` (wrist to middle MCP: the PCK unit), ``present``,
    ``extended`` (5,) bool, and the scene's spec as drawn."""

    keypoints_px: np.ndarray
    count: int
    gesture: str
    palm_px: float
    present: bool
    extended: np.ndarray
    spec: SceneSpec


def skin_colour(rng: np.random.Generator) -> np.ndarray:
    """A skin tone, BGR float in [0, 255]: hue 5-25 deg, pale to dark."""
    hsv = np.uint8([[[rng.uniform(3, 13), rng.uniform(60, 150), rng.uniform(90, 245)]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].astype(float)


def _background(rng: np.random.Generator, kind: str, h: int, w: int, skin: np.ndarray) -> np.ndarray:
    if kind == "skin":                     # a wall or a table the colour of the hand, a little textured
        base = np.clip(skin * rng.uniform(0.85, 1.15) + rng.normal(0, 8, 3), 0, 255)
        img = np.tile(base, (h, w, 1)) + cv2.GaussianBlur(rng.normal(0, 10, (h, w, 1)), (0, 0), 2)[..., None]
        return img
    if kind == "noise":
        small = rng.uniform(0, 255, (max(2, h // 16), max(2, w // 16), 3))
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    base = rng.uniform(60, 230) * np.ones(3) + rng.normal(0, 12, 3)
    img = np.tile(base, (h, w, 1)).astype(float)
    if kind == "clutter":
        for _ in range(rng.integers(3, 12)):
            colour = rng.uniform(0, 255, 3) if rng.random() > 0.15 else skin * rng.uniform(0.7, 1.2)
            x, y = rng.uniform(0, w), rng.uniform(0, h)
            s = rng.uniform(0.05, 0.4) * w
            shape = rng.integers(3)
            if shape == 0:
                cv2.rectangle(img, (int(x), int(y)), (int(x + s), int(y + s * rng.uniform(0.3, 2))), colour.tolist(), -1)
            elif shape == 1:
                cv2.circle(img, (int(x), int(y)), int(s / 2), colour.tolist(), -1, cv2.LINE_AA)
            else:
                cv2.line(img, (int(x), int(y)), (int(rng.uniform(0, w)), int(rng.uniform(0, h))), colour.tolist(),
                         int(rng.integers(1, 4)), cv2.LINE_AA)
    return img


def _capsule(img: np.ndarray, a: np.ndarray, b: np.ndarray, r: float, colour: np.ndarray, edge: np.ndarray,
             sh: int = 4) -> None:
    """A capsule of radius ``r`` px from ``a`` to ``b`` with a darker rim (the crease between fingers)."""
    f = 1 << sh
    pa, pb = tuple(np.round(a * f).astype(int)), tuple(np.round(b * f).astype(int))
    rr = max(r, 0.5)
    cv2.line(img, pa, pb, edge.tolist(), max(1, int(round(2 * rr + 1.2))), cv2.LINE_AA, sh)
    cv2.line(img, pa, pb, colour.tolist(), max(1, int(round(2 * rr - 0.6))), cv2.LINE_AA, sh)


def draw_hand(img: np.ndarray, pose: HandPose, *, centre_px: tuple[float, float], scale_px: float, skin: np.ndarray,
              arm_len: float = 0.0, sleeve: np.ndarray | None = None,
              shade: np.ndarray | None = None) -> np.ndarray:
    """Draw ``pose`` into ``img`` (float BGR, in place): forearm (``arm_len`` palm lengths, 0: none;
    a ``sleeve`` colour covers it beyond the wrist), palm, then the fingers far to near.
    ``shade`` (5,) multiplies each finger's colour. Returns the keypoints (21, 2) px."""
    kp3 = forward_kinematics(pose)
    kp, depth = project(kp3, pose, centre_px=centre_px, scale_px=scale_px)
    edge = skin * 0.72
    if arm_len > 0:
        ends = np.array([[0.0, 0.15, 0.0], [0.0, -arm_len, 0.0], [0.0, -0.55, 0.0]])
        e, _ = project(ends, pose, centre_px=centre_px, scale_px=scale_px)
        _capsule(img, e[0], e[1], 0.28 * scale_px, skin * 0.95, edge)
        if sleeve is not None:
            _capsule(img, e[2], e[1], 0.34 * scale_px, sleeve, sleeve * 0.8)
    palm3 = np.c_[_PALM, np.zeros(len(_PALM))]
    palm, _ = project(palm3, pose, centre_px=centre_px, scale_px=scale_px)
    cv2.fillPoly(img, [np.round(palm * 16).astype(np.int32)], skin.tolist(), cv2.LINE_AA, 4)
    web = np.array([kp[1], kp[2], palm[2], palm[1]])
    cv2.fillPoly(img, [np.round(web * 16).astype(np.int32)], (skin * 0.97).tolist(), cv2.LINE_AA, 4)
    shade = np.ones(5) if shade is None else shade
    chains = finger_chains()
    order = sorted(range(5), key=lambda f: float(np.mean(depth[chains[f][2:]])))
    for f in order:
        ch = chains[f]
        r = RADII[f] * scale_px
        segs = sorted(range(1, 4), key=lambda k: float(depth[ch[k]] + depth[ch[k + 1]]))
        for k in segs:
            _capsule(img, kp[ch[k]], kp[ch[k + 1]], r * (1.0 - 0.06 * k), skin * shade[f], edge)
    return kp


def _place(rng: np.random.Generator, kp_unit: np.ndarray, framing: str, w: int, h: int
           ) -> tuple[tuple[float, float], float]:
    """Wrist position and palm length (px) so the hand sits as ``framing`` asks."""
    lo, hi = kp_unit.min(axis=0), kp_unit.max(axis=0)
    ext = hi - lo
    if framing == "bottom":
        s = rng.uniform(0.55, 0.85) * h / max(ext[1], 1e-6)
        s = min(s, 0.95 * w / max(ext[0], 1e-6))
        cx = rng.uniform(0.3, 0.7) * w - s * (lo[0] + hi[0]) / 2
        return (cx, h - rng.uniform(-0.05, 0.12) * s), s
    s = rng.uniform(0.45, 0.85) * min(w, h) / max(ext.max(), 1e-6)
    if framing == "inside":
        room = np.array([w, h]) - s * ext
        off = rng.uniform(0, np.maximum(room, 1.0)) - s * lo
        return (float(off[0]), float(off[1])), s
    side = rng.integers(4)                                 # "border": cross an edge by 0-12 % of the hand
    over = rng.uniform(0.0, 0.12) * s * ext
    off = rng.uniform(0, np.maximum(np.array([w, h]) - s * ext, 1.0)) - s * lo
    if side == 0:
        off[0] = -s * lo[0] - over[0]
    elif side == 1:
        off[0] = w - s * hi[0] + over[0]
    elif side == 2:
        off[1] = -s * lo[1] - over[1]
    else:
        off[1] = h - s * hi[1] + over[1]
    return (float(off[0]), float(off[1])), s


def _look(rng: np.random.Generator, img: np.ndarray) -> np.ndarray:
    """Lighting gradient, colour cast, gamma, blur, noise -> uint8."""
    h, w = img.shape[:2]
    ang = rng.uniform(0, 2 * math.pi)
    yy, xx = np.mgrid[0:h, 0:w]
    grad = 1 + rng.uniform(0, 0.35) * (((xx / w - 0.5) * math.cos(ang) + (yy / h - 0.5) * math.sin(ang)))
    out = img * grad[..., None] * rng.uniform(0.6, 1.25) * rng.uniform(0.9, 1.1, 3)
    out = 255 * np.clip(out / 255, 0, 1) ** rng.uniform(0.8, 1.25)
    sigma = rng.uniform(0.0, 1.0)
    if sigma > 0.3:
        out = cv2.GaussianBlur(out, (0, 0), sigma)
    out = out + rng.normal(0, rng.uniform(1, 6), out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


def _random_spec(rng: np.random.Generator, spec: SceneSpec) -> SceneSpec:
    framing = spec.framing or str(rng.choice(FRAMINGS, p=[0.45, 0.35, 0.2]))
    background = spec.background or str(rng.choice(BACKGROUNDS, p=[0.4, 0.35, 0.15, 0.1]))
    arm = bool(rng.random() < 0.6) if spec.arm is None else spec.arm
    return replace(spec, framing=framing, background=background, arm=arm or framing == "bottom")


def render_scene(rng: np.random.Generator, spec: SceneSpec = SceneSpec()) -> tuple[np.ndarray, HandTruth]:
    """One image (H, W, 3) BGR uint8 (or (H, W) with ``spec.mono``) and the truth of its first hand."""
    spec = _random_spec(rng, spec)
    h, w = spec.height_px, spec.width_px
    skin = skin_colour(rng)
    img = _background(rng, spec.background, h, w, skin)
    truth = HandTruth(np.full((21, 2), np.nan), 0, "none", 0.0, False, np.zeros(5, bool), spec)
    poses = [sample_pose(rng, spec.gesture, spread=spec.spread, upright=spec.framing == "bottom")
             for _ in range(spec.hands)]
    placed = []
    for i, pose in enumerate(poses):
        kp_unit, _ = project(forward_kinematics(pose), pose, centre_px=(0.0, 0.0), scale_px=1.0)
        centre, s = _place(rng, kp_unit, spec.framing if i == 0 else "inside", w, h)
        if i == 1:                                         # the second hand: smaller, elsewhere, behind
            s *= rng.uniform(0.55, 0.8)
            lo, hi = kp_unit.min(axis=0) * s, kp_unit.max(axis=0) * s
            centre = (rng.uniform(-lo[0], max(w - hi[0], 1 - lo[0])), rng.uniform(-lo[1], max(h - hi[1], 1 - lo[1])))
        placed.append((pose, centre, s))
    for i in reversed(range(len(placed))):
        pose, centre, s = placed[i]
        tone = skin if i == 0 else skin_colour(rng)
        sleeve = rng.uniform(0, 255, 3) if rng.random() < 0.3 else None
        kp = draw_hand(img, pose, centre_px=centre, scale_px=s, skin=tone, sleeve=sleeve,
                       arm_len=rng.uniform(1.5, 4.0) if (spec.arm if i == 0 else rng.random() < 0.5) else 0.0,
                       shade=rng.uniform(0.9, 1.06, 5))
        if i == 0:
            truth = HandTruth(kp, count_of(pose.extended), gesture_of(pose.extended),
                              float(np.linalg.norm(kp[9] - kp[0])), True, pose.extended.copy(), spec)
    out = _look(rng, img)
    if spec.mono:
        out = cv2.cvtColor(out, cv2.COLOR_BGR2GRAY)
    return out, truth
