"""Highlight extension -> 3D line scan from one forward-looking-sonar ping (seed 01, eq. 7-17).

Frames: points come out in the sonar frame FRD (x along the boresight, y starboard, z down),
the frame in which eq. (15)-(17) are written (bearing positive to starboard, elevation positive
downwards). ``frd_to_flu`` converts to x forward, y left, z up.

Two elevation models:

* ``"paper"``: eq. (13) literally, phi = t + s/2 for every beam, eq. (7)-(8) for the effective
  region, eq. (15)-(17) in the level frame, rotated back into the sonar frame by the tilt.
* ``"beam"`` (default): the lower edge of the vertical aperture is the cone at elevation s/2 below
  the sonar's boresight plane, so its depression below the horizon is
  ``asin(sin t cos(s/2) cos(theta) + cos t sin(s/2))`` — equal to t + s/2 only at theta = 0. At
  theta = 65 deg, t = 15 deg, s = 20 deg it is 16 deg, not 25 deg; eq. (13) would put the wide
  beams' points metres too deep. Same detection, same equations otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

ELEVATION_MODELS = ("beam", "paper")


@dataclass(frozen=True)
class EffectiveRegion:
    """Per-beam effective region (eq. 7-10): ranges in m, rows as fractional 0-based indices.

    ``r_emin_m``/``r_emax_m`` are ``inf`` where that beam edge never reaches the seafloor
    (edge at or above the horizon, e.g. ``t - s/2 <= 0`` for the upper edge).
    """

    r_emin_m: np.ndarray
    r_emax_m: np.ndarray
    m_emin: np.ndarray
    m_emax: np.ndarray


@dataclass(frozen=True)
class LineScan:
    """One ping's line scan (eq. 12-17).

    Attributes
    ----------
    points_m : (K, 3) float64
        Sonar-frame FRD points of the beams that produced one (detected highlight, or the
        seafloor at ``M_emin`` when ``include_seafloor``).
    beams : (K,) int
        Column of each point.
    detected : (K,) bool
        True for highlight front ends, False for seafloor fill (m(j) = M_emin).
    strength : (K,) float32
        Filter response T at the front end (full scale = 1), 0 for seafloor fill.
    rows : (N,) float
        m(j) for every beam (fractional row, NaN where neither highlight nor seafloor).
    region : EffectiveRegion
    """

    points_m: np.ndarray
    beams: np.ndarray
    detected: np.ndarray
    strength: np.ndarray
    rows: np.ndarray
    region: EffectiveRegion


def edge_rays(bearings_rad: np.ndarray, spread_rad: float, lower: bool = True) -> np.ndarray:
    """Unit rays (N, 3) of the lower (or upper) vertical-aperture edge per beam, sonar FRD frame."""
    e = 0.5 * spread_rad if lower else -0.5 * spread_rad
    b = np.asarray(bearings_rad, dtype=float)
    return np.stack([np.cos(e) * np.cos(b), np.cos(e) * np.sin(b), np.full_like(b, np.sin(e))], axis=1)


def down_from_tilt(tilt_rad: float) -> np.ndarray:
    """Gravity direction in the sonar FRD frame of a sonar pitched down by ``tilt_rad`` with no roll."""
    return np.array([np.sin(tilt_rad), 0.0, np.cos(tilt_rad)])


def effective_region(bearings_rad: np.ndarray, altitude_m: float, spread_rad: float, *, tilt_rad: float,
                     n_ranges: int, range_resolution_m: float, r_min_m: float = 0.0,
                     down_frd: np.ndarray | None = None, model: str = "beam") -> EffectiveRegion:
    """Eq. (7)-(10) per beam.

    Parameters
    ----------
    bearings_rad : (N,) array
    altitude_m : float
        Sonar height above the seafloor h (m), > 0.
    spread_rad : float
        Vertical aperture s (rad), > 0.
    tilt_rad : float
        Boresight depression t (rad); used by ``"paper"`` and when ``down_frd`` is None.
    n_ranges, range_resolution_m, r_min_m
        Ping rows M, row size (m), near edge of row 0 (m); r_max = r_min + M * dr.
    down_frd : (3,) array, optional
        Gravity direction in the sonar frame (from the pose, includes roll); ``"beam"`` only.
    model : {"beam", "paper"}
    """
    if not (np.isfinite(altitude_m) and altitude_m > 0):
        raise ValueError(f"altitude must be finite and > 0 m (sonar above the seafloor), got {altitude_m}")
    if not (np.isfinite(spread_rad) and 0 < spread_rad < np.pi) or not np.isfinite(tilt_rad):
        raise ValueError(f"need 0 < spread < pi and a finite tilt (rad), got s={spread_rad}, t={tilt_rad}")
    if model not in ELEVATION_MODELS:
        raise ValueError(f"model must be one of {ELEVATION_MODELS}, got {model!r}")
    b = np.asarray(bearings_rad, dtype=float)
    if model == "paper":
        sin_low = np.full(b.shape, np.sin(tilt_rad + 0.5 * spread_rad))
        sin_up = np.full(b.shape, np.sin(tilt_rad - 0.5 * spread_rad))
    else:
        g = down_from_tilt(tilt_rad) if down_frd is None else np.asarray(down_frd, float) / np.linalg.norm(down_frd)
        sin_low = edge_rays(b, spread_rad, lower=True) @ g
        sin_up = edge_rays(b, spread_rad, lower=False) @ g
    with np.errstate(divide="ignore"):
        # An edge at or above the horizon never meets the seafloor: r_e is infinite (eq. 8 when t - s/2 <= 0).
        r_emin = np.where(sin_low > 1e-9, altitude_m / np.maximum(sin_low, 1e-9), np.inf)
        r_emax = np.where(sin_up > 1e-9, altitude_m / np.maximum(sin_up, 1e-9), np.inf)
    span = n_ranges * range_resolution_m
    m_emin = np.clip((r_emin - r_min_m) / span * n_ranges, 0, n_ranges)
    m_emax = np.clip((r_emax - r_min_m) / span * n_ranges, 0, n_ranges)
    return EffectiveRegion(r_emin, r_emax, m_emin, m_emax)


def split_regions(intensities: np.ndarray, region: EffectiveRegion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boolean (M, N) masks of S1 (i < M_emin), S2 (M_emin <= i <= M_emax) and S3 (i > M_emax) per column."""
    centres = np.arange(intensities.shape[0])[:, None] + 0.5    # row i spans cells [i, i + 1)
    s1 = centres < region.m_emin[None, :]
    s3 = centres > region.m_emax[None, :]
    return s1, ~(s1 | s3), s3


