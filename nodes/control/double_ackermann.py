"""Double-Ackermann trajectory-following controllers (seed 15): the final two-stage law and its predecessors.

State of the final model (seed Sec. IV-C): ``X = (x, y, theta, v_tan, v_lat_f, v_lat_b)``,
inputs ``u = (dv_f, ddelta_f, dv_b, ddelta_b)``; two integrator stages::

    u --S(X)--> s_dot,  s = (v_tan, v_lat_f, v_lat_b);   s --A(theta)--> p_dot,  p = (x, y, theta)

Fixes to the seed, each marked where it is applied:

1. ``theta_dot = (v_lat_f - v_lat_b) / L``, not ``2/L`` (F, B are L apart; see kinematics).
2. ``S(X)`` as printed is 3x3 for four inputs.  Its rows are the polar derivatives of the
   two wheel vectors; the rear tangential row (the derivative of the rigid-body constraint
   ``v_b cos(delta_b) = v_tan``) is the fourth equation that makes it square (block
   diagonal, determinant ``v_f v_b``).  Written with ``cos(delta)`` instead of
   ``v_tan / v_f`` it has no 0/0 at rest; the remaining steer-rate singularity at zero wheel
   speed is gated (:func:`kinematics.wheel_rates`).
3. The last line ``u = S^-1 (s_d - s) + s_dot_d`` misplaces a parenthesis:
   ``u = S^-1 ((s_d - s) + s_dot_d)`` (pole placement on s, then inversion).
4. ``s_dot_d = dA^-1/dtheta * theta_dot * v2 + A^-1 v2_dot``: the seed's ``dA^-1/dX A s_d``
   uses the desired instead of the measured heading rate; the measured one is used here.
5. Heading errors are wrapped to [-pi, pi) (the seed subtracts raw angles).

Drives take setpoints (wheel speed, steer angle), not rates, so the controller integrates
``s`` over a lead time ``T`` (half a control period for the zero-order hold, plus any
modelled drive lag and bus latency): ``s_cmd = s + T (k_s (s_d - s) + s_dot_d)``; with the
default ``k_s = 1/T`` that is ``s_d + T s_dot_d``.  :func:`nodes.control.kinematics.shape_command`
then picks steer branches, applies the actuator limits and enforces the rigid-body
constraint exactly.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

from nodes.control.kinematics import (Limits, Wheels, initial_wheels, predict_pose, s_from_wheels, s_from_world,
                                      shape_command, steer_targets, wheel_rates, world_from_s, wrap_angle)

Vec3 = Sequence[float]


class RefPoint(NamedTuple):
    """Reference pose (x m, y m, theta rad) and its first and second time derivatives (world frame)."""

    p: Vec3
    dp: Vec3
    ddp: Vec3


class FinalLaw(NamedTuple):
    """Outputs of :func:`final_law` (all 3-tuples; m/s or m/s^2)."""

    s_d: tuple[float, float, float]
    sdot_d: tuple[float, float, float]
    sdot_cmd: tuple[float, float, float]


def final_law(pose: Vec3, s: Vec3, ref: RefPoint, *, wheelbase_m: float, k_p: float, k_s: float) -> FinalLaw:
    """The seed's final controller: outer inversion of A(theta), inner pole placement on s.

    Parameters
    ----------
    pose : (x m, y m, theta rad)
    s : (v_tan, v_lat_f, v_lat_b), m/s, measured body velocities
    ref : RefPoint
    wheelbase_m : float, distance FB
    k_p, k_s : float, 1/s
        Outer (pose) and inner (body velocity) poles, placed at ``-k_p`` and ``-k_s``.

    Returns
    -------
    FinalLaw
        ``s_d = A^-1 (k_p (p_d - p) + p_dot_d)``, its derivative ``s_dot_d`` and
        ``s_dot_cmd = k_s (s_d - s) + s_dot_d`` (the desired s rate; ``u = S^-1 s_dot_cmd``).
    """
    x, y, th = pose
    ex, ey, eth = ref.p[0] - x, ref.p[1] - y, wrap_angle(ref.p[2] - th)       # fix 5
    pdx, pdy, pdth = world_from_s(th, s, wheelbase_m)
    v2x, v2y, v2t = k_p * ex + ref.dp[0], k_p * ey + ref.dp[1], k_p * eth + ref.dp[2]
    w2x = k_p * (ref.dp[0] - pdx) + ref.ddp[0]
    w2y = k_p * (ref.dp[1] - pdy) + ref.ddp[1]
    w2t = k_p * (ref.dp[2] - pdth) + ref.ddp[2]
    c, sn = math.cos(th), math.sin(th)
    bx, by = c * v2x + sn * v2y, -sn * v2x + c * v2y
    dbx = c * w2x + sn * w2y + pdth * by                                       # fix 4: measured theta_dot
    dby = -sn * w2x + c * w2y - pdth * bx
    half = 0.5 * wheelbase_m
    s_d = (bx, by + half * v2t, by - half * v2t)
    sdot_d = (dbx, dby + half * w2t, dby - half * w2t)
    sdot_cmd = tuple(k_s * (a - b) + d for a, b, d in zip(s_d, s, sdot_d))
    return FinalLaw(s_d, sdot_d, sdot_cmd)  # type: ignore[arg-type]


def paper_inputs(wheels: Wheels, sdot: Vec3, *, v_gate_mps: float = 0.01) -> tuple[float, float, float, float]:
    """``u = (dv_f, ddelta_f, dv_b, ddelta_b) = S(X)^-1 s_dot`` (fix 2; steering gated at rest)."""
    dvf, ddf = wheel_rates(wheels.v_front, wheels.delta_front, sdot[0], sdot[1], v_gate_mps)
    dvb, ddb = wheel_rates(wheels.v_rear, wheels.delta_rear, sdot[0], sdot[2], v_gate_mps)
    return dvf, ddf, dvb, ddb


def fblin_law(pose: Vec3, wheels: Wheels, ref: RefPoint, *, wheelbase_m: float,
              k_p: float) -> tuple[float, float, float]:
    """The seed's first controller (Sec. IV-A): feedback linearisation on ``X = (x, y, theta, d_f, d_b, v_f)``.

    ``p_dot = v_f g(theta, d_f, d_b)`` with ``sigma = sin d_f + cos d_f tan d_b`` and
    ``g = (c cos d_f - s sigma / 2, s cos d_f + c sigma / 2, (sin d_f - cos d_f tan d_b) / L)``
    (fix 1: 1/L).  ``p_ddot = A(X) (d_f_dot, d_b_dot, v_f_dot) + b(X)``; the seed's appendix
    has ``A_theta[1] = v_f sin d_f / cos^2 d_b`` where the derivative is ``-v_f cos d_f / cos^2 d_b``.
    Output error poles are a double pole at ``-k_p``.

    Returns ``u = (d_f_dot, d_b_dot, v_f_dot)``.  NOT finite-safe by design: ``tan d_b`` and
    ``1/cos^2 d_b`` blow up at ``|d_b| = pi/2`` and A is singular at ``v_f = 0``, which is
    the failure the seed's Fig. 6 shows.  Callers must check the result.
    """
    x, y, th = pose
    vf, df, db = wheels.v_front, wheels.delta_front, wheels.delta_rear
    L = wheelbase_m
    c, sn, cf, sf = math.cos(th), math.sin(th), math.cos(df), math.sin(df)
    tb = math.tan(db)
    sec2 = 1.0 + tb * tb
    sigma = sf + cf * tb
    g = (c * cf - sn * sigma / 2, sn * cf + c * sigma / 2, (sf - cf * tb) / L)
    dsig = cf - sf * tb
    a_df = (vf * (-c * sf - sn * dsig / 2), vf * (-sn * sf + c * dsig / 2), vf * (cf + sf * tb) / L)
    a_db = (-vf * sn * cf * sec2 / 2, vf * c * cf * sec2 / 2, -vf * cf * sec2 / L)
    thdot = vf * g[2]
    b = (vf * thdot * (-sn * cf - c * sigma / 2), vf * thdot * (c * cf - sn * sigma / 2), 0.0)
    pd = (vf * g[0], vf * g[1], vf * g[2])
    kd, kp = 2.0 * k_p, k_p * k_p
    e = (ref.p[0] - x, ref.p[1] - y, wrap_angle(ref.p[2] - th))
    v = [ref.ddp[i] + kd * (ref.dp[i] - pd[i]) + kp * e[i] - b[i] for i in range(3)]
    return _solve3((a_df, a_db, g), v)


def _solve3(cols: tuple[Vec3, Vec3, Vec3], rhs: Sequence[float]) -> tuple[float, float, float]:
    """Cramer's rule for a 3x3 system given by columns; inf/nan when singular (no exception)."""
    def det(a: Vec3, b: Vec3, cc: Vec3) -> float:
        return (a[0] * (b[1] * cc[2] - b[2] * cc[1]) - b[0] * (a[1] * cc[2] - a[2] * cc[1])
                + cc[0] * (a[1] * b[2] - a[2] * b[1]))
    d = det(*cols)
    if d == 0.0 or not math.isfinite(d):
        return math.inf, math.inf, math.inf
    a, b, cc = cols
    return det(rhs, b, cc) / d, det(a, rhs, cc) / d, det(a, b, rhs) / d


