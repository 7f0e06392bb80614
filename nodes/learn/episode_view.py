"""Episodes of a deployed policy: final metrics per episode, and a PNG of the paths and distances."""
from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np

from msgs.learn import EpisodeSummary, Observation
from nodes.learn.plots import draw_episodes
from tether import Node
from tether.node import Input


class Config(msgspec.Struct, frozen=True, kw_only=True):
    png: str = "out/rl_car.png"
    summary_json: str = ""          # also write the per-episode summaries here ("": no)
    walls: list[list[float]] = []   # segments [x0, y0, x1, y1] to draw (a maze)


class EpisodeView(Node):
    """Inputs ``obs`` and ``episode``; writes the PNG (and JSON) at shutdown."""

    Config = Config
    inputs = {"obs": Input(Observation, depth=256), "episode": Input(EpisodeSummary, depth=64)}
    outputs = {}

    def setup(self) -> None:
        self.paths: dict[int, list[np.ndarray]] = {}
        self.times: dict[int, list[float]] = {}
        self.summaries: list[EpisodeSummary] = []

    def on_obs(self, msg: Observation) -> None:
        self.paths.setdefault(msg.episode, []).append(np.asarray(msg.obs, np.float64).copy())
        self.times.setdefault(msg.episode, []).append(msg.sim_time_s)

    def on_episode(self, msg: EpisodeSummary) -> None:
        self.summaries.append(msg)

    def results(self) -> list[dict[str, float]]:
        return [{"episode": s.episode, "steps": s.steps, "return": s.return_, "terminated": s.terminated,
                 **{n: float(v) for n, v in zip(s.metric_names, s.metrics)}} for s in self.summaries]

    def teardown(self) -> None:
        if self.config.summary_json:
            Path(self.config.summary_json).write_text(json.dumps(self.results(), indent=1))
        if self.config.png and self.paths:
            finals = {s.episode: dict(zip(s.metric_names, s.metrics)) for s in self.summaries}
            draw_episodes({k: (np.array(self.times[k]), np.array(o)) for k, o in self.paths.items()}, finals,
                          self.config.png, walls=self.config.walls)
            self.log.info("wrote %s", self.config.png)
