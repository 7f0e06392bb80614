"""Motion laws inside a simulated CiA 402 drive: the profile approach to a position, and the
cyclic synchronous position interpolator. Pure functions of counts and seconds."""
from __future__ import annotations

import math
from typing import NamedTuple


def approach_velocity(error: float, v_max: float, accel: float, tau_s: float) -> float:
    """Velocity demand (counts/s) toward a position ``error`` counts away: at most ``v_max``,
    braking in time (``v^2 = 2 a d``), and no faster than the motor lag ``tau_s`` can stop."""
    return math.copysign(min(v_max, math.sqrt(2 * accel * abs(error)), abs(error) / tau_s), error)


class CspSegment(NamedTuple):
    """One SYNC's worth of CSP: from ``start`` to ``end`` (counts) over ``period_s`` from ``t0_s``."""

    start: float
    end: float
    t0_s: float
    period_s: float

    def demand(self, t_s: float) -> tuple[float, float]:
        """Position demand (counts) and its rate (counts/s) at ``t_s``: linear over the period, then held."""
        if self.period_s <= 0 or t_s >= self.t0_s + self.period_s:
            return self.end, 0.0
        u = max(0.0, (t_s - self.t0_s) / self.period_s)
        return self.start + u * (self.end - self.start), (self.end - self.start) / self.period_s
