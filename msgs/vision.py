"""Vision messages: rectified stereo pairs, a cable reconstructed in 3-D, and its ground truth.

Pixel coordinates are (x right, y down) from the top-left pixel's centre; 3-D points are in
the left camera's optical frame (x right, y down, z forward), metres."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class StereoPair(Message, tag="vision.StereoPair"):
    """A rectified stereo pair taken at one instant: both images (H, W, 3) uint8 BGR, equal
    rectified intrinsics (``f_px``, ``cx_px``, ``cy_px``) and the right camera at
    +``baseline_m`` along x. Rectified means a scene point lies on the same row in both."""

    left: np.ndarray = const(np.zeros((0, 0, 3), np.uint8))
    right: np.ndarray = const(np.zeros((0, 0, 3), np.uint8))
    f_px: float = 0.0
    cx_px: float = 0.0
    cy_px: float = 0.0
    baseline_m: float = 0.0


class Cable3D(Message, tag="vision.Cable3D"):
    """A cable as a 3-D polyline in tracked order: ``points_m`` (N, 3) with one-sigma
    ``sigma_m`` (N, 3) per axis, ``segment`` (N,) the image stretch each point is on (a cable
    that leaves the image and comes back has two), ``left_px`` (N, 2) where it was tracked.
    ``status``: "tracked", "lost" (no cable) or "ambiguous" (found but not trusted: along the
    epipolar lines, or two cables that match alike); ``reason`` says why."""

    points_m: np.ndarray = const(np.zeros((0, 3)))
    sigma_m: np.ndarray = const(np.zeros((0, 3)))
    segment: np.ndarray = const(np.zeros(0, np.int32))
    left_px: np.ndarray = const(np.zeros((0, 2)))
    status: str = "lost"
    reason: str = ""
    usable_frac: float = 0.0
    compute_ms: float = 0.0


class CableTruth(Message, tag="vision.CableTruth"):
    """Simulator ground truth: the true curve (N, 3) in the left camera frame, its left-image
    projection (N, 2), and which samples are visible in the left image; ``others_m`` (M, 3)
    the samples of any other cable in the scene."""

    points_m: np.ndarray = const(np.zeros((0, 3)))
    left_px: np.ndarray = const(np.zeros((0, 2)))
    visible: np.ndarray = const(np.zeros(0, bool))
    others_m: np.ndarray = const(np.zeros((0, 3)))
