"""Geo-registration node (seed 11): nadir frames + the INS's altitude and position -> geo fixes
in search or localisation mode; a failed frame is "no fix" with its reason, never a wrong one."""
from __future__ import annotations

import math
import time

import msgspec
import numpy as np

from msgs.sensor import Image
from msgs.uav import GeoFix, UavState
from nodes.vision.geolocate import GeoLocator
from nodes.vision.geomap import MAPS, load_map
from nodes.vision.georegister import METHODS, MapFeatures
from tether import Input, Node


class Config(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    map: str = "procedural"           # must be the map the camera flies over ("brighton": the real one)
    map_seed: int = 0
    features: str = "sift"            # sift | orb | akaze (SURF is not in pip OpenCV)
    width_px: int = 640
    hfov_deg: float = 80.0
    window_m: float = 30.0
    fail_limit: int = 3
    min_inliers: int = 12

    def __post_init__(self) -> None:
        if self.features not in METHODS:
            raise ValueError(f"features must be one of {METHODS}, got {self.features!r}")
        if self.map not in MAPS:
            raise ValueError(f"map must be one of {MAPS}, got {self.map!r}")


class GeoRegisterNode(Node):
    """Inputs ``image`` and ``ins`` (latest: altitude and a prediction); output ``fix``."""

    Config = Config
    inputs = {"image": Input(Image, depth=1, latest=True), "ins": Input(UavState, depth=1, latest=True)}
    outputs = {"fix": GeoFix}

    def setup(self) -> None:
        c = self.config
        gm = load_map(c.map, c.map_seed)
        self.loc = GeoLocator(gm, MapFeatures.of(gm.image, method=c.features), width_px=c.width_px,
                              hfov_deg=c.hfov_deg, window_m=c.window_m, fail_limit=c.fail_limit,
                              min_inliers=c.min_inliers)
        self.ins: UavState | None = None
        self.counts = {"fix": 0, "no_fix": 0}

    def on_ins(self, msg: UavState) -> None:
        self.ins = msg

    def on_image(self, msg: Image) -> dict[str, GeoFix] | None:
        if self.ins is None:
            return None
        ins_en = np.array([self.ins.e_m, self.ins.n_m])
        predicted = self.loc.predict(ins_en)
        t0 = time.perf_counter()
        f = self.loc.locate(np.asarray(msg.data), alt_m=max(self.ins.alt_m, 1.0), ins_en=ins_en)
        ms = 1000 * (time.perf_counter() - t0)
        self.counts["fix" if f.ok else "no_fix"] += 1
        r = f.reg
        pe = predicted if predicted is not None else tuple(ins_en)          # no fix: the prediction, or the INS
        return {"fix": GeoFix(stamp_ns=msg.stamp_ns, frame_id="world", ok=f.ok, reason=f.reason,
                              e_m=f.e_m if f.ok else float(pe[0]), n_m=f.n_m if f.ok else float(pe[1]),
                              yaw_rad=f.yaw_rad if f.ok else self.ins.yaw_rad, alt_m=f.alt_m if f.ok else self.ins.alt_m,
                              cov_m2=f.cov_m2, inliers=r.inliers, matches=r.matches,
                              alpha=r.alpha if math.isfinite(r.alpha) else 0.0,
                              theta_rad=r.theta_rad if math.isfinite(r.theta_rad) else 0.0,
                              b_px=np.nan_to_num(r.T[:, 2]), mode=f.mode, compute_ms=ms)}

    def teardown(self) -> None:
        self.log.info("geo register: %d fixes, %d frames without", self.counts["fix"], self.counts["no_fix"])
