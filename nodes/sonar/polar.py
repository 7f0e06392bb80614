"""Polar sonar ping -> Cartesian fan image through a lookup table cached per geometry (seed 01, eq. 1-6).

A ping is M ranges x N beams; row ``i`` is at range ``r_min + (i + 0.5) * dr`` (eq. 1, 3 with
0-based ``i``) and column ``j`` at the bearing the sonar reports for it (eq. 2, 4 assume a uniform
table; real Oculus tables are not uniform and may be descending, so we interpolate the table).
Each output pixel gets ``r = hypot(x, y)`` (eq. 5) and ``theta = arctan2(x, y)`` (eq. 6).

Frames: bearing 0 is straight ahead (+y in the image), positive to starboard (+x). Pixel
``(row, col)`` sits at ``x = (col - origin_col) * m_per_px``, ``y = (origin_row - row) * m_per_px``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

INTERPOLATIONS = ("nearest", "bilinear")
BACKENDS = ("numpy", "cv2")


@dataclass(frozen=True)
class FanGeometry:
    """Everything that fixes the polar -> Cartesian mapping of one ping.

    Attributes
    ----------
    n_ranges : int
        M, rows of the ping.
    range_resolution_m : float
        Radial size of one row (m).
    bearings_rad : tuple of float
        N beam bearings (rad), strictly ascending or strictly descending, |b| < pi.
    r_min_m : float
        Range of the near edge of row 0 (m).
    """

    n_ranges: int
    range_resolution_m: float
    bearings_rad: tuple[float, ...]
    r_min_m: float = 0.0

    def __post_init__(self) -> None:
        b = np.asarray(self.bearings_rad, dtype=float)
        if self.n_ranges < 1 or b.size < 2:
            raise ValueError(f"a fan needs >= 1 range and >= 2 beams, got {self.n_ranges} x {b.size}")
        if not (np.isfinite(self.range_resolution_m) and self.range_resolution_m > 0):
            raise ValueError(f"range_resolution_m must be finite and > 0, got {self.range_resolution_m}")
        if not (np.isfinite(self.r_min_m) and self.r_min_m >= 0):
            raise ValueError(f"r_min_m must be finite and >= 0, got {self.r_min_m}")
        if not np.all(np.isfinite(b)) or np.any(np.abs(b) >= np.pi):
            raise ValueError("bearings must be finite and inside (-pi, pi) rad; convert degrees to radians")
        d = np.diff(b)
        if not (np.all(d > 0) or np.all(d < 0)):
            raise ValueError("bearing table must be strictly ascending or strictly descending "
                             "(a shuffled or repeated table is a corrupt ping)")

    @classmethod
    def of(cls, intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
           r_min_m: float = 0.0) -> "FanGeometry":
        """Geometry of a ping given as arrays; checks that the bearing table matches the columns."""
        if intensities.ndim != 2:
            raise ValueError(f"intensities must be ranges x beams (2-D), got shape {intensities.shape}")
        if len(bearings_rad) != intensities.shape[1]:
            raise ValueError(f"{len(bearings_rad)} bearings for {intensities.shape[1]} beams; "
                             "the bearing table must have one entry per column")
        return cls(int(intensities.shape[0]), float(range_resolution_m),
                   tuple(float(v) for v in np.asarray(bearings_rad, dtype=float)), float(r_min_m))

    @property
    def r_max_m(self) -> float:
        return self.r_min_m + self.n_ranges * self.range_resolution_m

    @property
    def descending(self) -> bool:
        return self.bearings_rad[1] < self.bearings_rad[0]

    def sorted_bearings(self) -> np.ndarray:
        b = np.asarray(self.bearings_rad, dtype=float)
        return b[::-1].copy() if self.descending else b

    def edges_rad(self) -> tuple[float, float]:
        """Fan edges: half a beam spacing beyond the outermost beam centres (eq. 2 with j = 0.5, N + 0.5)."""
        b = self.sorted_bearings()
        lo = max(b[0] - 0.5 * (b[1] - b[0]), -np.pi)
        hi = min(b[-1] + 0.5 * (b[-1] - b[-2]), np.pi)
        return float(lo), float(hi)

    def bounding_box(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the fan sector (m)."""
        lo, hi = self.edges_rad()
        angles = [lo, hi] + [a for a in (-np.pi / 2, 0.0, np.pi / 2) if lo < a < hi]
        pts = [(r * np.sin(a), r * np.cos(a)) for a in angles for r in (self.r_min_m, self.r_max_m)]
        pts += [(self.r_min_m * np.sin(a), self.r_min_m * np.cos(a)) for a in (lo, hi)]
        xs, ys = zip(*pts)
        return min(xs), max(xs), min(ys), max(ys)


