"""Elevation-resolving sonar reconstruction: free-space carving and arc intersection over a voxel grid.

A forward-looking sonar measures range and bearing but not elevation: a return at range ``r`` in a
beam comes from *somewhere* on the arc of elevations across the vertical aperture
(``nodes.sonar.arcs``). Three facts hold for every ping whatever the elevation (Aykin & Negahdaripour
2017, space carving; Westman & Kaess 2019, wide-aperture sonar):

* the whole elevation arc at every range *before* a beam's first return (its highlight's front end)
  is empty -- nothing echoed there and nothing nearer can shadow it: those voxels are **carved**;
* some voxel on the arc of every return is occupied: each voxel the arc passes through gets a **hit**
  (once per ping);
* a voxel behind the front end, at a range where its beam is dark (no bright block there nor next to
  it), is empty or in the shadow of something nearer: a **dark** (weaker evidence than a miss, as a
  shadow is possible; ghosts of a return sit on arcs whose other ranges stay dark in later views).

Arc intersection then chooses the elevation: each arc, once ``settle_pings`` later pings have added
their evidence, **votes** for its voxels of best score ``hits - miss_weight * misses - dark_weight *
darks`` (where the arcs of many poses cross and no ping carved). The elevation extent of the arc's
near-best voxels (score >= ``near_best`` x best) is its elevation uncertainty: an arc no other view
crosses (one ping, a pass that never changes the view) stays flat along its whole length, ``r s``,
and says so; crossed by arcs of other poses it narrows to a few voxels. A voxel's ``sigma_m`` is the
RMS over the arcs that voted for it of ``extent / sqrt(12)`` (a uniform spread), at least
``voxel / sqrt(12)``. A voted voxel leaves the cloud when later views empty it (score <
``min_support`` x hits).

Occlusion (``occlusion``): a return behind its beam's front end comes from a surface the sonar sees, but
its arc also crosses the inside of the nearer structure (a column's core at the range of its far side),
and every view of a straight pass measures those ghosts alike. Such an arc does not vote for samples that
lie ``occlusion_margin_m`` or more behind a *front surface* on their line of sight in their own ping: the
voxels front-end arcs voted for (a front end has no such ghosts: nothing is nearer at any elevation), as a
z-buffer over 0.5 deg bearing x elevation cells. With ``shadow_darks`` the same z-buffer keeps shadows
from counting as dark (empty) evidence: a pass from the other side no longer carves the surfaces the
structure hides from it. Both are off by default: measured in ``bench/sonar_cloud.py`` they move the
cloud along the accuracy / completeness trade rather than past it -- occlusion publishes more points of
narrower extent (tripod demo pass better, square pier and two piles alike, wall and block worse), and
the darks they withhold refuted ghosts on single passes (tripod there and back: completeness up).

Gaps (``gap_weight``): a candidate in a ping's fan that none of that ping's return arcs passed through counts
a gap (``seen - hits``, ``seen`` counted from the ping it first became a candidate; a voxel an edge arc reached
with its centre just outside the fan is not counted as seen, so the aperture's weak edges are forgiven). Raw hits
favour the voxels a pass keeps longest in its fan -- the top of a pile's arcs over the water in front of its lower
face -- and gaps take that back. Off by default: measured in ``bench/sonar_cloud.py`` (gap_weight 2) they help the
tripod demo pass, the square pier, the two piles and the wall, but a surface that returns only now and then (a
block's top face at grazing incidence) loses to ghosts a few late pings saw, and the block's accuracy falls.

Evidence filter (``keep="evidence"``, off by default): instead of the sigma and support rules, every voted voxel
that a classifier over its whole carving evidence finds likely on a surface, at any sigma; its sigma stays what the
views resolved (``nodes.sonar.carving_filter``: the evidence, the model, what it measures on held-out passes).

Returns and their arcs (``nodes.sonar.carving_arcs``) are every beam's front end and, with ``returns="all"``, the bright
range blocks behind it; a beam is empty (carved) up to its front end, or the seafloor's near edge without one.
Frames: pings in the sonar FRD frame (x boresight, y starboard, z down), poses sonar -> world 4x4, grid and
cloud in the world. Pure numpy/OpenCV; a dense grid over ``bounds`` (arc samples outside it are counted and
ignored); carving projects only the *candidate* voxels (those ever hit) into each ping, so the work per ping
follows the surface seen, not the volume of the fan.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from nodes.sonar import carving_filter
from nodes.sonar.carving_arcs import RangeBlocks, extract_returns, sample_arcs

_U16 = np.iinfo(np.uint16).max
_DEAD = -4.0            # score below which a candidate is no longer carved


@dataclass(frozen=True)
class CarvingParams:
    """Tuning of :class:`CarvingGrid` (lengths in m)."""

    voxel_m: float = 0.1
    margin_m: float = 0.15            # carve only this far in front of a front end (detection + voxel size)
    arc_step_m: float = 0.1           # spacing of the hit samples along an arc (<= voxel_m)
    miss_weight: float = 2.0          # score = hits - miss_weight * misses - dark_weight * darks - gap_weight * gaps
    dark_weight: float = 4.0          # a dark range block behind the front end: empty (or in a nearer object's shadow)
    gap_weight: float = 0.0           # a ping with the candidate in its fan whose returns' arcs all missed it
    min_hits: int = 3                 # an arc votes only when its best voxel was hit by this many pings
    near_best: float = 0.8            # an arc's near-best voxels (its elevation extent): score >= this x best
    settle_pings: int = 20            # an arc votes once this many later pings have added evidence
    carve_stride: int = 2             # a ping tests every carve_stride-th candidate in turn, counting for the others
    min_votes: int = 2                # a voxel is in the cloud when this many arcs voted for it
    min_support: float = 0.7          # ... and its score is still >= this x its hits (later views did not empty it)
    floor_margin_m: float = 0.15      # voxels this close to the seafloor are the seafloor, not the structure
    returns: str = "all"              # "front": front ends only; "all": also the bright blocks behind them
    return_level: float = 0.3         # a bright block: blurred level above this (full scale = 1)
    return_step_m: float = 0.1        # range block of the bright returns
    floor_level: float = 0.6          # ... and beyond the seafloor's near edge, over its echo (>= 1: none there)
    sigma_px: float = 1.5             # front-end detection (nodes.sonar.highlight.detect_front_ends)
    sigma_beam_px: float = 0.5
    threshold: float = 0.12
    guard_px: float | None = None
    occlusion: bool = False           # an arc behind its beam's front end does not vote for what front surfaces shadow
    occlusion_margin_m: float = 0.15  # ... a hypothesis this far behind a front surface on its line of sight
    occlusion_bin_rad: float = 0.0087 # angular cells (bearing x elevation) of the shadow test (0.5 deg)
    shadow_darks: bool = False        # no dark evidence where a front surface shadows the candidate (revisits)
    keep: str = "sigma"               # the cloud: "sigma" (arcs pinned it) or "evidence" (nodes.sonar.carving_filter)
    min_surface_p: float | None = None  # "evidence": keep voxels this likely on a surface (None: the model's own)

    def __post_init__(self) -> None:
        if not (self.voxel_m > 0 and self.margin_m >= 0 and 0 < self.arc_step_m <= self.voxel_m):
            raise ValueError("need voxel_m > 0, margin_m >= 0 and 0 < arc_step_m <= voxel_m")
        if not (self.min_hits >= 1 and self.min_votes >= 1 and self.carve_stride >= 1 and self.settle_pings >= 0
                and 0 < self.near_best <= 1):
            raise ValueError("need min_hits >= 1, min_votes >= 1, carve_stride >= 1, settle_pings >= 0 and "
                             "0 < near_best <= 1")
        if self.returns not in ("front", "all") or not (0 < self.return_level < 1 and self.return_step_m > 0):
            raise ValueError("returns must be 'front' or 'all', 0 < return_level < 1, return_step_m > 0")
        if not (self.miss_weight >= 0 and self.dark_weight >= 0 and self.gap_weight >= 0 and self.min_support <= 1):
            raise ValueError("need miss_weight >= 0, dark_weight >= 0, gap_weight >= 0 and min_support <= 1 "
                             "(-inf: no support test)")
        if not (self.occlusion_margin_m >= 0 and 0 < self.occlusion_bin_rad < 0.5):
            raise ValueError("need occlusion_margin_m >= 0 and 0 < occlusion_bin_rad < 0.5")
        if self.keep not in ("sigma", "evidence") or not (self.min_surface_p is None or 0 <= self.min_surface_p <= 1):
            raise ValueError("keep must be 'sigma' or 'evidence', min_surface_p None or in [0, 1]")


@dataclass(frozen=True)
class PingUpdate:
    """What one ping did: beams with a front end, arcs (returns), voxels carved, voxels hit for the first time,
    arc samples outside the grid."""

    detected_beams: int
    arcs: int
    carved: int
    hit: int
    outside: int


@dataclass(frozen=True)
class VotedCloud:
    """Voxels voted for: ``points_m`` (K, 3) world centres, ``sigma_m`` (K,) elevation 1-sigma (m),
    ``votes`` (K,) arcs that chose each, ``hits`` (K,) pings whose arcs passed through it; with ``keep="evidence"``
    ``surface_p`` (K,) the evidence filter's probability that each is on a surface (None otherwise)."""

    points_m: np.ndarray
    sigma_m: np.ndarray
    votes: np.ndarray
    hits: np.ndarray
    surface_p: np.ndarray | None = None