class Controller:
    """Stateful shell shared by every law: lead time, command shaping, finite-or-stop.

    ``step(ref, pose, wheels, dt)`` returns the next per-axle command.  ``wheels`` are the
    achieved (measured) wheel speeds and steer angles.  Anything non-finite in or out gives
    a stop: zero speed with the steering held, and ``status`` says why.

    On the first step, and on the first after :meth:`reset` or :meth:`stop`, the previous
    command is *seeded from the measured wheels*: rate limits and steer branches start from
    where the wheels really are (after a stop, or before the drives were enabled, the last
    command says nothing about that), and from standstill the forward branch is taken.
    """

    def __init__(self, *, wheelbase_m: float = 1.0, limits: Limits = Limits(), k_p: float = 3.0,
                 k_s: float | None = None, lead_s: float = 0.0) -> None:
        if wheelbase_m <= 0 or k_p <= 0 or lead_s < 0 or (k_s is not None and k_s <= 0):
            raise ValueError("need wheelbase_m > 0, k_p > 0, k_s > 0 (or None for 1/lead) and lead_s >= 0")
        if limits.steer_limit_rad < math.pi / 2:
            raise ValueError("steer_limit_rad must be >= pi/2, or some wheel directions are unreachable")
        self.wheelbase_m, self.limits, self.k_p, self.k_s, self.lead_s = wheelbase_m, limits, k_p, k_s, lead_s
        self.prev: Wheels | None = None
        self._seed = True                                 # next step: prev <- measured wheels
        self._aim: tuple[float, float] | None = None     # last steer targets (branch hysteresis)
        self._fresh = True                                # at standstill: next motion picks the forward branch
        self.status = "idle"
        self.u: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)

    def reset(self) -> None:
        self.prev, self._aim, self._fresh, self._seed, self.status = None, None, True, True, "idle"

    def lead(self, dt: float) -> float:
        """Lead time T: half a zero-order-hold period plus the modelled lag and latency."""
        return 0.5 * dt + self.lead_s

    def step(self, ref: RefPoint, pose: Vec3, wheels: Wheels, dt: float, *, state_age_s: float = 0.0) -> Wheels:
        """Next command for a tick of period ``dt`` (s); ``pose`` was measured ``state_age_s`` ago."""
        if not (_finite(ref.p, ref.dp, ref.ddp, pose, wheels) and math.isfinite(dt) and dt > 0
                and math.isfinite(state_age_s)):
            return self.stop(wheels, "non-finite input")
        if self._seed:
            self.prev, self._aim, self._seed = Wheels(*map(float, wheels)), None, False
        pose = predict_pose(tuple(pose), wheels, state_age_s, self.wheelbase_m)
        desired = self.desired(ref, pose, wheels, dt)
        if desired is None or not _finite(*desired):
            return self.stop(wheels, "singular")
        aim = self._aim if self._aim is not None else (self.prev.delta_front, self.prev.delta_rear)
        way, ref_speed = self._path_direction(ref, pose[2], desired[0])
        if self._fresh:     # starting from standstill: take the forward branch (see kinematics.initial_wheels)
            fwd = initial_wheels(way, self.limits.steer_limit_rad)
            aim = (fwd.delta_front if fwd.v_front else aim[0], fwd.delta_rear if fwd.v_rear else aim[1])
            self._fresh = (ref_speed if ref_speed is not None else _speed(desired[0])) < self.limits.v_gate_mps
        # branches follow the path itself: feedback on a small error never swings a wheel half a turn
        s_path = way if ref_speed is not None else None
        # a law that plans the steering itself (the MPC) says which angles; else they follow s
        self._aim = desired[2] if len(desired) > 2 else steer_targets(desired[0], desired[1], aim, self.limits,
                                                                       s_path=s_path)
        cmd = shape_command(desired[0], desired[1], self.prev, self.limits, dt, targets=self._aim)
        if not _finite(cmd):
            return self.stop(wheels, "non-finite output")
        self.prev, self.status = cmd, "ok"
        return cmd

    def _path_direction(self, ref: RefPoint, theta: float, s_cmd: Vec3) -> tuple[Vec3, float | None]:
        """Body velocities of the path alone (the branches follow them; a start from standstill takes
        their forward branch), and the reference's speed.

        The reference's own velocity (else, for a ramped start at rest, its acceleration) in
        the body frame: at walking pace the command is dominated by feedback on millimetre
        errors, whose direction says nothing about where the path goes, and a wheel started on
        the wrong branch must flip half a turn later.  Without a moving reference: the command
        itself (and None for the speed).
        """
        ff = s_from_world(theta, *ref.dp, self.wheelbase_m)
        if _speed(ff) > 1e-9:
            return ff, _speed(ff)
        acc = s_from_world(theta, *ref.ddp, self.wheelbase_m)
        return (acc, 0.0) if _speed(acc) > 1e-9 else (s_cmd, None)

    def stop(self, wheels: Wheels | None = None, why: str = "stop") -> Wheels:
        """Zero speed, steering held at the last command (else the measured, else straight)."""
        hold = self.prev if self.prev is not None else wheels
        df = hold.delta_front if hold is not None and math.isfinite(hold.delta_front) else 0.0
        db = hold.delta_rear if hold is not None and math.isfinite(hold.delta_rear) else 0.0
        self.prev, self._aim, self._fresh, self.status = Wheels(0.0, df, 0.0, db), (df, db), True, why
        self._seed = True
        return self.prev

    def desired(self, ref: RefPoint, pose: Vec3, wheels: Wheels, dt: float):
        """``(s_cmd, s_hint)`` for this tick (optionally ``(s_cmd, s_hint, (delta_f, delta_b))`` when the
        law chose the steer angles itself), or None when the law has no answer."""
        raise NotImplementedError


