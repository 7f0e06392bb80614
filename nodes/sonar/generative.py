"""Generative elevation per beam: one sonar ping -> surface points with elevation 1-sigma (pure numpy).

After Westman & Kaess (2019, wide-aperture sonar reconstruction with generative models): in one beam
(an azimuth column) a surface is a curve in the range-elevation plane that starts at its *leading edge*
(the first return) on an aperture edge and runs on, one elevation per range bin. The image formation
model ties each bin's echo to the curve's slope there: an echo spread uniformly over the range
interval neighbouring elevations span (the simulator's ``sim.fls_render``) has level

    L(r) = echo_scale * cos(incidence) * beam(phi) * absorption(r) * |d phi / d r|,

and with the surface normal in the beam's plane ``cos(incidence) = |s| / sqrt(1 + s^2)`` for
``s = r d phi / d r``, so ``L r / (echo_scale beam absorption) = s^2 / sqrt(1 + s^2)``: one positive
root ``|s|`` per bin (a steep face fills few bins brightly, a grazing one many dimly). Integrating
``d phi = |s| dr / r`` from the leading edge gives every later bin's elevation: ``phi = -spread / 2 +
integral`` when the surface leads at the aperture's top edge (a face rising past the fan: a pile, a
wall; range grows with depression), ``spread / 2 - integral`` at its bottom edge (the seafloor, a
surface below the fan). Both hypotheses come out; which one holds is for other evidence to say
(free space from other views, :mod:`nodes.sonar.carving`; or the scene: ``leading``).

The ping is read in bins of ``bin_m`` along range, averaged over ``smooth_beams`` beams. Speckle is
exponential and the 8-bit image clips a steep face (its level is many times full scale at the demo's
gain): a bin's level is the maximum-likelihood mean of right-censored exponential samples (the sum
over the count of unclipped ones), noisy where few are unclipped. A run is a range interval of a beam
whose level stays above ``min_level``; with a flat seafloor given, runs end before its near edge
(beyond it the floor's own echo would be read as slope), and the floor is a witness: where its echo
starts at the near edge the bottom-edge ray reached it unblocked, so no run of that beam leads there;
where it is shadowed, the ray was blocked, and a beam's single run read from the top edge must sweep
``reach_frac`` of the aperture to be what blocked it (else only the bottom edge holds).

Every bin of a run gives one point per hypothesis. Its elevation 1-sigma (rad) adds the speckle noise
carried through the integration (relative sd ``1 / sqrt(n)`` for ``n`` unclipped samples; the root's
share of it 1/2 on a grazing surface, 1 on a steep one, taken as 3/4; independent bin to bin, so the
variance grows with range from the leading edge) to a model error of ``model_error`` times the
elevation swept (reflectivity, out-of-plane normals and clipping the model does not know) and the
bin's own extent. A run whose integral leaves the aperture is clipped at the far edge and flagged
``saturated``. Where the model does not hold -- a convex body (a cylinder, a box's top front edge)
leads at an elevation *inside* the aperture, and two branches of its surface share each range bin --
neither hypothesis is right: measured in ``bench/sonar_cloud.py``.
Frames: sonar FRD (x boresight, y starboard, z down; elevation positive down).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class GenerativeParams:
    """Tuning of :func:`surface_elevations` (levels in full scale = 1, before gain; lengths in m)."""

    echo_scale: float = 54.0          # level per unit cos(incidence) x beam x absorption x |dphi/dr| (rad/m)
    absorption_db_per_m: float = 0.05 # one way (the simulator's low frequency)
    gamma: float = 0.5                # the ping's intensity = level ** gamma (full scale = 1)
    noise_level: float = 0.01         # mean noise floor subtracted from the level
    min_level: float = 0.03           # a run's bins: smoothed level above this
    smooth_beams: int = 5             # box over neighbouring beams (odd)
    bin_m: float = 0.1                # the profile's range bin: one point per bin of a run and hypothesis
    min_run_m: float = 0.1            # shorter runs are dropped
    floor_guard_m: float = 0.08       # runs end this far before the seafloor's near edge
    floor_check_m: float = 0.3        # the floor's echo starting within this of its near edge: bottom ray unblocked
    floor_witness: bool = True        # ... then no bottom-edge hypothesis there; shadowed: see surface_elevations
    reach_frac: float = 0.5           # a top-leading run blocks the bottom ray if it sweeps this much of the aperture
    model_error: float = 0.2          # elevation 1-sigma per radian swept from the leading edge
    leading: str = "both"             # "top", "bottom" or "both" (both hypotheses, top first)

    def __post_init__(self) -> None:
        if not (self.echo_scale > 0 and self.absorption_db_per_m >= 0 and 0 < self.gamma <= 1):
            raise ValueError("need echo_scale > 0, absorption_db_per_m >= 0 and 0 < gamma <= 1")
        if not (self.min_level > 0 and self.noise_level >= 0 and self.model_error >= 0):
            raise ValueError("need min_level > 0, noise_level >= 0 and model_error >= 0")
        if not (self.smooth_beams >= 1 and self.smooth_beams % 2 == 1 and self.bin_m > 0 and self.min_run_m >= 0):
            raise ValueError("need an odd smooth_beams >= 1, bin_m > 0 and min_run_m >= 0")
        if not (self.floor_guard_m >= 0 and self.floor_check_m > 0 and 0 < self.reach_frac <= 1):
            raise ValueError("need floor_guard_m >= 0, floor_check_m > 0 and 0 < reach_frac <= 1")
        if self.leading not in ("top", "bottom", "both"):
            raise ValueError(f"leading must be 'top', 'bottom' or 'both', got {self.leading!r}")


@dataclass(frozen=True)
class SurfaceSamples:
    """Points of one ping's runs, one per hypothesis: ``range_m``, ``bearing_rad``, ``elevation_rad`` (positive
    down), ``sigma_rad`` (elevation 1-sigma), ``swept_rad`` (elevation from the leading edge), ``beam`` and
    ``run`` (int), ``top`` (bool: the top-edge hypothesis), ``saturated`` (bool: the integral left the aperture);
    all (K,). ``points_frd()`` gives (K, 3) sonar-frame points and ``sigma_m()`` the 1-sigma along the arc."""

    range_m: np.ndarray
    bearing_rad: np.ndarray
    elevation_rad: np.ndarray
    sigma_rad: np.ndarray
    swept_rad: np.ndarray
    beam: np.ndarray
    run: np.ndarray
    top: np.ndarray
    saturated: np.ndarray

    def points_frd(self) -> np.ndarray:
        r, b, e = self.range_m, self.bearing_rad, self.elevation_rad
        return np.stack([r * np.cos(e) * np.cos(b), r * np.cos(e) * np.sin(b), r * np.sin(e)], axis=1)

    def sigma_m(self) -> np.ndarray:
        return self.range_m * self.sigma_rad


def level_of(intensities: np.ndarray, *, gamma: float = 0.5, gain: float = 1.0) -> np.ndarray:
    """Echo level (full scale = 1, float32) of 8- or 16-bit intensities: ``(I / full) ** (1 / gamma) / gain``."""
    img = np.asarray(intensities)
    if img.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"intensities must be uint8 or uint16, got {img.dtype}")
    full = np.float32(np.iinfo(img.dtype).max)
    x = img.astype(np.float32) / full
    return (x * x if gamma == 0.5 else x ** np.float32(1.0 / gamma)) / np.float32(gain)


def slope_of(y: np.ndarray) -> np.ndarray:
    """The root ``|s| >= 0`` of ``s^2 / sqrt(1 + s^2) = y`` (``y >= 0``)."""
    y = np.maximum(y, 0.0)
    return np.sqrt(0.5 * (y * y + y * np.sqrt(y * y + 4.0)))    # s^2 = (y^2 + sqrt(y^4 + 4 y^2)) / 2, no y^4


def surface_elevations(intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
                       spread_rad: float, *, params: GenerativeParams = GenerativeParams(),
                       floor_rows: np.ndarray | None = None, gain: float = 1.0,
                       row_gains: np.ndarray | None = None) -> SurfaceSamples:
    """Every run's surface points of one ping, per leading-edge hypothesis (see the module docstring).

    Parameters
    ----------
    intensities : (M, N) uint8/uint16, ranges x beams, row i at (i + 0.5) * range_resolution_m.
    bearings_rad : (N,) bearings (rad), positive to starboard.
    range_resolution_m : m per row, > 0. spread_rad : vertical aperture (rad), in (0, pi).
    floor_rows : (N,) fractional row of each beam's seafloor near edge (where its bottom-edge ray meets a flat
        floor, :func:`nodes.sonar.carving_arcs.seafloor_rows`); runs end ``floor_guard_m`` before it, and where the
        floor's echo starts there (within ``floor_check_m``) the bottom-edge ray reached the floor unblocked: that
        beam's runs have no bottom-edge hypothesis. None: no seafloor, every run has both.
    gain : linear gain the ping was amplified by (1 at 50 %).
    row_gains : (M,) linear gain the device amplified each row by before its gamma and quantisation, with
        ``intensities`` the raw samples (not compensated: a row-gain-compensated image clips below full scale, where
        the censoring cannot see it); None: no row gains (or all 1).
    """
    img = np.asarray(intensities)
    bearings = np.asarray(bearings_rad, float)
    if img.ndim != 2 or img.shape[1] != bearings.size or img.shape[0] < 2:
        raise ValueError(f"intensities must be (ranges, beams) with one bearing per beam, got {img.shape} and "
                         f"{bearings.size} bearings")
    if not (range_resolution_m > 0 and 0 < spread_rad < np.pi and gain > 0):
        raise ValueError("need range_resolution_m > 0, 0 < spread_rad < pi and gain > 0")
    if row_gains is not None:
        row_gains = np.asarray(row_gains, np.float32).reshape(-1)
        if row_gains.size != img.shape[0] or not np.all(np.isfinite(row_gains) & (row_gains > 0)):
            raise ValueError(f"row_gains must be one finite gain > 0 per row ({img.shape[0]}), got {row_gains.size}: "
                             "repair them first, or pass the compensated image without them")
    p = params
    k = max(1, int(round(p.bin_m / range_resolution_m)))  # rows per profile bin
    dr = k * float(range_resolution_m)                     # the profile's bin (m)
    m = img.shape[0] // k
    floor = None if floor_rows is None else np.asarray(floor_rows, float) / k
    if floor is not None:                                  # nothing past the floor's near edge (and its check)
        m = int(min(m, max(np.ceil(floor.max(initial=0.0) + p.floor_check_m / dr), 0)))
    if m == 0:
        return _empty()
    level, unclipped = censored_level(img[:m * k], k, p, gain,
                                      None if row_gains is None else row_gains[:m * k])    # beams x bins
    unblocked = np.zeros(img.shape[1], bool)
    if floor is not None:
        bins = np.arange(m)[None, :]
        near_edge = (bins >= np.floor(floor)[:, None]) & (bins < (floor + p.floor_check_m / dr)[:, None])
        unblocked = np.any(near_edge & (level > p.min_level), axis=1)
    # a run's bins: bright over three bins (one dim bin inside a surface must not restart its integral)
    bright = cv2.blur(level, (3, 1), borderType=cv2.BORDER_REPLICATE) > p.min_level
    if floor is not None:
        bright &= np.arange(m)[None, :] + 1 <= (floor - p.floor_guard_m / dr)[:, None]
    cols, rows = np.nonzero(bright)                        # beam by beam, bins in range order
    if rows.size == 0:
        return _empty()
    level, unclipped = level[cols, rows], unclipped[cols, rows]
    new = np.r_[True, (np.diff(cols) != 0) | (np.diff(rows) != 1)]
    run = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    r = (rows + 0.5) * dr
    y0 = level * r / (p.echo_scale * 10.0 ** (-2 * p.absorption_db_per_m * r / 10))
    half = 0.5 * spread_rad
    # the n samples behind a level estimate: its relative sd 1 / sqrt(n) (censored: the unclipped ones count); the
    # slope's share of it 1/2 (grazing) .. 1 (steep), taken as 3/4; independent bin to bin: variances add along a run
    rel = 0.75 / np.sqrt(np.maximum(unclipped, 1.0))
    out = []
    # the floor as a witness: a beam whose floor echo starts at its near edge has its bottom-edge ray unblocked (no
    # surface leads there); one whose floor is shadowed there has it blocked -- and with a single run before the
    # floor, a top-leading reading of that run must reach the bottom edge to block it (else only the bottom edge)
    blocked = np.zeros(img.shape[1], bool) if floor is None else ~unblocked
    lone = np.bincount(cols[first], minlength=img.shape[1]) == 1
    for top in ((True, False) if p.leading == "both" else ((p.leading == "top"),)):
        swept = np.zeros(rows.size)
        for _ in range(2):                                 # the beam pattern at the edge, then where pass 1 put it
            inside = np.clip(swept, 0.0, 2 * half)          # the pattern where the aperture ends, past it
            phi = (-half + inside) if top else (half - inside)
            d_phi = slope_of(y0 / 2.0 ** (-(2 * phi / spread_rad) ** 2)) * dr / r
            swept = _in_runs(d_phi, run, first) - 0.5 * d_phi
        var = _in_runs((rel * d_phi) ** 2, run, first)
        sample = _sample(rows, cols, run, first, swept, var, top, half, bearings, dr, p)
        if p.floor_witness and floor is not None:
            if top:
                last = np.r_[first[1:], rows.size] - 1
                total = (swept + 0.5 * d_phi)[last]          # each run's whole sweep
                keep = ~(blocked & lone)[sample.beam] | (total[sample.run] >= p.reach_frac * 2 * half)
            else:
                keep = ~unblocked[sample.beam]
            sample = SurfaceSamples(*(getattr(sample, f)[keep] for f in SurfaceSamples.__dataclass_fields__))
        out.append(sample)
    return SurfaceSamples(*(np.concatenate([getattr(s, f) for s in out]) for f in SurfaceSamples.__dataclass_fields__))


def censored_level(img: np.ndarray, k: int, p: GenerativeParams, gain: float,
                   row_gains: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Echo level of bins of ``k`` rows smoothed over ``smooth_beams`` beams, and the number of unclipped samples
    behind it: both (N, M // k) float32, beams x bins, of the (M, N) ping ``img``.

    Speckle is exponential and the sonar clips at full scale: over a window the maximum-likelihood mean of
    right-censored exponential samples is the sum of all (clipped ones at full scale) over the count of unclipped
    ones -- a steep face whose level is many times full scale still reads as it is, if noisily. With ``row_gains``
    (M,) ``img`` holds the raw samples of a device that amplified row i by ``row_gains[i]``: each sample's level is
    divided by its row's gain and a sample is clipped where it reads full scale (compensating the image first would
    move a row's clipping point below full scale, where a clipped sample would pass for an unclipped one).
    """
    full = np.iinfo(img.dtype).max
    m, n = img.shape[0] // k, img.shape[1]
    if row_gains is not None and np.all(row_gains == 1.0):
        row_gains = None
    if row_gains is not None:                              # each row's level at unit gain, then the noise floor
        level = level_of(img, gamma=p.gamma) / np.asarray(row_gains, np.float32)[:, None]
        level = np.maximum(level - np.float32(p.noise_level), 0.0)
    elif img.dtype == np.uint8:                            # a 256-entry table beats the float arithmetic
        lut = np.maximum(level_of(np.arange(256, dtype=np.uint8), gamma=p.gamma) - np.float32(p.noise_level), 0)
        level = cv2.LUT(img, lut.astype(np.float32))
    else:
        level = np.maximum(level_of(img, gamma=p.gamma) - np.float32(p.noise_level), 0.0)
    # sums over each bin's k rows, then beams x bins
    total = cv2.transpose(level.reshape(m, k, n).sum(axis=1, dtype=np.float32))
    kept = cv2.transpose((img < full).reshape(m, k, n).sum(axis=1, dtype=np.float32))
    size = (1, p.smooth_beams)                             # cv2 (width along bins, height across beams)
    total = cv2.blur(total, size, borderType=cv2.BORDER_REPLICATE)
    kept = cv2.blur(kept, size, borderType=cv2.BORDER_REPLICATE)
    est = total / np.maximum(kept, np.float32(0.5)) / np.float32(gain)
    return est, kept * np.float32(p.smooth_beams)


