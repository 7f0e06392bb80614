"""A trained policy as a node: observation in, action out (the checkpoint of ``tether learn``)."""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.learn import Observation, PolicyAction
from nodes.learn.ppo import PPO
from tether import Node
from tether.node import Input


class Config(msgspec.Struct, frozen=True, kw_only=True):
    checkpoint: str = "nodes/learn/weights/reach_car.ppo"
    deterministic: bool = True


class PolicyNode(Node):
    """Input ``obs`` (latest only); output ``action``. An observation the policy cannot take (another
    size, NaN) gets no action -- logged once per kind -- so a dead man's rule downstream stops the robot."""

    Config = Config
    inputs = {"obs": Input(Observation, depth=1, latest=True)}
    outputs = {"action": PolicyAction}

    def setup(self) -> None:
        self.agent = PPO.load(self.config.checkpoint)
        self.refused = 0
        self._said: set[str] = set()

    def _refuse(self, kind: str, text: str) -> None:
        self.refused += 1
        if kind not in self._said:
            self._said.add(kind)
            self.log.error("%s: no action (%d refused so far)", text, self.refused)

    def on_obs(self, msg: Observation) -> dict[str, PolicyAction] | None:
        obs = np.asarray(msg.obs)
        if obs.shape != self.agent.obs_shape:
            self._refuse("shape", f"observation of shape {obs.shape}, the policy takes {self.agent.obs_shape}")
            return None
        if not np.all(np.isfinite(obs)):
            self._refuse("nan", "non-finite observation")
            return None
        action = self.agent.act(obs[None], deterministic=self.config.deterministic)[0]
        return {"action": PolicyAction(episode=msg.episode, step=msg.step, action=np.asarray(action, np.float32))}
