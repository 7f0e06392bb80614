"""Set-membership messages: measurements with bounded errors, and guaranteed sets (boxes,
pavings, tubes). A box is a (2, 2) array ``[[x_lo, y_lo], [x_hi, y_hi]]`` in metres;
box lists are (K, 2, 2). An empty set is a list with no boxes, never NaN."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class BoundedOdometry(Message, tag="sets.BoundedOdometry"):
    """One step of odometry: travelled distance and the heading it was made with, each
    as a value +- a guaranteed error bound (half-width)."""

    step: int = 0
    distance_m: float = 0.0
    distance_err_m: float = 0.0
    heading_rad: float = 0.0
    heading_err_rad: float = 0.0


class MarkerRanges(Message, tag="sets.MarkerRanges"):
    """Markers measured at one step: ``marker_id`` (N,) int32, ``range_m`` (N,) +- ``range_err_m``,
    ``bearing_rad`` (N,) relative to the heading (NaN: no bearing) +- ``bearing_err_rad``; the
    compass at the same instant (``heading_rad`` +- ``heading_err_rad``) turns them into world
    bearings. An empty message still marks the step (nothing was seen)."""

    step: int = 0
    marker_id: np.ndarray = const(np.zeros(0, np.int32))
    range_m: np.ndarray = const(np.zeros(0))
    range_err_m: np.ndarray = const(np.zeros(0))
    bearing_rad: np.ndarray = const(np.zeros(0))
    bearing_err_rad: np.ndarray = const(np.zeros(0))
    heading_rad: float = 0.0
    heading_err_rad: float = 0.0


class SetEstimate(Message, tag="sets.SetEstimate"):
    """The robot's position as a guaranteed set at one step: the hull ``box`` and the paving
    (``inner`` boxes proven inside, ``boundary`` boxes of width <= eps). ``consistent`` False:
    the measurements contradict the bounds (an outlier); ``box`` is then the prediction and
    ``outliers_allowed`` > 0 says a q-relaxed set was published instead."""

    step: int = 0
    box: np.ndarray = const(np.full((2, 2), np.nan))
    inner: np.ndarray = const(np.zeros((0, 2, 2)))
    boundary: np.ndarray = const(np.zeros((0, 2, 2)))
    width_m: float = 0.0
    consistent: bool = True
    outliers_allowed: int = 0
    compute_ms: float = 0.0


class SetMap(Message, tag="sets.SetMap"):
    """Set-membership SLAM after one step: the robot tube (K+1, 2, 2) over the whole history
    and the marker boxes (M, 2, 2; +-inf until a range bounds them)."""

    step: int = 0
    tube: np.ndarray = const(np.zeros((0, 2, 2)))
    markers: np.ndarray = const(np.zeros((0, 2, 2)))
    consistent: bool = True
    sweeps: int = 0
    compute_ms: float = 0.0
