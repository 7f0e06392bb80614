"""Model-predictive alternative to the seed's controller: CasADi ``sqpmethod`` + ``qrqp``, warm-started.

Model: pose ``p = (x, y, theta)`` driven by the seed's singularity-free body velocities
``s = (v_tan, v_lat_f, v_lat_b)`` through ``p_dot = A(theta) s`` (1/L fix, see kinematics).
The drives take per-axle setpoints ``w = (v_f, delta_f, v_b, delta_b)`` held over a
control period, so those are the decision variables, piecewise constant over ``horizon``
intervals of ``step_s`` (one RK4 step each), with ``s(w) = ((v_f cos d_f + v_b cos d_b) / 2,
v_f sin d_f, v_b sin d_b)``.  The actuators are modelled by their rate limits: the steer
angles move at most ``steer_rate * step_s`` and the wheel speeds ``wheel_accel * step_s``
per interval (relative to the setpoint already sent for k = 0), within the steer range and
top speed, and every setpoint satisfies the rigid-body constraint
``v_f cos d_f = v_b cos d_b``.  A plan is therefore one the wheels can follow: from rest,
with the wheels pointing the wrong way, it turns them first instead of pushing a body
velocity they cannot give yet.  Cost: squared pose error (heading against a reference
unwrapped around the current heading, so +-pi is no jump), body-velocity error against
``A^-1 p_dot_ref`` and setpoint-rate effort.

The reference preview comes from a callable (the benchmark passes the exact trajectory);
without one it is extrapolated from the current point at constant acceleration.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Callable

import casadi as ca
import numpy as np

from nodes.control.double_ackermann import Controller, RefPoint
from nodes.control.kinematics import choose_steer, predict_pose

Preview = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def _dynamics(wheelbase_m: float) -> ca.Function:
    p, s = ca.SX.sym("p", 3), ca.SX.sym("s", 3)
    th, vt, lf, lb = p[2], s[0], s[1], s[2]
    vy = 0.5 * (lf + lb)
    pdot = ca.vertcat(ca.cos(th) * vt - ca.sin(th) * vy, ca.sin(th) * vt + ca.cos(th) * vy, (lf - lb) / wheelbase_m)
    return ca.Function("f", [p, s], [pdot])


def _body(w: ca.SX) -> ca.SX:
    """``s(w)``: body velocities of per-axle setpoints ``w = (v_f, d_f, v_b, d_b)``."""
    return ca.vertcat(0.5 * (w[0] * ca.cos(w[1]) + w[2] * ca.cos(w[3])), w[0] * ca.sin(w[1]), w[2] * ca.sin(w[3]))


def build_solver(*, horizon: int, step_s: float, wheelbase_m: float, accel_max: float, speed_max: float,
                 steer_rate_max: float = 3.0, steer_limit: float = 2.5, q_pos: float = 1e4, q_theta: float = 1e3,
                 q_s: float = 1.0, r_dv: float = 1.0, r_ddelta: float = 0.01, max_iter: int = 3
                 ) -> tuple[ca.Function, dict]:
    """The NLP solver and its bounds. Parameters: p0 (3), w_prev (4), p_ref (3, N+1), s_ref (3, N)."""
    if horizon < 1 or step_s <= 0:
        raise ValueError("MPC needs horizon >= 1 and step_s > 0")
    f = _dynamics(wheelbase_m)
    N, h = horizon, step_s
    p, s = ca.SX.sym("p", 3), ca.SX.sym("s", 3)
    k1 = f(p, s)
    k2 = f(p + h / 2 * k1, s)
    k3 = f(p + h / 2 * k2, s)
    k4 = f(p + h * k3, s)
    F = ca.Function("F", [p, s], [p + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    P, W = ca.SX.sym("P", 3, N + 1), ca.SX.sym("W", 4, N)
    p0, wprev, pref, sref = ca.SX.sym("p0", 3), ca.SX.sym("wp", 4), ca.SX.sym("pr", 3, N + 1), ca.SX.sym("sr", 3, N)
    effort = ca.DM([r_dv, r_ddelta, r_dv, r_ddelta])
    cost, g_eq, g_rigid, g_rate = 0, [P[:, 0] - p0], [], []
    for k in range(N):
        w = W[:, k]
        g_eq.append(P[:, k + 1] - F(P[:, k], _body(w)))
        g_rigid.append(w[0] * ca.cos(w[1]) - w[2] * ca.cos(w[3]))
        g_rate.append(w - (wprev if k == 0 else W[:, k - 1]))
        e = P[:, k + 1]
        cost += q_pos * ca.sumsqr(e[:2] - pref[:2, k + 1]) + q_theta * (e[2] - pref[2, k + 1]) ** 2
        cost += q_s * ca.sumsqr(_body(w) - sref[:, k]) + ca.sumsqr(ca.sqrt(effort) * g_rate[-1])
    nlp = {"x": ca.veccat(P, W), "p": ca.veccat(p0, wprev, pref, sref), "f": cost,
           "g": ca.vertcat(*g_eq, *g_rigid, *g_rate)}
    # the Lagrangian's Hessian is indefinite (the steer angles enter through sin / cos): regularised for qrqp
    opts = {"qpsol": "qrqp", "max_iter": max_iter, "convexify_strategy": "regularize",
            "print_header": False, "print_iteration": False,
            "print_status": False, "print_time": False, "error_on_fail": False,
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False}}
    solver = ca.nlpsol("mpc", "sqpmethod", nlp, opts)
    npose = 3 * (N + 1)
    wmax = np.tile([speed_max, steer_limit, speed_max, steer_limit], N)
    dmax = np.tile([accel_max * h, steer_rate_max * h, accel_max * h, steer_rate_max * h], N)
    lbx = np.concatenate([np.full(npose, -np.inf), -wmax])
    lbg = np.concatenate([np.zeros(npose + N), -dmax])
    ubg = np.concatenate([np.zeros(npose + N), dmax])
    return solver, {"lbx": lbx, "ubx": -lbx, "lbg": lbg, "ubg": ubg, "npose": npose}


def taylor_preview(ref: RefPoint) -> Preview:
    """Constant-acceleration extrapolation of one reference point over the horizon."""
    p, dp, ddp = (np.asarray(v, dtype=float) for v in ref)
    return lambda tau: (p + np.outer(tau, dp) + 0.5 * np.outer(tau * tau, ddp), dp + np.outer(tau, ddp))


class MpcController(Controller):
    """``Controller`` whose law is the MPC above; ``step(..., preview=fn)`` gives it the future reference."""

    def __init__(self, *, horizon: int = 20, step_s: float | None = None, max_iter: int = 3, **kw: object) -> None:
        super().__init__(**kw)  # type: ignore[arg-type]
        self.horizon, self.step_s, self.max_iter = horizon, step_s, max_iter
        self._solver: ca.Function | None = None
        self._h = 0.0
        self._warm: dict | None = None
        self._sent: deque = deque()
        self.preview: Preview | None = None
        self.solve_ok = 0
        self.solve_fail = 0
        self.log_status = ""            # CasADi return status of the last failed solve

    def reset(self) -> None:
        super().reset()
        self._warm, self.preview = None, None
        self._sent.clear()

    def _ensure(self, dt: float) -> None:
        h = self.step_s if self.step_s is not None else dt
        if self._solver is None or abs(h - self._h) > 1e-3 * h:
            self._solver, self._bounds = build_solver(
                horizon=self.horizon, step_s=h, wheelbase_m=self.wheelbase_m, accel_max=self.limits.wheel_accel_mps2,
                speed_max=self.limits.wheel_speed_mps, steer_rate_max=self.limits.steer_rate_radps,
                steer_limit=self.limits.steer_limit_rad, max_iter=self.max_iter)
            self._h, self._warm = h, None

    def desired(self, ref, pose, wheels, dt):
        self._ensure(dt)
        N, h = self.horizon, self._h
        # Delay compensation: the setpoint takes effect lead_s from now (latency, ~drive lag), while the
        # previous one still runs; plan from the pose predicted that far ahead, against the reference then.
        lead = self.lead_s if self.prev is not None else 0.0
        if lead > 0.0:
            pose = self._predict_through_sent(tuple(pose), lead, dt)
        tau = lead + h * np.arange(N + 1)
        pr, dpr = (self.preview or taylor_preview(ref))(tau)
        pr, dpr = np.array(pr, dtype=float), np.asarray(dpr, dtype=float)
        th = pose[2]
        pr[:, 2] = th + np.unwrap(np.concatenate([[0.0], (pr[:, 2] - th + np.pi) % (2 * np.pi) - np.pi]))[1:]
        mid_th, mid_dp = 0.5 * (pr[1:, 2] + pr[:-1, 2]), 0.5 * (dpr[1:] + dpr[:-1])    # interval midpoints
        c, s = np.cos(mid_th), np.sin(mid_th)
        vx, vy = c * mid_dp[:, 0] + s * mid_dp[:, 1], -s * mid_dp[:, 0] + c * mid_dp[:, 1]
        half = 0.5 * self.wheelbase_m * mid_dp[:, 2]
        sref = np.stack([vx, vy + half, vy - half])
        wprev = np.asarray(self.prev if self.prev is not None else wheels, dtype=float)
        p0 = np.array([pose[0], pose[1], th])
        b = self._bounds
        args = dict(p=np.concatenate([p0, wprev, pr.ravel(), sref.ravel(order="F")]),
                    lbx=b["lbx"], ubx=b["ubx"], lbg=b["lbg"], ubg=b["ubg"])
        args.update(self._warm_start(p0, wprev, sref))
        sol = self._solver(**args)
        status = self._solver.stats().get("return_status", "")
        if self._solver.stats().get("success", False) or status.lower() == "maximum_iterations_exceeded":
            self.solve_ok += 1          # a capped SQP (real-time iteration style) is the intended use
        else:
            self.solve_fail += 1
            self.log_status = status
        x = np.asarray(sol["x"]).ravel()
        if not np.all(np.isfinite(x)):
            self._warm = None
            return None
        self._warm = {"x": x, "lam_x": np.asarray(sol["lam_x"]).ravel(), "lam_g": np.asarray(sol["lam_g"]).ravel()}
        W = x[b["npose"]:].reshape(N, 4)
        S = np.stack([0.5 * (W[:, 0] * np.cos(W[:, 1]) + W[:, 2] * np.cos(W[:, 3])),
                      W[:, 0] * np.sin(W[:, 1]), W[:, 2] * np.sin(W[:, 3])], axis=1)
        rate = (S[1] - S[0]) / h if N > 1 else np.zeros(3)
        # the plan's own steer angles: they respect the steer rate already, and at rest they are
        # what the wheels must turn to before they roll
        return tuple(float(v) for v in S[0]), tuple(float(v) for v in rate), (float(W[0, 1]), float(W[0, 3]))

    def _predict_through_sent(self, pose: tuple, lead: float, dt: float) -> tuple:
        """Dead-reckon ``lead`` s ahead through the setpoints already sent (sent at t - m dt, active from + lead)."""
        self._sent.appendleft(self.prev)                       # _sent[m-1] was sent m ticks ago
        while len(self._sent) > int(math.ceil(lead / dt - 1e-9)) + 1:
            self._sent.pop()
        for m in range(len(self._sent), 0, -1):                # oldest first
            start, end = max(0.0, lead - m * dt), min(lead, lead - (m - 1) * dt)
            if m == len(self._sent):
                start = 0.0                                    # older history unknown: the oldest we have
            if end > start:
                pose = predict_pose(pose, self._sent[m - 1], end - start, self.wheelbase_m)
        return pose

    def _warm_start(self, p0: np.ndarray, wprev: np.ndarray, sref: np.ndarray) -> dict:
        """Previous solution shifted one interval (last one repeated); cold: hold the pose, and wheels
        that realise the reference's body velocities on the branch nearest the current steering."""
        N, npose = self.horizon, self._bounds["npose"]
        if self._warm is None:
            lim = self.limits.steer_limit_rad
            guess = []
            for k in range(N):
                w = []
                for lat, prev_delta in ((sref[1, k], wprev[1]), (sref[2, k], wprev[3])):
                    if math.hypot(sref[0, k], lat) < 1e-9:
                        w += [0.0, float(prev_delta)]
                    else:
                        delta, v = choose_steer(sref[0, k], lat, float(prev_delta), lim)
                        w += [v, delta]
                guess.append(w)
            return {"x0": np.concatenate([np.tile(p0, N + 1), np.ravel(guess)])}
        x = self._warm["x"]
        P, S = x[:npose].reshape(N + 1, 3), x[npose:].reshape(N, 4)
        P[:, 2] += 2 * np.pi * np.round((p0[2] - P[1, 2]) / (2 * np.pi))   # measured heading wrapped past +-pi
        P = np.vstack([P[1:], P[-1:]])
        P[0] = p0
        S = np.vstack([S[1:], S[-1:]])
        return {"x0": np.concatenate([P.ravel(), S.ravel()]), "lam_x0": self._warm["lam_x"],
                "lam_g0": self._warm["lam_g"]}
