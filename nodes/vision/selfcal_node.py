"""Self-calibration node: an image stream from one camera -> its intrinsics with uncertainties,
or a clear "degenerate" when the camera's motion cannot determine them (seed 12)."""
from __future__ import annotations

import time

import msgspec
import numpy as np

from msgs.sensor import CameraInfo, Image
from nodes.vision.features import METHODS, Features, detect, match
from nodes.vision.selfcal import Calibration, PairGeometry, pair_geometry, self_calibrate
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    features: str = "sift"            # or "orb": faster, 10x less accurate here (bench/selfcal.py); no SURF in pip OpenCV
    n_features: int = 2000
    keyframe_every: int = 1           # every n-th image is a keyframe
    max_keyframes: int = 16           # the oldest pairs are dropped beyond this
    pair_gap: int = 2                 # each keyframe is matched with this many previous ones
    min_keyframes: int = 4            # nothing is published before
    sigma_px: float = 1.0             # feature localisation noise assumed by the F-or-H choice
    principal_point: tuple[float, ...] = ()   # (cx, cy) if known; empty: estimated

    def __post_init__(self) -> None:
        if self.features not in METHODS:
            raise ValueError(f"features must be one of {METHODS}, got {self.features!r}")
        if self.keyframe_every < 1 or self.pair_gap < 1 or self.min_keyframes < 3 or self.max_keyframes < self.min_keyframes:
            raise ValueError("need keyframe_every >= 1, pair_gap >= 1, 3 <= min_keyframes <= max_keyframes")
        if len(self.principal_point) not in (0, 2):
            raise ValueError(f"principal_point is (cx, cy) or empty, got {self.principal_point}")


def camera_info(cal: Calibration, size: tuple[int, int], **header) -> CameraInfo:
    """A CameraInfo message from a calibration (finite numbers always; sigma inf = unknown)."""
    K, s = cal.K, cal.sigma_px
    return CameraInfo(width_px=size[0], height_px=size[1], fx_px=float(K[0, 0]), fy_px=float(K[1, 1]),
                      cx_px=float(K[0, 2]), cy_px=float(K[1, 2]), fx_sigma_px=float(s[0]), fy_sigma_px=float(s[1]),
                      cx_sigma_px=float(s[2]), cy_sigma_px=float(s[3]), method=cal.method, degenerate=cal.degenerate,
                      reason="; ".join(cal.reasons), **header)


class SelfCalibration(Node):
    """Input ``image`` (mono8 or bgr8); output ``camera_info`` after every keyframe once there
    are ``min_keyframes``."""

    Config = Config
    inputs = {"image": Image}
    outputs = {"camera_info": CameraInfo}

    def setup(self) -> None:
        self.frames = 0
        self.keyframes: list[Features] = []
        self.pairs: list[tuple[int, PairGeometry]] = []     # (index of the newer keyframe, geometry)
        self.size: tuple[int, int] | None = None
        self.n_keyframes = 0
        self.last_reason = ""

    def on_image(self, msg: Image) -> dict[str, CameraInfo] | None:
        c = self.config
        self.frames += 1
        if (self.frames - 1) % c.keyframe_every:
            return None
        data = np.asarray(msg.data)
        size = (data.shape[1], data.shape[0])
        if self.size is not None and size != self.size:
            raise ValueError(f"image size changed from {self.size} to {size}: one camera per node")
        self.size = size
        feats = detect(data, method=c.features, n_features=c.n_features)
        for back, older in enumerate(reversed(self.keyframes[-c.pair_gap:]), start=1):
            a, b = match(older, feats)
            self.pairs.append((self.n_keyframes, pair_geometry(a, b, sigma_px=c.sigma_px, seed=self.n_keyframes)))
        self.keyframes = (self.keyframes + [feats])[-c.pair_gap:]
        self.n_keyframes += 1
        self.pairs = [p for p in self.pairs if p[0] > self.n_keyframes - c.max_keyframes]
        if self.n_keyframes < c.min_keyframes:
            return None
        t0 = time.perf_counter()
        cal = self_calibrate([p for _, p in self.pairs], size,
                             principal_point=tuple(c.principal_point) if c.principal_point else None)
        reason = "; ".join(cal.reasons)
        if cal.degenerate and reason != self.last_reason:
            self.log.warning("self-calibration degenerate: %s", reason)
        self.last_reason = reason
        self.log.debug("self-calibration over %d pairs in %.0f ms", len(self.pairs), 1000 * (time.perf_counter() - t0))
        return {"camera_info": camera_info(cal, size, stamp_ns=msg.stamp_ns, frame_id=msg.frame_id)}
