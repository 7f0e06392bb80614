"""Trajectory generator node: publishes the reference pose and its derivatives at ``rate_hz``.

A real vehicle must not be handed a reference that left without it. With
``wait_for_enable`` the trajectory's clock starts only when the ``enable`` input says true
(e.g. ``can/ready``: every drive OPERATION ENABLED); while it says false the reference
holds its pose with zero rates, and on the next true it restarts from rest (ramped over
``ramp_s``, after standing still for ``align_s`` while announcing the way it will leave, so
the wheels can turn first). With ``start_from_state`` the whole trajectory is moved rigidly so that it
starts at the vehicle's pose (``state``) as it was when the clock first started. Nothing
is published before the clock first starts.
"""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.control import TrajectoryPoint, VehicleState
from msgs.std import Bool
from nodes.control.trajectory import GENERATORS, Reference, anchor, make_trajectory, ramp_time, resume
from tether import Input, Node, Tick


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    kind: str = "figure8"               # circle | figure8 | crab | spin | focus
    rate_hz: float = 50.0
    params: dict[str, float | str | list[float]] = {}   # keyword arguments of the generator
    ramp_s: float = 0.0                 # > 0: (re)start from rest, reaching full speed smoothly over ramp_s
    align_s: float = 0.0                # > 0: on (re)start first stand still this long, announcing the way out
    duration_s: float = 0.0             # > 0: after this much trajectory time, hold the last pose (zero rates)
    wait_for_enable: bool = False       # start the clock on enable=true; pause while it is false
    start_from_state: bool = False      # move the trajectory to start at the vehicle's pose (waits for a state)
    frame_id: str = "odom"

    def __post_init__(self) -> None:
        if self.kind not in GENERATORS:
            raise ValueError(f"kind must be one of {sorted(GENERATORS)}, not {self.kind!r}")
        if self.ramp_s < 0 or self.duration_s < 0 or self.align_s < 0:
            raise ValueError("ramp_s, align_s and duration_s must be >= 0 s")
        try:
            make_trajectory(self.kind, **_params(self.params))
        except TypeError as exc:      # unknown keyword: say which generator refused it
            raise ValueError(f"{self.kind} params: {exc}") from None


def _params(params: dict) -> dict:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}


class TrajectoryGenerator(Node):
    """Timer ``tick`` -> output ``reference``; inputs ``enable`` and ``state`` gate and place the start.

    ``TrajectoryPoint.t_s`` is the trajectory's own time (it stands still while paused).
    """

    Config = Config
    inputs = {"enable": Input(Bool, latest=True), "state": Input(VehicleState, latest=True)}
    outputs = {"reference": TrajectoryPoint}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        self.traj = make_trajectory(self.config.kind, **_params(self.config.params))
        self._enabled = False
        self._pose: tuple[float, float, float] | None = None
        self._anchor: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        self._started = False            # the clock has started at least once
        self._run_ns: int | None = None  # when the current run (re)started; None: paused / not started
        self._s0 = 0.0                   # trajectory time at that (re)start
        self._s = 0.0                    # trajectory time of the last reference
        self.pauses = 0
        self._waiting_logged = False

    def on_enable(self, msg: Bool) -> None:
        self._enabled = bool(msg.data)

    def on_state(self, msg: VehicleState) -> None:
        if all(np.isfinite((msg.x_m, msg.y_m, msg.theta_rad))):
            self._pose = (msg.x_m, msg.y_m, msg.theta_rad)

    def _may_run(self) -> bool:
        cfg = self.config
        return (self._enabled or not cfg.wait_for_enable) and (self._pose is not None or not cfg.start_from_state
                                                               or self._started)

    def on_tick(self, tick: Tick) -> dict[str, TrajectoryPoint] | None:
        now = self.now_ns()
        run = self._may_run()
        if run and self._run_ns is None:
            self._start(now)
        elif not run and self._run_ns is not None:
            self.pauses += 1
            self._s0 = self._progress(now)
            self._run_ns = None
            self.log.warning("enable dropped at trajectory time %.2f s: holding the reference", self._s)
        if not self._started:
            if not self._waiting_logged:
                self._waiting_logged = True
                self.log.info("waiting for %s before starting the trajectory", " and ".join(
                    w for w, need in (("enable", self.config.wait_for_enable and not self._enabled),
                                      ("a vehicle state", self.config.start_from_state and self._pose is None))
                    if need))
            return None
        ref = self._reference(now)
        p, dp, ddp = ref.p[0], ref.dp[0], ref.ddp[0]
        return {"reference": TrajectoryPoint(
            stamp_ns=now, frame_id=self.config.frame_id, t_s=self._s, x_m=float(p[0]), y_m=float(p[1]),
            theta_rad=float(p[2]), dx_mps=float(dp[0]), dy_mps=float(dp[1]), dtheta_radps=float(dp[2]),
            ddx_mps2=float(ddp[0]), ddy_mps2=float(ddp[1]), ddtheta_radps2=float(ddp[2]))}

    def _start(self, now: int) -> None:
        self._run_ns = now
        if not self._started and self.config.start_from_state and self._pose is not None:
            start = tuple(float(v) for v in self.traj(0.0).p[0])
            self._anchor = (start, self._pose)        # type: ignore[assignment]
        self.log.info("trajectory %s at t=%.2f s%s", "started" if not self._started else "resumed", self._s,
                      f" from the vehicle pose {tuple(round(v, 3) for v in self._pose)}"
                      if self._anchor is not None and not self._started else "")
        self._started = True

    def _progress(self, now: int) -> float:
        """Trajectory time now (held while paused, capped at duration_s)."""
        s = self._s0
        if self._run_ns is not None:
            s += float(ramp_time(self._moving_s(now), self.config.ramp_s)[0][0])
        return min(s, self.config.duration_s) if self.config.duration_s > 0 else s

    def _moving_s(self, now: int) -> float:
        """Seconds since the reference started to move in this run (0 while aligning)."""
        return max(0.0, (now - self._run_ns) * 1e-9 - self.config.align_s) if self._run_ns is not None else 0.0

    def _reference(self, now: int) -> Reference:
        cfg = self.config
        if self._run_ns is None:                       # paused: hold the pose, zero rates
            ref, s = resume(self.traj, self._s0, 0.0, 0.0)
            ref = Reference(ref.p, ref.dp * 0.0, ref.ddp * 0.0)
        elif (now - self._run_ns) * 1e-9 < cfg.align_s:
            # Aligning: at rest, about to leave along the path. A vanishing acceleration (1e-6 m/s^2,
            # moving the reference < 1e-7 m over a stale period) tells the controller which way, so
            # the steering turns before the wheels roll.
            ref, s = resume(self.traj, self._s0, 0.0, 0.0)
            ref = Reference(ref.p, ref.dp * 0.0, self.traj(self._s0).dp * 1e-6)
        else:
            ref, s = resume(self.traj, self._s0, self._moving_s(now), cfg.ramp_s)
        self._s = float(s[0])
        if 0.0 < cfg.duration_s < self._s:             # past the end: hold the last pose
            self._s = cfg.duration_s
            end = self.traj(cfg.duration_s)
            ref = Reference(end.p, end.dp * 0.0, end.ddp * 0.0)
        if self._anchor is not None:
            ref = anchor(ref, *self._anchor)
        return ref