def _in_runs(x: np.ndarray, run: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Cumulative sum of ``x`` along each run (``first``: each run's first index in the beam-major list)."""
    c = np.cumsum(x)
    return c - (c[first] - x[first])[run]


def _sample(rows, cols, run, first, swept, var, top: bool, half: float, bearings: np.ndarray, dr: float,
            p: GenerativeParams) -> SurfaceSamples:
    """One point per bin of each run at least ``min_run_m`` long, with its sigma."""
    length = np.diff(np.r_[first, rows.size])
    keep = length[run] * dr >= p.min_run_m
    rows, cols, run, s, var = rows[keep], cols[keep], run[keep], swept[keep], var[keep]
    r = (rows + 0.5) * dr
    sigma = np.sqrt(var + (p.model_error * s) ** 2 + (dr / r) ** 2)
    saturated = s > 2 * half
    s = np.minimum(s, 2 * half)
    return SurfaceSamples(range_m=r, bearing_rad=bearings[cols], elevation_rad=(-half + s) if top else (half - s),
                          sigma_rad=sigma, swept_rad=s, beam=cols.astype(np.int64), run=run.astype(np.int64),
                          top=np.full(rows.size, top), saturated=saturated)


def _empty() -> SurfaceSamples:
    f, i = np.zeros(0), np.zeros(0, np.int64)
    return SurfaceSamples(f, f, f, f, f, i, i, np.zeros(0, bool), np.zeros(0, bool))
