"""Hand messages (seed 13): a hand's 21 keypoints (MediaPipe order), its finger count and
gesture as estimated, and the simulator's ground truth. Pixels are (x right, y down) from the
top-left pixel's centre."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class HandGesture(Message, tag="hand.HandGesture"):
    """A hand seen in one image (``stamp_ns`` is the image's). ``present`` False: no hand (then
    ``count`` 0, ``gesture`` "none", keypoints NaN). ``keypoints_px`` (21, 2), ``keypoint_conf``
    (21,) in [0, 1] (empty for a method without keypoints); ``extended`` (5,) bool thumb..pinky;
    ``gesture`` a name ("fist", "point", "thumb", "victory", "L", "three", "four", "open") or
    "count<n>"; ``confidence`` in [0, 1]; ``method`` "learned" or "convexity"."""

    present: bool = False
    keypoints_px: np.ndarray = const(np.full((21, 2), np.nan, np.float32))
    keypoint_conf: np.ndarray = const(np.zeros(0, np.float32))
    extended: np.ndarray = const(np.zeros(5, bool))
    count: int = 0
    gesture: str = "none"
    confidence: float = 0.0
    method: str = "learned"
    compute_ms: float = 0.0


class HandTruth(Message, tag="hand.HandTruth"):
    """Simulator ground truth of the (first) hand in an image: keypoints (21, 2) px (NaN when
    no hand), finger count, gesture, palm length in px (wrist to middle MCP)."""

    present: bool = False
    keypoints_px: np.ndarray = const(np.full((21, 2), np.nan, np.float32))
    count: int = 0
    gesture: str = "none"
    palm_px: float = 0.0
