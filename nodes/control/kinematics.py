"""Double-Ackermann (four-wheel-steer) kinematics: body velocities <-> per-axle wheel speed and steer angle.

Geometry (seed 15, Fig. 2-4): robot frame x forward, y left, origin O at the centre; the
front axle centre F at (+L/2, 0), the rear axle centre B at (-L/2, 0).  Each axle is a
"bicycle" wheel with signed speed ``v`` (m/s, along the wheel) and steer angle ``delta``
(rad, from the robot x axis, counter-clockwise).  The wheel velocity vectors in the robot
frame are ``w_f = v_f (cos delta_f, sin delta_f)`` and ``w_b = v_b (cos delta_b, sin delta_b)``.

The body is rigid, so F and B have the same velocity component along FB (the robot x axis)::

    v_f cos(delta_f) = v_b cos(delta_b) = v_tan                      (rigid-body constraint)

which leaves three independent body velocities ``s = (v_tan, v_lat_f, v_lat_b)`` with
``v_lat_f = v_f sin(delta_f)`` and ``v_lat_b = v_b sin(delta_b)``.  The body twist of O is
``(v_x, v_y, omega) = (v_tan, (v_lat_f + v_lat_b) / 2, (v_lat_f - v_lat_b) / L)``.

Paper erratum: the seed writes ``theta_dot = (2/L)(v_lat_f - v_lat_b)``.  F and B are
L apart (they sit at +-L/2), so the lateral speeds differ by ``omega * L``:
``theta_dot = (v_lat_f - v_lat_b) / L``.  (2/L would hold if F and B sat at +-L.)

Everything here is scalar ``math`` on floats: the controller calls it every tick and the
numpy call overhead on 2-vectors would dominate its budget.
"""
from __future__ import annotations

import math
from typing import NamedTuple

TWO_PI = 2.0 * math.pi


class Wheels(NamedTuple):
    """Per-axle actuation: signed wheel speeds (m/s) and steer angles (rad)."""

    v_front: float
    delta_front: float
    v_rear: float
    delta_rear: float


def wrap_angle(angle: float) -> float:
    """Wrap an angle (rad) to [-pi, pi)."""
    return (angle + math.pi) % TWO_PI - math.pi


def s_from_wheels(w: Wheels) -> tuple[float, float, float]:
    """Body velocities ``s = (v_tan, v_lat_f, v_lat_b)`` (m/s) of measured wheels.

    Measured wheels need not satisfy the rigid-body constraint exactly (drive lag, noise);
    ``v_tan`` is then the mean of the two axles' tangential components.
    """
    v_tan = 0.5 * (w.v_front * math.cos(w.delta_front) + w.v_rear * math.cos(w.delta_rear))
    return v_tan, w.v_front * math.sin(w.delta_front), w.v_rear * math.sin(w.delta_rear)


def body_twist(w: Wheels, wheelbase_m: float) -> tuple[float, float, float, float]:
    """Least-squares body twist of O from both wheel velocity vectors.

    Returns
    -------
    (v_x, v_y, omega, scrub) : m/s, m/s, rad/s, m/s
        ``scrub = v_f cos(delta_f) - v_b cos(delta_b)`` is the rigid-body constraint
        residual: the speed at which the tyres are dragged along FB when the wheels fight.
    """
    tf = w.v_front * math.cos(w.delta_front)
    tb = w.v_rear * math.cos(w.delta_rear)
    lf = w.v_front * math.sin(w.delta_front)
    lb = w.v_rear * math.sin(w.delta_rear)
    return 0.5 * (tf + tb), 0.5 * (lf + lb), (lf - lb) / wheelbase_m, tf - tb


def s_from_world(theta: float, dx: float, dy: float, dtheta: float,
                 wheelbase_m: float) -> tuple[float, float, float]:
    """``s = A(theta)^-1 p_dot``: body velocities that produce the world rates (dx, dy, dtheta).

    ``A(theta)`` (seed eq. for p_dot, with the 1/L fix) is always invertible: its
    determinant is ``-1/L``.  This is the outer stage of the final controller.
    """
    c, s = math.cos(theta), math.sin(theta)
    vx = c * dx + s * dy
    vy = -s * dx + c * dy
    half = 0.5 * wheelbase_m * dtheta
    return vx, vy + half, vy - half


