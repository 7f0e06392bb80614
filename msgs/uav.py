"""UAV messages: commands, state estimates and geo fixes (east-north metres, yaw CCW from east
of the camera image's "up")."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class UavCommand(Message, tag="uav.UavCommand"):
    """The four motions of seed 11: planar velocity in the body frame (forward = image up),
    yaw rate, climb rate (negative: descend)."""

    forward_mps: float = 0.0
    right_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    climb_mps: float = 0.0


class UavState(Message, tag="uav.UavState"):
    """A pose: east, north, altitude above ground, yaw. ``source``: "truth" or "ins"."""

    e_m: float = 0.0
    n_m: float = 0.0
    alt_m: float = 0.0
    yaw_rad: float = 0.0
    source: str = "truth"


class GeoFix(Message, tag="uav.GeoFix"):
    """A frame registered to the map, or not (``ok`` False with ``reason``; the numbers are then
    the prediction). ``cov_m2`` (2, 2) east-north covariance; ``alpha``, ``theta_rad``,
    ``b_px`` the similarity of seed 11 eq. (2.2); ``mode`` "search" or "localise"."""

    ok: bool = False
    reason: str = ""
    e_m: float = 0.0
    n_m: float = 0.0
    yaw_rad: float = 0.0
    alt_m: float = 0.0
    cov_m2: np.ndarray = const(np.full((2, 2), np.inf))
    inliers: int = 0
    matches: int = 0
    alpha: float = 0.0
    theta_rad: float = 0.0
    b_px: np.ndarray = const(np.zeros(2))
    mode: str = "search"
    compute_ms: float = 0.0
