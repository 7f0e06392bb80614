"""An articulated hand (seed 13): palm plus five fingers with joint limits, 21 keypoints in the
MediaPipe order, posed in 3-D and projected (weak perspective) into an image. Only what the
gesture scenes need: rigid segments, flexion and splay per finger, a tilt out of the image
plane; the renderer (:mod:`sim.hand_render`) draws it as capsules and a palm polygon.

Hand frame, in units of the palm length (wrist to middle-finger MCP = 1): x toward the thumb,
y toward the fingers, z out of the palm (toward the camera when the palm faces it). Flexion
curls a finger toward +z, so a curled finger projects onto the palm.

    rng = np.random.default_rng(0)
    pose = sample_pose(rng, "victory", spread=True)
    kp3 = forward_kinematics(pose)                      # (21, 3) hand frame
    px, depth = project(kp3, pose, centre_px=(64, 100), scale_px=40)   # (21, 2) image, (21,) toward camera
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from nodes.vision.hand_geometry import GESTURE_SETS

__all__ = ["FINGERS", "GESTURES", "KEYPOINT_NAMES", "LIMITS", "HandPose", "count_of", "finger_chains",
           "forward_kinematics", "gesture_of", "project", "sample_pose"]

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
KEYPOINT_NAMES = ("wrist",
                  "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
                  "index_mcp", "index_pip", "index_dip", "index_tip",
                  "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
                  "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
                  "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip")

# Gestures by the set of extended fingers (thumb, index, middle, ring, pinky). A count is the
# number of extended fingers; the wrist and arm are never fingers. One table for the simulator
# and the recogniser (nodes/ does not import sim/, so it lives there).
GESTURES = GESTURE_SETS

# Geometry (palm lengths): MCPs of index..pinky, thumb CMC, segment lengths, radii.
_MCP = np.array([[0.30, 0.95], [0.10, 1.0], [-0.10, 0.96], [-0.28, 0.88]])
_CMC = np.array([0.24, 0.20])
_SEGMENTS = np.array([[0.40, 0.32, 0.26], [0.42, 0.25, 0.20], [0.47, 0.29, 0.21], [0.44, 0.27, 0.20],
                      [0.34, 0.21, 0.18]])
RADII = np.array([0.11, 0.095, 0.10, 0.093, 0.08])

# Joint limits (rad). Fingers: MCP, PIP, DIP flexion; splay (abduction, + toward the thumb).
# Thumb: CMC abduction from the palm's axis, MCP and IP flexion (curl across the palm).
LIMITS = {"flex": ((-0.2, 1.6), (0.0, 1.9), (0.0, 1.3)), "splay": (-0.45, 0.45),
          "thumb_abd": (0.1, 1.3), "thumb_flex": ((0.0, 1.1), (0.0, 1.4))}


@dataclass(frozen=True)
class HandPose:
    """Joint angles (rad) and the hand's orientation.

    ``flex`` (5, 3): per finger (thumb first) the three flexions (thumb: CMC abduction, MCP, IP);
    ``splay`` (5,): abduction per finger (thumb unused); ``roll_rad`` in the image plane
    (0: fingers up, + counter-clockwise on screen); ``yaw_rad``/``pitch_rad`` tilt the palm out
    of the image plane; ``mirror`` makes it the other hand; ``extended`` (5,) bool: the fingers
    posed straight (the ground truth a count is made of); ``scale`` (5,) finger length factors.
    """

    flex: np.ndarray = field(default_factory=lambda: np.zeros((5, 3)))
    splay: np.ndarray = field(default_factory=lambda: np.zeros(5))
    roll_rad: float = 0.0
    yaw_rad: float = 0.0
    pitch_rad: float = 0.0
    mirror: bool = False
    extended: np.ndarray = field(default_factory=lambda: np.ones(5, bool))
    scale: np.ndarray = field(default_factory=lambda: np.ones(5))

    def clipped(self) -> "HandPose":
        """The pose with every joint inside :data:`LIMITS`."""
        flex = self.flex.copy()
        for j, (lo, hi) in enumerate(LIMITS["flex"]):
            flex[1:, j] = np.clip(flex[1:, j], lo, hi)
        flex[0, 0] = np.clip(flex[0, 0], *LIMITS["thumb_abd"])
        for j, (lo, hi) in enumerate(LIMITS["thumb_flex"]):
            flex[0, j + 1] = np.clip(flex[0, j + 1], lo, hi)
        return replace(self, flex=flex, splay=np.clip(self.splay, *LIMITS["splay"]))


def finger_chains() -> list[list[int]]:
    """Keypoint indices of each finger's chain from the wrist: [[0, 1, 2, 3, 4], [0, 5, 6, 7, 8], ...]."""
    return [[0] + [1 + 4 * f + k for k in range(4)] for f in range(5)]


