"""Per-axle wheel commands <-> per-drive CiA 402 set-points (counts/s and counts).

A double-Ackermann vehicle is commanded per axle: axle-centre wheel speed ``v`` (m/s)
and steer angle ``delta`` (rad) for the front and the rear. On the bus each axle is a
*wheel* drive in profile velocity (counts/s) and a *steer* drive in profile position
(counts). ``counts_per_unit`` is counts per metre of wheel travel for a wheel drive and
counts per radian of steer angle for a steer drive (negative to flip a mounting).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping

ROLES = ("wheel", "steer")
AXLES = ("front", "rear")


@dataclass(frozen=True)
class AxleDrive:
    """One motor: ``name``, ``role`` (wheel / steer), ``axle`` (front / rear), scale."""

    name: str
    role: str
    axle: str
    counts_per_unit: float

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"drive {self.name!r}: role must be one of {ROLES}, not {self.role!r}")
        if self.axle not in AXLES:
            raise ValueError(f"drive {self.name!r}: axle must be one of {AXLES}, not {self.axle!r}")
        if not math.isfinite(self.counts_per_unit) or self.counts_per_unit == 0:
            raise ValueError(f"drive {self.name!r}: counts_per_unit must be finite and non-zero")


def fold_steer(v_mps: float, delta_rad: float, steer_limit_rad: float) -> tuple[float, float]:
    """Bring a steer angle inside ``[-limit, limit]`` by turning the wheel half a turn and
    reversing its speed (the same axle velocity vector).

    Parameters
    ----------
    v_mps, delta_rad : float
        Axle-centre speed (m/s) and steer angle (rad, any value; wrapped to [-pi, pi)).
    steer_limit_rad : float
        Mechanical limit, >= pi/2 so every direction is reachable one way or the other.

    Returns
    -------
    (v_mps, delta_rad) : tuple of float
        Equivalent command with ``|delta| <= limit`` (clipped when the limit is < pi/2).
    """
    if not (math.isfinite(v_mps) and math.isfinite(delta_rad)):
        raise ValueError(f"wheel command must be finite, got v={v_mps}, delta={delta_rad}")
    delta = (delta_rad + math.pi) % (2 * math.pi) - math.pi
    if abs(delta) > steer_limit_rad:
        flipped = delta - math.copysign(math.pi, delta)
        if abs(flipped) <= steer_limit_rad or abs(flipped) < abs(delta):
            v_mps, delta = -v_mps, flipped
        delta = max(-steer_limit_rad, min(steer_limit_rad, delta))
    return v_mps, delta


def setpoints_from_command(v_front_mps: float, delta_front_rad: float, v_rear_mps: float, delta_rear_rad: float,
                           drives: Iterable[AxleDrive], *, steer_limit_rad: float = math.pi / 2 + 0.1
                           ) -> dict[str, int]:
    """Per-drive set-points: counts/s for wheel drives, counts for steer drives.

    Raises ``ValueError`` on a non-finite command (the caller must then hold or stop).
    """
    axle = {"front": fold_steer(v_front_mps, delta_front_rad, steer_limit_rad),
            "rear": fold_steer(v_rear_mps, delta_rear_rad, steer_limit_rad)}
    out: dict[str, int] = {}
    for d in drives:
        v, delta = axle[d.axle]
        value = v if d.role == "wheel" else delta
        out[d.name] = int(round(value * d.counts_per_unit))
    return out


def command_from_actuals(actuals: Mapping[str, float], drives: Iterable[AxleDrive]) -> tuple[float, float, float, float]:
    """Inverse of :func:`setpoints_from_command` on measured values.

    ``actuals`` maps drive name to velocity actual (counts/s) for wheels and position
    actual (counts) for steering. Returns ``(v_front, delta_front, v_rear, delta_rear)``
    in m/s and rad; an axle with several drives of a role gets their mean, a missing
    drive reads 0.
    """
    sums: dict[tuple[str, str], list[float]] = {}
    for d in drives:
        if d.name in actuals:
            sums.setdefault((d.axle, d.role), []).append(actuals[d.name] / d.counts_per_unit)

    def mean(axle: str, role: str) -> float:
        vals = sums.get((axle, role), [])
        return sum(vals) / len(vals) if vals else 0.0

    return mean("front", "wheel"), mean("front", "steer"), mean("rear", "wheel"), mean("rear", "steer")
