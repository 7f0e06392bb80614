"""Fourier registration of sonar images: translation by phase correlation, rotation from the
polar resampled magnitude spectrum (seed 08, section III; Hurtos et al.).

Conventions. Images are (rows, cols) arrays; a shift is ``(dx, dy)`` in pixels, x along
columns and y along rows (down), and means ``moving[y, x] ~ fixed[y - dy, x - dx]``: the
content of ``fixed`` moved by (dx, dy). This is the sign of ``cv2.phaseCorrelate(fixed,
moving)`` and the opposite of ``skimage.registration.phase_cross_correlation(fixed,
moving)``, which returns the (row, col) shift that *registers* moving back onto fixed. A
rotation ``angle`` (rad) turns the content about the image centre counter-clockwise as
displayed (y down), like ``cv2.getRotationMatrix2D(centre, degrees(angle), 1)``;
:func:`warp` applies (angle, shift) in that order.

Translation (:func:`phase_correlate`):

1. remove the (masked) mean, apply a Hann window times a softened validity mask (the fan's
   edges would otherwise dominate the spectrum);
2. cross-power spectrum ``conj(F) G`` whitened with a floor and limited to a band: plain
   whitening (``/|conj(F) G|``) gives every frequency the same weight, and on speckle the
   high frequencies are noise -- a cos^2 taper to ``band`` x Nyquist keeps the texture's;
3. the integer peak of the band-limited surface, then Newton's method on the continuous
   correlation ``c(p) = sum_k w_k Re(R_k exp(i 2 pi k.p))`` (exact sub-pixel position of the
   band-limited peak: no parabola or sinc-fit bias, no upsampled grid);
4. a peak-to-noise ratio (peak over the surface's spread away from it) and a covariance
   from the peak's curvature and that spread.

Rotation (:func:`estimate_rotation`): the magnitude spectrum does not move with the
content, only turns with it; resampled on a polar grid (angle over 180 degrees, radius in a
mid-frequency band, log-compressed) the turn is a circular shift along the angle, found by
1-D phase correlation. A magnitude spectrum is symmetric, so the angle is known modulo 180
degrees; :func:`register` tries both and keeps the one whose translation peak is stronger.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.fft as sfft

DEFAULT_BAND = 0.25          # cut-off of the cross-power taper, fraction of Nyquist (bench/phase_correlation.py's tuning rule)
DEFAULT_FLOOR = 0.05         # whitening floor, fraction of the band's median cross-power magnitude
NEWTON_STEPS = 3
FOLLOW_FRACTION = 0.02       # a second, content-centred pass past this shift (fraction of the size)


@dataclass(frozen=True)
class Shift:
    """A translation estimate. ``pnr``: peak-to-noise ratio (peak height over the surface's
    standard deviation away from the peak); ``covariance``: 2x2 over (dx, dy), px^2."""

    dx: float
    dy: float
    pnr: float
    covariance: np.ndarray
    overlap: float = 1.0         # fraction of the smaller mask's valid pixels that overlap at this shift
    ambiguity: float = 0.0       # the next peak's height over this one's (1: a periodic texture, no answer)


@dataclass(frozen=True)
class Registration:
    """A rigid estimate: rotation (rad) then shift; ``covariance`` 3x3 over (dx, dy, angle)."""

    angle: float
    dx: float
    dy: float
    pnr: float
    covariance: np.ndarray
    overlap: float = 1.0
    ambiguity: float = 0.0


# -- helpers -----------------------------------------------------------------------------------
def _prepare(image: np.ndarray, mask: np.ndarray | None, taper_px: float, window: np.ndarray | None = None,
             log_intensity: bool = False) -> np.ndarray:
    """Zero-mean, windowed, mask-softened float32 image (log-compressed first when asked and non-negative)."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2 or min(img.shape) < 8:
        raise ValueError(f"an image is a 2-D array of at least 8 x 8, got shape {img.shape}")
    if not np.isfinite(img).all():
        img = np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0)
    if log_intensity and img.size and float(img.min()) >= 0.0:
        # Speckle multiplies the echo: in the log it adds, and its bright tail no longer dominates.
        scale = float(img[mask].mean()) if mask is not None and np.any(mask) else float(img.mean())
        if scale <= 0:
            return np.zeros_like(img)                   # a blank image: nothing to compress
        img = np.log(img + np.float32(0.05 * scale))
    window = _hann(img.shape[0], img.shape[1]) if window is None else window
    if mask is not None:
        valid = np.asarray(mask, dtype=np.float32)
        if valid.shape != img.shape:
            raise ValueError(f"mask shape {valid.shape} differs from the image's {img.shape}")
        if taper_px > 0:
            k = int(2 * round(2 * taper_px) + 1)
            soft = cv2.GaussianBlur(valid, (k, k), taper_px) * valid     # fades to 0 inside the edge
        else:
            soft = valid
        window = window * soft
        weight = float(window.sum())
        mean = float((img * window).sum() / weight) if weight > 0 else 0.0
    else:
        mean = float(img.mean())
    return (img - mean) * window


