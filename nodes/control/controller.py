"""Double-Ackermann controller node: reference + vehicle state -> per-axle wheel command, with a watchdog."""
from __future__ import annotations

import math

import msgspec

from msgs.control import TrajectoryPoint, VehicleState, WheelCommand
from nodes.control.double_ackermann import (Controller, FblinController, FinalController, KinematicController,
                                            RefPoint)
from nodes.control.kinematics import Limits, Wheels
from tether import Input, Node, Tick

LAWS = ("final", "fblin", "kinematic", "mpc")


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rate_hz: float = 50.0
    law: str = "final"                  # final | fblin (seed's first, singular) | kinematic | mpc
    wheelbase_m: float = 1.0
    k_p: float = 3.0                    # pose pole (1/s)
    k_s: float | None = None            # body-velocity pole (1/s); None: 1/lead (deadbeat on the setpoint)
    lead_s: float = 0.0                 # modelled drive lag + bus latency added to the half-period lead
    steer_limit_rad: float = 2.5
    steer_rate_radps: float = 3.0
    wheel_accel_mps2: float = 2.0
    wheel_speed_mps: float = 2.0
    v_gate_mps: float = 0.01            # below this wheel speed the steering is held (or pre-steers)
    clamp_margin_rad: float = 0.35      # a wanted angle this far past the steer stop is clamped, not flipped
    stale_s: float = 0.25               # watchdog: no fresh reference or state for this long -> stop
    mpc_horizon: int = 20
    mpc_max_iter: int = 3

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {LAWS}, not {self.law!r}")
        if self.stale_s <= 0:
            raise ValueError("stale_s must be > 0")