def difference_filter(image: np.ndarray, axis: int = 0) -> np.ndarray:
    """Eq. (11): T(i, j) = S(i + 1, j) - S(i - 1, j) along ``axis`` (range), zero at both ends.

    The paper prints the 3 x N kernel as (1, 0, 1); that would be a smoothing, not a difference:
    the minus sign was lost, D = (-1, 0, 1), so a dark-to-bright rising edge gives a positive peak.
    """
    out = np.zeros(image.shape, np.int16 if image.dtype == np.int16 else np.float32)  # int16: x64 fixed point
    if image.shape[axis] >= 3:
        if axis == 0:
            np.subtract(image[2:], image[:-2], out=out[1:-1], dtype=out.dtype)
        else:
            np.subtract(image[:, 2:], image[:, :-2], out=out[:, 1:-1], dtype=out.dtype)
    return out


def detect_front_ends(intensities: np.ndarray, m_emin: np.ndarray, *, sigma_px: float = 1.5,
                      threshold: float = 0.12, guard_px: float | None = None,
                      sigma_beam_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Front end of the highlight extension per column, in S1 only (sec. 3.2.2).

    Parameters
    ----------
    intensities : (M, N) array
        Raw ping (uint8/uint16 scaled by their full scale, floats taken as 0..1).
    m_emin : (N,) array
        Fractional row of r_emin per column; S1 is rows i < m_emin(j).
    sigma_px : float
        Gaussian blur sigma along range, in ping cells (0: none).
    threshold : float
        Minimum rise T of the front end, as a fraction of full scale.
    guard_px : float, optional
        Rows before M_emin left out, so the seafloor's own rising edge at r_emin (smeared by the
        blur and the beam pattern) is not taken for a highlight; default 2 sigma + 2.
    sigma_beam_px : float, optional
        Blur sigma across beams (default: ``sigma_px``, the paper's isotropic blur). Across-beam
        blur spreads a highlight into the neighbouring beams.

    Returns
    -------
    rows : (N,) float
        Sub-cell row of the first peak of T above ``threshold`` (nearest the sonar: the front end
        when several peaks are present), NaN where none.
    strength : (N,) float32
        T at that peak (full scale = 1), 0 where none.
    """
    m, n = intensities.shape
    rows_out = np.full(n, np.nan)
    strength = np.zeros(n, np.float32)
    guard = 2.0 * sigma_px + 2.0 if guard_px is None else guard_px
    limit = np.floor(np.asarray(m_emin, float) - 0.5 - guard)          # rows i < limit(j) are S1
    k = int(min(m, max(np.max(limit, initial=0.0), 0.0)))
    if k < 3:
        return rows_out, strength
    pad = int(min(m - k, np.ceil(3 * sigma_px) + 1))
    s1, full_scale = _blurred_transposed(intensities[:k + pad], sigma_px,
                                         sigma_px if sigma_beam_px is None else sigma_beam_px)
    t = difference_filter(s1, axis=1)[:, :k]                         # eq. (11) along range, per beam
    threshold = threshold * full_scale
    first = np.argmax(t > threshold, axis=1)
    beams = np.arange(n)
    cols = np.flatnonzero((t[beams, first] > threshold) & (first < limit))   # front end inside S1
    if cols.size == 0:
        return rows_out, strength
    # The peak is the maximum of T in the contiguous run above threshold that starts at `first`.
    win = int(max(3, np.ceil(4 * sigma_px) + 2))
    idx = first[cols][:, None] + np.arange(win)[None, :]
    vals = np.where(idx < limit[cols][:, None], t[cols[:, None], np.minimum(idx, k - 1)], -np.inf)
    vals[:, 0] = t[cols, first[cols]]
    run = np.cumprod(vals > threshold, axis=1).astype(bool)
    peak = first[cols] + np.argmax(np.where(run, vals, -np.inf), axis=1)
    rows_out[cols] = peak + _parabolic_offset(t, peak, cols)
    strength[cols] = t[cols, peak] / full_scale
    return rows_out, strength


def _blurred_transposed(rows: np.ndarray, sigma_r: float, sigma_b: float) -> tuple[np.ndarray, float]:
    """Gaussian-blurred ping, beams x ranges (so per-beam scans run over contiguous memory).

    uint8 pings stay in fixed point (int16, x64: 6 fractional bits), the fast path; other dtypes
    become float32 in 0..1. Returns the array and the value of full scale in it.
    """
    kr = 2 * int(np.ceil(3 * sigma_r)) + 1 if sigma_r > 0 else 1
    kb = 2 * int(np.ceil(3 * sigma_b)) + 1 if sigma_b > 0 else 1
    if rows.dtype == np.uint8:
        src, scale = cv2.transpose(np.ascontiguousarray(rows)), 64.0
        ker_r = cv2.getGaussianKernel(kr, max(sigma_r, 1e-3)) * scale if kr > 1 else np.array([[scale]])
        ker_b = cv2.getGaussianKernel(kb, max(sigma_b, 1e-3)) if kb > 1 else np.array([[1.0]])
        out = cv2.sepFilter2D(src, cv2.CV_16S, ker_r, ker_b, borderType=cv2.BORDER_REFLECT)
        return out, 255.0 * scale
    src = cv2.transpose(_normalised(rows))
    if kr > 1 or kb > 1:
        src = cv2.GaussianBlur(src, (kr, kb), sigmaX=max(sigma_r, 1e-3), sigmaY=max(sigma_b, 1e-3),
                               borderType=cv2.BORDER_REFLECT)
    return src, 1.0


def _normalised(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image.astype(np.float32) * np.float32(1 / 255)
    if np.issubdtype(image.dtype, np.integer):
        return image.astype(np.float32) * np.float32(1 / np.iinfo(image.dtype).max)
    out = np.nan_to_num(image.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return out


def _parabolic_offset(t: np.ndarray, peak: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sub-cell offset of a peak of T (beams x rows) from the parabola through its neighbours."""
    lo = t[cols, np.maximum(peak - 1, 0)].astype(float)
    mid = t[cols, peak].astype(float)
    hi = t[cols, np.minimum(peak + 1, t.shape[1] - 1)].astype(float)
    den = lo - 2 * mid + hi
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < -1e-12, 0.5 * (lo - hi) / den, 0.0)
    return np.clip(off, -0.5, 0.5)


