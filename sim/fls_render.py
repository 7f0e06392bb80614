"""FLS image formation: one ping's polar intensities and true first hits for a given sonar pose (pure numpy).

``render_ping(scene, pose, settings, rng=...)`` casts rays over azimuth (one per beam of a real,
non-uniform bearing table) x elevation (``elevation_rays`` across the vertical aperture), keeps the
first hit of each (so shadows follow), gives each hit an echo ``reflectivity x |cos incidence| x
vertical beam pattern x two-way absorption``, and spreads it over the range bins of its beam:
between two neighbouring elevation rays on the same surface the echo is spread uniformly over the
range interval they span (a grazing seafloor fills many bins, a wall few); an isolated hit (an
edge) fills ``point_extent_m``. Then speckle (exponential intensity), a noise floor, the gain,
the gamma and 8/16-bit quantisation, as the sonar's image. With ``row_gain_db_per_m`` the device
also amplifies each range row by its own gain (a time-varying gain, 0 dB at mid-range) and reports
it (``row_gains``), as an Oculus does with the per-row gain flag.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.fls_scene import Scene, cast_rays

_TABLE_WARP_RAD = np.radians(30.0)
_FIXED = float(2 ** 30)


def bearing_table(n_beams: int, aperture_rad: float) -> np.ndarray:
    """Beam bearings (n_beams,) int16 in 0.01 deg, ascending, symmetric, denser at the centre.

    The shape is that of the real M1200d table (uniform in sine: 0.22 deg/beam at the centre and
    0.26 at the edges over +-30 deg), stretched to ``aperture_rad``.
    """
    if n_beams < 2 or not 0 < aperture_rad < np.pi:
        raise ValueError(f"need n_beams >= 2 and 0 < aperture < pi rad, got {n_beams}, {aperture_rad}")
    u = np.linspace(-1.0, 1.0, n_beams)
    theta = np.arcsin(u * np.sin(_TABLE_WARP_RAD)) / _TABLE_WARP_RAD * (aperture_rad / 2)
    return np.round(np.degrees(theta) * 100).astype(np.int16)


@dataclass(frozen=True)
class PingSettings:
    """What a SimpleFire asks for (plus the simulator's ray count)."""

    n_beams: int = 512
    range_m: float = 20.0
    frequency: str = "low"
    gain_percent: float = 50.0         # +-20 dB around 50 %
    gamma: float = 0.5
    bits: int = 8
    n_ranges: int = 0                  # 0: range / min_resolution, capped at the scene's max_ranges
    elevation_rays: int = 0            # 0: the scene's
    point_extent_m: float = 0.05
    row_gain_db_per_m: float = 0.0     # per-row gain slope (intensity dB per metre of range, 0 dB at mid-range)


@dataclass(frozen=True)
class RenderedPing:
    """One simulated ping.

    Attributes
    ----------
    intensities : (R, B) uint8 or uint16, row i at range (i + 0.5) * range_resolution_m.
    level : (R, B) float32, the noise-free echo level (full scale = 1) before gain and gamma.
    bearings_cdeg : (B,) int16 (0.01 deg); bearings_rad : (B,) float64 of the same.
    range_resolution_m, range_m, frequency_hz, vertical_aperture_rad, horizontal_aperture_rad.
    hits_m : (K, 3) world coordinates of the first hits inside the range (K <= rays).
    hit_ranges_m, hit_bearings_rad, hit_elevations_rad (positive down), hit_echo : (K,).
    hit_labels : (K,) int, 0 = seafloor, k = scene.structures[k - 1].
    row_gains : (R,) linear gain each row was amplified by before gamma and quantisation.
    """

    intensities: np.ndarray
    level: np.ndarray
    bearings_cdeg: np.ndarray
    bearings_rad: np.ndarray
    range_resolution_m: float
    range_m: float
    frequency_hz: float
    vertical_aperture_rad: float
    horizontal_aperture_rad: float
    hits_m: np.ndarray
    hit_ranges_m: np.ndarray
    hit_bearings_rad: np.ndarray
    hit_elevations_rad: np.ndarray
    hit_echo: np.ndarray
    hit_labels: np.ndarray
    row_gains: np.ndarray | None = None    # (R,) linear gain applied to each row (ones without a slope)


def _intervals(t: np.ndarray, echo: np.ndarray, labels: np.ndarray, valid: np.ndarray, ext: float):
    """Range intervals (lo, hi, energy, column) from the (E, B) ray grid (see the module docstring)."""
    half = 0.5 * echo
    cont = valid[:-1] & valid[1:] & (labels[:-1] == labels[1:])
    cols = np.broadcast_to(np.arange(t.shape[1]), t.shape)
    lo = [np.minimum(t[:-1], t[1:])[cont]]
    hi = [np.maximum(t[:-1], t[1:])[cont]]
    w = [(half[:-1] + half[1:])[cont]]
    c = [cols[:-1][cont]]
    alone = np.zeros_like(half)                       # half-energies not shared with a neighbour
    alone[:-1] += np.where(valid[:-1] & ~cont, half[:-1], 0.0)
    alone[1:] += np.where(valid[1:] & ~cont, half[1:], 0.0)
    alone[0] += np.where(valid[0], half[0], 0.0)
    alone[-1] += np.where(valid[-1], half[-1], 0.0)
    pts = alone > 0
    lo.append(t[pts] - ext / 2)
    hi.append(t[pts] + ext / 2)
    w.append(alone[pts])
    c.append(cols[pts])
    return (np.concatenate(lo), np.concatenate(hi), np.concatenate(w), np.concatenate(c))


_CAST_BEYOND = 3.0     # rays are cast to this multiple of the maximum range (see render_ping)


def _accumulate(lo, hi, w, col, n_ranges: int, n_beams: int, res: float) -> np.ndarray:
    """Mean echo per metre of range over each (bin, beam): each interval's energy spread evenly along it.

    Exact bin coverage: whole bins inside an interval get its density, the two end bins the
    covered fraction of it (so the level does not depend on the bin size or the ray count).
    """
    lo = np.maximum(lo, 0.0)
    hi = np.maximum(hi, lo + 1e-6)
    density = w / (hi - lo)
    i0, i1 = (lo / res).astype(np.int64), (hi / res).astype(np.int64)
    rows = n_ranges + 2                               # room past the last bin; cropped below
    i0, i1 = np.minimum(i0, rows - 2), np.minimum(i1, rows - 2)
    same = i0 == i1
    first = np.where(same, w / res, density * ((i0 + 1) * res - lo) / res)   # end bins: covered fraction
    last = np.where(same, 0.0, density * (hi - i1 * res) / res)
    inner = np.where(i1 - i0 >= 2, density, 0.0)                              # whole bins i0+1 .. i1-1
    # one difference array: a value v over bins a..b is +v at a, -v at b+1; a cumulative sum restores it
    idx = np.concatenate([i0, i0 + 1, i1, i1 + 1, i0 + 1, np.maximum(i1, i0 + 1)]) * n_beams + np.tile(col, 6)
    # in units of 2^-30, so every partial sum is an exact float64 integer: no round-off left in the shadows
    val = np.rint(np.concatenate([first, -first, last, -last, inner, -inner]) * _FIXED)
    out = np.bincount(idx, val, (rows + 1) * n_beams).reshape(rows + 1, n_beams)
    for i in range(1, rows):                          # row loop: 3x faster than cumsum(axis=0) here
        np.add(out[i - 1], out[i], out=out[i])
    return (out[:n_ranges] * (1.0 / _FIXED)).astype(np.float32)


def render_ping(scene: Scene, pose: np.ndarray, settings: PingSettings = PingSettings(), *,
                rng: np.random.Generator | None = None) -> RenderedPing:
    """Simulate one ping of ``scene.sonar`` at ``pose``.

    Parameters
    ----------
    scene : from :func:`sim.fls_scene.load_scene`.
    pose : (4, 4) sonar (FRD head: x boresight, y starboard, z down) -> world transform, metres.
    settings : beams, range, frequency, gain, gamma, bits (what the fire request asks).
    rng : speckle and noise source; ``None`` renders the noise-free image (no speckle, no floor).
    """
    mode = scene.sonar.modes[settings.frequency]
    range_m = min(float(settings.range_m), mode["max_range_m"])
    if range_m <= 0 or settings.bits not in (8, 16) or settings.n_beams < 2:
        raise ValueError(f"need range_m > 0, bits 8 or 16, n_beams >= 2; got {settings}")
    sonar = scene.sonar
    n_ranges = settings.n_ranges or int(min(sonar.max_ranges, np.ceil(range_m / sonar.min_resolution_m)))
    res = range_m / n_ranges
    vert = np.radians(mode["vertical_aperture_deg"])
    cdeg = bearing_table(settings.n_beams, np.radians(mode["horizontal_aperture_deg"]))
    theta = np.radians(cdeg / 100.0)
    n_el = settings.elevation_rays or sonar.elevation_rays
    phi = np.linspace(-vert / 2, vert / 2, n_el)
    d_head = np.stack(np.broadcast_arrays(np.cos(phi)[:, None] * np.cos(theta), np.cos(phi)[:, None] * np.sin(theta),
                                          np.sin(phi)[:, None]), axis=-1)                      # (E, B, 3)
    rot, origin = np.asarray(pose, float)[:3, :3], np.asarray(pose, float)[:3, 3]
    dirs = d_head.reshape(-1, 3) @ rot.T
    # Cast past the maximum range: the echo between the last ray inside it and the first ray beyond is
    # spread over its interval and clipped at the edge by _accumulate, instead of being lost (which left
    # the fan's far edge stair-stepped at the elevation-ray spacing). Ground truth keeps in-range hits only.
    t, normals, labels = cast_rays(scene, origin, dirs, max_range_m=_CAST_BEYOND * range_m)
    hit = np.isfinite(t)
    valid = hit & (t < range_m)
    refl = np.array([s.reflectivity if s is not None else 0.0 for s in scene.surfaces()] + [0.0])
    cos_inc = np.abs(np.einsum("ij,ij->i", normals, dirs))
    pattern = np.repeat(2.0 ** (-(2 * phi / vert) ** 2), settings.n_beams)       # -3 dB at the aperture edges
    absorb = 10.0 ** (-2 * mode["absorption_db_per_m"] * np.where(hit, t, 0.0) / 10)
    refl_hit = refl[labels]
    floor = scene.seafloor
    if floor is not None and getattr(floor, "texture", None) is not None:
        on_floor = hit & (labels == 0)                # a textured seabed: reflectivity where each ray lands
        points = origin + t[on_floor, None] * dirs[on_floor]
        refl_hit = refl_hit.copy()
        refl_hit[on_floor] = floor.reflectivity_at(points[:, 0], points[:, 1])
    echo = np.where(hit, refl_hit * cos_inc * pattern * absorb * (vert / max(n_el - 1, 1)), 0.0)
    shape = (n_el, settings.n_beams)
    tt = np.where(hit, t, 0.0).reshape(shape)
    lo, hi, w, col = _intervals(tt, echo.reshape(shape), labels.reshape(shape), hit.reshape(shape),
                                settings.point_extent_m)
    level = _accumulate(lo, hi, w, col, n_ranges, settings.n_beams, res) * np.float32(sonar.level_scale)
    gain = np.float32(10.0 ** (0.4 * (settings.gain_percent - 50.0) / 10.0))
    noisy = level
    if rng is not None:
        # one exponential draw serves both: the noise floor reads it reversed (independent but for one pixel)
        e = rng.standard_exponential(level.shape, np.float32)
        noisy = level * ((1 - sonar.speckle) + sonar.speckle * e) + np.float32(sonar.noise_floor) * e[::-1, ::-1]
    full = 255 if settings.bits == 8 else 65535
    row_r = (np.arange(n_ranges) + 0.5) * res
    row_gains = (10.0 ** (settings.row_gain_db_per_m * (row_r - range_m / 2) / 10.0)).astype(np.float32)
    if not np.all(np.isfinite(row_gains)) or not np.all(row_gains > 0):
        raise ValueError(f"row_gain_db_per_m {settings.row_gain_db_per_m} gives non-finite gains over {range_m} m")
    out = np.clip(noisy * gain * row_gains[:, None], 0, 1)
    out = (np.sqrt(out) if settings.gamma == 0.5 else out ** np.float32(settings.gamma)) * np.float32(full)
    intensities = np.rint(out).astype(np.uint8 if settings.bits == 8 else np.uint16)
    el_of_ray = np.repeat(phi, settings.n_beams)
    az_of_ray = np.tile(theta, n_el)
    return RenderedPing(intensities=intensities, level=level, bearings_cdeg=cdeg, bearings_rad=theta,
                        range_resolution_m=res, range_m=range_m, frequency_hz=mode["frequency_hz"],
                        vertical_aperture_rad=float(vert),
                        horizontal_aperture_rad=float(np.radians(mode["horizontal_aperture_deg"])),
                        hits_m=origin + t[valid, None] * dirs[valid], hit_ranges_m=t[valid],
                        hit_bearings_rad=az_of_ray[valid], hit_elevations_rad=el_of_ray[valid],
                        hit_echo=echo[valid], hit_labels=labels[valid], row_gains=row_gains)
