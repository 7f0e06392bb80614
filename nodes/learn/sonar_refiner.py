"""A SimGAN refiner as a node: simulated sonar pings in, pings that look more like a real sonar's out.

Sits between the FLS simulator and the imager (``launch/sonar_refined.yaml``)::

    sim/ping -> refiner (sim_image -> refined_image) -> imager

Only ``intensities`` change (same shape and dtype); bearings, ranges, stamps and the rest pass
through, so everything downstream works unchanged. The shipped weights
(``nodes/learn/weights/sonar_refiner.simgan``, made by ``bench/sonar_refiner.py --export``) were
trained on 64 px patches of simulated 2 m pings against three real Oculus M1200d pings of one
sediment scene (../shared/data/sonar): they move the simulator's histogram and speckle toward
that sonar's, and say nothing about scenes, ranges or frequencies unlike it (the bench's note).
"""
from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np

from msgs.sonar import SonarPing
from tether import Node
from tether.node import Input

DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "sonar_refiner.simgan"


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    weights: str = ""             # a bench/sonar_refiner.py --export file; "" = the shipped weights


class Refiner:
    """The pure part: a loaded refiner applied to one (ranges, beams) uint8 / uint16 image."""

    def __init__(self, path: str | Path = "") -> None:
        from nodes.learn.simgan import load_refiner

        self.path = Path(path) if path else DEFAULT_WEIGHTS
        if not self.path.is_file():
            raise FileNotFoundError(f"sonar refiner weights {self.path} not found (bench/sonar_refiner.py --export makes them)")
        self.params, self.cfg, self.meta = load_refiner(self.path)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        from nodes.learn.simgan import refine_images

        a = np.asarray(image)
        if a.ndim != 2 or a.dtype not in (np.uint8, np.uint16) or a.size == 0:
            raise ValueError(f"expected a non-empty 2-D uint8 or uint16 image, got {a.dtype} {a.shape}")
        full = 255.0 if a.dtype == np.uint8 else 65535.0
        x = (a.astype(np.float32) * np.float32(2.0 / full) - 1.0)[None, ..., None]
        y = refine_images(self.params, x, self.cfg)[0, ..., 0]
        return np.rint(np.clip((y + 1.0) * (full / 2.0), 0.0, full)).astype(a.dtype)


class SonarRefiner(Node):
    """Input ``sim_image`` (SonarPing, latest only); output ``refined_image`` (the same ping, refined).

    A ping the refiner cannot take (empty, not 2-D, float samples) is logged once per kind,
    counted in ``dropped`` and not forwarded.
    """

    Config = Config
    inputs = {"sim_image": Input(SonarPing, latest=True)}
    outputs = {"refined_image": SonarPing}

    def setup(self) -> None:
        self.refiner = Refiner(self.config.weights)
        self.refined = 0
        self.dropped = 0
        self._said: set[str] = set()

    def on_sim_image(self, ping: SonarPing) -> dict[str, SonarPing] | None:
        try:
            out = self.refiner(ping.intensities)
        except ValueError as exc:
            self.dropped += 1
            kind = str(np.asarray(ping.intensities).dtype) + str(np.ndim(ping.intensities))
            if kind not in self._said:
                self._said.add(kind)
                self.log.error("refiner: ping %d dropped: %s (%d dropped so far)", ping.ping_id, exc, self.dropped)
            return None
        self.refined += 1
        return {"refined_image": msgspec.structs.replace(ping, intensities=out)}

    def teardown(self) -> None:
        self.log.info("refiner: %d pings refined, %d dropped", self.refined, self.dropped)