def world_from_s(theta: float, s: tuple[float, float, float],
                 wheelbase_m: float) -> tuple[float, float, float]:
    """``p_dot = A(theta) s``: world rates (m/s, m/s, rad/s) of body velocities ``s``."""
    v_tan, lat_f, lat_b = s
    vy = 0.5 * (lat_f + lat_b)
    c, sn = math.cos(theta), math.sin(theta)
    return c * v_tan - sn * vy, sn * v_tan + c * vy, (lat_f - lat_b) / wheelbase_m


def choose_steer(tangential: float, lateral: float, prev_delta: float, steer_limit_rad: float, *,
                 clamp_margin_rad: float = 0.0) -> tuple[float, float]:
    """Steer angle and signed speed realising the wheel vector (tangential, lateral).

    A wheel vector is reached with ``(v, delta)`` or ``(-v, delta + pi)``; the branch
    nearest ``prev_delta`` inside ``[-steer_limit_rad, steer_limit_rad]`` is taken, so the
    wheel reverses instead of swinging half a turn, and the steer angle is unwrapped
    (no jump at +-pi).  Needs ``steer_limit_rad >= pi/2`` so a branch always exists.
    If the nearest branch lies at most ``clamp_margin_rad`` beyond the stop, the angle is
    clamped at the stop (speed: the vector's projection on the wheel) instead of starting
    a half-turn flip: transients that graze the stop do not flip the wheel.
    """
    speed = math.hypot(tangential, lateral)
    base = math.atan2(lateral, tangential)
    k0 = round((prev_delta - base) / math.pi)
    best = nearest = None
    for k in (k0 - 1, k0, k0 + 1, k0 + 2, k0 - 2):
        cand = base + k * math.pi
        cost = abs(cand - prev_delta) + (1e-9 if k % 2 else 0.0)     # ties (e.g. 0 -> +-pi/2): drive forward
        if nearest is None or cost < nearest[0]:
            nearest = (cost, cand)
        if abs(cand) > steer_limit_rad + 1e-12:
            continue
        if best is None or cost < best[0]:
            best = (cost, cand, speed if k % 2 == 0 else -speed)
    if best is None or (nearest is not None and abs(nearest[1]) - steer_limit_rad <= clamp_margin_rad
                        and nearest[1] != best[1]):
        # clamp at the stop (also the only way out when steer_limit_rad < pi/2)
        cand = math.copysign(steer_limit_rad, nearest[1]) if best is not None else \
            max(-steer_limit_rad, min(steer_limit_rad, base))
        return cand, tangential * math.cos(cand) + lateral * math.sin(cand)
    return best[1], best[2]


def wheel_rates(v: float, delta: float, d_tan: float, d_lat: float, v_gate_mps: float) -> tuple[float, float]:
    """Invert one axle's block of S(X): wheel-vector rate -> (v_dot, delta_dot).

    ``w = v (cos delta, sin delta)`` gives ``w_dot = v_dot e + v delta_dot e_perp``, so
    ``v_dot = w_dot . e`` and ``delta_dot = w_dot . e_perp / v``.  The seed writes
    ``cos(delta_f) = v_tan / v_f``, which is 0/0 at rest; here the block's determinant is
    ``v`` and the steer rate is unbounded as ``v -> 0``: below ``v_gate_mps`` it is gated
    to zero (steering held), the finite choice.
    """
    c, s = math.cos(delta), math.sin(delta)
    v_dot = d_tan * c + d_lat * s
    if abs(v) < v_gate_mps:
        return v_dot, 0.0
    return v_dot, (-d_tan * s + d_lat * c) / v


class Limits(NamedTuple):
    """Actuator limits the controller respects when it shapes commands.

    steer_limit_rad : mechanical steer range +-limit (>= pi/2 so every wheel vector is reachable).
    steer_rate_radps, wheel_accel_mps2, wheel_speed_mps : per-axle rate / acceleration / speed bounds.
    v_gate_mps : below this wheel speed the steer angle is not derived from the (ill-defined)
        wheel-vector direction: it follows the acceleration hint, or is held.
    clamp_margin_rad : a wanted angle up to this far beyond the stop is clamped rather than
        flipped by half a turn (see :func:`choose_steer`).
    """

    steer_limit_rad: float = 2.5
    steer_rate_radps: float = 3.0
    wheel_accel_mps2: float = 2.0
    wheel_speed_mps: float = 2.0
    v_gate_mps: float = 0.01
    clamp_margin_rad: float = 0.35