class FinalController(Controller):
    """The seed's final two-stage controller (the default)."""

    def desired(self, ref, pose, wheels, dt):
        s = s_from_wheels(wheels)
        T = self.lead(dt)
        k_s = self.k_s if self.k_s is not None else 1.0 / T
        law = final_law(pose, s, ref, wheelbase_m=self.wheelbase_m, k_p=self.k_p, k_s=k_s)
        self.u = paper_inputs(wheels, law.sdot_cmd, v_gate_mps=self.limits.v_gate_mps)
        return tuple(a + T * b for a, b in zip(s, law.sdot_cmd)), law.sdot_cmd


class KinematicController(Controller):
    """Baseline: outer stage only, ``s_cmd = A^-1 (k_p (p_d - p) + p_dot_d)`` (no s dynamics, no lead)."""

    def desired(self, ref, pose, wheels, dt):
        s = s_from_wheels(wheels)
        law = final_law(pose, s, ref, wheelbase_m=self.wheelbase_m, k_p=self.k_p, k_s=0.0)
        return law.s_d, law.sdot_d


class FblinController(Controller):
    """The seed's first feedback-linearisation controller; singular at |delta_b| = pi/2 and at rest."""

    def desired(self, ref, pose, wheels, dt):
        if abs(math.cos(wheels.delta_rear)) < 1e-6 or abs(wheels.v_front) < self.limits.v_gate_mps:
            self.u = (math.inf, math.inf, math.inf)     # tan(d_b) undefined / A(X) rank-deficient
            return None
        u = fblin_law(pose, wheels, ref, wheelbase_m=self.wheelbase_m, k_p=self.k_p)
        self.u = u
        if not _finite(u):
            return None
        T = self.lead(dt)
        df, db = wheels.delta_front + T * u[0], wheels.delta_rear + T * u[1]
        vf = wheels.v_front + T * u[2]
        vb = vf * math.cos(df) / math.cos(db)      # the seed's constraint, solved for v_b: 1/cos d_b
        s_cmd = (vf * math.cos(df), vf * math.sin(df), vb * math.sin(db))
        return s_cmd, (0.0, 0.0, 0.0)


def _speed(s: Vec3) -> float:
    """The larger axle speed of body velocities ``s = (v_tan, v_lat_f, v_lat_b)``."""
    return math.hypot(s[0], max(abs(s[1]), abs(s[2])))


def _finite(*groups: Sequence[float]) -> bool:
    return all(math.isfinite(v) for g in groups for v in g)
