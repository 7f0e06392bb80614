"""Hand gesture node (seed 13): camera image -> the hand's keypoints, finger count, gesture and
confidence, by the learned keypoint net (default) or the OpenCV convexity method."""
from __future__ import annotations

import msgspec
import numpy as np

from msgs.hand import HandGesture
from msgs.sensor import Image
from nodes.vision.hand_recognise import FINGER_READERS, METHODS, Recogniser
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    method: str = "learned"          # or "convexity"
    weights: str = ""                # "" = the committed nodes/vision/weights/hand_keypoints.msgpack
    presence_min: float = 0.5
    fingers: str = "head"            # learned: "head" (finger-state head), "geometry" (keypoints) or "fused"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.fingers not in FINGER_READERS:
            raise ValueError(f"fingers must be one of {FINGER_READERS}, got {self.fingers!r}")
        if not 0.0 <= self.presence_min <= 1.0:
            raise ValueError("presence_min must be in [0, 1]")


class HandGestureNode(Node):
    """Input ``image`` (latest: a slow frame is skipped, not queued); output ``gesture``."""

    Config = Config
    inputs = {"image": Input(Image, depth=1, latest=True)}
    outputs = {"gesture": HandGesture}

    def setup(self) -> None:
        c = self.config
        kw = {"weights": c.weights} if c.weights else {}
        self.recognise = Recogniser(c.method, presence_min=c.presence_min, fingers=c.fingers, **kw)
        self.recognise(np.zeros((96, 96, 3), np.uint8))   # compile the net now, not on the first frame

    def on_image(self, msg: Image) -> dict[str, HandGesture]:
        img = msg.data
        if msg.encoding == "rgb8":
            img = np.ascontiguousarray(img[..., ::-1])
        r = self.recognise(img)
        return {"gesture": HandGesture(stamp_ns=msg.stamp_ns, frame_id=msg.frame_id, present=r.present,
                                       keypoints_px=r.keypoints_px.astype(np.float32),
                                       keypoint_conf=r.keypoint_conf.astype(np.float32), extended=r.extended,
                                       count=r.count, gesture=r.gesture, confidence=r.confidence,
                                       method=self.config.method, compute_ms=r.ms)}
