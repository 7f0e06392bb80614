"""A :class:`~nodes.learn.vec_sim.VecSim` on the bus: answers every reset and action with one step.

Lockstep, no clock: the simulator advances only when asked, and each reply carries the
simulation time of every instance. A request seen twice (a client resending a reset
until the subscription is up, or a duplicated message) gets the same reply again without
stepping twice, so a retry can never desynchronise the episode.
"""
from __future__ import annotations

import importlib
from typing import Any

import msgspec
import numpy as np

from msgs.learn import EnvAction, EnvReset, EnvStep
from nodes.learn.vec_sim import Batch, VecSim
from tether import Node, NonNegativeInt, PositiveInt
from tether.errors import ConfigError
from tether.node import Input

#: where simulators may be loaded from (a launch file names one by "module:Class")
SIM_PACKAGES = ("nodes.", "sim.")


class Config(msgspec.Struct, frozen=True, kw_only=True):
    sim: str = "sim.car_env:ReachCar"
    n_envs: PositiveInt = 1
    max_steps: NonNegativeInt = 0   # 0: the scenario's default
    params: dict[str, Any] = {}   # the scenario's own keyword arguments


def load_sim(path: str, n: int = 1, *, max_steps: int = 0, params: dict[str, Any] | None = None) -> VecSim:
    """Instantiate ``"module:Class"`` (a VecSim under ``nodes.`` or ``sim.``)."""
    module, _, name = path.partition(":")
    if not name or not module.startswith(SIM_PACKAGES):
        raise ConfigError(f"sim {path!r}: give 'module:Class' with the module under {' or '.join(SIM_PACKAGES)}",
                          key="sim")
    try:
        cls = getattr(importlib.import_module(module), name, None)
    except ImportError as exc:        # a mistyped module: one line, not a traceback
        raise ConfigError(f"sim {path!r}: cannot import {module!r}: {exc}", key="sim") from None
    if not (isinstance(cls, type) and issubclass(cls, VecSim)):
        raise ConfigError(f"sim {path!r} is not a VecSim subclass", key="sim")
    return cls(n, max_steps=max_steps, **(params or {}))


def step_message(batch: Batch, names: tuple[str, ...], epoch: int, step: int) -> EnvStep:
    return EnvStep(epoch=epoch, step=step, sim_time_s=batch.sim_time_s, obs=batch.obs, final_obs=batch.final_obs,
                   rewards=batch.rewards, terminated=batch.terminated, truncated=batch.truncated,
                   metrics=batch.metrics, metric_names=list(names))


class SimNode(Node):
    """Inputs ``reset`` and ``action``; output ``step`` (one per request, echoing its epoch and step)."""

    Config = Config
    inputs = {"reset": Input(EnvReset, depth=64), "action": Input(EnvAction, depth=64)}
    outputs = {"step": EnvStep}

    def setup(self) -> None:
        cfg = self.config
        self.sim = load_sim(cfg.sim, cfg.n_envs, max_steps=cfg.max_steps, params=cfg.params)
        self._last: tuple[int, int] | None = None
        self._reply: EnvStep | None = None

    def _again(self, key: tuple[int, int]) -> bool:
        return key == self._last and self._reply is not None

    def _refuse(self, epoch: int, step: int, text: str) -> dict[str, EnvStep]:
        self.log.warning("refused epoch %d step %d: %s", epoch, step, text)
        return {"step": EnvStep(epoch=epoch, step=step, error=text)}

    def on_reset(self, msg: EnvReset) -> dict[str, EnvStep]:
        key = (msg.epoch, 0)
        if self._again(key):
            return {"step": self._reply}
        try:
            obs = self.sim.reset(msg.seeds if msg.seeds.size else None)
        except ValueError as exc:
            return self._refuse(msg.epoch, 0, str(exc))
        n = self.sim.n
        batch = Batch(obs=obs, final_obs=obs, rewards=np.zeros(n), terminated=np.zeros(n, bool),
                      truncated=np.zeros(n, bool), metrics=np.zeros((n, len(self.sim.metric_names))),
                      sim_time_s=np.zeros(n))
        reply = step_message(batch, self.sim.metric_names, msg.epoch, 0)
        self._last, self._reply = key, reply
        return {"step": reply}

    def on_action(self, msg: EnvAction) -> dict[str, EnvStep] | None:
        key = (msg.epoch, msg.step)
        if self._again(key):
            return {"step": self._reply}
        if self._last is None or msg.epoch != self._last[0] or msg.step != self._last[1] + 1:
            # Out of order (a reply lost, or an action for an epoch never reset): say so rather than step.
            return self._refuse(msg.epoch, msg.step, f"expected step {None if self._last is None else self._last[1] + 1} "
                                f"of epoch {None if self._last is None else self._last[0]}")
        try:
            batch = self.sim.step(msg.actions)
        except ValueError as exc:
            return self._refuse(msg.epoch, msg.step, str(exc))
        reply = step_message(batch, self.sim.metric_names, msg.epoch, msg.step)
        self._last, self._reply = key, reply
        return {"step": reply}