def _axle_angle(tan: float, lat: float, hint_tan: float, hint_lat: float, prev_delta: float,
                limits: Limits, path: tuple[float, float] | None = None) -> float:
    """Desired steer angle of one axle (before rate limiting), gated at low speed.

    With the path's own wheel vector ``path`` (moving), the branch is chosen on it (flips
    only where the path needs them) and the command's angle is taken on that branch,
    clamped at the stops: feedback on a small error may turn the wheel, reverse it, push it
    against a stop -- but never make it swing half a turn.
    """
    lim, margin = limits.steer_limit_rad, limits.clamp_margin_rad
    if path is not None and math.hypot(*path) > 1e-9:
        branch = choose_steer(path[0], path[1], prev_delta, lim, clamp_margin_rad=margin)[0]
        if math.hypot(tan, lat) < limits.v_gate_mps:
            return branch                           # (about to) move slowly: steer along the path itself
        base = math.atan2(lat, tan)
        cand = base + math.pi * round((branch - base) / math.pi)
        return max(-lim, min(lim, cand))
    if math.hypot(tan, lat) >= limits.v_gate_mps:
        return choose_steer(tan, lat, prev_delta, lim, clamp_margin_rad=margin)[0]
    if math.hypot(hint_tan, hint_lat) > 1e-9:      # about to move: pre-steer along the acceleration
        return choose_steer(hint_tan, hint_lat, prev_delta, lim, clamp_margin_rad=margin)[0]
    return prev_delta                               # at rest: hold the steering


def _interval(lo: float, hi: float, n: float) -> tuple[float, float]:
    """Range of lambda with ``lo <= lambda * n <= hi``."""
    if n > 1e-9:
        return lo / n, hi / n
    if n < -1e-9:
        return hi / n, lo / n
    return -math.inf, math.inf       # this wheel's speed is pinned near 0 by the constraint itself


def steer_targets(s_cmd: tuple[float, float, float], s_hint: tuple[float, float, float],
                  aim: tuple[float, float], limits: Limits, *,
                  s_path: tuple[float, float, float] | None = None) -> tuple[float, float]:
    """Wanted (front, rear) steer angles before rate limiting: the branch nearest ``aim`` (rad).

    Aiming at the previous *targets* rather than the previous (slewed) angles adds
    hysteresis: a wheel turning from 0 toward a sideways direction whose forward component
    flickers in sign keeps turning the same way instead of hunting between +-pi/2.
    ``s_path``: body velocities of the reference path alone (no feedback); when given, the
    branches follow the path and the command only moves the angle within them.
    """
    pf = (s_path[0], s_path[1]) if s_path is not None else None
    pb = (s_path[0], s_path[2]) if s_path is not None else None
    return (_axle_angle(s_cmd[0], s_cmd[1], s_hint[0], s_hint[1], aim[0], limits, pf),
            _axle_angle(s_cmd[0], s_cmd[2], s_hint[0], s_hint[2], aim[1], limits, pb))


