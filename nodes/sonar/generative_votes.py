"""Generative elevations voted over many pings, free space from carving deciding between hypotheses.

Each ping's runs (:func:`nodes.sonar.generative.surface_elevations`) give two surfaces, one per leading
edge (the aperture's top or bottom). One view cannot tell them apart; later views can: once
``settle_pings`` later pings have carved (:class:`nodes.sonar.carving.CarvingGrid`), a run hypothesis
whose points fall in voxels that some ping saw empty (a miss, or more than ``max_darks`` darks) in more
than ``max_contradiction`` of its points is dropped, and the points of the others vote for their voxels
(points with elevation 1-sigma above ``max_sigma_m`` do not vote, nor points within ``floor_margin_m``
of a flat seafloor). The cloud is the voxels with at least ``min_votes`` votes that no ping has emptied
since, each with the RMS of its voters' sigma (m, along the elevation arc) and its votes.

The two share the grid's voxels and bounds: this adds two arrays over the grid (votes, summed sigma^2).
Frames: pings sonar FRD, poses sonar -> world 4x4, cloud in the world.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from nodes.sonar.carving import CarvingGrid
from nodes.sonar.carving_arcs import seafloor_rows
from nodes.sonar.generative import GenerativeParams, surface_elevations


@dataclass(frozen=True)
class GenerativeCloud:
    """Voxels the generative elevations voted for: ``points_m`` (K, 3) world centres, ``sigma_m`` (K,) RMS
    elevation 1-sigma of their voters (m), ``votes`` (K,)."""

    points_m: np.ndarray
    sigma_m: np.ndarray
    votes: np.ndarray


class GenerativeVotes:
    """Votes of the generative elevations of every ping, checked against ``grid``'s free space."""

    def __init__(self, grid: CarvingGrid, params: GenerativeParams = GenerativeParams(), *, settle_pings: int = 50,
                 max_contradiction: float = 0.1, max_darks: int = 1, max_sigma_m: float = 0.4, min_votes: int = 8,
                 floor_margin_m: float = 0.15) -> None:
        if not (settle_pings >= 0 and 0 <= max_contradiction <= 1 and max_darks >= 0 and max_sigma_m > 0
                and min_votes >= 1 and floor_margin_m >= 0):
            raise ValueError("need settle_pings >= 0, 0 <= max_contradiction <= 1, max_darks >= 0, max_sigma_m > 0, "
                             "min_votes >= 1 and floor_margin_m >= 0")
        self.grid, self.params = grid, params
        self.settle_pings, self.max_contradiction, self.max_darks = settle_pings, max_contradiction, max_darks
        self.max_sigma_m, self.min_votes, self.floor_margin_m = max_sigma_m, min_votes, floor_margin_m
        n = int(np.prod(grid.shape))
        self.votes = np.zeros(n, np.uint16)
        self.sigma2 = np.zeros(n, np.float32)
        self._pending: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque()
        self.pings = 0

    def integrate(self, intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
                  pose: np.ndarray, spread_rad: float, *, gain: float = 1.0, gamma: float | None = None,
                  row_gains: np.ndarray | None = None) -> int:
        """Add one ping's generative points (taken at ``pose``); returns how many fell in the grid. Call it after
        ``grid.integrate`` with the same ping (so the grid has carved with it); ``gamma`` the ping's, when it is
        not the params'; ``row_gains`` the device's per-row gains, ``intensities`` then raw (not compensated: see
        :func:`nodes.sonar.generative.censored_level`)."""
        img = np.asarray(intensities)
        bearings = np.asarray(bearings_rad, float)
        pose = np.asarray(pose, float)
        g = self.grid
        floor = None
        if g.seafloor_z_m is not None:      # the seafloor's echo past its near edge is not the structure's slope
            floor = seafloor_rows(bearings, img.shape[0], range_resolution_m, pose, spread_rad, g.seafloor_z_m)
        params = self.params if gamma is None or gamma == self.params.gamma else replace(self.params, gamma=gamma)
        s = surface_elevations(img, bearings, range_resolution_m, spread_rad, params=params, floor_rows=floor,
                               gain=gain, row_gains=row_gains)
        world = s.points_frd() @ pose[:3, :3].T + pose[:3, 3]
        cell = np.floor((world - g.origin) / g.params.voxel_m).astype(np.int64)
        ok = np.all((cell >= 0) & (cell < np.array(g.shape)), axis=1) & ~s.saturated
        sigma = s.sigma_m()
        if g.seafloor_z_m is not None:
            ok &= world[:, 2] > g.seafloor_z_m + self.floor_margin_m
        voxel = np.full(len(world), -1, np.int64)
        voxel[ok] = np.ravel_multi_index(cell[ok].T, g.shape)
        key = s.run * 2 + s.top                         # one run hypothesis
        self._pending.append((voxel, key, np.where(sigma <= self.max_sigma_m, sigma, np.inf).astype(np.float32)))
        self.pings += 1
        while len(self._pending) > self.settle_pings:
            self._vote(*self._pending.popleft())
        return int(ok.sum())

    def _vote(self, voxel: np.ndarray, key: np.ndarray, sigma: np.ndarray) -> None:
        """Drop the run hypotheses free space contradicts; the others' points vote."""
        if voxel.size == 0:
            return
        inside = voxel >= 0
        bad = ~inside
        v = voxel[inside]
        bad[inside] = (self.grid.misses[v] > 0) | (self.grid.darks[v] > self.max_darks)
        frac = np.bincount(key, bad) / np.maximum(np.bincount(key), 1)   # keys are small: run id x 2 + top
        good = (frac[key] <= self.max_contradiction) & inside & np.isfinite(sigma)
        np.add.at(self.votes, voxel[good], 1)
        np.add.at(self.sigma2, voxel[good], sigma[good] ** 2)

    def flush(self) -> None:
        """Let the pings still settling vote with the evidence there is."""
        while self._pending:
            self._vote(*self._pending.popleft())

    def cloud(self, *, flush: bool = False, min_votes: int | None = None) -> GenerativeCloud:
        """The voxels with at least ``min_votes`` (default: the constructor's) that no ping has emptied since."""
        if flush:
            self.flush()
        v = np.flatnonzero(self.votes >= (self.min_votes if min_votes is None else min_votes))
        v = v[self.grid.misses[v] == 0]
        votes = self.votes[v].astype(np.int64)
        return GenerativeCloud(points_m=self.grid.centres(v).astype(np.float64),
                               sigma_m=np.sqrt(self.sigma2[v] / votes).astype(np.float64), votes=votes)


def fuse(carved_points: np.ndarray, carved_sigma: np.ndarray, carved_votes: np.ndarray, generative: GenerativeCloud,
         voxel_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The carved cloud plus the generative voxels it does not already hold: points (K, 3), sigma (K,, m) and votes
    (K,) -- the carved points' own first."""
    carved_points = np.asarray(carved_points, float).reshape(-1, 3)
    carved_sigma, carved_votes = np.asarray(carved_sigma, float), np.asarray(carved_votes, np.int64)
    if generative.points_m.size == 0:
        return carved_points, carved_sigma, carved_votes
    # both are voxel centres of the same grid: on a grid of half voxels they coincide exactly
    have = {tuple(k) for k in np.floor(carved_points / voxel_m).astype(np.int64)}
    new = np.array([tuple(k) not in have for k in np.floor(generative.points_m / voxel_m).astype(np.int64)], bool)
    return (np.concatenate([carved_points, generative.points_m[new]]),
            np.concatenate([carved_sigma, generative.sigma_m[new]]),
            np.concatenate([carved_votes, generative.votes[new]]))
