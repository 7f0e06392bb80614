"""Episodes of a deployed policy: final metrics per episode, and a PNG of the paths and distances."""
from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np

from msgs.learn import EpisodeSummary, Observation
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
        self.summaries: list[EpisodeSummary] = []

    def on_obs(self, msg: Observation) -> None:
        self.paths.setdefault(msg.episode, []).append(np.asarray(msg.obs, np.float64).copy())

    def on_episode(self, msg: EpisodeSummary) -> None:
        self.summaries.append(msg)

    def results(self) -> list[dict[str, float]]:
        return [{"episode": s.episode, "steps": s.steps, "return": s.return_, "terminated": s.terminated,
                 **{n: float(v) for n, v in zip(s.metric_names, s.metrics)}} for s in self.summaries]

    def teardown(self) -> None:
        if self.config.summary_json:
            Path(self.config.summary_json).write_text(json.dumps(self.results(), indent=1))
        if self.config.png and self.paths:
            self._draw(Path(self.config.png))

    def _draw(self, path: Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.6))
        for seg in self.config.walls:
            ax.plot([seg[0], seg[2]], [seg[1], seg[3]], "k-", lw=2)
        finals = {s.episode: dict(zip(s.metric_names, s.metrics)) for s in self.summaries}
        for k, obs in sorted(self.paths.items()):
            o = np.array(obs)
            line, = ax.plot(o[:, 0], o[:, 1], "-", lw=1.2)
            ax.plot(o[0, 0], o[0, 1], "o", color=line.get_color(), ms=4)
            ax.plot(o[0, 4], o[0, 5], "x", color=line.get_color(), ms=9, mew=2)
            dist = np.hypot(o[:, 4] - o[:, 0], o[:, 5] - o[:, 1])
            label = f"episode {k}"
            if k in finals and "distance_m" in finals[k]:
                label += f": final {finals[k]['distance_m'] * 1000:.1f} mm"
            bx.semilogy(np.arange(len(dist)) * 0.1, np.maximum(dist, 1e-4), color=line.get_color(), label=label)
        ax.set_aspect("equal")
        ax.set_title("paths (o start, x target)")
        bx.axhline(0.008, color="grey", ls="--", lw=1, label="paper's 8 mm")
        bx.set_xlabel("time (s)")
        bx.set_ylabel("straight-line distance to target (m)")
        bx.legend(fontsize=8)
        for a in (ax, bx):
            a.grid(alpha=0.3)
        fig.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=90)
        plt.close(fig)
        self.log.info("wrote %s", path)
