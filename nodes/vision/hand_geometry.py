"""Gestures from 21 hand keypoints (MediaPipe order) by their geometry alone: a finger is
extended when its tip lies well beyond its middle joint as seen from the wrist and far from
the palm; the thumb when its tip is away from the palm's centre line and the index base. Scale
free: lengths are in units of the palm (wrist to middle-finger MCP), so it works at any
distance, rotation and handedness.

    ext = extended_fingers(kp)            # (5,) bool, thumb first
    gesture_label(ext)                    # "victory"
"""
from __future__ import annotations

import numpy as np

__all__ = ["GESTURE_SETS", "THRESHOLDS", "extended_fingers", "finger_scores", "gesture_label"]

# Finger sets (thumb, index, middle, ring, pinky) of the named gestures; the simulator renders
# from this table too (sim.hand.GESTURES).
GESTURE_SETS: dict[str, tuple[tuple[int, ...], ...]] = {
    "fist": ((0, 0, 0, 0, 0),),
    "point": ((0, 1, 0, 0, 0),),
    "thumb": ((1, 0, 0, 0, 0),),
    "victory": ((0, 1, 1, 0, 0),),
    "L": ((1, 1, 0, 0, 0),),
    "three": ((0, 1, 1, 1, 0), (1, 1, 1, 0, 0)),
    "four": ((0, 1, 1, 1, 1),),
    "open": ((1, 1, 1, 1, 1),),
}


# Thresholds (palm lengths) halfway across the gap between straight and curled fingers in
# simulated poses (training seeds): the tip's distance from its MCP (index..pinky), and the
# thumb tip's distance from the pinky MCP.
THRESHOLDS = np.array([0.76, 0.60, 0.70, 0.66, 0.52])


def finger_scores(keypoints: np.ndarray) -> np.ndarray:
    """Extension scores (5,) for thumb..pinky in palm lengths, 0 at the decision threshold,
    positive = extended.

    Fingers: the tip's distance from the MCP (a straight index reaches ~0.85, a curled one
    ~0.3-0.5). Thumb: the tip's distance from the pinky MCP (a tucked thumb lies across the
    palm, ~0.6; an extended one ~1.0).

    Parameters
    ----------
    keypoints : (21, 2) or (21, 3) float, pixels, MediaPipe order.
    """
    kp = np.asarray(keypoints, float)
    if kp.ndim != 2 or kp.shape[0] != 21 or kp.shape[1] < 2 or not np.all(np.isfinite(kp[:, :2])):
        raise ValueError(f"need 21 finite keypoints (21, 2), got shape {np.shape(keypoints)} "
                         "(no hand: check presence before asking for a gesture)")
    kp = kp[:, :2]
    palm = max(float(np.linalg.norm(kp[9] - kp[0])), 1e-6)
    dist = np.empty(5)
    dist[0] = np.linalg.norm(kp[4] - kp[17])
    for f in range(1, 5):
        dist[f] = np.linalg.norm(kp[4 + 4 * f] - kp[1 + 4 * f])
    return dist / palm - THRESHOLDS


def extended_fingers(keypoints: np.ndarray) -> np.ndarray:
    """(5,) bool: which fingers (thumb first) are extended, from :func:`finger_scores`."""
    return finger_scores(keypoints) > 0


def gesture_label(extended: np.ndarray) -> str:
    """The gesture whose finger set this is, else ``"count<n>"``."""
    key = tuple(int(b) for b in np.asarray(extended, bool))
    for name, sets in GESTURE_SETS.items():
        if key in sets:
            return name
    return f"count{sum(key)}"
