"""Cable viewer node: a PNG of both images with the tracked curve and the 3-D cable against the truth."""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from msgs.vision import Cable3D, CableTruth, StereoPair
from nodes.vision.cable import colour_distance, track_cable
from nodes.vision.draw import draw_cable
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/stereo_cable.png"
    rate_hz: float = 0.5              # how often the PNG is rewritten (and once at the end)
    reference_bgr: tuple[float, float, float] = (10.0, 180.0, 150.0)   # to redraw the right image's tracks


class CableView(Node):
    """Inputs ``pair`` and ``truth`` (latest kept by stamp) and ``cable``; writes ``path``.
    Keeps the RMS 3-D error against the truth (distance to the true curve) over the run."""

    Config = Config
    inputs = {"pair": Input(StereoPair, depth=4), "cable": Cable3D, "truth": Input(CableTruth, depth=4)}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        self.pairs: dict[int, StereoPair] = {}
        self.truths: dict[int, CableTruth] = {}
        self.last: tuple[StereoPair, Cable3D, CableTruth | None] | None = None
        self.sq_err: list[np.ndarray] = []
        self._dirty = False

    def on_pair(self, msg: StereoPair) -> None:
        self.pairs[msg.stamp_ns] = msg
        for s in sorted(self.pairs)[:-8]:
            del self.pairs[s]

    def on_truth(self, msg: CableTruth) -> None:
        self.truths[msg.stamp_ns] = msg
        for s in sorted(self.truths)[:-8]:
            del self.truths[s]

    def on_cable(self, msg: Cable3D) -> None:
        pair = self.pairs.get(msg.stamp_ns)
        if pair is None:
            return
        truth = self.truths.get(msg.stamp_ns)
        if truth is not None and len(msg.points_m):
            ref = np.vstack([truth.points_m, truth.others_m]) if len(truth.others_m) else truth.points_m
            d, _ = cKDTree(ref).query(np.asarray(msg.points_m))
            self.sq_err.append(d ** 2)
        self.last = (pair, msg, truth)
        self._dirty = True

    def rms_mm(self) -> float:
        return float(1000 * np.sqrt(np.mean(np.concatenate(self.sq_err)))) if self.sq_err else float("nan")

    def on_draw(self, tick: Any) -> None:
        if self._dirty:
            self.write()

    def teardown(self) -> None:
        if self.last is not None:
            self.write()
            self.log.info("cable view: RMS 3-D error %.1f mm over %d frames", self.rms_mm(), len(self.sq_err))

    def write(self) -> None:
        self._dirty = False
        pair, cable, truth = self.last
        ref = tuple(self.config.reference_bgr)
        tl = [t.points_px for t in track_cable(colour_distance(pair.left, ref))]
        tr = [t.points_px for t in track_cable(colour_distance(pair.right, ref))]
        title = (f"cable {cable.status}{' (' + cable.reason + ')' if cable.reason else ''}: {len(cable.points_m)} points, "
                 f"{cable.compute_ms:.0f} ms; RMS 3-D error so far {self.rms_mm():.1f} mm over {len(self.sq_err)} frames")
        draw_cable(self.config.path, left=pair.left, right=pair.right, points_m=np.asarray(cable.points_m),
                   sigma_m=np.asarray(cable.sigma_m), left_px=np.asarray(cable.left_px),
                   truth_m=None if truth is None else np.asarray(truth.points_m), tracks_left=tl, tracks_right=tr,
                   title=title)
