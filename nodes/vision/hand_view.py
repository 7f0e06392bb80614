"""Gesture teleoperation viewer: the gestures shown and recognised over time, the commands and
the dead man's stops, the wheelchair's path, a few frames with keypoints, as a PNG."""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from msgs.geometry import Odometry2D, Twist2D
from msgs.hand import HandGesture, HandTruth
from msgs.sensor import Image
from nodes.vision.hand_draw import draw_keypoints, draw_teleop
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    path: str = "out/gesture_teleop.png"   # "" = draw nothing (tests)
    deadman_s: float = 0.3
    frame_every_s: float = 3.0       # keep a thumbnail this often (at most 6)
    rate_hz: float = 0.2


class HandView(Node):
    """Inputs ``image``, ``truth``, ``gesture``, ``cmd``, ``odom``; writes ``path``."""

    Config = Config
    inputs = {"image": Input(Image, depth=1, latest=True), "truth": HandTruth, "gesture": HandGesture,
              "cmd": Twist2D, "odom": Input(Odometry2D, depth=1, latest=True)}
    timers = {"draw": "rate_hz"}

    def setup(self) -> None:
        self.t0: int | None = None
        self.truth: list[tuple[float, str]] = []
        self.seen: list[tuple[float, str, float]] = []
        self.cmds: list[tuple[float, float, float]] = []
        self.path: list[tuple[float, float]] = []
        self.frames: list[np.ndarray] = []
        self.image: Image | None = None
        self.next_frame_s = 0.5

    def _t(self, stamp_ns: int) -> float:
        self.t0 = stamp_ns if self.t0 is None else self.t0
        return (stamp_ns - self.t0) / 1e9

    def on_image(self, m: Image) -> None:
        self.image = m

    def on_truth(self, m: HandTruth) -> None:
        self.truth.append((self._t(m.stamp_ns), m.gesture))

    def on_gesture(self, m: HandGesture) -> None:
        t = self._t(m.stamp_ns)
        self.seen.append((t, m.gesture, m.confidence))
        if self.image is not None and self.image.stamp_ns == m.stamp_ns and t >= self.next_frame_s \
                and len(self.frames) < 6:
            self.frames.append(draw_keypoints(self.image.data, m.keypoints_px, text=f"{m.gesture} {m.confidence:.2f}"))
            self.next_frame_s = t + self.config.frame_every_s

    def on_cmd(self, m: Twist2D) -> None:
        self.cmds.append((self._t(m.stamp_ns), m.vx_mps, m.wz_radps))

    def on_odom(self, m: Odometry2D) -> None:
        self.path.append((m.pose.x_m, m.pose.y_m))

    def on_draw(self, tick: Any) -> None:
        if self.cmds and self.config.path:
            self.write()

    def teardown(self) -> None:
        if self.cmds and self.config.path:
            self.write()

    def write(self) -> None:
        draw_teleop(self.config.path, truth=self.truth, seen=self.seen, cmds=np.array(self.cmds).reshape(-1, 3),
                    path_xy=np.array(self.path).reshape(-1, 2), frames=self.frames, deadman_s=self.config.deadman_s)