@dataclass(frozen=True)
class FanLut:
    """A cached mapping from fan pixels to fractional ping indices.

    ``mask`` (H x W uint8) is 1 inside the fan; ``row_f``/``col_f`` (H x W float32) are the
    fractional ping row and column of each pixel (-1 outside); ``nearest`` (H*W int32) flat
    indices into the ping padded with zeros (index M*N = outside). Bilinear tables and cv2 maps
    are derived on first use and kept with the table.
    """

    geometry: FanGeometry
    shape: tuple[int, int]
    m_per_px: float
    origin_row_px: float
    origin_col_px: float
    mask: np.ndarray
    row_f: np.ndarray
    col_f: np.ndarray
    nearest: np.ndarray
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def bilinear_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(inside, index00, w_row, w_col)`` over the fan's pixels only, built on first use."""
        if "idx" not in self._cache:
            m, n = self.geometry.n_ranges, len(self.geometry.bearings_rad)
            inside = np.flatnonzero(self.mask.ravel()).astype(np.int32)
            r = np.clip(self.row_f.ravel()[inside], 0, m - 1)
            c = np.clip(self.col_f.ravel()[inside], 0, n - 1)
            # One-row pings interpolate against the zero pad with weight 0.
            r0 = np.minimum(np.floor(r), max(m - 2, 0)).astype(np.int32)
            c0 = np.minimum(np.floor(c), n - 2).astype(np.int32)
            self._cache.update(inside=inside, idx=(r0 * n + c0).astype(np.int32),
                               wr=(r - r0).astype(np.float32), wc=(c - c0).astype(np.float32))
        b = self._cache
        return b["inside"], b["idx"], b["wr"], b["wc"]

    def cv2_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """``(map_col, map_row)`` for ``cv2.remap``: clamped inside the fan, far outside the ping elsewhere."""
        if "map_x" not in self._cache:
            m, n = self.geometry.n_ranges, len(self.geometry.bearings_rad)
            inside = self.mask > 0
            # -16 is beyond the bilinear footprint, so BORDER_CONSTANT gives exact zeros outside the fan.
            self._cache["map_x"] = np.where(inside, np.clip(self.col_f, 0, n - 1), -16).astype(np.float32)
            self._cache["map_y"] = np.where(inside, np.clip(self.row_f, 0, m - 1), -16).astype(np.float32)
        return self._cache["map_x"], self._cache["map_y"]


def build_lut(geometry: FanGeometry, *, width_px: int = 1024, height_px: int = 0) -> FanLut:
    """Build the pixel -> (row, column) table of a fan (eq. 5, 6, fan membership test).

    Parameters
    ----------
    geometry : FanGeometry
    width_px : int
        Output width in pixels.
    height_px : int
        Output height; 0 picks it from the fan's aspect ratio. The fan is scaled to fit and centred.

    Returns
    -------
    FanLut
    """
    if width_px < 2 or height_px < 0 or height_px == 1:
        raise ValueError(f"width_px must be >= 2 and height_px 0 (auto) or >= 2, got {width_px} x {height_px}")
    x0, x1, y0, y1 = geometry.bounding_box()
    if height_px == 0:
        height_px = max(2, int(round(width_px * (y1 - y0) / max(x1 - x0, 1e-12))))
    mpp = max((x1 - x0) / width_px, (y1 - y0) / height_px)
    # Centre the fan: pixel col's centre is at x = (col - origin_col) * mpp.
    origin_col = (width_px - 1) / 2.0 - 0.5 * (x0 + x1) / mpp
    origin_row = (height_px - 1) / 2.0 + 0.5 * (y0 + y1) / mpp
    x = ((np.arange(width_px, dtype=np.float64) - origin_col) * mpp)[None, :]
    y = ((origin_row - np.arange(height_px, dtype=np.float64)) * mpp)[:, None]
    r = np.hypot(x, y)
    # The paper's theta = arctan(y / x) loses the quadrant (x < 0 folds onto x > 0) and divides by
    # zero straight ahead; arctan2 with bearing measured from +y (ahead) towards +x (starboard) does not.
    theta = np.arctan2(x, y)
    lo, hi = geometry.edges_rad()
    inside = (r >= geometry.r_min_m) & (r <= geometry.r_max_m) & (theta >= lo) & (theta <= hi)
    row_f = (r - geometry.r_min_m) / geometry.range_resolution_m - 0.5
    col_f = _fractional_beam(theta, geometry)
    row_f = np.where(inside, row_f, -1.0).astype(np.float32)
    col_f = np.where(inside, col_f, -1.0).astype(np.float32)
    m, n = geometry.n_ranges, len(geometry.bearings_rad)
    ri = np.clip(np.rint(row_f), 0, m - 1).astype(np.int32)
    ci = np.clip(np.rint(col_f), 0, n - 1).astype(np.int32)
    nearest = np.where(inside, ri * n + ci, m * n).astype(np.int32).ravel()
    mask = inside.astype(np.uint8)
    for a in (mask, row_f, col_f, nearest):
        a.flags.writeable = False
    return FanLut(geometry, (height_px, width_px), float(mpp), float(origin_row), float(origin_col),
                  mask, row_f, col_f, nearest)


def _fractional_beam(theta: np.ndarray, geometry: FanGeometry) -> np.ndarray:
    """Fractional column of each bearing through the real (non-uniform) table; linear beyond the ends."""
    b = geometry.sorted_bearings()
    n = b.size
    k = np.interp(theta, b, np.arange(n, dtype=float))
    k = np.where(theta < b[0], (theta - b[0]) / (b[1] - b[0]), k)
    k = np.where(theta > b[-1], n - 1 + (theta - b[-1]) / (b[-1] - b[-2]), k)
    return (n - 1) - k if geometry.descending else k