def make_controller(cfg: Config) -> Controller:
    """The pure controller object a config describes."""
    limits = Limits(cfg.steer_limit_rad, cfg.steer_rate_radps, cfg.wheel_accel_mps2, cfg.wheel_speed_mps,
                    cfg.v_gate_mps, cfg.clamp_margin_rad)
    kw = dict(wheelbase_m=cfg.wheelbase_m, limits=limits, k_p=cfg.k_p, k_s=cfg.k_s, lead_s=cfg.lead_s)
    if cfg.law == "mpc":
        from nodes.control.mpc import MpcController   # casadi only when asked for
        return MpcController(horizon=cfg.mpc_horizon, max_iter=cfg.mpc_max_iter, **kw)
    return {"final": FinalController, "fblin": FblinController, "kinematic": KinematicController}[cfg.law](**kw)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class DoubleAckermannController(Node):
    """Inputs ``reference``, ``state``, ``measured`` (latest only) and timer ``tick``; output ``cmd`` every tick.

    The pose comes from ``state``; the wheels (speeds and steer angles the law starts from
    and linearises about) from ``measured`` -- the drives' own actuals, e.g. ``can/measured``
    at the control rate -- while it is fresh, else from ``state``.

    The command is always finite.  Nothing is commanded before the first state (the
    steering to hold is unknown: the drives stay disabled).  Until a reference has arrived
    too, and whenever either is older than ``stale_s`` (arrival time), the command is zero
    wheel speed with the steering held where it is.  The reference is extrapolated from its
    stamp to the tick with its own derivatives (at most ``stale_s`` ahead).  On every
    (re)start the law is seeded from the measured wheels (see ``Controller``).
    """

    Config = Config
    inputs = {"reference": Input(TrajectoryPoint, latest=True), "state": Input(VehicleState, latest=True),
              "measured": Input(WheelCommand, latest=True)}
    outputs = {"cmd": WheelCommand}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        self.ctrl = make_controller(self.config)
        self._ref: tuple[int, TrajectoryPoint] | None = None
        self._state: tuple[int, VehicleState] | None = None
        self._measured: tuple[int, Wheels] | None = None
        self.bad_inputs = self.stale_ticks = self.singular_ticks = self.ticks = 0
        self._was_stale = self._was_fresh = False

    def on_reference(self, msg: TrajectoryPoint) -> None:
        if not _finite(msg.x_m, msg.y_m, msg.theta_rad, msg.dx_mps, msg.dy_mps, msg.dtheta_radps,
                       msg.ddx_mps2, msg.ddy_mps2, msg.ddtheta_radps2):
            self._bad("reference", msg)
            return
        self._ref = (self.now_ns(), msg)

    def on_state(self, msg: VehicleState) -> None:
        if not _finite(msg.x_m, msg.y_m, msg.theta_rad, msg.v_front_mps, msg.v_rear_mps,
                       msg.delta_front_rad, msg.delta_rear_rad):
            self._bad("state", msg)
            return
        self._state = (self.now_ns(), msg)

    def on_measured(self, msg: WheelCommand) -> None:
        w = Wheels(msg.v_front_mps, msg.delta_front_rad, msg.v_rear_mps, msg.delta_rear_rad)
        if not _finite(*w):
            self._bad("measured wheels", msg)
            return
        self._measured = (self.now_ns(), w)

    def _bad(self, what: str, msg: object) -> None:
        self.bad_inputs += 1
        self.log.error("non-finite %s dropped (%d bad inputs so far): %r", what, self.bad_inputs, msg)

    def on_tick(self, tick: Tick) -> dict[str, WheelCommand] | None:
        now = self.now_ns()
        if self._state is None:
            return None                     # steering position unknown: command nothing
        self.ticks += 1
        dt = tick.period_ns * 1e-9 if tick.period_ns > 0 else 1.0 / self.config.rate_hz
        stale_ns = int(self.config.stale_s * 1e9)
        wheels = self._wheels()
        if (self._ref is None or self._state is None or now - self._ref[0] > stale_ns
                or now - self._state[0] > stale_ns):
            self.stale_ticks += 1
            if not self._was_stale and self._was_fresh:
                self.log.warning("reference or state stale (> %.3f s): commanding zero speed, steering held",
                                 self.config.stale_s)
            elif not self._was_stale:
                self.log.info("waiting for a reference: commanding zero speed, steering held")
            self._was_stale = True
            return {"cmd": self._msg(self.ctrl.stop(wheels, "stale"), now)}
        self._was_stale, self._was_fresh = False, True
        st = self._state[1]
        age = min(max((now - st.stamp_ns) * 1e-9, 0.0), self.config.stale_s)    # dead-reckoned by the law
        cmd = self.ctrl.step(self._ref_at(now), (st.x_m, st.y_m, st.theta_rad), wheels, dt, state_age_s=age)
        if self.ctrl.status != "ok":
            self.singular_ticks += 1
        return {"cmd": self._msg(cmd, now)}

    def _wheels(self) -> Wheels | None:
        if self._measured is not None and self.now_ns() - self._measured[0] <= self.config.stale_s * 1e9:
            return self._measured[1]
        if self._state is None:
            return None
        st = self._state[1]
        return Wheels(st.v_front_mps, st.delta_front_rad, st.v_rear_mps, st.delta_rear_rad)

    def _ref_at(self, now: int) -> RefPoint:
        r = self._ref[1]  # type: ignore[index]
        tau = min(max((now - r.stamp_ns) * 1e-9, 0.0), self.config.stale_s)
        dp, ddp = (r.dx_mps, r.dy_mps, r.dtheta_radps), (r.ddx_mps2, r.ddy_mps2, r.ddtheta_radps2)
        p = tuple(a + b * tau + 0.5 * c * tau * tau for a, b, c in zip((r.x_m, r.y_m, r.theta_rad), dp, ddp))
        return RefPoint(p, tuple(a + b * tau for a, b in zip(dp, ddp)), ddp)

    def _msg(self, w: Wheels, now: int) -> WheelCommand:
        return WheelCommand(stamp_ns=now, v_front_mps=w.v_front, delta_front_rad=w.delta_front,
                            v_rear_mps=w.v_rear, delta_rear_rad=w.delta_rear)

    def teardown(self) -> None:
        self.log.info("controller %s: %d ticks, %d stale (stopped), %d singular/non-finite, %d bad inputs",
                      self.config.law, self.ticks, self.stale_ticks, self.singular_ticks, self.bad_inputs)
