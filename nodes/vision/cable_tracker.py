"""Cable tracker node: rectified stereo pair -> the cable as a 3-D polyline with sigmas (seed 05)."""
from __future__ import annotations

import time

import msgspec

from msgs.vision import Cable3D, StereoPair
from nodes.vision.cable import FollowParams, Rectified, reconstruct
from tether import Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    reference_bgr: tuple[float, float, float] = (10.0, 180.0, 150.0)   # the cable's colour as the camera sees it (B, G, R)
    valley_max: float = 0.45          # colour distance above which a pixel is not cable
    step_px: float = 3.0
    max_gap_px: float = 40.0          # occlusions bridged up to this length
    depth_min_m: float = 0.5
    depth_max_m: float = 10.0
    sigma_px: float = 0.3             # centre-line localisation, one sigma (pixels)
    min_angle_deg: float = 10.0       # no depth where the cable runs closer than this to the rows
    matching: str = "order"           # or "row": the nearest-per-row baseline

    def __post_init__(self) -> None:
        if len(self.reference_bgr) != 3 or not all(0 <= v <= 255 for v in self.reference_bgr):
            raise ValueError(f"reference_bgr must be three values in 0..255, got {self.reference_bgr}")
        if self.matching not in ("order", "row"):
            raise ValueError(f"matching must be 'order' or 'row', got {self.matching!r}")
        if not 0 < self.depth_min_m < self.depth_max_m:
            raise ValueError("need 0 < depth_min_m < depth_max_m")
        if not (0 < self.valley_max <= 2 and self.step_px > 0 and self.sigma_px > 0):
            raise ValueError("valley_max must be in (0, 2], step_px and sigma_px positive")


class CableTracker(Node):
    """Input ``pair``; output ``cable`` (status tracked / lost / ambiguous, with a reason)."""

    Config = Config
    inputs = {"pair": StereoPair}
    outputs = {"cable": Cable3D}

    def setup(self) -> None:
        c = self.config
        self.prm = FollowParams(step_px=c.step_px, valley_max=c.valley_max, max_gap_px=c.max_gap_px)
        self.counts = {"tracked": 0, "lost": 0, "ambiguous": 0}

    def on_pair(self, pair: StereoPair) -> dict[str, Cable3D]:
        c = self.config
        if pair.f_px <= 0 or pair.baseline_m <= 0:
            raise ValueError(f"stereo pair without a usable rectification (f {pair.f_px}, baseline {pair.baseline_m})")
        t0 = time.perf_counter()
        r = reconstruct(pair.left, pair.right, Rectified(pair.f_px, pair.cx_px, pair.cy_px, pair.baseline_m),
                        reference_bgr=tuple(c.reference_bgr), prm=self.prm,
                        depth_range_m=(c.depth_min_m, c.depth_max_m), sigma_px=c.sigma_px,
                        min_angle_deg=c.min_angle_deg, matching=c.matching)
        ms = 1000 * (time.perf_counter() - t0)
        if r.status != "tracked" and self.counts[r.status] == 0:
            self.log.warning("cable %s: %s", r.status, r.reason)
        self.counts[r.status] += 1
        return {"cable": Cable3D(stamp_ns=pair.stamp_ns, frame_id=pair.frame_id, points_m=r.points_m, sigma_m=r.sigma_m,
                                 segment=r.segment, left_px=r.left_px, status=r.status, reason=r.reason,
                                 usable_frac=r.usable_frac, compute_ms=ms)}

    def teardown(self) -> None:
        self.log.info("cable tracker: %s", ", ".join(f"{k} {v}" for k, v in self.counts.items()))
