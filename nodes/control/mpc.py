"""Model-predictive alternative to the seed's controller: CasADi ``sqpmethod`` + ``qrqp``, warm-started.

Model (the seed's final, singularity-free state): ``z = (x, y, theta, v_tan, v_lat_f, v_lat_b)``
with ``p_dot = A(theta) s`` (1/L fix, see kinematics) and ``s_dot = a``; the decision inputs
``a`` are body-velocity accelerations, which map to the seed's ``u`` through ``S(X)^-1``.
Multiple shooting, one RK4 step per interval of ``step_s``, ``horizon`` intervals.  Cost:
squared pose error (heading error taken against a reference unwrapped around the current
heading, so +-pi is not a jump), body-velocity error against ``A^-1 p_dot_ref``, input and
input-rate effort.  Bounds: |a| <= wheel_accel, |s| <= wheel_speed.  Steer rates are
nonlinear in s and left to the command shaping that every controller shares.

The reference preview comes from a callable (the benchmark passes the exact trajectory);
without one it is extrapolated from the current point at constant acceleration.
"""
from __future__ import annotations

import math
from typing import Callable

import casadi as ca
import numpy as np

from nodes.control.double_ackermann import Controller, RefPoint
from nodes.control.kinematics import s_from_wheels

Preview = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def _dynamics(wheelbase_m: float) -> ca.Function:
    z, a = ca.SX.sym("z", 6), ca.SX.sym("a", 3)
    th, vt, lf, lb = z[2], z[3], z[4], z[5]
    vy = 0.5 * (lf + lb)
    zdot = ca.vertcat(ca.cos(th) * vt - ca.sin(th) * vy, ca.sin(th) * vt + ca.cos(th) * vy,
                      (lf - lb) / wheelbase_m, a)
    return ca.Function("f", [z, a], [zdot])


