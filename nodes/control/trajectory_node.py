"""Trajectory generator node: publishes the reference pose and its derivatives at ``rate_hz``."""
from __future__ import annotations

import msgspec

from msgs.control import TrajectoryPoint
from nodes.control.trajectory import GENERATORS, make_trajectory
from tether import Node, Tick


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    kind: str = "figure8"               # circle | figure8 | crab | spin | focus
    rate_hz: float = 50.0
    params: dict[str, float | str | list[float]] = {}   # keyword arguments of the generator
    ramp_s: float = 0.0                 # > 0: start from rest, reaching full speed smoothly over ramp_s
    duration_s: float = 0.0             # > 0: after this, hold the last pose with zero rates
    frame_id: str = "odom"

    def __post_init__(self) -> None:
        if self.kind not in GENERATORS:
            raise ValueError(f"kind must be one of {sorted(GENERATORS)}, not {self.kind!r}")
        try:
            make_trajectory(self.kind, ramp_s=self.ramp_s, **_params(self.params))
        except TypeError as exc:      # unknown keyword: say which generator refused it
            raise ValueError(f"{self.kind} params: {exc}") from None


def _params(params: dict) -> dict:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}


class TrajectoryGenerator(Node):
    """Timer ``tick`` -> output ``reference``; trajectory time starts at the first tick."""

    Config = Config
    outputs = {"reference": TrajectoryPoint}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        self.traj = make_trajectory(self.config.kind, ramp_s=self.config.ramp_s, **_params(self.config.params))
        self._t0_ns: int | None = None

    def on_tick(self, tick: Tick) -> dict[str, TrajectoryPoint]:
        now = self.now_ns()
        if self._t0_ns is None:
            self._t0_ns = now
        t = (now - self._t0_ns) * 1e-9
        hold = 0.0 < self.config.duration_s < t
        ref = self.traj(self.config.duration_s if hold else t)
        p, dp, ddp = ref.p[0], ref.dp[0] * (not hold), ref.ddp[0] * (not hold)
        return {"reference": TrajectoryPoint(
            stamp_ns=now, frame_id=self.config.frame_id, t_s=t, x_m=float(p[0]), y_m=float(p[1]),
            theta_rad=float(p[2]), dx_mps=float(dp[0]), dy_mps=float(dp[1]), dtheta_radps=float(dp[2]),
            ddx_mps2=float(ddp[0]), ddy_mps2=float(ddp[1]), ddtheta_radps2=float(ddp[2]))}