def forward_kinematics(pose: HandPose) -> np.ndarray:
    """The 21 keypoints (21, 3) in the hand frame (palm lengths), joints clipped to their limits."""
    p = pose.clipped()
    kp = np.zeros((21, 3))
    # thumb: an in-plane fan from the palm axis toward x, flexion turning it back across the palm
    abd, mcp, ip = p.flex[0]
    kp[1, :2] = _CMC
    angles = np.array([abd, abd - mcp, abd - mcp - ip])
    elev = np.array([0.15, 0.15 + 0.5 * mcp, 0.15 + 0.5 * (mcp + ip)])
    pts = kp[1].copy()
    for k in range(3):
        d = np.array([math.sin(angles[k]) * math.cos(elev[k]), math.cos(angles[k]) * math.cos(elev[k]), math.sin(elev[k])])
        pts = pts + _SEGMENTS[0, k] * p.scale[0] * d
        kp[2 + k] = pts
    for f in range(1, 5):
        base = 1 + 4 * f
        kp[base, :2] = _MCP[f - 1]
        s = p.splay[f]
        u = np.array([math.sin(s), math.cos(s), 0.0])
        theta = np.cumsum(p.flex[f])
        pts = kp[base].copy()
        for k in range(3):
            d = math.cos(theta[k]) * u + np.array([0.0, 0.0, math.sin(theta[k])])
            pts = pts + _SEGMENTS[f, k] * p.scale[f] * d
            kp[base + 1 + k] = pts
    return kp


def _rotation(pose: HandPose) -> np.ndarray:
    cy, sy = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    cp, sp = math.cos(pose.pitch_rad), math.sin(pose.pitch_rad)
    cr, sr = math.cos(pose.roll_rad), math.sin(pose.roll_rad)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return rz @ rx @ ry


def project(points: np.ndarray, pose: HandPose, *, centre_px: tuple[float, float], scale_px: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """Hand-frame points (N, 3) -> image pixels (N, 2) (x right, y down) and depth (N,) toward
    the camera (palm lengths; larger is nearer). The wrist (hand-frame origin) lands on
    ``centre_px``; ``scale_px`` is the palm length in pixels."""
    q = np.asarray(points, float).copy()
    if pose.mirror:
        q[:, 0] = -q[:, 0]
    q = q @ _rotation(pose).T
    px = np.stack([centre_px[0] + scale_px * q[:, 0], centre_px[1] - scale_px * q[:, 1]], axis=1)
    return px, q[:, 2]


def count_of(extended: np.ndarray) -> int:
    """Finger count: the extended fingers (the thumb included)."""
    return int(np.sum(np.asarray(extended, bool)))


def gesture_of(extended: np.ndarray) -> str:
    """The gesture whose finger set this is, else ``"count<n>"`` (e.g. pinky alone: ``"count1"``)."""
    key = tuple(int(b) for b in np.asarray(extended, bool))
    for name, sets in GESTURES.items():
        if key in sets:
            return name
    return f"count{sum(key)}"


def sample_pose(rng: np.random.Generator, gesture: str | None = None, *, spread: bool | None = None,
                upright: bool = False) -> HandPose:
    """A random pose of ``gesture`` (a key of :data:`GESTURES`; None: any, uniformly).

    Extended fingers are straight within a little flexion, curled ones near full flexion;
    ``spread`` True splays the extended fingers wide apart (the "spread V"), False keeps
    them together; ``upright`` keeps the fingers within 35 deg of image-up (like a signer).
    """
    if gesture is None:
        gesture = str(rng.choice(list(GESTURES)))
    if gesture not in GESTURES:
        raise ValueError(f"unknown gesture {gesture!r}; one of {sorted(GESTURES)}")
    sets = GESTURES[gesture]
    ext = np.array(sets[rng.integers(len(sets))], bool)
    flex = np.zeros((5, 3))
    for f in range(1, 5):
        if ext[f]:
            flex[f] = rng.uniform([-0.1, 0.0, 0.0], [0.25, 0.25, 0.2])
        else:
            flex[f] = rng.uniform([1.25, 1.45, 0.6], [1.6, 1.9, 1.2])
    if ext[0]:
        flex[0] = rng.uniform([0.75, 0.0, 0.0], [1.2, 0.25, 0.3])
    else:
        flex[0] = rng.uniform([0.25, 0.7, 0.8], [0.45, 1.0, 1.3])
    if spread is None:
        spread = bool(rng.random() < 0.5)
    width = rng.uniform(0.12, 0.3) if spread else rng.uniform(0.0, 0.08)
    splay = np.array([0.0, 1.5, 0.5, -0.5, -1.5]) * width + rng.normal(0, 0.03, 5)
    if ext[1] and ext[2] and not ext[3] and spread:            # a V: the two fingers fan apart
        splay[1], splay[2] = rng.uniform(0.2, 0.4), rng.uniform(-0.35, -0.15)
    roll = rng.uniform(-0.6, 0.6) if upright else rng.uniform(-math.pi, math.pi)
    return HandPose(flex=flex, splay=splay, roll_rad=float(roll), yaw_rad=float(rng.uniform(-0.5, 0.5)),
                    pitch_rad=float(rng.uniform(-0.35, 0.35)), mirror=bool(rng.random() < 0.5), extended=ext,
                    scale=rng.uniform(0.92, 1.1, 5)).clipped()
