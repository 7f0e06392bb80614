"""Interval mosaic registration (seed 08, section VII): image centres as boxes, translations
between images (from phase correlation) as constraints with bounded errors, contracted
to a fixpoint over the chain and the loop closures.

Only translations, as in the seed: the images share one orientation (the unrotated
experiment; with rotations the constraint is no longer linear in the centres). Image 0 is
anchored; every other centre starts as the whole plane. A link ``(i, j, z)`` says
``c_j - c_i in z +- e`` with ``e`` the larger of ``floor_px`` and ``k_sigma`` standard
deviations of the registration. If some bound is wrong the boxes can come out empty: that
is reported, not hidden.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nodes.sets.tube import contract_edges


@dataclass
class MosaicBoxes:
    lo: np.ndarray                # (N, 2) lower corners of the centre boxes (pixels)
    hi: np.ndarray
    sweeps: int
    half_width: np.ndarray        # (E, 2) the error bound used for each link

    @property
    def consistent(self) -> bool:
        return bool(np.all(self.lo <= self.hi))

    def contains(self, centres: np.ndarray) -> np.ndarray:
        return np.all((self.lo <= centres) & (centres <= self.hi), axis=1)


def link_bounds(covariances: np.ndarray, *, k_sigma: float = 3.0, floor_px: float = 1.0) -> np.ndarray:
    """(E, 2) half-widths: max(floor, k sigma) per axis of each link's translation."""
    sd = np.sqrt(np.maximum(np.diagonal(np.asarray(covariances), axis1=1, axis2=2)[:, :2], 0.0))
    return np.maximum(k_sigma * sd, floor_px)


def contract_mosaic(n: int, i: Sequence[int], j: Sequence[int], z: np.ndarray, half_width: np.ndarray,
                    anchor_xy: np.ndarray, *, anchor: int = 0) -> MosaicBoxes:
    """Centre boxes of ``n`` images from translation links ``c_j - c_i in z +- half_width``."""
    lo, hi = np.full((n, 2), -np.inf), np.full((n, 2), np.inf)
    lo[anchor] = hi[anchor] = np.asarray(anchor_xy, np.float64)
    z, e = np.asarray(z, np.float64).reshape(-1, 2), np.asarray(half_width, np.float64).reshape(-1, 2)
    lo, hi, sweeps = contract_edges(lo, hi, np.asarray(i), np.asarray(j), z - e, z + e)
    return MosaicBoxes(lo, hi, sweeps, e)
