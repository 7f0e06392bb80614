"""Carving's front end: one sonar ping -> each beam's free range, its bright range blocks, the returns
(range, bearing) and the voxel samples of their elevation arcs, which the carving grid (``nodes.sonar.carving``)
hits and votes with.

Returns are every beam's front end (``nodes.sonar.highlight.detect_front_ends``, in the region before
the seafloor's near edge ``r_emin``, eq. 8) and, with ``returns="all"``, every bright range block
behind it: brighter than ``return_level`` before ``r_emin``, than ``floor_level`` beyond it (a structure
standing out of the seafloor's own echo; the flat floor's 10 cm blocks stay below 0.5 of full scale
in the simulator). Beams without a front end carve up to ``r_emin`` (less a guard), or their whole
range when no seafloor is given; nothing is carved beyond ``r_emin``. The ping is first averaged
over range cells of at most 0.4 voxel (a fraction of the work; the front end still lands well inside
a voxel). A return's arc (``nodes.sonar.arcs``) is sampled every ``arc_step_m`` across the vertical
aperture, in float32. Frames: pings in the sonar FRD frame (x boresight, y starboard, z down), poses
sonar -> world 4x4, the grid in the world. Pure numpy/OpenCV.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from nodes.sonar.highlight import detect_front_ends, effective_region

if TYPE_CHECKING:                      # the grid's tuning; carving.py imports this module
    from nodes.sonar.carving import CarvingParams


@dataclass(frozen=True)
class RangeBlocks:
    """One ping's range blocks (every other beam): ``bright`` (B, N/2), ``near`` (bright or next to a bright
    one), block centres in rows, ``step`` rows per block, ``dr`` m per row."""

    bright: np.ndarray
    near: np.ndarray
    centre: np.ndarray
    step: int
    dr: float


@dataclass(frozen=True)
class PingReturns:
    """What one ping says: ``free_m`` (N,) range (m) each beam is empty to (its front end or the seafloor's near
    edge, less ``margin_m``); the returns' ``ranges_m`` and ``bearings_rad`` (K,), the first ``n_front`` the
    front ends (one per beam that has one); ``blocks`` its bright range blocks (None: no block fits)."""

    free_m: np.ndarray
    ranges_m: np.ndarray
    bearings_rad: np.ndarray
    n_front: int
    blocks: RangeBlocks | None


@dataclass(frozen=True)
class ArcSamples:
    """The samples of one ping's return arcs that fall in the grid: ``voxel`` (S,) int64 flat index, ``arc`` (S,)
    int32 return, ``phi`` (S,) float32 elevation (rad), ``range_m`` (S,) float32 the return's range; ``outside``:
    samples beyond the grid (dropped)."""

    voxel: np.ndarray
    arc: np.ndarray
    phi: np.ndarray
    range_m: np.ndarray
    outside: int


def extract_returns(intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
                    pose: np.ndarray, spread_rad: float, *, params: CarvingParams,
                    seafloor_z_m: float | None = None) -> PingReturns:
    """Free ranges, bright blocks and returns of one ping taken at ``pose``.

    Parameters
    ----------
    intensities : (M, N) array, ranges x beams (row i at (i + 0.5) * range_resolution_m).
    bearings_rad : (N,) ascending bearings (rad), positive to starboard.
    range_resolution_m : float, > 0.
    pose : (4, 4) sonar FRD -> world.
    spread_rad : vertical aperture s (rad).
    params : the grid's tuning (``voxel_m``, ``margin_m``, ``returns``, the detection and bright-block fields).
    seafloor_z_m : world height of a flat seafloor (m), or None (no seafloor: beams carve their whole range).
    """
    p = params
    pose, b, img = np.asarray(pose, float), np.asarray(bearings_rad, float), np.asarray(intensities)
    if img.ndim != 2 or img.shape[1] != b.size or b.size < 2 or img.shape[0] < 3:
        raise ValueError(f"need ranges x beams intensities with one bearing per beam, got {img.shape}, {b.size}")
    if not (np.all(np.isfinite(b)) and np.all(np.diff(b) > 0)):
        raise ValueError("bearings must be finite and ascending")
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError("pose must be a finite 4x4 sonar -> world transform")
    if not (range_resolution_m > 0 and 0 < spread_rad < np.pi):
        raise ValueError(f"need range_resolution_m > 0 and 0 < spread < pi, got {range_resolution_m}, {spread_rad}")
    img, dr, f = coarsen_ping(img, range_resolution_m, p.voxel_m)
    m_emin = seafloor_rows(b, img.shape[0], dr, pose, spread_rad, seafloor_z_m)
    rows, _ = detect_front_ends(img, m_emin, sigma_px=p.sigma_px / f, threshold=p.threshold,
                                guard_px=None if p.guard_px is None else p.guard_px / f,
                                sigma_beam_px=p.sigma_beam_px)
    detected = np.isfinite(rows)
    guard = (2.0 * p.sigma_px / f + 2.0) if p.guard_px is None else p.guard_px / f
    r_front = (rows + 0.5) * dr
    free = np.where(detected, r_front, (m_emin - guard) * dr) - p.margin_m
    blocks = bright_blocks(img, m_emin - guard, dr, return_step_m=p.return_step_m, return_level=p.return_level,
                           floor_level=p.floor_level)
    r_hit, b_hit = r_front[detected], b[detected]
    if p.returns == "all":
        more_r, more_b = block_returns(blocks, b, rows)
        r_hit, b_hit = np.concatenate([r_hit, more_r]), np.concatenate([b_hit, more_b])
    return PingReturns(free, r_hit, b_hit, int(detected.sum()), blocks)


def coarsen_ping(img: np.ndarray, dr: float, voxel_m: float) -> tuple[np.ndarray, float, int]:
    """The ping averaged over ``f`` range cells, the coarsest that keeps cells <= 0.4 voxel (the front end is
    still placed to a fraction of a voxel, at a fraction of the work); floats with NaN/inf made finite
    (no data is dark). Returns the ping, its range resolution (m) and ``f``."""
    if img.dtype.kind == "f":
        img = np.nan_to_num(img.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    f = int(max(1, min(np.floor(0.4 * voxel_m / dr), img.shape[0] // 3)))
    if f == 1:
        return img, dr, 1
    m = img.shape[0] // f * f
    if f == 2:                       # the usual case (2 cm cells, 10 cm voxels): one pass over strided rows
        small = cv2.addWeighted(img[0:m:2], 0.5, img[1:m:2], 0.5, 0.0)
    else:
        small = img[:m].reshape(m // f, f, -1).mean(axis=1, dtype=np.float32)
        small = np.rint(small).astype(img.dtype) if img.dtype.kind in "ui" else small
    return small, dr * f, f


def seafloor_rows(bearings: np.ndarray, m: int, dr: float, pose: np.ndarray, spread: float,
                  seafloor_z_m: float | None) -> np.ndarray:
    """Fractional row of each beam's seafloor near edge (eq. 8-9) in a ping of ``m`` rows of ``dr`` m; all
    rows without a seafloor."""
    if seafloor_z_m is None:
        return np.full(bearings.size, float(m))
    rot, origin = pose[:3, :3], pose[:3, 3]
    altitude = float(origin[2] - seafloor_z_m)
    if not altitude > 0:
        raise ValueError(f"the sonar is not above the seafloor (altitude {altitude:.2f} m)")
    down = rot.T @ np.array([0.0, 0.0, -1.0])
    return effective_region(bearings, altitude, spread, tilt_rad=float(np.arcsin(np.clip(down[0], -1, 1))),
                            n_ranges=m, range_resolution_m=dr, down_frd=down).m_emin


def bright_blocks(img: np.ndarray, limit_rows: np.ndarray, dr: float, *, return_step_m: float, return_level: float,
                  floor_level: float) -> RangeBlocks | None:
    """Bright range blocks of every other beam of a finite ping (:func:`coarsen_ping`): block mean above
    ``return_level`` before ``limit_rows`` (the seafloor's near edge), above ``floor_level`` beyond it (over the
    seafloor's echo; >= 1: no blocks there)."""
    step = max(1, int(round(return_step_m / dr)))
    k = (img.shape[0] if floor_level < 1 else
         int(min(img.shape[0], max(float(np.nanmax(limit_rows, initial=0.0)), 0.0)))) // step * step
    if k < step:
        return None
    full = float(np.iinfo(img.dtype).max) if img.dtype.kind in "ui" else 1.0
    # the mean over each block (its speckle averaged, as a blur would), every other beam: neighbours lie a
    # few cm apart, well inside a voxel
    cols = img[:k, ::2]
    block = cols.reshape(k // step, step, cols.shape[1]).mean(axis=1, dtype=np.float32) * np.float32(1.0 / full)
    centre = (np.arange(k // step) + 0.5) * step
    level = np.where(centre[:, None] < limit_rows[::2][None, :], np.float32(return_level), np.float32(floor_level))
    bright = block > level
    # a voxel spans a few beams and range blocks: dark only where no neighbouring block is bright
    near = cv2.dilate(bright.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    return RangeBlocks(bright, near, centre, step, dr)


def block_returns(blocks: RangeBlocks | None, bearings: np.ndarray, front_rows: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (m) and bearings (rad) of the bright range blocks behind each beam's front end (row; NaN: none)."""
    if blocks is None:
        return np.zeros(0), np.zeros(0)
    front = np.where(np.isfinite(front_rows), front_rows, np.inf)[::2]
    blk, beam = np.nonzero(blocks.bright & (blocks.centre[:, None] > front[None, :] + blocks.step))
    return blocks.centre[blk] * blocks.dr, bearings[::2][beam]


def sample_arcs(ranges_m: np.ndarray, bearings_rad: np.ndarray, pose: np.ndarray, half_spread_rad: float, *,
                grid_origin_m: np.ndarray, shape: tuple[int, ...], voxel_m: float, step_m: float) -> ArcSamples:
    """Voxels of a grid (corner ``grid_origin_m``, ``shape`` voxels of ``voxel_m``, flat C order) under each
    return's elevation arc, sampled every ``step_m`` or less (at least both aperture edges) from -s/2 to s/2.

    ``ranges_m``, ``bearings_rad`` (K,): the returns; ``pose`` (4, 4) sonar FRD -> world.
    """
    rot, origin = pose[:3, :3], pose[:3, 3]
    half = half_spread_rad
    per_arc = np.maximum(2, np.ceil(2 * half * ranges_m / step_m).astype(np.int64) + 1)
    arc = np.repeat(np.arange(ranges_m.size), per_arc)
    start = np.cumsum(per_arc) - per_arc
    phi = (-half + (np.arange(arc.size) - start[arc]) * (2 * half / (per_arc - 1))[arc]).astype(np.float32)
    r = ranges_m.astype(np.float32)[arc]
    along, across = r * np.cos(phi), r * np.sin(phi)       # along the beam's horizontal direction, along z
    axes = rot.astype(np.float32)                          # columns: the sonar's x, y, z in the world
    beam_dir = axes[:, :2] @ np.stack([np.cos(bearings_rad), np.sin(bearings_rad)]).astype(np.float32)  # (3, K)
    rel = (origin - grid_origin_m) * (1.0 / voxel_m)
    flat = np.zeros(arc.size, np.int32)
    ok = np.ones(arc.size, bool)
    for axis, n in enumerate(shape):              # world = origin + along * beam_dir + across * z of the sonar
        i = np.floor((along * beam_dir[axis][arc] + across * axes[axis, 2]) * np.float32(1.0 / voxel_m)
                     + np.float32(rel[axis])).astype(np.int32)
        ok &= (i >= 0) & (i < n)
        flat = flat * np.int32(n) + i
    return ArcSamples(flat[ok].astype(np.int64), arc[ok].astype(np.int32), phi[ok], r[ok], int((~ok).sum()))
