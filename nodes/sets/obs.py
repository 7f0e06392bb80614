"""Bounded-error messages to interval observations (outward rounded): the one place that
turns ``value +- err`` into the intervals the set methods contract with."""
from __future__ import annotations

import math

import numpy as np

from msgs.sets import BoundedOdometry, MarkerRanges
from nodes.sets import interval as iv
from nodes.sets.localize import Observation, displacement, world_bearing


def pm(value: float, err: float) -> tuple[float, float]:
    """[value - err, value + err], each bound one ulp outward."""
    lo, hi = iv.sub(iv.interval(value), iv.interval(err)), iv.add(iv.interval(value), iv.interval(err))
    return float(lo[0]), float(hi[1])


def step_box(msg: BoundedOdometry) -> np.ndarray:
    """(2, 2) displacement box of one odometry step."""
    return displacement(pm(msg.distance_m, msg.distance_err_m), pm(msg.heading_rad, msg.heading_err_rad))


def observations(msg: MarkerRanges, markers: dict[int, tuple[float, float]] | None = None) -> tuple[list[Observation], list[int]]:
    """(observations, unknown ids). ``markers`` maps ids to known positions; None: positions
    are unknown (SLAM), and each observation's ``marker`` holds (id, nan)."""
    out, unknown = [], []
    heading = pm(msg.heading_rad, msg.heading_err_rad)
    for j, r, er, b, eb in zip(msg.marker_id.tolist(), msg.range_m.tolist(), msg.range_err_m.tolist(),
                               msg.bearing_rad.tolist(), msg.bearing_err_rad.tolist()):
        if not (math.isfinite(r) and math.isfinite(er) and er >= 0):
            unknown.append(j)
            continue
        if markers is not None and j not in markers:
            unknown.append(j)
            continue
        bearing = world_bearing(heading, pm(b, eb)) if math.isfinite(b) and math.isfinite(eb) else None
        if bearing is not None and bearing[1] - bearing[0] >= math.pi - 1e-6:
            bearing = None                              # too wide to be a wedge: the range alone
        pos = markers[j] if markers is not None else (float(j), math.nan)
        out.append(Observation(pos, pm(r, er), bearing))
    return out, unknown