def extract_line_scan(intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float, *,
                      altitude_m: float, tilt_rad: float, spread_rad: float, r_min_m: float = 0.0,
                      down_frd: np.ndarray | None = None, model: str = "beam", sigma_px: float = 1.5,
                      threshold: float = 0.12, guard_px: float | None = None,
                      sigma_beam_px: float | None = None, include_seafloor: bool = True) -> LineScan:
    """Eq. (7)-(17): one ping -> one line scan of 3D points in the sonar FRD frame.

    Parameters are those of :func:`effective_region` and :func:`detect_front_ends`;
    ``include_seafloor`` adds the seafloor point at M_emin for beams without a highlight
    (the paper's m(j) = M_emin), where the seafloor is inside the ping's range.

    Returns
    -------
    LineScan
    """
    if intensities.ndim != 2 or intensities.shape[1] != len(bearings_rad) or intensities.shape[0] < 1:
        raise ValueError(f"intensities must be ranges x beams with one bearing per beam, got "
                         f"{intensities.shape} and {len(bearings_rad)} bearings")
    if not (np.isfinite(range_resolution_m) and range_resolution_m > 0):
        raise ValueError(f"range_resolution_m must be > 0, got {range_resolution_m}")
    b = np.asarray(bearings_rad, dtype=float)
    if not np.all(np.isfinite(b)):
        raise ValueError("bearings must be finite")
    m = intensities.shape[0]
    region = effective_region(b, altitude_m, spread_rad, tilt_rad=tilt_rad, n_ranges=m,
                              range_resolution_m=range_resolution_m, r_min_m=r_min_m, down_frd=down_frd,
                              model=model)
    rows, strength = detect_front_ends(intensities, region.m_emin, sigma_px=sigma_px, threshold=threshold,
                                       guard_px=guard_px, sigma_beam_px=sigma_beam_px)
    detected = np.isfinite(rows)
    if include_seafloor:
        fill = ~detected & (region.m_emin < m)
        # m(j) = M_emin (eq. 9 gives an edge in cells; as a row-centre index that is M_emin - 0.5).
        rows = np.where(fill, region.m_emin - 0.5, rows)
    beams = np.flatnonzero(np.isfinite(rows))
    r = r_min_m + (rows[beams] + 0.5) * range_resolution_m      # eq. (12), row centres as in eq. (1)
    points = line_scan_points(r, b[beams], spread_rad, tilt_rad=tilt_rad, model=model)
    return LineScan(points, beams, detected[beams], strength[beams], rows, region)


def line_scan_points(ranges_m: np.ndarray, bearings_rad: np.ndarray, spread_rad: float, *, tilt_rad: float,
                     model: str = "beam") -> np.ndarray:
    """Eq. (13)-(17): (K, 3) sonar-frame FRD points on the lower aperture edge at the given ranges."""
    r = np.asarray(ranges_m, float)[:, None]
    if model == "beam":
        return r * edge_rays(bearings_rad, spread_rad, lower=True)
    phi = tilt_rad + 0.5 * spread_rad                                # eq. (13)
    th = np.asarray(bearings_rad, float)
    level = r * np.stack([np.cos(phi) * np.cos(th), np.cos(phi) * np.sin(th),     # eq. (15), (16)
                          np.full_like(th, np.sin(phi))], axis=1)                  # eq. (17)
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)
    # level = R_pitch(t) @ sonar  ->  sonar = R_pitch(t).T @ level (pitch down by t about +y, FRD)
    rot = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    return level @ rot


def frd_to_flu(points: np.ndarray) -> np.ndarray:
    """(K, 3) FRD (x fwd, y starboard, z down) -> FLU (x fwd, y port, z up)."""
    return np.asarray(points) * np.array([1.0, -1.0, -1.0])