@dataclass(frozen=True)
class _PingArcs:
    """One ping's arc samples: voxel, arc (0..n-1 in the ping; the first ``n_front`` are front ends), elevation
    along the arc (m); for the shadow test, each sample's range (m) and bearing and elevation (rad), and the
    ping's pose."""

    voxel: np.ndarray
    arc: np.ndarray
    along: np.ndarray
    n_front: int = 0
    rng: np.ndarray | None = None
    bearing: np.ndarray | None = None
    phi: np.ndarray | None = None
    rot: np.ndarray | None = None
    origin: np.ndarray | None = None
    half: float = 0.0


class CarvingGrid:
    """Carving and arc voting over the world box ``bounds_m = ((x0, y0, z0), (x1, y1, z1))``.

    ``integrate(...)`` one ping at a time; ``cloud()`` the voxels voted for so far (``flush=True``
    lets the arcs still settling vote with the evidence there is).
    """

    def __init__(self, bounds_m, params: CarvingParams = CarvingParams(), *, seafloor_z_m: float | None = None,
                 max_voxels: int = 20_000_000) -> None:
        lo, hi = (np.asarray(b, float).reshape(3) for b in bounds_m)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ValueError(f"bounds must be finite ((x0, y0, z0), (x1, y1, z1)) with x1 > x0 etc., got {bounds_m}")
        self.params, self.seafloor_z_m, self.origin = params, seafloor_z_m, lo
        self.shape = tuple(int(np.ceil((h - l) / params.voxel_m)) for l, h in zip(lo, hi))
        n = int(np.prod(self.shape))
        if n > max_voxels:
            raise ValueError(f"{self.shape} = {n} voxels exceeds {max_voxels}: shrink the bounds or grow voxel_m")
        self.hits = np.zeros(n, np.uint16)
        self.misses = np.zeros(n, np.uint16)
        self.darks = np.zeros(n, np.uint16)
        # pings with the voxel in the fan since it became a candidate (gap evidence only)
        self.seen = np.zeros(n, np.uint16) if params.gap_weight > 0 or params.keep == "evidence" else None
        self._lut_key: bytes | None = None
        self._lut: tuple = ()
        self._slot = np.full(n, -1, np.int32)           # voxel -> row of the candidate arrays
        self._cand = np.zeros(0, np.int64)              # candidates (ever hit): voxel, centre, votes, sum extent^2
        self._centre = np.zeros((0, 3), np.float32)
        self._votes = np.zeros(0, np.int32)
        self._extent2 = np.zeros(0, np.float64)
        self._front_votes = np.zeros(0, np.int32)      # votes from front-end arcs (the surfaces that shadow)
        self._near_votes = np.zeros(0, np.int32)       # arc samples that were near-best (keep="evidence" only)
        self._count = 0
        self._alive_voxel = np.zeros(0, np.int64)       # the candidates carving still tests: voxels, centres
        self._alive_centre = np.zeros((0, 3), np.float32)
        self._n_alive = 0
        self._pending: deque[_PingArcs] = deque()      # arcs still settling, oldest first
        # the evidence filter's model, read (and checked) once here rather than at the first cloud
        self._model = carving_filter.load_model() if params.keep == "evidence" else None
        self._mark: np.ndarray | None = None           # scratch mask over the grid (carving_filter.neighbours)
        self.pings = 0

    # -- one ping -------------------------------------------------------------------------
    def integrate(self, intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
                  pose: np.ndarray, spread_rad: float) -> PingUpdate:
        """Carve, hit and let the settled arcs vote, with one ping taken at ``pose`` (the ping's
        arguments as :func:`nodes.sonar.carving_arcs.extract_returns` takes them)."""
        p = self.params
        ret = extract_returns(intensities, bearings_rad, range_resolution_m, pose, spread_rad, params=p,
                              seafloor_z_m=self.seafloor_z_m)         # validates the ping
        pose = np.asarray(pose, float)
        rot, origin, half = pose[:3, :3], pose[:3, 3], 0.5 * spread_rad
        carved = self._carve(rot, origin, np.asarray(bearings_rad, float), ret.free_m, half, ret.blocks)
        hit, outside = self._hit(pose, ret.ranges_m, ret.bearings_rad, half, ret.n_front)
        self.pings += 1
        while len(self._pending) > p.settle_pings:
            self._vote(self._pending.popleft())
        return PingUpdate(ret.n_front, int(ret.ranges_m.size), carved, hit, outside)

    def _carve(self, rot: np.ndarray, origin: np.ndarray, bearings: np.ndarray, free_m: np.ndarray,
               half: float, blocks: RangeBlocks | None) -> int:
        """Count a miss on the candidates inside the fan nearer than their beam's free range, and a dark on those
        behind their beam's front end (past ``margin_m``) in a range block with no bright return near it."""
        p = self.params
        if self.pings % 10 == 0 and self._count:
            # a candidate carved far more than hit can never be an arc's best: stop testing it (it comes back
            # if hits lift its score again)
            rows = np.arange(self._count)
            self._set_alive(rows[self._score(self._cand[rows]) > _DEAD])
        if self._n_alive == 0:
            return 0
        reach = float(max(free_m.max(initial=0.0), 0.0))
        if blocks is not None and p.dark_weight > 0:
            reach = max(reach, blocks.centre.size * blocks.step * blocks.dr)
        # world -> sonar FRD as three contiguous rows (x, y, z); every test on squares, no gather until the end
        # consecutive pings are a few cm apart and see nearly the same thing: each tests a share of the candidates
        # in turn, and counts for the pings that skip them
        stride = p.carve_stride
        share = slice(self.pings % stride, None, stride)
        voxels = self._alive_voxel[:self._n_alive][share]
        x, y, z = rot.astype(np.float32).T @ (self._alive_centre[:self._n_alive][share] - origin.astype(np.float32)).T
        r2 = x * x + y * y + z * z
        with np.errstate(divide="ignore", invalid="ignore"):
            cell = self._bearing_cells(bearings, y / x)
        ok = ((x > 0) & (r2 < np.float32(reach * reach)) & (z * z < np.float32(np.sin(half) ** 2) * r2)
              & (cell >= 0) & (cell < self._lut[2].size))
        sel = np.flatnonzero(ok)
        if sel.size == 0:
            return 0
        if self.seen is not None:
            seen = voxels[sel]
            self.seen[seen] = np.minimum(self.seen[seen].astype(np.int32) + stride, _U16)
        rr, beam = np.sqrt(r2[sel]), self._lut[2][cell[sel]]
        free = free_m[beam]
        idx = voxels[sel[rr < free]]
        self.misses[idx] = np.minimum(self.misses[idx].astype(np.int32) + stride, _U16)
        if blocks is not None and p.dark_weight > 0:
            blk = (rr * np.float32(1.0 / (blocks.step * blocks.dr))).astype(np.int64)
            behind = np.flatnonzero((rr > free + 2 * p.margin_m) & (blk < blocks.centre.size))
            dark = ~blocks.near[blk[behind], np.minimum(beam[behind] // 2, blocks.near.shape[1] - 1)]
            if p.shadow_darks:                        # a shadow is not empty water: unknown
                zbuf = self._front_zbuffer(rot.astype(np.float32), origin.astype(np.float32), half)
                if zbuf is not None:
                    s_ = sel[behind]
                    bear = np.arctan2(y[s_], x[s_])
                    dark &= ~self._behind(zbuf, half, bear, np.arcsin(np.clip(z[s_] / rr[behind], -1, 1)), rr[behind])
            didx = voxels[sel[behind[dark]]]
            self.darks[didx] = np.minimum(self.darks[didx].astype(np.int32) + stride, _U16)
        return int(idx.size)

    def _bearing_cells(self, bearings: np.ndarray, tan_b: np.ndarray) -> np.ndarray:
        """Cell of each direction's bearing tangent (x > 0) in a table of fine uniform bins over the fan
        (``self._lut[2]`` maps a cell to its beam; outside the table: < 0 or >= its size). Cached per bearing
        table: no arctan or sorted search per candidate."""
        key = bearings.tobytes()
        if self._lut_key != key:
            half_beam = 0.5 * float(np.median(np.diff(bearings)))
            edges = np.tan(np.clip(np.r_[bearings[0] - half_beam, 0.5 * (bearings[1:] + bearings[:-1]),
                                         bearings[-1] + half_beam], -1.5, 1.5))
            bins = 16 * bearings.size
            centres = edges[0] + (np.arange(bins) + 0.5) * (edges[-1] - edges[0]) / bins
            lut = np.clip(np.searchsorted(edges, centres) - 1, 0, bearings.size - 1).astype(np.int32)
            self._lut, self._lut_key = (np.float32(edges[0]), np.float32(bins / (edges[-1] - edges[0])), lut), key
        t0, scale, lut = self._lut
        cell = np.nan_to_num((tan_b - t0) * scale, nan=-1.0, posinf=-1.0, neginf=-1.0)
        return np.clip(cell, -1.0, float(lut.size)).astype(np.int32)       # no cast overflow near x = 0

    def _score(self, voxels: np.ndarray) -> np.ndarray:
        """hits - miss_weight * misses - dark_weight * darks - gap_weight * gaps of ``voxels`` (float32); gaps: the
        pings that had the voxel in their fan (``seen``) less those whose arcs passed through it (``hits``)."""
        p = self.params
        hits = self.hits[voxels].astype(np.float32)
        score = hits - np.float32(p.miss_weight) * self.misses[voxels] - np.float32(p.dark_weight) * self.darks[voxels]
        if p.gap_weight > 0:
            score -= np.float32(p.gap_weight) * np.maximum(self.seen[voxels] - hits, np.float32(0.0))
        return score

    def _hit(self, pose: np.ndarray, ranges: np.ndarray, bearings: np.ndarray, half: float,
             n_front: int) -> tuple[int, int]:
        """A hit on every voxel each return's elevation arc passes through (once per ping per voxel); the first
        ``n_front`` returns are front ends."""
        if ranges.size == 0:
            return 0, 0
        p = self.params
        s = sample_arcs(ranges, bearings, pose, half, grid_origin_m=self.origin, shape=self.shape, voxel_m=p.voxel_m,
                        step_m=p.arc_step_m)
        if p.occlusion:
            self._pending.append(_PingArcs(s.voxel, s.arc, s.phi * s.range_m, n_front, s.range_m,
                                           bearings.astype(np.float32)[s.arc], s.phi, pose[:3, :3].astype(np.float32),
                                           pose[:3, 3].astype(np.float32), half))
        else:
            self._pending.append(_PingArcs(s.voxel, s.arc, s.phi * s.range_m, n_front))
        self.hits[s.voxel] = np.minimum(self.hits[s.voxel].astype(np.int32) + 1, _U16)   # buffered: once per ping
        return self._slots_for(s.voxel), s.outside

    def _slots_for(self, voxels: np.ndarray) -> int:
        """Make candidates of the new ones among ``voxels`` (those hit for the first time); how many."""
        new = voxels[self._slot[voxels] < 0]
        if new.size:
            new = np.unique(new)
            need = self._count + new.size
            if need > self._cand.size:
                cap = max(need, 2 * self._cand.size, 4096)
                self._cand, self._centre = np.resize(self._cand, cap), np.resize(self._centre, (cap, 3))
                self._votes = np.concatenate([self._votes, np.zeros(cap - self._votes.size, np.int32)])
                self._extent2 = np.concatenate([self._extent2, np.zeros(cap - self._extent2.size)])
                self._front_votes = np.concatenate([self._front_votes, np.zeros(cap - self._front_votes.size, np.int32)])
                self._near_votes = np.concatenate([self._near_votes, np.zeros(cap - self._near_votes.size, np.int32)])
            rows = np.arange(self._count, need)
            self._cand[rows], self._centre[rows] = new, self.centres(new)
            self._slot[new] = rows
            self._count = need
            self._add_alive(new, self._centre[rows])
        return int(new.size)

    def _set_alive(self, rows: np.ndarray) -> None:
        """The candidates carving tests: their voxels and centres packed (no gather per ping)."""
        self._n_alive = 0
        self._add_alive(self._cand[rows], self._centre[rows])

    def _add_alive(self, voxels: np.ndarray, centres: np.ndarray) -> None:
        """Append to the packed candidates carving tests (capacity doubles: no copy of all of them per ping)."""
        n, need = self._n_alive, self._n_alive + voxels.size
        if need > self._alive_voxel.size:
            cap = max(need, 2 * self._alive_voxel.size, 4096)
            self._alive_voxel = np.concatenate([self._alive_voxel[:n], np.zeros(cap - n, np.int64)])
            self._alive_centre = np.concatenate([self._alive_centre[:n], np.zeros((cap - n, 3), np.float32)])
        self._alive_voxel[n:need], self._alive_centre[n:need] = voxels, centres
        self._n_alive = need

    def _vote(self, arcs: _PingArcs) -> None:
        """Each arc of one ping votes for its best-scoring voxels, with the extent of its near-best ones."""
        p = self.params
        if arcs.voxel.size == 0:
            return
        score = self._score(arcs.voxel)
        if p.occlusion and arcs.n_front < arcs.arc[-1] + 1:
            score = np.where(self._shadowed(arcs), np.float32(-np.inf), score)
        starts = np.flatnonzero(np.r_[True, arcs.arc[1:] != arcs.arc[:-1]])
        counts = np.diff(np.r_[starts, arcs.arc.size])
        best = np.repeat(np.maximum.reduceat(score, starts), counts)
        near = score >= p.near_best * best
        lo = np.minimum.reduceat(np.where(near, arcs.along, np.inf), starts)
        hi = np.maximum.reduceat(np.where(near, arcs.along, -np.inf), starts)
        extent = np.repeat(hi - lo + p.arc_step_m, counts)
        win = (score >= best) & (best >= p.min_hits)
        slots = self._slot[arcs.voxel[win]]
        np.add.at(self._votes, slots, 1)
        np.add.at(self._front_votes, slots[arcs.arc[win] < arcs.n_front], 1)
        np.add.at(self._extent2, slots, extent[win].astype(np.float64) ** 2)
        if p.keep == "evidence":
            np.add.at(self._near_votes, self._slot[arcs.voxel[near & (best >= p.min_hits)]], 1)

    def _shadowed(self, arcs: _PingArcs) -> np.ndarray:
        """The samples of arcs behind their beam's front end that a front surface shadows in that ping.

        A return behind the front end comes from a surface the sonar sees; its arc also crosses the inside of
        the nearer structure (a column's core at the range of its far side), which every view measures alike.
        The front ends' own arcs have no such hypotheses (nothing is nearer than a front end at any elevation):
        the voxels they voted for are the surfaces that shadow (:meth:`_front_zbuffer`).
        """
        shadowed = np.zeros(arcs.voxel.size, bool)
        zbuf = self._front_zbuffer(arcs.rot, arcs.origin, arcs.half)
        if zbuf is not None:
            behind = np.flatnonzero(arcs.arc >= arcs.n_front)
            shadowed[behind] = self._behind(zbuf, arcs.half, arcs.bearing[behind], arcs.phi[behind], arcs.rng[behind])
        return shadowed

    def _front_zbuffer(self, rot: np.ndarray, origin: np.ndarray, half: float) -> np.ndarray | None:
        """Nearest range (m) of a front surface (a voxel some front-end arc voted for) over (bearing, elevation)
        cells of ``occlusion_bin_rad`` in a ping at ``rot``, ``origin`` (float32), each voxel over 3 x 3 cells;
        None without front surfaces."""
        p = self.params
        rows = np.flatnonzero(self._front_votes[:self._count] > 0)
        if rows.size == 0:
            return None
        w = p.occlusion_bin_rad
        nb, ne = int(np.ceil(np.pi / w)) + 4, int(np.ceil(2 * half / w)) + 4
        x, y, z = rot.T @ (self._centre[rows] - origin).T
        r = np.sqrt(x * x + y * y + z * z)
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.arcsin(np.clip(z / r, -1.0, 1.0))
        keep = (x > 0) & (np.abs(phi) < half + w)
        bi = np.clip(np.floor((np.arctan2(y[keep], x[keep]) + np.pi / 2) / w).astype(np.int64) + 2, 0, nb - 1)
        ei = np.clip(np.floor((phi[keep] + half) / w).astype(np.int64) + 2, 0, ne - 1)
        zbuf = np.full((nb, ne), np.inf, np.float32)
        np.minimum.at(zbuf, (bi, ei), r[keep])
        return cv2.erode(zbuf, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)   # 3 x 3 minimum

    def _behind(self, zbuf: np.ndarray, half: float, bearing: np.ndarray, phi: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Whether points at ``bearing``, ``phi`` (rad) and range ``r`` (m) lie ``occlusion_margin_m`` or more
        behind a front surface of ``zbuf`` (:meth:`_front_zbuffer`)."""
        w = self.params.occlusion_bin_rad
        nb, ne = zbuf.shape
        bi = np.clip(np.floor((bearing + np.pi / 2) / w).astype(np.int64) + 2, 0, nb - 1)
        ei = np.clip(np.floor((phi + half) / w).astype(np.int64) + 2, 0, ne - 1)
        return zbuf[bi, ei] < r - np.float32(self.params.occlusion_margin_m)

    # -- results --------------------------------------------------------------------------
    def centres(self, voxels: np.ndarray) -> np.ndarray:
        """World centres (K, 3) of the voxels with flat indices ``voxels``."""
        ijk = np.stack(np.unravel_index(voxels, self.shape), axis=1)
        return ((ijk + 0.5) * self.params.voxel_m + self.origin).astype(np.float32)

    def candidate_points(self) -> np.ndarray:
        """World centres (K, 3) of every voxel ever hit: all the voting can choose from."""
        return self._centre[:self._count].copy()

    @property
    def candidates(self) -> int:
        """Voxels ever hit (those carving tests in each ping)."""
        return self._count

    def cloud(self, *, flush: bool = False, max_sigma_m: float = np.inf,
              min_surface_p: float | None = None) -> VotedCloud:
        """Voxels with >= ``min_votes`` votes, off the seafloor, still supported (``min_support``), elevation
        sigma <= ``max_sigma_m``; with ``keep="evidence"`` instead every voted voxel off the seafloor that the
        evidence filter (:mod:`nodes.sonar.carving_filter`) finds likely enough on a surface, sigma <= ``max_sigma_m``.

        ``flush`` first lets every arc still settling vote (the end of a run; or a single ping); ``min_surface_p``
        overrides the params' threshold of the evidence filter.
        """
        if flush:
            self.flush()
        p = self.params
        rows = self.off_floor(self.voted_rows(1 if p.keep == "evidence" else p.min_votes))
        pts = self._centre[rows]
        surface_p = None
        if p.keep == "evidence":
            surface_p = carving_filter.candidate_probability(self, rows, self._model)
            given = min_surface_p if min_surface_p is not None else p.min_surface_p   # None: the model's threshold
            keep = carving_filter.select(surface_p, self._model, min_surface_p=given).keep
        else:
            keep = self.default_keep(rows)
        rows, pts = rows[keep], pts[keep]
        surface_p = None if surface_p is None else surface_p[keep].astype(np.float32)
        votes = self._votes[rows]
        sigma = self.sigma_m(rows)
        keep = sigma <= max_sigma_m
        return VotedCloud(points_m=pts[keep].copy(), sigma_m=sigma[keep], votes=votes[keep].astype(np.int32),
                           hits=self.hits[self._cand[rows[keep]]].astype(np.int32),
                           surface_p=None if surface_p is None else surface_p[keep])

    def sigma_m(self, rows: np.ndarray) -> np.ndarray:
        """Elevation 1-sigma (m) of candidate ``rows``: the spread of the extents their voting arcs chose (a
        uniform spread over the extent), at least a voxel's own (``voxel_m`` / sqrt 12); rows need >= 1 vote."""
        spread = np.sqrt(self._extent2[rows] / self._votes[rows] / 12.0)
        return np.maximum(spread, self.params.voxel_m / np.sqrt(12.0)).astype(np.float32)

    def default_keep(self, rows: np.ndarray, *, max_sigma_m: float = np.inf) -> np.ndarray:
        """Which candidate ``rows`` the default rule (``keep="sigma"``) keeps: >= ``min_votes`` votes, a score
        still >= ``min_support`` x hits (later views did not empty the voxel), elevation sigma <= ``max_sigma_m``."""
        p, voxels = self.params, self._cand[rows]
        keep = (self._votes[rows] >= p.min_votes) & (self._score(voxels) >= p.min_support * self.hits[voxels])
        if np.isfinite(max_sigma_m):
            keep[keep] = self.sigma_m(rows[keep]) <= max_sigma_m
        return keep

    def flush(self) -> None:
        """Let every arc still settling vote with the evidence there is (the end of a run)."""
        while self._pending:
            self._vote(self._pending.popleft())

    def voted_rows(self, min_votes: int = 1) -> np.ndarray:
        """Candidate rows (of :meth:`candidate_points`, :func:`nodes.sonar.carving_filter.evidence`) with
        >= ``min_votes`` votes."""
        return np.flatnonzero(self._votes[:self._count] >= min_votes)

    def off_floor(self, rows: np.ndarray) -> np.ndarray:
        """``rows`` whose voxel centre is above the seafloor by more than ``floor_margin_m`` (all without one)."""
        if self.seafloor_z_m is None:
            return rows
        return rows[self._centre[rows, 2] > self.seafloor_z_m + self.params.floor_margin_m]
