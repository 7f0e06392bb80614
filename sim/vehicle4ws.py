"""Double-Ackermann (four-wheel-steer) vehicle simulator: pure model plus the ``Vehicle4WS`` node.

The model integrates what the drives actually achieve.  Each axle's steer angle and wheel
speed move toward the command as a first-order lag (time constant ``*_tau_s``; 0 = reach
it at once) bounded by the steer rate / wheel acceleration limits, the steer range and
the top speed.  The body twist is the least-squares fit of both wheel velocity vectors
(:func:`nodes.control.kinematics.body_twist`), so wheels that violate the rigid-body
constraint ``v_f cos d_f = v_b cos d_b`` scrub instead of being obeyed blindly (the
residual is kept in ``scrub_mps``).  Optional slip is an Ornstein-Uhlenbeck perturbation of
the twist, proportional to speed, from a seeded generator.  The pose is integrated
exactly for a constant twist over sub-steps of at most ``max_substep_s``.

Node ``sim.vehicle4ws:Vehicle4WS``
    inputs  ``cmd`` (control.WheelCommand): setpoints, passed through the actuator model above.
            ``actuation`` (control.WheelCommand): *achieved* wheel speeds / steer angles as
            measured by real or simulated drives (the CAN loop feeds the CiA 402 velocity /
            position actuals here).  From the first ``actuation`` message on, the sim ignores
            ``cmd`` and integrates the measured actuation (held between messages) with no
            actuator model of its own: the drives already are the actuators.
    output  ``state`` (control.VehicleState) at ``rate_hz``: pose and achieved actuation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import msgspec
import numpy as np

from msgs.control import VehicleState, WheelCommand
from nodes.control.kinematics import Wheels, body_twist, wrap_angle
from tether import Input, Node


@dataclass(frozen=True)
class VehicleParams:
    """Vehicle geometry and actuator limits (SI units); see the module docstring."""

    wheelbase_m: float = 1.0
    steer_limit_rad: float = 2.5
    steer_rate_radps: float = 3.0
    wheel_accel_mps2: float = 2.0
    wheel_speed_mps: float = 2.0
    wheel_tau_s: float = 0.0
    steer_tau_s: float = 0.0
    slip_std: float = 0.0
    slip_tau_s: float = 0.5
    seed: int = 0
    max_substep_s: float = 1e-3

    def __post_init__(self) -> None:
        if self.wheelbase_m <= 0 or self.max_substep_s <= 0 or self.slip_tau_s <= 0:
            raise ValueError("wheelbase_m, max_substep_s and slip_tau_s must be > 0")
        if min(self.steer_rate_radps, self.wheel_accel_mps2, self.wheel_speed_mps, self.steer_limit_rad) <= 0:
            raise ValueError("actuator limits must be > 0 (use a large value for 'unlimited')")
        if self.wheel_tau_s < 0 or self.steer_tau_s < 0 or self.slip_std < 0:
            raise ValueError("time constants and slip_std must be >= 0")


def _actuate(x: float, target: float, tau: float, rate_max: float, h: float) -> float:
    """One actuator sub-step: first-order lag toward ``target`` (exact discretisation), rate-limited."""
    step = (target - x) * (-math.expm1(-h / tau) if tau > 0 else 1.0)
    lim = rate_max * h
    return x + max(-lim, min(lim, step))


class Vehicle4WSModel:
    """Pose ``(x, y, theta)`` and achieved wheels, advanced by :meth:`step` (commands) or :meth:`step_measured`."""

    def __init__(self, params: VehicleParams = VehicleParams(), *, pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 wheels: Wheels = Wheels(0.0, 0.0, 0.0, 0.0)) -> None:
        self.p = params
        self.x, self.y, self.theta = (float(v) for v in pose)
        self.wheels = Wheels(*(float(v) for v in wheels))
        self.t_s = 0.0
        self.scrub_mps = 0.0
        self.twist = (0.0, 0.0, 0.0)
        self._rng = np.random.default_rng(params.seed)
        self._slip = np.zeros(3)

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x m, y m, theta rad) with theta wrapped to [-pi, pi)."""
        return self.x, self.y, wrap_angle(self.theta)

    def step(self, cmd: Wheels, dt: float) -> None:
        """Advance ``dt`` seconds holding the setpoints ``cmd`` (non-finite values are ignored: held)."""
        self._advance(cmd, dt, actuate=True)

    def step_measured(self, wheels: Wheels, dt: float) -> None:
        """Advance ``dt`` seconds with the achieved actuation ``wheels`` held constant."""
        if all(math.isfinite(v) for v in wheels):
            self.wheels = Wheels(*wheels)
        self._advance(self.wheels, dt, actuate=False)

    def _advance(self, cmd: Wheels, dt: float, *, actuate: bool) -> None:
        if not dt > 0:
            return
        cmd = Wheels(*(c if math.isfinite(c) else w for c, w in zip(cmd, self.wheels)))
        n = max(1, math.ceil(dt / self.p.max_substep_s - 1e-9))
        h = dt / n
        for _ in range(n):
            before = self.wheels
            if actuate:
                self.wheels = self._actuate(cmd, h)
            mid = Wheels(*(0.5 * (a + b) for a, b in zip(before, self.wheels)))
            self._integrate(mid, h)
        self.t_s += dt

    def _actuate(self, cmd: Wheels, h: float) -> Wheels:
        p, w = self.p, self.wheels
        lim = p.steer_limit_rad
        df = _actuate(w.delta_front, max(-lim, min(lim, cmd.delta_front)), p.steer_tau_s, p.steer_rate_radps, h)
        db = _actuate(w.delta_rear, max(-lim, min(lim, cmd.delta_rear)), p.steer_tau_s, p.steer_rate_radps, h)
        vm = p.wheel_speed_mps
        vf = _actuate(w.v_front, max(-vm, min(vm, cmd.v_front)), p.wheel_tau_s, p.wheel_accel_mps2, h)
        vb = _actuate(w.v_rear, max(-vm, min(vm, cmd.v_rear)), p.wheel_tau_s, p.wheel_accel_mps2, h)
        return Wheels(vf, df, vb, db)

    def _integrate(self, wheels: Wheels, h: float) -> None:
        """Exact SE(2) motion for a constant body twist over ``h`` seconds."""
        L = self.p.wheelbase_m
        vx, vy, om, self.scrub_mps = body_twist(wheels, L)
        if self.p.slip_std > 0:
            a = h / self.p.slip_tau_s
            self._slip += -a * self._slip + self.p.slip_std * math.sqrt(2 * a) * self._rng.standard_normal(3)
            speed = math.hypot(vx, vy) + 0.5 * L * abs(om)
            vx, vy, om = vx + self._slip[0] * speed, vy + self._slip[1] * speed, om + self._slip[2] * speed / L
        self.twist = (vx, vy, om)
        dth = om * h
        if abs(dth) < 1e-6:                          # series of sin(x)/x and (1-cos x)/x
            a, b = 1.0 - dth * dth / 6.0, 0.5 * dth
        else:
            a, b = math.sin(dth) / dth, (1.0 - math.cos(dth)) / dth
        dx, dy = (a * vx - b * vy) * h, (b * vx + a * vy) * h
        c, s = math.cos(self.theta), math.sin(self.theta)
        self.x += c * dx - s * dy
        self.y += s * dx + c * dy
        self.theta += dth


