"""Moving camera simulator node: grey images of a textured room seen by one camera moving in
one of :data:`sim.camera_motion.MOTIONS`, for self-calibration.

Each tick publishes ``image`` (sensor.Image, mono8) and ``truth`` (sensor.CameraInfo: the true
intrinsics). After ``frames`` ticks it stops.
"""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from msgs.sensor import CameraInfo, Image
from sim.camera_motion import MOTIONS, camera_views
from sim.textured_scene import make_room, render_view
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    motion: str = "general"
    frames: int = 10
    rate_hz: float = 2.0
    seed: int = 0
    width_px: int = 640
    height_px: int = 480
    fx_px: float = 536.07               # the chessboard set's left camera (its calibrateCamera result)
    fy_px: float = 536.02
    cx_px: float = 342.37
    cy_px: float = 235.54
    noise_grey: float = 2.0

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise ValueError(f"motion must be one of {MOTIONS}, got {self.motion!r}")
        if self.frames < 1 or self.rate_hz <= 0 or self.fx_px <= 0 or self.fy_px <= 0:
            raise ValueError("frames, rate_hz and the focal lengths must be positive")


class MovingCamera(Node):
    """Timer ``tick``; outputs ``image`` and ``truth``."""

    Config = Config
    outputs = {"image": Image, "truth": CameraInfo}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        c = self.config
        rng = np.random.default_rng(c.seed)
        self.room = make_room(rng=rng)
        self.views = camera_views(c.motion, n_views=c.frames, rng=rng)
        self.K = np.array([[c.fx_px, 0, c.cx_px], [0, c.fy_px, c.cy_px], [0, 0, 1.0]])
        self.rng = rng
        self.frame = 0

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        c = self.config
        if self.frame >= c.frames:
            return []
        v = self.views[self.frame]
        img = render_view(self.room, self.K, v.R, v.C, (c.width_px, c.height_px), rng=self.rng, noise_grey=c.noise_grey)
        self.frame += 1
        stamp = self.now_ns()
        truth = CameraInfo(stamp_ns=stamp, frame_id="camera", width_px=c.width_px, height_px=c.height_px,
                           fx_px=c.fx_px, fy_px=c.fy_px, cx_px=c.cx_px, cy_px=c.cy_px, method="truth")
        return [("image", Image(stamp_ns=stamp, frame_id="camera", data=img, encoding="mono8")), ("truth", truth)]
