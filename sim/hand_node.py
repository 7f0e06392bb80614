"""Hand camera simulator node (seed 13): a scripted sequence of gestures rendered by
:mod:`sim.hand_render` at ``rate_hz``, with the ground truth. Each script segment holds one
hand pose (a camera watching a still hand: only the sensor noise changes between frames).
A ``blackout`` window models a dropped camera stream: no image is published in it.

Script: ``"open:2,point:3,none:1,..."`` (gesture name or "none" for an empty view, seconds),
looped. Outputs ``image`` (sensor.Image, bgr8) and ``truth`` (hand.HandTruth).
"""
from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from msgs.hand import HandTruth
from msgs.sensor import Image
from sim.hand import GESTURES
from sim.hand_render import BACKGROUNDS, FRAMINGS, SceneSpec, render_scene
from tether import Node


def parse_script(script: str) -> list[tuple[str, float]]:
    """``"open:2,point:3"`` -> [("open", 2.0), ("point", 3.0)]; ``ValueError`` naming the bad item."""
    out = []
    for item in script.split(","):
        name, _, dur = item.strip().partition(":")
        if name not in GESTURES and name != "none":
            raise ValueError(f"script item {item!r}: gesture must be 'none' or one of {sorted(GESTURES)}")
        try:
            seconds = float(dur)
        except ValueError:
            raise ValueError(f"script item {item!r}: give 'gesture:seconds'") from None
        if not seconds > 0:
            raise ValueError(f"script item {item!r}: seconds must be > 0")
        out.append((name, seconds))
    return out


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    script: str = "open:2,point:3,victory:3,fist:2,none:1,L:3,four:2"
    rate_hz: float = 15.0
    width_px: int = 128
    height_px: int = 128
    framing: str = "inside"          # or "bottom", "border", "" (random per segment)
    background: str = ""             # "plain", "clutter", "noise", "skin" or "" (random per segment)
    blackout_start_s: float = -1.0   # camera stream dropped from here ...
    blackout_end_s: float = -1.0     # ... to here (negative: never)
    noise_grey: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        parse_script(self.script)
        if self.rate_hz <= 0 or self.width_px < 16 or self.height_px < 16:
            raise ValueError("rate_hz must be > 0 and the image at least 16x16")
        if self.framing not in FRAMINGS + ("",) or self.background not in BACKGROUNDS + ("",):
            raise ValueError(f"framing in {FRAMINGS} or '', background in {BACKGROUNDS} or ''")


class HandCamera(Node):
    """Timer ``tick``; outputs ``image`` and ``truth``."""

    Config = Config
    outputs = {"image": Image, "truth": HandTruth}
    timers = {"tick": "rate_hz"}

    def setup(self) -> None:
        self.script = parse_script(self.config.script)
        self.period_s = sum(d for _, d in self.script)
        self.t0_ns: int | None = None
        self.cache: tuple[int, np.ndarray, Any] | None = None
        self.rng = np.random.default_rng(self.config.seed)
        self.dropped = 0

    def segment(self, t_s: float) -> tuple[int, str]:
        """Index (counting loops) and gesture of the script segment at ``t_s``."""
        loops, r = divmod(t_s, self.period_s)
        for i, (name, dur) in enumerate(self.script):
            if r < dur:
                return int(loops) * len(self.script) + i, name
            r -= dur
        return (int(loops) + 1) * len(self.script) - 1, self.script[-1][0]

    def on_tick(self, tick: Any) -> list[tuple[str, Any]]:
        c = self.config
        now = self.now_ns()
        self.t0_ns = now if self.t0_ns is None else self.t0_ns
        t = (now - self.t0_ns) / 1e9
        if c.blackout_start_s <= t < c.blackout_end_s:
            self.dropped += 1
            return []
        k, name = self.segment(t)
        if self.cache is None or self.cache[0] != k:
            spec = SceneSpec(gesture=None if name == "none" else name, hands=0 if name == "none" else 1,
                             framing=c.framing or None, background=c.background or None,
                             width_px=c.width_px, height_px=c.height_px)
            img, truth = render_scene(np.random.default_rng([c.seed, k]), spec)
            self.cache = (k, img, truth)
        _, img, truth = self.cache
        noisy = np.clip(img + self.rng.normal(0, c.noise_grey, img.shape), 0, 255).astype(np.uint8)
        return [("image", Image(stamp_ns=now, frame_id="hand_camera", data=noisy, encoding="bgr8")),
                ("truth", HandTruth(stamp_ns=now, frame_id="hand_camera", present=truth.present,
                                    keypoints_px=truth.keypoints_px.astype(np.float32), count=truth.count,
                                    gesture=truth.gesture, palm_px=truth.palm_px))]

    def teardown(self) -> None:
        if self.dropped:
            self.log.info("hand camera: %d frames dropped in the blackout", self.dropped)
