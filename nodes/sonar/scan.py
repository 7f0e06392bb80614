"""A scanning sonar's image assembled beam by beam as the head turns (Ping360: 400 angles).

:class:`ScanImage` keeps the latest beam at every angle (``polar`` (angles, samples), NaN where
no beam yet) and renders the disc around the head in Cartesian pixels, x to starboard, y
ahead (up in the picture), the sonar at the centre. A beam of another length is resampled
to the image's samples; a beam at another range restarts the image (the old beams no longer
share its scale).
"""
from __future__ import annotations

import math

import cv2
import numpy as np


class ScanImage:
    def __init__(self, n_angles: int = 400, n_samples: int = 600) -> None:
        if n_angles < 4 or n_samples < 2:
            raise ValueError("need at least 4 angles and 2 samples")
        self.n_angles, self.n_samples = n_angles, n_samples
        self.polar = np.full((n_angles, n_samples), np.nan, np.float32)
        self.range_m = 0.0
        self.beams = 0
        self.turns = 0
        self._last: int | None = None

    def add(self, bearing_rad: float, samples: np.ndarray, range_m: float) -> bool:
        """Store one beam; True when the head has just completed a turn (crossed angle 0)."""
        if not (math.isfinite(bearing_rad) and math.isfinite(range_m) and range_m > 0) or len(samples) == 0:
            raise ValueError("a beam needs a finite bearing, a positive range and at least one sample")
        if self.range_m and abs(range_m - self.range_m) > 1e-6 * self.range_m:
            self.polar[:] = np.nan
            self._last = None
        self.range_m = range_m
        k = int(round(bearing_rad / (2 * math.pi) * self.n_angles)) % self.n_angles
        row = np.asarray(samples, np.float32).ravel()
        if len(row) != self.n_samples:
            row = np.interp(np.linspace(0, len(row) - 1, self.n_samples), np.arange(len(row)), row).astype(np.float32)
        self.polar[k] = row
        self.beams += 1
        wrapped = self._last is not None and k < self._last and self._last - k > self.n_angles // 2
        self._last = k
        self.turns += wrapped
        return wrapped

    @property
    def coverage(self) -> float:
        """Fraction of the angles that hold a beam."""
        return float(np.mean(np.isfinite(self.polar[:, 0])))

    def cartesian(self, size_px: int = 512) -> np.ndarray:
        """(size, size) float32 image of the disc (NaN outside it and where no beam is)."""
        half = size_px / 2
        v, u = np.mgrid[0:size_px, 0:size_px].astype(np.float32)
        x, y = (u + 0.5 - half) / half, (half - v - 0.5) / half          # unit disc, y ahead
        r = np.hypot(x, y) * self.n_samples - 0.5
        a = (np.arctan2(x, y) % (2 * np.pi)) / (2 * np.pi) * self.n_angles  # bearing from ahead, to starboard
        # wrap the angle axis: one extra row so angle 399.6 interpolates with angle 0
        polar = np.vstack([self.polar, self.polar[:1]])
        out = cv2.remap(np.nan_to_num(polar, nan=-1.0), r, a.astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        known = cv2.remap(np.isfinite(polar).astype(np.float32), r, a.astype(np.float32), cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        out[(known < 0.5) | (np.hypot(x, y) > 1)] = np.nan
        return out
