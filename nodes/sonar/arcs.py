"""Elevation arcs: what a forward-looking sonar's line scan really measures (range and bearing, not elevation).

A highlight front end at range ``r`` in the beam at bearing ``theta`` is a return from *somewhere*
on the arc of elevations across the vertical aperture, ``r * (cos phi cos theta, cos phi sin theta,
sin phi)`` for ``phi`` in ``[-s/2, s/2]`` (sonar FRD frame, elevation positive down). Eq. (13)
places it on the lower edge (``phi = s/2``); for a vertical pylon the first return comes from the
upper edge instead, and for a sloping leg from anywhere in between. Registering arcs instead of
points (``nodes.sonar.icp.align`` with (N, K, 3) samples) needs no elevation guess at all.

The line scans of ``nodes.sonar.highlight`` (``model="beam"``) put each point on the lower edge,
so a scan point ``p`` gives back ``r = |p|``, ``theta = atan2(p_y, p_x)`` and ``s/2 = asin(p_z / r)``.
"""
from __future__ import annotations

import numpy as np


def arc_samples(ranges_m: np.ndarray, bearings_rad: np.ndarray, half_spread_rad: np.ndarray | float,
                samples: int) -> np.ndarray:
    """(N, K, 3) sonar-FRD points at ``K = samples`` elevations from the upper to the lower aperture edge.

    Parameters
    ----------
    ranges_m, bearings_rad : (N,) arrays
    half_spread_rad : float or (N,) array
        s/2, the lower edge's elevation below the boresight plane (rad, > 0).
    samples : int
        K >= 2 (K = 1 gives the lower-edge point itself, the paper's eq. 13-17).
    """
    if samples < 1:
        raise ValueError(f"samples must be >= 1 (K elevations per arc), got {samples}")
    r = np.asarray(ranges_m, float)[:, None]
    b = np.asarray(bearings_rad, float)[:, None]
    e = np.broadcast_to(np.asarray(half_spread_rad, float), r.shape[:1])[:, None]
    phi = e * (np.linspace(-1.0, 1.0, samples)[None, :] if samples > 1 else np.ones((1, 1)))
    return r[..., None] * np.stack([np.cos(phi) * np.cos(b), np.cos(phi) * np.sin(b), np.sin(phi)], axis=-1)


def arcs_from_scan(points_frd: np.ndarray, pose: np.ndarray, samples: int, *,
                   spread_rad: float = 0.0) -> np.ndarray:
    """World-frame arc samples (N, K, 3) of one line scan.

    Parameters
    ----------
    points_frd : (N, 3) array
        The scan's lower-edge points in the sonar frame (``HighlightCloud`` output ``scan``, FRD).
    pose : (4, 4) array
        Sonar (FRD) -> world transform the scan was taken at (metres).
    samples : int
        Elevations per arc.
    spread_rad : float
        Vertical aperture s; 0 reads s/2 from each point's own elevation (beam model).
    """
    p = np.asarray(points_frd, float).reshape(-1, 3)
    t = np.asarray(pose, float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise ValueError("pose must be a finite 4x4 sonar -> world transform")
    p = p[np.all(np.isfinite(p), axis=1)]
    r = np.linalg.norm(p, axis=1)
    p, r = p[r > 0], r[r > 0]
    half = 0.5 * spread_rad if spread_rad > 0 else np.arcsin(np.clip(p[:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
    local = arc_samples(r, np.arctan2(p[:, 1], p[:, 0]), half, samples)
    return local @ t[:3, :3].T + t[:3, 3]