def _frequencies(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Cycles per pixel of the rfft2 layout: (h, 1) rows, (1, w//2+1) columns."""
    return np.fft.fftfreq(h)[:, None], np.fft.rfftfreq(w)[None, :]


@functools.lru_cache(maxsize=16)
def _hann(h: int, w: int) -> np.ndarray:
    """The 2-D Hann window of an image shape (cached; read-only)."""
    window = np.outer(np.hanning(h), np.hanning(w)).astype(np.float32)
    window.flags.writeable = False
    return window


@functools.lru_cache(maxsize=16)
def _plan(h: int, w: int, band: float) -> "_Plan":
    return _Plan(h, w, band)


class _Plan:
    """What depends only on the image shape and the band: window, band taper, frequencies."""

    def __init__(self, h: int, w: int, band: float) -> None:
        self.window = _hann(h, w)
        fy, fx = _frequencies(h, w)
        rho = np.sqrt((fy / 0.5) ** 2 + (fx / 0.5) ** 2)              # 1 = Nyquist
        weight = np.where(rho < band, np.cos(0.5 * np.pi * rho / band) ** 2, 0.0)
        self.keep = weight > 0
        self.weight = weight[self.keep].astype(np.float32)
        cols = np.arange(w // 2 + 1)
        multiplicity = np.where((cols == 0) | ((w % 2 == 0) & (cols == w // 2)), 1.0, 2.0)
        self.multiplicity = np.broadcast_to(multiplicity, weight.shape)[self.keep]
        self.wy = (2 * np.pi * np.broadcast_to(fy, weight.shape))[self.keep]
        self.wx = (2 * np.pi * np.broadcast_to(fx, weight.shape))[self.keep]
        self.shape = (h, w)
        self.band = band
        # A coarse grid for the integer peak: the band-limited surface needs no more samples than
        # its band, so the inverse FFT runs on a crop of the spectrum.
        ky, kx = int(math.ceil(band * h / 2)), int(math.ceil(band * w / 2))
        self.coarse = (min(h, sfft.next_fast_len(2 * ky + 3)), min(w, sfft.next_fast_len(2 * kx + 3)))
        rows = np.fft.fftfreq(h, 1.0 / h).astype(int)[:, None]           # integer frequencies of each row
        row_index = np.broadcast_to(rows % self.coarse[0], weight.shape)[self.keep]
        col_index = np.broadcast_to(np.arange(w // 2 + 1)[None, :], weight.shape)[self.keep]
        self.coarse_index = (row_index, col_index)
        self.coarse_scale = self.coarse[0] * self.coarse[1] / float(h * w)
        # Noise on the surface: its gradient's covariance per unit variance, over this band.
        nw = self.weight.astype(float) ** 2 * self.multiplicity
        self.grad_noise = np.array([[(nw * self.wy ** 2).sum(), (nw * self.wy * self.wx).sum()],
                                    [(nw * self.wy * self.wx).sum(), (nw * self.wx ** 2).sum()]]) / nw.sum()


class _Surface:
    """The band-limited correlation ``c(p)`` of one whitened cross-power spectrum, evaluated anywhere."""

    def __init__(self, plan: _Plan, r_band: np.ndarray) -> None:
        self.plan = plan
        self.r_band = r_band                                     # cross-power x weights, in-band entries
        h, w = plan.shape
        norm = plan.multiplicity / float(h * w)                  # the scale of irfft2 on the full grid
        self.a = r_band.real * norm
        self.b = r_band.imag * norm
        self.wy, self.wx = plan.wy, plan.wx

    def grid(self) -> np.ndarray:
        """The surface on the coarse grid (spacing h / coarse_h, w / coarse_w px), on the full grid's scale."""
        ch, cw = self.plan.coarse
        small = np.zeros((ch, cw // 2 + 1), np.complex64)
        small[self.plan.coarse_index] = self.r_band
        return sfft.irfft2(small, s=(ch, cw), workers=1) * self.plan.coarse_scale

    def derivatives(self, py: float, px: float) -> tuple[float, np.ndarray, np.ndarray]:
        phi = self.wy * py + self.wx * px
        c, s = np.cos(phi), np.sin(phi)
        val = self.a * c - self.b * s
        dval = -self.a * s - self.b * c
        grad = np.array([(dval * self.wy).sum(), (dval * self.wx).sum()])
        hyy, hyx, hxx = (-(val * self.wy * self.wy).sum(), -(val * self.wy * self.wx).sum(),
                         -(val * self.wx * self.wx).sum())
        return float(val.sum()), grad, np.array([[hyy, hyx], [hyx, hxx]])


def _refine(surface: _Surface, py: float, px: float, steps: int) -> tuple[float, float, float, np.ndarray]:
    """Newton's method on the continuous surface from the integer peak; (py, px, value, hessian)."""
    value, grad, hess = surface.derivatives(py, px)
    for _ in range(steps):
        try:
            step = np.linalg.solve(hess, grad)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.linalg.eigvalsh(hess) < 0) or np.abs(step).max() > 1.0:
            break                                   # not in the peak's concave core: keep the grid peak
        py, px = py - step[0], px - step[1]
        value, grad, hess = surface.derivatives(py, px)
        if np.abs(step).max() < 1e-6:
            break
    return py, px, value, hess


def _vertex(left: float, centre: float, right: float) -> float:
    """Offset of a parabola's vertex through three samples at -1, 0, 1 (0 when it is not a maximum)."""
    denom = left - 2 * centre + right
    return float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5)) if denom < 0 else 0.0


def _wrap_index(k: float, n: int) -> float:
    return k - n if k > n / 2 else k


# -- translation --------------------------------------------------------------------------------
def phase_correlate(fixed: np.ndarray, moving: np.ndarray, *, fixed_mask: np.ndarray | None = None,
                    moving_mask: np.ndarray | None = None, band: float = DEFAULT_BAND,
                    floor: float = DEFAULT_FLOOR, newton_steps: int = NEWTON_STEPS,
                    taper_px: float = 4.0, follow_window: bool = True,
                    shift_hint: tuple[float, float] | None = None, log_intensity: bool = True) -> Shift:
    """The shift (dx, dy) of ``moving`` relative to ``fixed`` (same shape), sub-pixel.

    Parameters
    ----------
    fixed, moving : (H, W) arrays (any real dtype; NaN / inf read as 0).
    fixed_mask, moving_mask : (H, W) bool, True where the pixel is valid (e.g. inside the fan).
    band : cross-power taper cut-off, fraction of Nyquist (0, 1]; lower is more robust to
        speckle, higher resolves finer texture.
    floor : whitening floor, fraction of the median cross-power magnitude in the band.
    newton_steps : sub-pixel refinement steps (0: the integer peak).
    follow_window : a second pass with each image's window over the content both share (at
        the first estimate): a window that stays put while the content moves pulls the peak
        towards zero (0.12 px at a shift of 3 % of the width on a clean texture; the bench's
        clean family goes from 0.048 to 0.0012 px, its speckled ones do not change), so it runs
        past ``FOLLOW_FRACTION`` of the size or with a hint, at twice the time.
    log_intensity : correlate the log of non-negative images (multiplicative speckle becomes
        additive; on the bench's tuning set the pooled median error drops from 0.150 to 0.128 px).
    shift_hint : (dx, dy) expected (navigation, the current estimate): the windows cover the
        expected overlap from the first pass, and of the circular correlation's aliases the
        one nearest the hint is kept -- what makes shifts of half an image and more work.

    A blank image (no variation), two that share nothing, or a periodic texture give a low
    ``pnr`` or a high ``ambiguity``: gate constraints on them (:func:`is_reliable`).
    """
    if np.ndim(fixed) != 2 or np.shape(fixed) != np.shape(moving):
        raise ValueError(f"two 2-D arrays of at least 8 x 8 and the same shape, got {np.shape(fixed)} "
                         f"and {np.shape(moving)}: images differ in shape" if np.shape(fixed) != np.shape(moving)
                         else f"an image is a 2-D array of at least 8 x 8, got shape {np.shape(fixed)}")
    if not 0 < band <= 1:
        raise ValueError("band is a fraction of Nyquist in (0, 1]")
    h, w = np.shape(fixed)
    plan = _plan(h, w, float(band))
    masks = (fixed_mask, moving_mask)
    if shift_hint is not None:
        if not (abs(shift_hint[0]) < w - 8 and abs(shift_hint[1]) < h - 8):
            return Shift(0.0, 0.0, 0.0, np.full((2, 2), np.inf), 0.0, 1.0)   # the hint says: no overlap
        windows = _overlap_windows(h, w, shift_hint[0], shift_hint[1])
        masks = _shared_masks(fixed_mask, moving_mask, shift_hint[0], shift_hint[1])
    else:
        windows = (plan.window, plan.window)
    first = _correlate(fixed, moving, *masks, plan, floor, newton_steps, taper_px, *windows, log_intensity)
    if first is None:
        return Shift(0.0, 0.0, 0.0, np.full((2, 2), np.inf), 0.0, 1.0)   # a blank image: nothing to correlate
    if shift_hint is not None:                # the circular correlation's alias nearest the hint
        first = _nearest_alias(first, shift_hint, h, w)
    result = first
    if follow_window and (shift_hint is not None or max(abs(first.dx) / w, abs(first.dy) / h) > FOLLOW_FRACTION):
        second = _correlate(fixed, moving, *_shared_masks(fixed_mask, moving_mask, first.dx, first.dy), plan, floor,
                            newton_steps, taper_px, *_overlap_windows(h, w, first.dx, first.dy), log_intensity)
        if second is not None:
            second = _nearest_alias(second, (first.dx, first.dy), h, w)
            if math.hypot(second.dx - first.dx, second.dy - first.dy) < 2.0:
                result = second
    overlap = _overlap(fixed_mask, moving_mask, result.dx, result.dy)
    return Shift(result.dx, result.dy, result.pnr, result.covariance, overlap, result.ambiguity)


def _overlap_windows(h: int, w: int, dx: float, dy: float) -> tuple[np.ndarray, np.ndarray]:
    """Hann windows over the part of each image the other also sees, when content moves by (dx, dy)."""
    def segment(n: int, shift: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(round(shift))
        k = max(-(n - 8), min(n - 8, k))
        span = n - abs(k)
        window = np.hanning(span).astype(np.float32)
        a, b = np.zeros(n, np.float32), np.zeros(n, np.float32)
        a[max(0, -k):max(0, -k) + span] = window                        # fixed: where content will still be seen
        b[max(0, k):max(0, k) + span] = window                          # moving: where it arrived
        return a, b

    ay, by = segment(h, dy)
    ax, bx = segment(w, dx)
    return np.outer(ay, ax), np.outer(by, bx)


def _shift_mask(mask: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``mask`` moved by the integer nearest (dx, dy), zero-filled."""
    kx, ky = int(round(dx)), int(round(dy))
    h, w = mask.shape
    out = np.zeros_like(mask)
    if abs(kx) < w and abs(ky) < h:
        out[max(0, ky):h + min(0, ky), max(0, kx):w + min(0, kx)] = \
            mask[max(0, -ky):h - max(0, ky), max(0, -kx):w - max(0, kx)]
    return out


def _shared_masks(fixed_mask: np.ndarray | None, moving_mask: np.ndarray | None, dx: float, dy: float
                  ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Each image's mask cut to what the other also sees at shift (dx, dy).

    A validity mask fixed to the sensor (a fan) sits at the same place in both images: its
    softened edges then correlate best at zero shift and pull the estimate there (0.9 px
    of 20 here). Cut to the shared part, the two supports move with the content instead.
    """
    if fixed_mask is None and moving_mask is None:
        return None, None
    shape = (fixed_mask if fixed_mask is not None else moving_mask).shape
    a = np.ones(shape, bool) if fixed_mask is None else np.asarray(fixed_mask, bool)
    b = np.ones(shape, bool) if moving_mask is None else np.asarray(moving_mask, bool)
    return a & _shift_mask(b, -dx, -dy), b & _shift_mask(a, dx, dy)


def _nearest_alias(shift: Shift, hint: tuple[float, float], h: int, w: int) -> Shift:
    dx = shift.dx + w * round((hint[0] - shift.dx) / w)
    dy = shift.dy + h * round((hint[1] - shift.dy) / h)
    return Shift(dx, dy, shift.pnr, shift.covariance, shift.overlap, shift.ambiguity)


def _correlate(fixed, moving, fixed_mask, moving_mask, plan: _Plan, floor: float, newton_steps: int,
               taper_px: float, window_f: np.ndarray, window_g: np.ndarray, log_intensity: bool = False) -> Shift | None:
    h, w = plan.shape
    band = plan.band
    f = _prepare(fixed, fixed_mask, taper_px, window_f, log_intensity)
    g = _prepare(moving, moving_mask, taper_px, window_g, log_intensity)
    cross = (np.conj(sfft.rfft2(f, workers=1)) * sfft.rfft2(g, workers=1))[plan.keep]
    magnitude = np.abs(cross)
    scale = float(np.median(magnitude)) if magnitude.size else 0.0
    if not np.isfinite(scale) or scale <= 0:
        return None
    surface = _Surface(plan, cross * (plan.weight / (magnitude + floor * scale)))
    grid = surface.grid()
    ch, cw = grid.shape
    iy, ix = np.unravel_index(int(np.argmax(grid)), grid.shape)
    sy, sx = h / ch, w / cw                       # coarse grid spacing (px)
    # A parabola through the neighbours, then Newton on the continuous surface.
    py = (_wrap_index(iy, ch) + _vertex(grid[(iy - 1) % ch, ix], grid[iy, ix], grid[(iy + 1) % ch, ix])) * sy
    px = (_wrap_index(ix, cw) + _vertex(grid[iy, (ix - 1) % cw], grid[iy, ix], grid[iy, (ix + 1) % cw])) * sx
    if newton_steps > 0:
        py, px, peak, hess = _refine(surface, py, px, newton_steps)
    else:
        peak, _, hess = surface.derivatives(py, px)
    # Noise: the surface's spread away from the peak's main lobe; ambiguity: the next peak's height.
    lobe_y, lobe_x = int(math.ceil(2.0 / max(band, 1e-3) / sy)), int(math.ceil(2.0 / max(band, 1e-3) / sx))
    rolled = np.roll(grid, (ch // 2 - iy, cw // 2 - ix), axis=(0, 1)).astype(np.float64)
    rolled[max(ch // 2 - lobe_y, 0):ch // 2 + lobe_y + 1, max(cw // 2 - lobe_x, 0):cw // 2 + lobe_x + 1] = np.nan
    mean, sigma = float(np.nanmean(rolled)), float(np.nanstd(rolled))
    pnr = float((peak - mean) / sigma) if sigma > 0 else 0.0
    ambiguity = float((np.nanmax(rolled) - mean) / (peak - mean)) if peak > mean else 1.0
    if _few_directions(plan, magnitude):
        ambiguity = 1.0                           # a periodic or one-directional texture: no unique shift
    return Shift(dx=px, dy=py, pnr=pnr, covariance=_covariance(plan, hess, sigma), overlap=1.0,
                 ambiguity=float(np.clip(ambiguity, 0.0, 1.0)))


def _few_directions(plan: _Plan, magnitude: np.ndarray, *, min_frequencies: float = 16.0,
                    min_isotropy: float = 0.01) -> bool:
    """True when the shared energy sits in a handful of frequencies (a periodic pattern: its
    shift is known only modulo the period) or along one direction (stripes: the shift along
    them is not observed at all, the aperture problem)."""
    m = magnitude * plan.multiplicity
    total = float(m.sum())
    if total <= 0:
        return True
    effective = total ** 2 / float((m * m).sum())                     # participation: how many frequencies carry it
    t = np.array([[(m * plan.wy * plan.wy).sum(), (m * plan.wy * plan.wx).sum()],
                  [(m * plan.wy * plan.wx).sum(), (m * plan.wx * plan.wx).sum()]])
    eig = np.linalg.eigvalsh(t)
    return bool(effective < min_frequencies or eig[0] < min_isotropy * eig[1])


def _covariance(plan: _Plan, hess: np.ndarray, sigma: float) -> np.ndarray:
    """(dx, dy) covariance: noise sigma on the surface moves the argmax by H^-1 grad(noise)."""
    if not np.isfinite(hess).all():
        return np.full((2, 2), np.inf)
    g = sigma ** 2 * plan.grad_noise               # gradient of band-limited noise of std sigma
    try:
        inv = np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        return np.full((2, 2), np.inf)
    cov_yx = inv @ g @ inv.T
    return cov_yx[::-1, ::-1].copy()                  # (dy, dx) -> (dx, dy)


def _overlap(fixed_mask: np.ndarray | None, moving_mask: np.ndarray | None, dx: float, dy: float) -> float:
    if fixed_mask is None and moving_mask is None:
        return 1.0
    shape = (fixed_mask if fixed_mask is not None else moving_mask).shape
    a = np.ones(shape, bool) if fixed_mask is None else np.asarray(fixed_mask, bool)
    b = np.ones(shape, bool) if moving_mask is None else np.asarray(moving_mask, bool)
    moved = warp(a.astype(np.float32), 0.0, dx, dy, interpolation=cv2.INTER_NEAREST) > 0.5
    smaller = min(int(a.sum()), int(b.sum()))
    return float((moved & b).sum() / smaller) if smaller else 0.0


def is_reliable(estimate: Shift | Registration, *, min_pnr: float = 8.0, min_overlap: float = 0.2,
                max_ambiguity: float = 0.6) -> bool:
    """The peak-to-noise gate of seed 08 section IV-E, plus shared area and a unique peak: a constraint or not."""
    return bool(estimate.pnr >= min_pnr and estimate.overlap >= min_overlap and estimate.ambiguity <= max_ambiguity
                and np.isfinite(estimate.covariance).all())


# -- rotation -----------------------------------------------------------------------------------
def polar_spectrum(image: np.ndarray, mask: np.ndarray | None = None, *, n_angles: int = 360, n_radii: int = 96,
                   radii: tuple[float, float] = (0.05, 0.4), taper_px: float = 4.0,
                   window: np.ndarray | None = None) -> np.ndarray:
    """(n_angles, n_radii) log magnitude spectrum on a polar grid: angles over [-90, 90) degrees,
    radii in ``radii`` x Nyquist. Translation-invariant; a rotation of the image shifts it along axis 0."""
    f = _prepare(image, mask, taper_px, window)
    h, w = f.shape
    spectrum = np.log1p(np.abs(sfft.rfft2(f, workers=1))).astype(np.float32)
    spectrum = np.fft.fftshift(spectrum, axes=0)                         # row h//2 is frequency 0
    theta = -0.5 * np.pi + np.pi * np.arange(n_angles) / n_angles
    rho = 0.5 * np.linspace(radii[0], radii[1], n_radii)                 # cycles per pixel
    # Frequency (fy, fx) = rho (sin t, cos t); the rows hold fy, the columns fx >= 0.
    fy = rho[None, :] * np.sin(theta)[:, None]
    fx = rho[None, :] * np.cos(theta)[:, None]
    map_x = (fx * w).astype(np.float32)
    map_y = (fy * h + h // 2).astype(np.float32)
    polar = cv2.remap(spectrum, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    polar -= polar.mean(axis=0, keepdims=True)                            # each radius: its own contrast
    return polar


def estimate_rotation(fixed: np.ndarray, moving: np.ndarray, *, fixed_mask: np.ndarray | None = None,
                      moving_mask: np.ndarray | None = None, n_angles: int = 720,
                      shift_hint: tuple[float, float] | None = None) -> tuple[float, float]:
    """``(angle, pnr)``: the rotation of ``moving`` relative to ``fixed``, modulo pi, in [-pi/2, pi/2).

    The magnitude spectrum ignores translation only for the same content: with a
    ``shift_hint`` both spectra are taken over the part the images share (their overlap
    windows), which is what makes partial overlaps (mosaics) work.
    """
    wf = wm = None
    if shift_hint is not None:
        wf, wm = _overlap_windows(*np.shape(fixed), shift_hint[0], shift_hint[1])
    pf = polar_spectrum(fixed, fixed_mask, n_angles=n_angles, window=wf)
    pm = polar_spectrum(moving, moving_mask, n_angles=n_angles, window=wm)
    # A turn of the content by +a turns its spectrum by +a; with y down and the angle
    # counter-clockwise as displayed, the spectrum's angle index moves by -a.
    ff, fm = np.fft.rfft(pf, axis=0), np.fft.rfft(pm, axis=0)
    cross = (np.conj(ff) * fm).sum(axis=1)
    cross /= np.abs(cross) + 1e-3 * np.abs(cross).max() + 1e-30
    k = np.arange(len(cross))
    band = np.cos(0.5 * np.pi * np.minimum(k / (0.5 * n_angles), 1.0)) ** 2
    corr = np.fft.irfft(cross * band, n=n_angles)
    i = int(np.argmax(corr))
    # Newton on the continuous 1-D surface.
    mult = np.where((k == 0) | (k == n_angles // 2), 1.0, 2.0) * band
    omega = 2 * np.pi * k / n_angles
    p = float(i)
    for _ in range(NEWTON_STEPS):
        phi = omega * p
        d1 = (mult * omega * (-cross.real * np.sin(phi) - cross.imag * np.cos(phi))).sum()
        d2 = (mult * omega ** 2 * (-cross.real * np.cos(phi) + cross.imag * np.sin(phi))).sum()
        if d2 >= 0:
            break
        step = d1 / d2
        if abs(step) > 1.0:
            break
        p -= step
    away = np.delete(corr, np.arange(i - 8, i + 9) % n_angles)
    pnr = float((corr[i] - away.mean()) / away.std()) if away.std() > 0 else 0.0
    shift = _wrap_index(p % n_angles, n_angles)
    angle = -shift * np.pi / n_angles
    return float((angle + 0.5 * np.pi) % np.pi - 0.5 * np.pi), pnr


def warp(image: np.ndarray, angle: float, dx: float, dy: float, *, interpolation: int = cv2.INTER_LINEAR,
         border_value: float = 0.0) -> np.ndarray:
    """Rotate ``image`` about its centre by ``angle`` (counter-clockwise as displayed), then shift by (dx, dy)."""
    h, w = image.shape[:2]
    m = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), math.degrees(angle), 1.0)
    m[0, 2] += dx
    m[1, 2] += dy
    return cv2.warpAffine(np.asarray(image, dtype=np.float32), m, (w, h), flags=interpolation,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=border_value)


def register(fixed: np.ndarray, moving: np.ndarray, *, fixed_mask: np.ndarray | None = None,
             moving_mask: np.ndarray | None = None, angle_hint: float | None = None,
             shift_hint: tuple[float, float] | None = None, angle_search: float = 0.0,
             band: float = DEFAULT_BAND, floor: float = DEFAULT_FLOOR) -> Registration:
    """Rotation and translation of ``moving`` relative to ``fixed``; see the module's conventions.

    The rotation comes from the polar spectrum (modulo pi) unless ``angle_hint`` is given
    (e.g. from a compass: then only the translation is estimated after de-rotating). Both
    ``angle`` and ``angle + pi`` are tried; the translation peak decides (the 180-degree
    ambiguity of a magnitude spectrum). ``shift_hint`` is the expected (dx, dy) in this
    function's convention (see :func:`phase_correlate`). With ``angle_search`` > 0 (rad) the
    angle is searched within ``angle_hint +- angle_search`` for the strongest translation
    peak: slower (about 15 correlations), and on partial overlaps far more accurate than
    the polar spectrum.
    """
    if angle_hint is not None and angle_search > 0:
        # A compass-grade hint, refined: the angle whose de-rotated translation peak is strongest.
        from scipy.optimize import minimize_scalar

        def negative_pnr(a: float) -> float:
            return -register(fixed, moving, fixed_mask=fixed_mask, moving_mask=moving_mask, angle_hint=a,
                             shift_hint=shift_hint, band=band, floor=floor).pnr

        found = minimize_scalar(negative_pnr, bounds=(angle_hint - angle_search, angle_hint + angle_search),
                                method="bounded", options={"xatol": math.radians(0.01)})
        best_reg = register(fixed, moving, fixed_mask=fixed_mask, moving_mask=moving_mask, angle_hint=float(found.x),
                            shift_hint=shift_hint, band=band, floor=floor)
        cov = best_reg.covariance.copy()
        cov[2, 2] = math.radians(0.05) ** 2
        return Registration(best_reg.angle, best_reg.dx, best_reg.dy, best_reg.pnr, cov, best_reg.overlap,
                            best_reg.ambiguity)
    if angle_hint is not None:
        candidates, rot_pnr = [angle_hint], math.inf
    else:
        base, rot_pnr = estimate_rotation(fixed, moving, fixed_mask=fixed_mask, moving_mask=moving_mask,
                                          shift_hint=shift_hint)
        candidates = [base, base + math.pi]
    best: tuple[Shift, float] | None = None
    for angle in candidates:
        # De-rotate the moving image about its centre: then moving' ~ fixed shifted by R(-a) t.
        back = warp(moving, -angle, 0.0, 0.0)
        back_mask = None
        if moving_mask is not None:
            back_mask = warp(np.asarray(moving_mask, np.float32), -angle, 0.0, 0.0) > 0.5
        elif angle != 0.0:
            back_mask = warp(np.ones(np.shape(moving), np.float32), -angle, 0.0, 0.0) > 0.5
        hint = None
        if shift_hint is not None:               # t = A s  =>  s = A^T t
            c, s_ = math.cos(angle), math.sin(angle)
            hint = (c * shift_hint[0] - s_ * shift_hint[1], s_ * shift_hint[0] + c * shift_hint[1])
        shift = phase_correlate(fixed, back, fixed_mask=fixed_mask, moving_mask=back_mask, band=band, floor=floor,
                                shift_hint=hint)
        if best is None or shift.pnr > best[0].pnr:
            best = (shift, angle)
    shift, angle = best  # type: ignore[misc]
    # warp(fixed, a, t): p' = A (p - c) + c + t with cv2's A = [[cos, sin], [-sin, cos]] (y down).
    # De-rotating moving by -a gives fixed shifted by s = A^T t, so t = A s.
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, s], [-s, c]])
    t = rot @ np.array([shift.dx, shift.dy])
    cov = np.zeros((3, 3))
    cov[:2, :2] = rot @ shift.covariance @ rot.T if np.isfinite(shift.covariance).all() else np.inf
    cov[2, 2] = (math.radians(0.5) / max(rot_pnr, 1.0)) ** 2 if math.isfinite(rot_pnr) else 0.0
    wrapped = (angle + math.pi) % (2 * math.pi) - math.pi
    return Registration(angle=wrapped, dx=float(t[0]), dy=float(t[1]), pnr=shift.pnr, covariance=cov,
                        overlap=shift.overlap, ambiguity=shift.ambiguity)
