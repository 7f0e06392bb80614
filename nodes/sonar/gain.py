"""Per-row gain compensation of a raw sonar image, in the device's own sample encoding.

An Oculus ping can carry one gain per range row (SimpleFire flag bit 2): the device amplified row
``i``'s echo level by ``g_i`` before the gamma curve and the 8/16-bit quantisation,
``sample = full * (g_i * level) ** gamma``. Dividing the sample by ``g_i ** gamma`` gives back the
sample the device would have sent with a gain of 1 on every row, so near and far echoes are
comparable and a detection threshold means the same at every range. (ENSTA's driver divides by
``sqrt(g)``: the same for the default gamma of 0.5.) The result keeps the input's dtype and full
scale (uint8 255, uint16 65535), saturating at full scale; float input is returned as float32.

How the 4-byte gain is read (IEEE float or u32; the spec says it is disputed) is the driver's
choice (``drivers.oculus`` ``row_gain_encoding``); here gains are plain linear factors.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

GainStatus = Literal["applied", "absent", "repaired", "invalid", "mismatch"]


@dataclass(frozen=True)
class GainResult:
    """``image`` (R, B) compensated (or the input, unscaled); ``status``; ``bad_rows`` replaced by neighbours."""

    image: np.ndarray
    status: GainStatus
    bad_rows: int = 0


def full_scale(dtype: np.dtype) -> float:
    """Full-scale sample value of a raw image dtype (1.0 for float images)."""
    dtype = np.dtype(dtype)
    return float(np.iinfo(dtype).max) if dtype.kind in "ui" else 1.0


def compensate_row_gains(intensities: np.ndarray, row_gains: np.ndarray, gamma: float = 1.0) -> GainResult:
    """Divide each row of ``intensities`` by its gain raised to ``gamma``.

    Parameters
    ----------
    intensities : (R, B) uint8, uint16 or float
        Raw samples, row 0 nearest the sonar. Non-finite float samples become 0 (a NaN must not
        reach an interpolating renderer, where it would spread to the neighbouring pixels).
    row_gains : (R,) or (0,)
        Linear gain of each row as the device reports it; empty: no gains sent.
    gamma : float
        The device's gamma (0 < gamma <= 1; anything else is read as 1).

    Returns
    -------
    GainResult
        ``status`` "applied"; "absent" (no gains); "repaired" (some rows had a non-finite or
        non-positive gain: those take the gain of the nearest valid rows, counted in ``bad_rows``);
        "invalid" (every gain zero, negative or NaN) or "mismatch" (not one gain per row): the
        image passes through unscaled.
    """
    img = np.asarray(intensities)
    if img.dtype.kind == "f" and not np.all(np.isfinite(img)):
        img = np.where(np.isfinite(img), img, 0).astype(np.float32)
    g = np.asarray(row_gains, dtype=np.float64).reshape(-1)
    if g.size == 0:
        return GainResult(img, "absent")
    if img.ndim != 2 or g.size != img.shape[0]:
        return GainResult(img, "mismatch")
    good = np.isfinite(g) & (g > 0)
    if not good.any():
        return GainResult(img, "invalid", int(g.size))
    bad = int(g.size - good.sum())
    if bad:
        rows = np.arange(g.size)
        g = np.interp(rows, rows[good], g[good])
    status: GainStatus = "repaired" if bad else "applied"
    if np.all(g == 1.0):
        return GainResult(img, status, bad)      # unit gains (the simulator's, a fixed-gain sonar's): nothing to divide
    gamma = float(gamma) if np.isfinite(gamma) and 0 < gamma <= 1 else 1.0
    scale = (1.0 / g ** gamma).astype(np.float32)[:, None]
    out = img.astype(np.float32) * scale
    if img.dtype.kind in "ui":
        out = np.clip(np.rint(out), 0, full_scale(img.dtype)).astype(img.dtype)
    return GainResult(out, status, bad)
