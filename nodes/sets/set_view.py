"""Set viewer node: a PNG of the step boxes, the last paving, the SLAM tube and marker boxes, and the truth."""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from msgs.geometry import Pose2D
from msgs.sets import SetEstimate, SetMap
from nodes.sets.draw import draw_sets
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/set_localize.png"
    rate_hz: float = 0.5              # how often the PNG is rewritten (and once at the end)
    markers: list[list[float]] = []   # known markers to draw


class SetView(Node):
    """Inputs ``estimate`` (localiser), ``map`` (SLAM, latest only) and ``truth``; writes ``path``."""

    Config = Config
    inputs = {"estimate": SetEstimate, "map": Input(SetMap, depth=1, latest=True), "truth": Pose2D}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        self.truth: dict[int, np.ndarray] = {}
        self.boxes: dict[int, np.ndarray] = {}
        self.last: SetEstimate | None = None
        self.map: SetMap | None = None
        self.outside = 0
        self._dirty = False

    def on_truth(self, msg: Pose2D) -> None:
        self.truth[msg.stamp_ns] = np.array([msg.x_m, msg.y_m])

    def on_estimate(self, msg: SetEstimate) -> None:
        self.boxes[msg.stamp_ns] = np.asarray(msg.box)
        self.last = msg
        self._dirty = True

    def on_map(self, msg: SetMap) -> None:
        self.map = msg
        self._dirty = True

    def on_draw(self, tick: Any) -> None:
        if self._dirty:
            self.write()

    def teardown(self) -> None:
        if self.last is not None or self.map is not None:
            self.write()

    def write(self) -> None:
        self._dirty = False
        stamps = sorted(s for s in self.boxes if s in self.truth)
        truth = np.array([self.truth[s] for s in sorted(self.truth)]).reshape(-1, 2)
        paired_truth = np.array([self.truth[s] for s in stamps]).reshape(-1, 2)
        boxes = np.array([self.boxes[s] for s in stamps]).reshape(-1, 2, 2)
        inside = np.all((boxes[:, 0] <= paired_truth) & (paired_truth <= boxes[:, 1]), axis=1)
        self.outside = int((~inside).sum())
        title = f"{len(truth)} steps"
        if len(boxes):
            title += f"; truth outside its box at {self.outside} of {len(boxes)} steps"
        if self.last is not None:
            title += f"; last width {self.last.width_m:.2f} m"
        if self.map is not None:
            title += f"; SLAM {'consistent' if self.map.consistent else 'INCONSISTENT'}"
        last = self.last
        draw_sets(self.config.path, truth=truth if not len(boxes) else paired_truth, boxes=boxes,
                  inner=None if last is None else np.asarray(last.inner),
                  boundary=None if last is None else np.asarray(last.boundary),
                  markers=np.asarray(self.config.markers, float).reshape(-1, 2),
                  marker_boxes=None if self.map is None else np.asarray(self.map.markers),
                  tube=None if self.map is None else np.asarray(self.map.tube), title=title)
