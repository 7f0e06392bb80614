"""Reference trajectories for a double-Ackermann robot, with analytic first and second derivatives.

Every generator maps times ``t`` (s, shape (N,)) to a :class:`Reference`: pose
``p = (x, y, theta)`` and its time derivatives, each of shape (N, 3), in metres, radians
and seconds.  Headings are wrapped to [-pi, pi); their derivatives are those of the
continuous angle.  A four-wheel-steer robot controls its heading independently of its
path, so besides the usual "heading along the tangent" every path takes a heading law:
fixed, sinusoidal, spinning, or aimed at a focus point (seed 15, Fig. 8).
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np


class Reference(NamedTuple):
    """Pose, velocity and acceleration references, each (N, 3): (x m, y m, theta rad) and rates."""

    p: np.ndarray
    dp: np.ndarray
    ddp: np.ndarray


def _as_t(t: np.ndarray | float) -> np.ndarray:
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError("t must be a finite scalar or 1-D array of times in seconds")
    return t


def _pack(xy: tuple, dxy: tuple, ddxy: tuple, th: tuple) -> Reference:
    """Stack (x, y), their rates and a heading triple (theta, dtheta, ddtheta) into a Reference."""
    theta = (th[0] + np.pi) % (2 * np.pi) - np.pi
    return Reference(np.stack([xy[0], xy[1], theta], axis=1),
                     np.stack([dxy[0], dxy[1], th[1]], axis=1),
                     np.stack([ddxy[0], ddxy[1], th[2]], axis=1))


def circle(t: np.ndarray | float, *, radius_m: float = 1.5, speed_mps: float = 0.5,
           center_xy: tuple[float, float] = (0.0, 0.0), heading: str | float = "tangent") -> Reference:
    """Counter-clockwise circle at constant speed, starting at ``center + (radius, 0)``.

    heading : "tangent" (drive forward), "reverse" (tangent + pi: the robot backs round it),
        or a number (rad): a fixed heading, so the wheels sweep the full circle of directions.
    """
    t = _as_t(t)
    if radius_m <= 0 or speed_mps == 0:
        raise ValueError("circle needs radius_m > 0 and a non-zero speed_mps")
    w = speed_mps / radius_m
    c, s = np.cos(w * t), np.sin(w * t)
    xy = (center_xy[0] + radius_m * c, center_xy[1] + radius_m * s)
    dxy = (-radius_m * w * s, radius_m * w * c)
    ddxy = (-radius_m * w * w * c, -radius_m * w * w * s)
    if heading in ("tangent", "reverse"):
        off = 0.0 if heading == "tangent" else np.pi
        base = np.arctan2(dxy[1], dxy[0]) + off
        th = (base, np.full_like(t, w), np.zeros_like(t))
    else:
        th = (np.full_like(t, float(heading)), np.zeros_like(t), np.zeros_like(t))
    return _pack(xy, dxy, ddxy, th)


def figure_eight(t: np.ndarray | float, *, half_length_m: float = 2.0, half_width_m: float = 1.0,
                 period_s: float = 40.0, heading_rad: float = -math.pi / 2,
                 heading_amp_rad: float = 0.4, heading_period_s: float = 13.0) -> Reference:
    """Lemniscate of Gerono ``x = a sin(wt)``, ``y = b sin(wt) cos(wt)`` with an independent heading.

    The heading ``theta = heading_rad + heading_amp_rad * sin(2 pi t / heading_period_s)``
    is unrelated to the path tangent.  The default mean heading faces -y, the direction of
    travel at both lobe tips, so the wheels' direction in the robot frame swings about
    +-(pi/2 + atan(b/a) + amp) around straight ahead: with the defaults the steer angles
    stay within +-2.41 rad at under 1.1 rad/s (no half-turn flip with a 2.5 rad steer range,
    provided the wheels start on the forward branch, see ``kinematics.initial_wheels``) and
    the rear wheel crosses |delta_b| = pi/2 every lap.
    """
    t = _as_t(t)
    if period_s <= 0 or heading_period_s <= 0:
        raise ValueError("figure_eight periods must be > 0 s")
    a, b, w = half_length_m, half_width_m, 2 * np.pi / period_s
    s1, c1 = np.sin(w * t), np.cos(w * t)
    s2, c2 = np.sin(2 * w * t), np.cos(2 * w * t)
    xy = (a * s1, 0.5 * b * s2)
    dxy = (a * w * c1, b * w * c2)
    ddxy = (-a * w * w * s1, -2 * b * w * w * s2)
    wh = 2 * np.pi / heading_period_s
    th = (heading_rad + heading_amp_rad * np.sin(wh * t),
          heading_amp_rad * wh * np.cos(wh * t),
          -heading_amp_rad * wh * wh * np.sin(wh * t))
    return _pack(xy, dxy, ddxy, th)


def crab(t: np.ndarray | float, *, amplitude_m: float = 1.0, period_s: float = 12.0,
         heading_rad: float = 0.0, start_xy: tuple[float, float] = (0.0, 0.0)) -> Reference:
    """Pure sideways motion, back and forth: ``p = start + A sin(wt) * (-sin h, cos h)``, heading fixed.

    The body never moves along its own x axis (v_tan = 0, both steer angles +-pi/2), and
    the speed passes through zero and reverses twice a period.
    """
    t = _as_t(t)
    if period_s <= 0:
        raise ValueError("crab needs period_s > 0")
    w = 2 * np.pi / period_s
    nx, ny = -math.sin(heading_rad), math.cos(heading_rad)
    d, dd, ddd = amplitude_m * np.sin(w * t), amplitude_m * w * np.cos(w * t), -amplitude_m * w * w * np.sin(w * t)
    z = np.zeros_like(t)
    return _pack((start_xy[0] + nx * d, start_xy[1] + ny * d), (nx * dd, ny * dd), (nx * ddd, ny * ddd),
                 (np.full_like(t, heading_rad), z, z))


def spin(t: np.ndarray | float, *, rate_radps: float = 0.8, center_xy: tuple[float, float] = (0.0, 0.0),
         heading_rad: float = 0.0) -> Reference:
    """Spin in place: fixed position, ``theta = heading + rate * t`` (wraps through +-pi)."""
    t = _as_t(t)
    z = np.zeros_like(t)
    return _pack((np.full_like(t, center_xy[0]), np.full_like(t, center_xy[1])), (z, z), (z, z),
                 (heading_rad + rate_radps * t, np.full_like(t, rate_radps), z))


def focus(t: np.ndarray | float, *, focus_xy: tuple[float, float] = (0.5, 0.3), path: str = "circle",
          **path_params: float) -> Reference:
    """Follow ``path`` ("circle" or "figure8") while the robot's x axis aims at ``focus_xy`` (seed Fig. 8).

    ``theta = atan2(f_y - y, f_x - x)`` (the seed's arctan of a ratio would lose the quadrant),
    with ``r = f - p``: ``dtheta = (r_x dr_y - r_y dr_x) / |r|^2`` and its derivative.
    Raises ValueError if the path passes within 1 cm of the focus point (heading undefined).
    """
    if path not in ("circle", "figure8"):
        raise ValueError(f"focus path must be 'circle' or 'figure8', not {path!r}")
    ref = (circle if path == "circle" else figure_eight)(t, **path_params)
    rx, ry = focus_xy[0] - ref.p[:, 0], focus_xy[1] - ref.p[:, 1]
    drx, dry = -ref.dp[:, 0], -ref.dp[:, 1]
    ddrx, ddry = -ref.ddp[:, 0], -ref.ddp[:, 1]
    d = rx * rx + ry * ry
    if np.any(d < 1e-4):
        raise ValueError("the path passes within 1 cm of the focus point; move focus_xy off the path")
    n = rx * dry - ry * drx
    dn = rx * ddry - ry * ddrx
    dd = 2 * (rx * drx + ry * dry)
    th = (np.arctan2(ry, rx), n / d, (dn * d - n * dd) / (d * d))
    return _pack((ref.p[:, 0], ref.p[:, 1]), (ref.dp[:, 0], ref.dp[:, 1]), (ref.ddp[:, 0], ref.ddp[:, 1]), th)


GENERATORS: dict[str, Callable[..., Reference]] = {
    "circle": circle, "figure8": figure_eight, "crab": crab, "spin": spin, "focus": focus,
}


def ramp_time(t: np.ndarray | float, ramp_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth start: warped time ``tau(t)`` and its first two derivatives.

    ``tau' = (1 - cos(pi t / ramp_s)) / 2`` rises from 0 to 1 over ``ramp_s`` seconds
    (then ``tau = t - ramp_s / 2``), so a trajectory starts at rest with zero acceleration
    and reaches full speed smoothly; ``tau = 0`` before ``t = 0``.
    """
    t = _as_t(t)
    if ramp_s <= 0:
        return t, np.ones_like(t), np.zeros_like(t)
    tc = np.clip(t, 0.0, ramp_s)
    w = np.pi / ramp_s
    tau = np.where(t >= ramp_s, t - 0.5 * ramp_s, 0.5 * tc - np.sin(w * tc) / (2 * w))
    dtau = np.where(t >= ramp_s, 1.0, 0.5 * (1 - np.cos(w * tc)))
    ddtau = np.where((t > 0) & (t < ramp_s), 0.5 * w * np.sin(w * tc), 0.0)
    return tau, dtau, ddtau


def resume(traj: Callable[[np.ndarray | float], Reference], s0_s: float, t_s: np.ndarray | float,
           ramp_s: float) -> tuple[Reference, np.ndarray]:
    """``traj`` (re)started from rest at its own time ``s0_s``, ``t_s`` seconds ago.

    The trajectory's time runs ``s = s0 + tau(t)`` with the raised-cosine ramp of
    :func:`ramp_time` (``ramp_s = 0``: full speed at once), and the chain rule gives the
    derivatives: ``dp = p'(s) tau'``, ``ddp = p''(s) tau'^2 + p'(s) tau''``.

    Returns
    -------
    (Reference, s) : the reference (N, 3) arrays and the trajectory times ``s`` (N,), s
    """
    tau, d1, d2 = ramp_time(t_s, ramp_s)
    s = s0_s + tau
    r = traj(s)
    return Reference(r.p, r.dp * d1[:, None], r.ddp * (d1 * d1)[:, None] + r.dp * d2[:, None]), s


def anchor(ref: Reference, start: tuple[float, float, float], at: tuple[float, float, float]) -> Reference:
    """Move a reference rigidly (SE(2)) so that the pose ``start`` lands on the pose ``at``.

    Positions are rotated by ``at[2] - start[2]`` about ``start`` and shifted to ``at``; the
    headings turn by the same angle (wrapped to [-pi, pi)); velocities and accelerations
    rotate with the path, heading rates are unchanged. Used to start a trajectory where the
    vehicle actually stands.
    """
    dth = at[2] - start[2]
    c, s = math.cos(dth), math.sin(dth)

    def rot(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return c * x - s * y, s * x + c * y

    px, py = rot(ref.p[:, 0] - start[0], ref.p[:, 1] - start[1])
    th = (ref.p[:, 2] + dth + np.pi) % (2 * np.pi) - np.pi
    p = np.stack([px + at[0], py + at[1], th], axis=1)
    dp = np.stack([*rot(ref.dp[:, 0], ref.dp[:, 1]), ref.dp[:, 2]], axis=1)
    ddp = np.stack([*rot(ref.ddp[:, 0], ref.ddp[:, 1]), ref.ddp[:, 2]], axis=1)
    return Reference(p, dp, ddp)


def make_trajectory(kind: str, *, ramp_s: float = 0.0, **params: object) -> Callable[[np.ndarray | float], Reference]:
    """``t -> Reference`` for a named generator (circle, figure8, crab, spin, focus) and its parameters.

    ``ramp_s > 0`` starts the trajectory from rest (see :func:`ramp_time`): a robot that
    starts standing still can align its wheels first instead of chasing a reference that
    is already moving (the chain rule keeps the derivatives analytic).
    """
    try:
        gen = GENERATORS[kind]
    except KeyError:
        raise ValueError(f"unknown trajectory {kind!r}; choose one of {sorted(GENERATORS)}") from None
    if ramp_s < 0:
        raise ValueError("ramp_s must be >= 0 s")
    gen(0.0, **params)      # validate the parameters now, not on the first tick
    if ramp_s == 0:
        return lambda t: gen(t, **params)

    def base(t: np.ndarray | float) -> Reference:
        return gen(t, **params)

    def ramped(t: np.ndarray | float) -> Reference:
        return resume(base, 0.0, t, ramp_s)[0]
    return ramped
