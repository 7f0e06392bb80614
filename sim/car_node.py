"""A deployed simulator: one instance of a VecSim scenario (the simple car by default) run on a
timer, driven by a policy over the bus, with a dead man's rule.

Each tick advances the scenario one step (its ``DT_S``) with the latest action; an action older
than ``hold_s``, or none, is replaced by the zero action (the car stops: no motion continues
uncommanded), counted and logged once per lapse. The first tick of an episode only publishes its
first observation. After ``episodes`` episodes the car holds still.
"""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Pose2D
from msgs.learn import EpisodeSummary, Observation, PolicyAction
from nodes.learn.sim_node import load_sim
from tether import Node
from tether.node import Input, Tick


class Config(msgspec.Struct, frozen=True, kw_only=True):
    scenario: str = "sim.car_env:ReachCar"
    params: dict[str, Any] = {}
    seed: int = 10_000              # episode k is seeded seed + k
    episodes: int = 3               # then hold still (0: forever)
    rate_hz: float = 10.0           # ticks per second (1 / DT_S: real time)
    hold_s: float = 0.3             # an action older than this is not applied: zero action
    max_steps: int = 0


class CarSim(Node):
    """Input ``action`` (latest only) and a timer; outputs ``obs``, ``odom`` and ``episode`` (summaries)."""

    Config = Config
    inputs = {"action": Input(PolicyAction, depth=1, latest=True)}
    outputs = {"obs": Observation, "odom": Odometry2D, "episode": EpisodeSummary}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        cfg = self.config
        self.sim = load_sim(cfg.scenario, 1, max_steps=cfg.max_steps, params=cfg.params)
        self.zero = np.zeros((1, *self.sim.action_space.shape), self.sim.action_space.dtype)
        self.episode, self.step, self.ret, self.started = 0, 0, 0.0, False
        self.last: PolicyAction | None = None
        self.last_ns = 0
        self.stale = 0
        self._lapsed = False

    def on_action(self, msg: PolicyAction) -> None:
        self.last, self.last_ns = msg, self.now_ns()

    def _action(self) -> np.ndarray:
        fresh = self.last is not None and (self.now_ns() - self.last_ns) <= self.config.hold_s * 1e9
        if fresh:
            self._lapsed = False
            return np.asarray(self.last.action).reshape(self.zero.shape)
        self.stale += 1
        if not self._lapsed:
            self._lapsed = True
            self.log.warning("no action for %.2f s: holding still (zero action; %d stale ticks so far)",
                             self.config.hold_s, self.stale)
        return self.zero

    def _publish_obs(self, obs: np.ndarray, metrics: np.ndarray) -> dict[str, Any]:
        names = list(self.sim.metric_names)
        t = self.step * self.sim.DT_S
        pose = getattr(self.sim, "pose", np.zeros((1, 3)))[0]
        return {"obs": Observation(episode=self.episode, step=self.step, sim_time_s=t, obs=obs[0], metrics=metrics,
                                   metric_names=names),
                "odom": Odometry2D(pose=Pose2D(x_m=float(pose[0]), y_m=float(pose[1]), yaw_rad=float(pose[2])))}

    def on_tick(self, tick: Tick) -> dict[str, Any] | None:
        cfg = self.config
        if cfg.episodes and self.episode >= cfg.episodes:
            return None
        if not self.started:
            obs = self.sim.reset([cfg.seed + self.episode])
            self.started, self.step, self.ret = True, 0, 0.0
            self.last = None                       # an action for the previous episode is not this one's
            return self._publish_obs(obs, np.full(len(self.sim.metric_names), np.nan))
        try:
            batch = self.sim.step(self._action())
        except ValueError as exc:                  # a NaN action: refused, the car holds still this tick
            self.log.error("action refused: %s", exc)
            batch = self.sim.step(self.zero)
        self.step += 1
        self.ret += float(batch.rewards[0])
        out = self._publish_obs(batch.final_obs, batch.metrics[0])
        if batch.terminated[0] or batch.truncated[0]:
            out["episode"] = EpisodeSummary(episode=self.episode, steps=self.step, return_=self.ret,
                                            terminated=bool(batch.terminated[0]), truncated=bool(batch.truncated[0]),
                                            metrics=batch.metrics[0], metric_names=list(self.sim.metric_names))
            self.log.info("episode %d ended after %d steps: %s", self.episode, self.step,
                          ", ".join(f"{n} {v:.4g}" for n, v in zip(self.sim.metric_names, batch.metrics[0])))
            self.episode += 1
            self.started = False
        return out
