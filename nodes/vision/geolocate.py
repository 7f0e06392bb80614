"""From registrations to geo fixes, with the seed's two modes (seed 11 fig. 2.1): *search* (no
recent fix: the whole map, the frame at several scales) and *localisation* (a window of the map
around the predicted position, the frame at the altitude's scale), switching back to search
after ``fail_limit`` failed frames in a row.

    loc = GeoLocator(gm, MapFeatures.of(gm.image), width_px=640, hfov_deg=80)
    fix = loc.locate(frame, alt_m=40.0, predicted_en=(12.0, -3.0))
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nodes.vision.geomap import GeoMap
from nodes.vision.georegister import GeoFix as Registration
from nodes.vision.georegister import MapFeatures, register

__all__ = ["Fix", "GeoLocator"]


@dataclass
class Fix:
    ok: bool
    reason: str
    e_m: float
    n_m: float
    yaw_rad: float
    alt_m: float
    cov_m2: np.ndarray
    mode: str
    reg: Registration = field(repr=False, default_factory=lambda: Registration(False))


@dataclass
class GeoLocator:
    gm: GeoMap
    mf: MapFeatures
    width_px: int = 640
    hfov_deg: float = 80.0
    window_m: float = 30.0              # margin around the frame's footprint in localisation mode
    fail_limit: int = 3
    search_pyramid: tuple[float, ...] = (0.7, 1.0, 1.4)
    min_inliers: int = 12
    mode: str = "search"
    failures: int = 0
    last_fix_en: np.ndarray | None = None      # the last fix, and where the INS was then
    ins_at_fix: np.ndarray | None = None

    def predict(self, ins_en: np.ndarray | None) -> tuple[float, float] | None:
        """The last fix moved by what the INS measured since (the INS alone drifts)."""
        if ins_en is None or self.last_fix_en is None:
            return None
        p = self.last_fix_en + (np.asarray(ins_en, float) - self.ins_at_fix)
        return float(p[0]), float(p[1])

    def frame_m_per_px(self, alt_m: float) -> float:
        return 2 * alt_m * math.tan(math.radians(self.hfov_deg) / 2) / self.width_px

    def locate(self, frame: np.ndarray, *, alt_m: float, ins_en: np.ndarray | None = None,
               predicted_en: tuple[float, float] | None = None) -> Fix:
        """One frame -> a fix in east-north metres (or no fix, with the reason). The window of
        localisation mode is centred on ``predicted_en``, else on :meth:`predict` from ``ins_en``."""
        if predicted_en is None:
            predicted_en = self.predict(ins_en)
        if not (alt_m > 0 and math.isfinite(alt_m)):
            raise ValueError(f"altitude must be positive and finite, got {alt_m}")
        prescale = self.frame_m_per_px(alt_m) / self.gm.m_per_px
        mode = self.mode if predicted_en is not None else "search"
        if mode == "localise":
            h, w = frame.shape[:2]
            half = (math.hypot(w, h) / 2 * self.frame_m_per_px(alt_m) + self.window_m) / self.gm.m_per_px
            c = self.gm.to_px(np.array(predicted_en))[0]
            reg = register(frame, self.mf, prescale=prescale, window=(c[0] - half, c[1] - half, c[0] + half, c[1] + half),
                           min_inliers=self.min_inliers)
        else:
            reg = register(frame, self.mf, prescale=prescale, pyramid=self.search_pyramid, min_inliers=self.min_inliers,
                           alpha_range=(0.5, 2.0))
        if not reg.ok:
            self.failures += 1
            if self.failures >= self.fail_limit and self.mode != "search":
                self.mode = "search"
            return Fix(False, reg.reason, math.nan, math.nan, math.nan, math.nan, np.full((2, 2), np.inf), mode, reg)
        self.failures = 0
        self.mode = "localise"
        en = self.gm.to_world(reg.centre_px)[0]
        if ins_en is not None:
            self.last_fix_en, self.ins_at_fix = en.copy(), np.asarray(ins_en, float).copy()
        up = self.gm.G[:, :2] @ (reg.T[:, :2] @ np.array([0.0, -1.0]))
        yaw = math.atan2(up[1], up[0])
        scale = math.sqrt(abs(np.linalg.det(reg.T[:, :2])))            # map px per frame px
        alt = scale * self.gm.m_per_px * self.width_px / (2 * math.tan(math.radians(self.hfov_deg) / 2))
        J = self.gm.G[:, :2]
        return Fix(True, "", float(en[0]), float(en[1]), yaw, alt, J @ reg.cov_px @ J.T, mode, reg)