def build_solver(*, horizon: int, step_s: float, wheelbase_m: float, accel_max: float, speed_max: float,
                 q_pos: float = 1e4, q_theta: float = 1e3, q_s: float = 10.0, r_a: float = 1e-2,
                 r_da: float = 1e-1, max_iter: int = 3) -> tuple[ca.Function, dict]:
    """The NLP solver and its bounds. Parameters: z0 (6), p_ref (3, N+1), s_ref (3, N+1), a_prev (3)."""
    if horizon < 1 or step_s <= 0:
        raise ValueError("MPC needs horizon >= 1 and step_s > 0")
    f = _dynamics(wheelbase_m)
    N, h = horizon, step_s
    z, a = ca.SX.sym("z", 6), ca.SX.sym("a", 3)
    k1 = f(z, a)
    k2 = f(z + h / 2 * k1, a)
    k3 = f(z + h / 2 * k2, a)
    k4 = f(z + h * k3, a)
    F = ca.Function("F", [z, a], [z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    Z, U = ca.SX.sym("Z", 6, N + 1), ca.SX.sym("U", 3, N)
    z0, pref, sref, aprev = ca.SX.sym("z0", 6), ca.SX.sym("pr", 3, N + 1), ca.SX.sym("sr", 3, N + 1), ca.SX.sym("ap", 3)
    cost, g = 0, [Z[:, 0] - z0]
    for k in range(N):
        g.append(Z[:, k + 1] - F(Z[:, k], U[:, k]))
        e = Z[:, k + 1]
        cost += q_pos * ca.sumsqr(e[:2] - pref[:2, k + 1]) + q_theta * (e[2] - pref[2, k + 1]) ** 2
        cost += q_s * ca.sumsqr(e[3:] - sref[:, k + 1]) + r_a * ca.sumsqr(U[:, k])
        cost += r_da * ca.sumsqr(U[:, k] - (aprev if k == 0 else U[:, k - 1]))
    nlp = {"x": ca.veccat(Z, U), "p": ca.veccat(z0, pref, sref, aprev), "f": cost, "g": ca.vertcat(*g)}
    opts = {"qpsol": "qrqp", "max_iter": max_iter, "print_header": False, "print_iteration": False,
            "print_status": False, "print_time": False, "error_on_fail": False,
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False}}
    solver = ca.nlpsol("mpc", "sqpmethod", nlp, opts)
    lbz = np.tile([-np.inf, -np.inf, -np.inf, -speed_max, -speed_max, -speed_max], N + 1)
    nz = 6 * (N + 1)
    lbx = np.concatenate([lbz, np.full(3 * N, -accel_max)])
    ubx = -lbx
    return solver, {"lbx": lbx, "ubx": ubx, "lbg": 0.0, "ubg": 0.0, "nz": nz}


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
        self._a_prev = np.zeros(3)
        self.preview: Preview | None = None
        self.solve_ok = 0
        self.solve_fail = 0

    def reset(self) -> None:
        super().reset()
        self._warm, self._a_prev = None, np.zeros(3)

    def _ensure(self, dt: float) -> None:
        h = self.step_s if self.step_s is not None else dt
        if self._solver is None or abs(h - self._h) > 1e-3 * h:
            self._solver, self._bounds = build_solver(
                horizon=self.horizon, step_s=h, wheelbase_m=self.wheelbase_m, accel_max=self.limits.wheel_accel_mps2,
                speed_max=self.limits.wheel_speed_mps, max_iter=self.max_iter)
            self._h, self._warm = h, None

    def desired(self, ref, pose, wheels, dt):
        self._ensure(dt)
        N, h = self.horizon, self._h
        tau = h * np.arange(N + 1)
        pr, dpr = (self.preview or taylor_preview(ref))(tau)
        pr = np.array(pr, dtype=float)
        th = pose[2]
        pr[:, 2] = th + np.unwrap(np.concatenate([[0.0], (pr[:, 2] - th + np.pi) % (2 * np.pi) - np.pi]))[1:]
        c, s = np.cos(pr[:, 2]), np.sin(pr[:, 2])
        vx, vy = c * dpr[:, 0] + s * dpr[:, 1], -s * dpr[:, 0] + c * dpr[:, 1]
        half = 0.5 * self.wheelbase_m * dpr[:, 2]
        sref = np.stack([vx, vy + half, vy - half])
        s0 = s_from_wheels(wheels)
        z0 = np.array([pose[0], pose[1], th, *s0])
        p = np.concatenate([z0, pr.T.ravel(order="F"), sref.ravel(order="F"), self._a_prev])
        args = dict(p=p, lbx=self._bounds["lbx"], ubx=self._bounds["ubx"], lbg=0.0, ubg=0.0)
        args.update(self._warm_start(z0))
        sol = self._solver(**args)
        if not self._solver.stats().get("success", False):
            self.solve_fail += 1
        else:
            self.solve_ok += 1
        x = np.asarray(sol["x"]).ravel()
        if not np.all(np.isfinite(x)):
            self._warm = None
            return None
        self._warm = {"x": x, "lam_x": np.asarray(sol["lam_x"]).ravel(), "lam_g": np.asarray(sol["lam_g"]).ravel()}
        a0 = x[self._bounds["nz"]:self._bounds["nz"] + 3]
        self._a_prev = a0.copy()
        T = self.lead(dt)
        return tuple(float(v) for v in np.asarray(s0) + T * a0), tuple(float(v) for v in a0)

    def _warm_start(self, z0: np.ndarray) -> dict:
        """Previous solution shifted one interval (last interval repeated); cold: hold z0, zero input."""
        N, nz = self.horizon, self._bounds["nz"]
        if self._warm is None:
            return {"x0": np.concatenate([np.tile(z0, N + 1), np.zeros(3 * N)])}
        x, lx, lg = self._warm["x"], self._warm["lam_x"], self._warm["lam_g"]
        Z, U = x[:nz].reshape(N + 1, 6), x[nz:].reshape(N, 3)
        Z = np.vstack([Z[1:], Z[-1:]])
        Z[0] = z0
        U = np.vstack([U[1:], U[-1:]])
        return {"x0": np.concatenate([Z.ravel(), U.ravel()]), "lam_x0": lx, "lam_g0": lg}