@dataclass
class Tracking:
    """Closed-loop run sampled at the control ticks: arrays of shape (n,) or (n, k)."""

    t_s: np.ndarray          # (n,) tick times
    pose: np.ndarray         # (n, 3) vehicle pose at the tick (x m, y m, theta rad)
    ref: np.ndarray          # (n, 3) reference pose at the tick
    cmd: np.ndarray          # (n, 4) commands (v_f, d_f, v_b, d_b) computed at the tick
    status: list[str]        # controller status per tick

    @property
    def pos_err_m(self) -> np.ndarray:
        return np.hypot(self.pose[:, 0] - self.ref[:, 0], self.pose[:, 1] - self.ref[:, 1])

    @property
    def heading_err_rad(self) -> np.ndarray:
        return (self.pose[:, 2] - self.ref[:, 2] + np.pi) % (2 * np.pi) - np.pi

    def summary(self) -> dict[str, float]:
        """RMS / max position error (mm) and heading error (deg), and the share of non-ok ticks."""
        e, h = self.pos_err_m, np.abs(self.heading_err_rad)
        return {"rms_mm": float(np.sqrt(np.mean(e * e)) * 1e3), "max_mm": float(e.max() * 1e3),
                "rms_deg": float(np.degrees(np.sqrt(np.mean(h * h)))), "max_deg": float(np.degrees(h.max())),
                "bad_ticks": float(np.mean([s != "ok" for s in self.status]))}