def render_fan(intensities: np.ndarray, lut: FanLut, *, interpolation: str = "bilinear",
               backend: str = "numpy", out: np.ndarray | None = None) -> np.ndarray:
    """Cartesian fan image of one ping.

    Parameters
    ----------
    intensities : (M, N) array
        Ping, row 0 nearest the sonar; any real dtype (uint8/uint16/float).
    lut : FanLut
        From :func:`build_lut` for this ping's geometry.
    interpolation : {"nearest", "bilinear"}
    backend : {"numpy", "cv2"}
        ``cv2`` uses ``cv2.remap`` on the cached fractional indices (same geometry, same mask).
    out : (H, W) array of the ping's dtype, optional
        Where to write the image (a node's ``self.loan``: the fan then crosses to its subscribers
        without a copy); a fresh array when None.

    Returns
    -------
    (H, W) array, same dtype as ``intensities`` (``out`` when given); 0 outside the fan.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    m, n = lut.geometry.n_ranges, len(lut.geometry.bearings_rad)
    if intensities.shape != (m, n):
        raise ValueError(f"ping is {intensities.shape}, the lookup table was built for {(m, n)}; rebuild it")
    if out is not None and (out.shape != lut.shape or out.dtype != intensities.dtype):
        raise ValueError(f"out is {out.shape} {out.dtype}, the fan is {lut.shape} {intensities.dtype}")
    if backend == "cv2":
        return _render_cv2(intensities, lut, interpolation, out)
    padded = np.concatenate([intensities.ravel(), np.zeros(n + 2, intensities.dtype)])
    if interpolation == "nearest":
        if out is None:
            return padded.take(lut.nearest).reshape(lut.shape)
        padded.take(lut.nearest, out=out.reshape(-1))
        return out
    inside, idx, wr, wc = lut.bilinear_tables()
    a, b = padded.take(idx), padded.take(idx + 1)
    c, d = padded.take(idx + n), padded.take(idx + n + 1)
    top = a + wc * (b.astype(np.float32) - a)
    bottom = c + wc * (d.astype(np.float32) - c)
    bottom -= top
    bottom *= wr
    bottom += top
    flat = np.zeros(lut.shape[0] * lut.shape[1], intensities.dtype) if out is None else out.reshape(-1)
    if out is not None:
        flat[:] = 0
    flat[inside] = _cast_like(bottom, intensities.dtype)
    return flat.reshape(lut.shape) if out is None else out


def _render_cv2(intensities: np.ndarray, lut: FanLut, interpolation: str, out: np.ndarray | None = None) -> np.ndarray:
    src = intensities
    if src.dtype not in (np.uint8, np.uint16, np.int16, np.float32):
        src = src.astype(np.float32)
    flag = cv2.INTER_NEAREST if interpolation == "nearest" else cv2.INTER_LINEAR
    map_x, map_y = lut.cv2_maps()
    direct = out is not None and src.dtype == out.dtype
    image = cv2.remap(src, map_x, map_y, flag, dst=out if direct else None, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0)
    if direct:
        return out
    image = _cast_like(image, intensities.dtype)
    if out is None:
        return image
    out[...] = image
    return out


def _cast_like(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    if values.dtype == dtype:
        return values
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return np.clip(np.rint(values), info.min, info.max).astype(dtype)
    return values.astype(dtype, copy=False)


class FanRenderer:
    """Render pings, rebuilding the lookup table only when the geometry or output size changes."""

    def __init__(self, *, width_px: int = 1024, height_px: int = 0, interpolation: str = "bilinear",
                 backend: str = "numpy") -> None:
        if interpolation not in INTERPOLATIONS or backend not in BACKENDS:
            raise ValueError(f"interpolation in {INTERPOLATIONS} and backend in {BACKENDS}, "
                             f"got {interpolation!r}, {backend!r}")
        self.width_px, self.height_px = width_px, height_px
        self.interpolation, self.backend = interpolation, backend
        self.lut: FanLut | None = None
        self.builds = 0

    def render(self, intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
               r_min_m: float = 0.0, alloc: Callable[[tuple[int, ...], np.dtype], np.ndarray] | None = None,
               ) -> tuple[np.ndarray, FanLut]:
        """``(image, lut)`` for one ping; raises ``ValueError`` on an inconsistent ping.

        ``alloc(shape, dtype)`` gives the array to render into (a node passes its ``loan``)."""
        geometry = FanGeometry.of(intensities, bearings_rad, range_resolution_m, r_min_m)
        if self.lut is None or self.lut.geometry != geometry:
            self.lut = build_lut(geometry, width_px=self.width_px, height_px=self.height_px)
            self.builds += 1
        out = alloc(self.lut.shape, intensities.dtype) if alloc is not None else None
        return render_fan(intensities, self.lut, interpolation=self.interpolation, backend=self.backend,
                          out=out), self.lut