def shape_command(s_cmd: tuple[float, float, float], s_hint: tuple[float, float, float],
                  prev: Wheels | None, limits: Limits, dt: float, *,
                  aim: tuple[float, float] | None = None, targets: tuple[float, float] | None = None) -> Wheels:
    """Turn desired body velocities into feasible per-axle commands that satisfy the constraint.

    Parameters
    ----------
    s_cmd : (v_tan, v_lat_f, v_lat_b), m/s
        Desired body velocities (any finite values).
    s_hint : (3,), m/s^2
        Their rate; only used to pre-steer a wheel that is (nearly) at rest.
    prev : Wheels or None
        The previous command; rate and acceleration limits are relative to it (None: no rate limits).
    limits : Limits
    dt : float, s
        Time since ``prev``.
    aim : (2,), rad, optional
        Angles the steer branches are chosen nearest to (see :func:`steer_targets`);
        default the previous command's.
    targets : (2,), rad, optional
        Wanted steer angles already chosen (by :func:`steer_targets`); used as given.

    Returns
    -------
    Wheels
        Steer angles slewed at most ``steer_rate * dt`` toward the wanted branch; speeds the
        least-squares fit of the wanted wheel vectors along those angles, projected onto the
        rigid-body constraint ``v_f cos(delta_f) = v_b cos(delta_b)`` (which always holds
        exactly: the acceleration bound gives way if both cannot hold), then bounded.
    """
    v_tan, lat_f, lat_b = s_cmd
    pf = prev.delta_front if prev is not None else 0.0
    pb = prev.delta_rear if prev is not None else 0.0
    df, db = targets if targets is not None else steer_targets(s_cmd, s_hint, aim if aim is not None else (pf, pb),
                                                               limits)
    vmax = limits.wheel_speed_mps
    if prev is not None and dt > 0.0:
        step = limits.steer_rate_radps * dt
        df = pf + max(-step, min(step, df - pf))
        db = pb + max(-step, min(step, db - pb))
        dv = limits.wheel_accel_mps2 * dt
        box_f = (max(prev.v_front - dv, -vmax), min(prev.v_front + dv, vmax))
        box_b = (max(prev.v_rear - dv, -vmax), min(prev.v_rear + dv, vmax))
    else:
        box_f = box_b = (-vmax, vmax)
    cf, sf, cb, sb = math.cos(df), math.sin(df), math.cos(db), math.sin(db)
    vf = v_tan * cf + lat_f * sf                    # least-squares speed along the (slewed) wheel
    vb = v_tan * cb + lat_b * sb
    norm = math.hypot(cf, cb)
    if norm < 1e-9:                                 # both wheels sideways: constraint is 0 = 0
        vf = max(box_f[0], min(box_f[1], vf))
        vb = max(box_b[0], min(box_b[1], vb))
        return Wheels(vf, df, vb, db)
    nf, nb = cb / norm, cf / norm                   # the constraint's null direction (c . n = 0)
    lam = nf * vf + nb * vb
    lo_f, hi_f = _interval(*box_f, nf)
    lo_b, hi_b = _interval(*box_b, nb)
    lo, hi = max(lo_f, lo_b), min(hi_f, hi_b)
    if lo > hi:        # boxes miss the constraint line: keep the constraint and top speed, give up accel
        top_f, top_b = _interval(-vmax, vmax, nf), _interval(-vmax, vmax, nb)
        lam = max(top_f[0], top_b[0], min(top_f[1], top_b[1], 0.5 * (lo + hi)))
    else:
        lam = max(lo, min(hi, lam))
    return Wheels(lam * nf, df, lam * nb, db)


def initial_wheels(s: tuple[float, float, float], steer_limit_rad: float = 2.5) -> Wheels:
    """Wheels realising body velocities ``s``, preferring forward wheel speed (for initial states).

    Starting on the forward branch centres the steer range on straight ahead; a start on
    the reverse branch can run a wheel into its steer stop later on the same path.
    """
    out = []
    for lat in (s[1], s[2]):
        if math.hypot(s[0], lat) < 1e-12:
            out += [0.0, 0.0]
            continue
        delta = math.atan2(lat, s[0])
        if abs(delta) > steer_limit_rad:
            delta -= math.copysign(math.pi, delta)
        out += [s[0] * math.cos(delta) + lat * math.sin(delta), delta]
    return Wheels(*out)


def predict_pose(pose: tuple[float, float, float], wheels: Wheels, age_s: float,
                 wheelbase_m: float) -> tuple[float, float, float]:
    """Dead-reckon a pose measured ``age_s`` seconds ago to now, holding the measured wheels' twist.

    Compensates a measurement delay (bus, transport, publication rate): without it the
    controller steers the *old* pose onto the *current* reference and the robot runs
    ``speed * age`` ahead of it.  Exact SE(2) motion for a constant twist.
    """
    if age_s <= 0.0:
        return pose
    vx, vy, om, _ = body_twist(wheels, wheelbase_m)
    dth = om * age_s
    if abs(dth) < 1e-6:
        a, b = 1.0 - dth * dth / 6.0, 0.5 * dth
    else:
        a, b = math.sin(dth) / dth, (1.0 - math.cos(dth)) / dth
    dx, dy = (a * vx - b * vy) * age_s, (b * vx + a * vy) * age_s
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return pose[0] + c * dx - s * dy, pose[1] + s * dx + c * dy, wrap_angle(pose[2] + dth)