def simulate_tracking(controller, traj, *, rate_hz: float, duration_s: float,
                      params: VehicleParams = VehicleParams(), latency_s: float = 0.0, state_delay_s: float = 0.0,
                      preview: bool = True) -> Tracking:
    """Run ``controller`` against the model on ``traj`` (``t -> Reference``), starting on the reference.

    The bus is modelled as a command delay ``latency_s`` (commands apply ``latency_s`` after
    their tick, then are held: zero-order hold) and a measurement delay ``state_delay_s``
    (the controller sees the pose and wheels of that long ago); drive dynamics come from
    ``params`` (``wheel_tau_s``, ``steer_tau_s``).  A controller with a ``preview``
    attribute (the MPC) is given the exact future reference when ``preview`` is True.
    """
    from nodes.control.double_ackermann import RefPoint                # pure; imported late to keep sim light
    from nodes.control.kinematics import initial_wheels, s_from_world
    r0 = traj(0.0)
    w0 = initial_wheels(s_from_world(r0.p[0, 2], *r0.dp[0], params.wheelbase_m), params.steer_limit_rad)
    model = Vehicle4WSModel(params, pose=tuple(r0.p[0]), wheels=w0)
    controller.reset()
    controller.prev = w0
    dt, n = 1.0 / rate_hz, int(round(duration_s * rate_hz))
    history = [(0.0, model.pose, model.wheels)]                        # for the measurement delay
    pending: list[tuple[float, Wheels]] = []
    cmd, out = w0, {"t": [], "pose": [], "ref": [], "cmd": [], "status": []}
    for k in range(n):
        t = k * dt
        while len(history) > 1 and history[1][0] <= t - state_delay_s + 1e-12:
            history.pop(0)
        seen_t, seen_pose, seen_wheels = history[0]
        r = traj(t)
        if preview and hasattr(controller, "preview"):
            controller.preview = lambda tau, t=t: (traj(t + tau).p, traj(t + tau).dp)
        c = controller.step(RefPoint(tuple(r.p[0]), tuple(r.dp[0]), tuple(r.ddp[0])), seen_pose, seen_wheels, dt,
                            state_age_s=t - seen_t)
        for key, val in (("t", t), ("pose", model.pose), ("ref", r.p[0]), ("cmd", tuple(c)),
                         ("status", controller.status)):
            out[key].append(val)
        pending.append((t + latency_s, c))
        now, end = t, t + dt
        while now < end - 1e-12:
            if pending and pending[0][0] <= now + 1e-12:
                cmd = pending.pop(0)[1]
                continue
            nxt = min(end, pending[0][0], now + params.max_substep_s) if pending else min(end, now + params.max_substep_s)
            model.step(cmd, nxt - now)
            now = nxt
            if state_delay_s > 0:
                history.append((now, model.pose, model.wheels))
        if state_delay_s <= 0:
            history = [(end, model.pose, model.wheels)]
    return Tracking(np.array(out["t"]), np.array(out["pose"]), np.array(out["ref"]), np.array(out["cmd"]),
                    out["status"])


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rate_hz: float = 100.0              # state publication rate
    wheelbase_m: float = 1.0
    steer_limit_rad: float = 2.5
    steer_rate_radps: float = 3.0
    wheel_accel_mps2: float = 2.0
    wheel_speed_mps: float = 2.0
    wheel_tau_s: float = 0.0            # first-order drive lag (0: ideal, only rate-limited)
    steer_tau_s: float = 0.0
    slip_std: float = 0.0               # stationary std of the slip fractions (0: no slip)
    slip_tau_s: float = 0.5
    seed: int = 0
    x_m: float = 0.0                    # initial pose
    y_m: float = 0.0
    theta_rad: float = 0.0
    frame_id: str = "odom"


def _wheels_of(msg: WheelCommand) -> Wheels:
    return Wheels(msg.v_front_mps, msg.delta_front_rad, msg.v_rear_mps, msg.delta_rear_rad)


class Vehicle4WS(Node):
    """Inputs ``cmd`` (setpoints) and ``actuation`` (measured, overrides cmd); output ``state`` at ``rate_hz``."""

    Config = Config
    inputs = {"cmd": Input(WheelCommand, latest=True), "actuation": Input(WheelCommand, latest=True)}
    outputs = {"state": VehicleState}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        params = VehicleParams(**{f: getattr(c, f) for f in VehicleParams.__dataclass_fields__ if f != "max_substep_s"})
        self.model = Vehicle4WSModel(params, pose=(c.x_m, c.y_m, c.theta_rad))
        self._cmd = Wheels(0.0, 0.0, 0.0, 0.0)
        self._measured: Wheels | None = None
        self._t_ns: int | None = None
        self.bad_inputs = 0

    def _advance(self) -> None:
        now = self.now_ns()
        if self._t_ns is not None and now > self._t_ns:
            dt = (now - self._t_ns) * 1e-9
            if self._measured is not None:
                self.model.step_measured(self._measured, dt)
            else:
                self.model.step(self._cmd, dt)
        self._t_ns = now if self._t_ns is None else max(self._t_ns, now)

    def _accept(self, msg: WheelCommand, what: str) -> Wheels | None:
        w = _wheels_of(msg)
        if all(math.isfinite(v) for v in w):
            return w
        self.bad_inputs += 1
        self.log.error("non-finite %s %s dropped (%d so far); holding the previous one", what, tuple(w), self.bad_inputs)
        return None

    def on_cmd(self, msg: WheelCommand) -> None:
        self._advance()
        w = self._accept(msg, "cmd")
        if w is not None:
            self._cmd = w

    def on_actuation(self, msg: WheelCommand) -> None:
        self._advance()
        w = self._accept(msg, "actuation")
        if w is not None:
            self._measured = w

    def on_tick(self, tick: object) -> dict[str, VehicleState]:
        self._advance()
        m = self.model
        x, y, th = m.pose
        w = m.wheels
        # Stamped with the time the pose is for (what _advance integrated to), not a second
        # clock reading: a preemption between the two would date the pose late.
        return {"state": VehicleState(stamp_ns=self._t_ns, frame_id=self.config.frame_id, x_m=x, y_m=y,
                                      theta_rad=th, v_front_mps=w.v_front, v_rear_mps=w.v_rear,
                                      delta_front_rad=w.delta_front, delta_rear_rad=w.delta_rear)}
