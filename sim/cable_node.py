"""Cable stereo simulator node: a rectified pair of a swaying underwater cable on a timer.

Each tick publishes ``pair`` (vision.StereoPair) and ``truth`` (vision.CableTruth), stamped
alike. The cable (one of :data:`sim.cable.CABLE_SHAPES`) sways in depth by ``sway_m`` over
``sway_period_s``; each frame has its own image noise. After ``frames`` ticks it stops.
"""
from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from msgs.vision import CableTruth, StereoPair
from sim.cable import CABLE_SHAPES, StereoRig, scene_pair
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    shape: str = "crossing"
    depth_m: float = 2.0
    sway_m: float = 0.3
    sway_period_s: float = 10.0
    rate_hz: float = 2.0
    frames: int = 20
    seed: int = 0
    noise_grey: float = 3.0
    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 70.0
    baseline_m: float = 0.3

    def __post_init__(self) -> None:
        if self.shape not in CABLE_SHAPES:
            raise ValueError(f"shape must be one of {CABLE_SHAPES}, got {self.shape!r}")
        if not (0 < self.depth_m - abs(self.sway_m)) or self.rate_hz <= 0 or self.frames < 1:
            raise ValueError("depth_m must exceed |sway_m|; rate_hz and frames must be positive")
        if self.baseline_m <= 0 or not 1 < self.hfov_deg < 179:
            raise ValueError("baseline_m must be positive and hfov_deg in (1, 179)")


class CableSim(Node):
    """Timer ``tick``; outputs ``pair`` and ``truth``."""

    Config = Config
    outputs = {"pair": StereoPair, "truth": CableTruth}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        self.rig = StereoRig(c.width_px, c.height_px, c.hfov_deg, c.baseline_m)
        self.frame = 0

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        c = self.config
        if self.frame >= c.frames:
            return []
        t = self.frame / c.rate_hz
        depth = c.depth_m + c.sway_m * math.sin(2 * math.pi * t / c.sway_period_s)
        p = scene_pair(c.shape, depth_m=depth, rig=self.rig, seed=c.seed * 100003 + self.frame,
                       noise_grey=c.noise_grey)
        self.frame += 1
        stamp = self.now_ns()
        K = self.rig.K
        pair = StereoPair(stamp_ns=stamp, frame_id="left_camera", left=p.left, right=p.right, f_px=float(K[0, 0]),
                          cx_px=float(K[0, 2]), cy_px=float(K[1, 2]), baseline_m=c.baseline_m)
        others = np.vstack(p.others_m) if p.others_m else np.zeros((0, 3))
        truth = CableTruth(stamp_ns=stamp, frame_id="left_camera", points_m=p.cable_m, left_px=p.truth_left_px,
                           visible=p.visible, others_m=others)
        if self.frame == c.frames:
            self.log.info("cable sim: %d frames of the %s cable done", c.frames, c.shape)
        return [("pair", pair), ("truth", truth)]
