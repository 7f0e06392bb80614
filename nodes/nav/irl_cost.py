"""IRL cost node: crowd feature grid + learnt weights -> strictly positive cost grid (C = c0 + w . phi)."""
from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np

from msgs.nav import CostGrid, FeatureGrid
from nodes.nav.irl import CostWeights, cell_costs
from tether import Node

DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "default.json"


def load_weights(path: str | Path = "") -> CostWeights:
    """Read a weights JSON file (``""`` = the shipped ``nodes/nav/weights/default.json``)."""
    p = Path(path) if path else DEFAULT_WEIGHTS
    if not p.is_file():
        raise FileNotFoundError(f"weights file {p} not found; learn one with `python -m nodes.nav.irl_learn -o {p}`")
    return CostWeights.from_json(p.read_text(encoding="utf-8"))


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    weights_path: str = ""        # "" = the shipped default weights
    step_cost: float = 0.0        # > 0 overrides the file's step cost


class IrlCost(Node):
    """Input ``features`` (nav.FeatureGrid); output ``costs`` (nav.CostGrid, same cells and frame)."""

    Config = Config
    inputs = {"features": FeatureGrid}
    outputs = {"costs": CostGrid}

    def setup(self) -> None:
        self.weights = load_weights(self.config.weights_path)
        self.step_cost = self.config.step_cost if self.config.step_cost > 0 else self.weights.step_cost
        self._vector: tuple[tuple[str, ...], int, np.ndarray] | None = None
        self.bad_inputs = 0
        self.log.info("IRL weights %s (step cost %.3g)", {n: round(float(v), 3) for n, v in zip(self.weights.names, self.weights.weights)},
                      self.step_cost)

    def _weights_for(self, names: list[str], k: int) -> np.ndarray:
        key = (tuple(names), k)
        if self._vector is None or self._vector[:2] != key:
            self._vector = (*key, self.weights.vector_for(names, k))
        return self._vector[2]

    def on_features(self, msg: FeatureGrid) -> dict[str, CostGrid] | None:
        f = np.asarray(msg.features)
        try:
            if f.ndim != 3:
                raise ValueError(f"features must be rows x cols x K, got shape {f.shape}")
            w = self._weights_for(list(msg.names), f.shape[2])
            features = np.nan_to_num(f.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0).clip(min=0.0)
            cost = cell_costs(features, w, step_cost=self.step_cost).astype(np.float32)
        except ValueError as exc:
            self.bad_inputs += 1
            self.log.error("feature grid dropped (%d so far): %s", self.bad_inputs, exc)
            return None
        return {"costs": CostGrid(stamp_ns=msg.stamp_ns, frame_id=msg.frame_id, cost=cost,
                                  resolution_m=msg.resolution_m, origin_x_m=msg.origin_x_m, origin_y_m=msg.origin_y_m)}
