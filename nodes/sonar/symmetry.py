"""A structure model's own yaw symmetries, found once when the model is built.

Self-registration: a subsample of the model is turned by each yaw on a grid about the vertical
through its centroid, shifted to where its plan view best overlaps the model's (FFT
cross-correlation of occupancy grids: the symmetry axis need not pass through the centroid, and
a partial match must still be found), aligned back onto the model (x, y, yaw free, a few ICP
steps), and scored by the share of its points that land within
``tolerance_m`` of the model. The turns at which that share has a local maximum are the model's
twins: a four-fold pier has them at 90, 180 and 270 deg, the tripod without pylons at 120 and
240 deg, a wall at 180 deg; a single pile matches at every yaw (``continuous``). A twin that
matches almost everywhere (``match >= symmetric_match``) makes any view ambiguous; a partial one
(the tripod with its two pylons: the legs match, one pylon does not) only views that miss the
difference. :func:`nodes.sonar.icp.align` starts a hypothesis at every twin of its first fit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nodes.sonar.icp_model import IcpModel


@dataclass(frozen=True)
class Twin:
    """A model -> model transform (4x4) that maps a share ``match`` of the model onto itself."""

    yaw_rad: float
    transform: np.ndarray
    match: float


@dataclass(frozen=True)
class ModelSymmetry:
    """Twins (yaw != 0) found by self-registration, and whether every yaw matches (a body of revolution)."""

    twins: tuple[Twin, ...]
    continuous: bool
    symmetric_match: float

    @property
    def exact(self) -> tuple[Twin, ...]:
        """Twins that map (nearly) the whole model onto itself."""
        return tuple(t for t in self.twins if t.match >= self.symmetric_match)

    def describe(self) -> str:
        if self.continuous:
            return "symmetric about a vertical axis at every yaw (yaw unobservable)"
        if not self.twins:
            return "no yaw symmetry"
        parts = [f"{np.degrees(t.yaw_rad) % 360:.0f} deg ({100 * t.match:.0f} %)" for t in self.twins]
        return "yaw twins at " + ", ".join(parts)


def _rot_z(yaw: float, pivot: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:3, 3] = pivot - out[:3, :3] @ pivot
    return out


def _plan(xy: np.ndarray, lo: np.ndarray, cell: float, size: int) -> np.ndarray:
    ij = np.floor((xy - lo) / cell).astype(int)
    ok = np.all((ij >= 0) & (ij < size), axis=1)
    img = np.zeros((size, size))
    np.add.at(img, (ij[ok, 0], ij[ok, 1]), 1.0)
    return np.minimum(img, 1.0)


def _best_shift(model_plan: np.ndarray, xy: np.ndarray, lo: np.ndarray, cell: float) -> np.ndarray:
    """Horizontal shift (2,) that best overlaps the plan view of ``xy`` with ``model_plan``."""
    from scipy.signal import fftconvolve

    size = model_plan.shape[0]
    corr = fftconvolve(model_plan, _plan(xy, lo, cell, size)[::-1, ::-1], mode="same")
    i, j = np.unravel_index(int(np.argmax(corr)), corr.shape)
    return (np.array([i, j]) - size // 2) * cell            # size is odd: the centre cell is no shift


def find_symmetries(model: IcpModel, *, step_deg: float = 10.0, tolerance_m: float = 0.1, n_points: int = 600,
                    min_match: float = 0.6, symmetric_match: float = 0.95, seed: int = 0) -> ModelSymmetry:
    """Yaw twins of ``model`` (see the module docstring).

    Parameters
    ----------
    model : IcpModel
    step_deg : yaw grid spacing; a twin is found if ICP from the nearest grid yaw reaches it.
    tolerance_m : a turned point within this of the model matches (about the sonar's resolution).
    n_points : model subsample registered at each yaw.
    min_match : local maxima of the match share below this are not twins.
    symmetric_match : share above which a twin is an exact symmetry (see :class:`ModelSymmetry`).
    """
    from nodes.sonar.icp import IcpSettings, _iterate

    if not 0 < step_deg <= 90 or tolerance_m <= 0:
        raise ValueError("need 0 < step_deg <= 90 and tolerance_m > 0")
    rng = np.random.default_rng(seed)
    pts = model.points if len(model.points) <= n_points else model.points[rng.choice(len(model.points), n_points,
                                                                                       replace=False)]
    src = pts[:, None, :]
    settings = IcpSettings(dof="xy_yaw", max_correspondence_m=2.5, kernel="cauchy", min_correspondence_m=max(2 * tolerance_m, 0.1),
                           kernel_scale_m=tolerance_m, max_points=len(pts), coarse_fraction=1.0, min_inliers=6)
    yaws = np.radians(np.arange(0.0, 360.0, step_deg))
    cell = 0.2
    radius = float(np.max(np.linalg.norm(pts[:, :2] - model.centroid[:2], axis=1))) + 1.0
    size = int(np.ceil(2 * radius / cell)) | 1                 # odd: the centre cell is the zero shift
    lo = model.centroid[:2] - size * cell / 2
    model_plan = _plan(model.points[:, :2], lo, cell, size)
    match, found = np.zeros(len(yaws)), []
    for i, yaw in enumerate(yaws):
        start = _rot_z(float(yaw), model.centroid)
        start[:2, 3] += _best_shift(model_plan, pts[:, :2] @ start[:2, :2].T + start[:2, 3], lo, cell)
        t, _, _, _ = _iterate(src, model, start, settings, 20, polish=False)
        moved = pts @ t[:3, :3].T + t[:3, 3]
        d, _ = model.tree.query(moved, k=1, distance_upper_bound=tolerance_m)
        match[i] = float(np.mean(np.isfinite(d)))
        found.append(t)
    if np.all(match >= symmetric_match):
        return ModelSymmetry((), True, symmetric_match)
    twins: list[Twin] = []
    n = len(yaws)
    for i in range(1, n):
        if match[i] < min_match or match[i] < match[i - 1] or match[i] < match[(i + 1) % n]:
            continue
        t = found[i]
        yaw = float(np.arctan2(t[1, 0], t[0, 0]))
        if abs(np.remainder(yaw + np.pi, 2 * np.pi) - np.pi) < np.radians(step_deg) / 2:
            continue                                   # slid back to the identity
        if any(abs(np.remainder(yaw - tw.yaw_rad + np.pi, 2 * np.pi) - np.pi) < np.radians(step_deg) / 2
               for tw in twins):
            continue
        twins.append(Twin(yaw, t, float(match[i])))
    return ModelSymmetry(tuple(twins), False, symmetric_match)
