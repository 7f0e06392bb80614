"""The simple car of seed 14: two driven wheels and a caster, i.e. a differential drive on a plane,
commanded in forward velocity and yaw rate, among walls given as segments.

Only what the scenes need: 2-D kinematics integrated exactly over a step (arcs, not Euler
chords, so accuracy at the millimetre does not depend on the step), a disc for the body,
walls as segments, range readings by ray casting. Everything is batched over N cars.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the paper's action box ([-pi, pi] x [-5, 5]) keeps its yaw-rate limit; velocity is set to this
#: car's scale (a 2 m arena: 5 m/s would cross it in four 0.1 s steps)
V_MAX_MPS = 1.0
W_MAX_RADPS = np.pi
RADIUS_M = 0.1


def integrate(pose: np.ndarray, v_mps: np.ndarray, w_radps: np.ndarray, dt_s: float) -> np.ndarray:
    """Poses (N, 3) [x, y, yaw] after ``dt_s`` at constant (v, w): the exact arc.

    Near w = 0 the arc's ``sin(w dt)/w`` is replaced by its series (no division near zero).
    The returned yaw is wrapped to [-pi, pi).
    """
    th = pose[:, 2]
    dth = w_radps * dt_s
    small = np.abs(dth) < 1e-6
    if small.any():
        safe = np.where(small, 1.0, dth)
        s = np.where(small, 1.0 - dth**2 / 6.0, np.sin(safe) / safe)
        c = np.where(small, dth / 2.0, (1.0 - np.cos(safe)) / safe)
    else:                                   # the common case, without the series' masks
        s, c = np.sin(dth) / dth, (1.0 - np.cos(dth)) / dth
    step = v_mps * dt_s
    ct, st = np.cos(th), np.sin(th)
    out = np.empty_like(pose, dtype=np.float64)
    out[:, 0] = pose[:, 0] + step * (s * ct - c * st)
    out[:, 1] = pose[:, 1] + step * (s * st + c * ct)
    out[:, 2] = np.remainder(th + dth + np.pi, 2.0 * np.pi) - np.pi       # [-pi, pi)
    return out


@dataclass(frozen=True)
class Walls:
    """Wall segments (W, 4) [x0, y0, x1, y1] in metres."""

    segments: np.ndarray

    @property
    def a(self) -> np.ndarray:
        return self.segments[:, :2]

    @property
    def b(self) -> np.ndarray:
        return self.segments[:, 2:]

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance (N,) from each point (N, 2) to the nearest wall (inf with no walls)."""
        if len(self.segments) == 0:
            return np.full(len(points), np.inf)
        a, d = self.a, self.b - self.a                                    # (W, 2)
        rel = points[:, None, :] - a[None]                                 # (N, W, 2)
        len2 = np.maximum((d * d).sum(1), 1e-18)
        t = np.clip((rel * d[None]).sum(2) / len2, 0.0, 1.0)
        near = rel - t[..., None] * d[None]
        return np.sqrt((near * near).sum(2)).min(axis=1)

    def ranges(self, pose: np.ndarray, angles_rad: np.ndarray, max_range_m: float) -> np.ndarray:
        """Range readings (N, R) along ``angles_rad`` (R,) from each pose's heading, capped at ``max_range_m``."""
        n = len(pose)
        out = np.full((n, len(angles_rad)), max_range_m)
        if len(self.segments) == 0:
            return out
        ang = pose[:, 2:3] + angles_rad[None]                              # (N, R)
        ux, uy = np.cos(ang)[..., None], np.sin(ang)[..., None]            # (N, R, 1)
        a, d = self.a, self.b - self.a
        ox = a[None, None, :, 0] - pose[:, 0, None, None]                  # (N, 1, W)
        oy = a[None, None, :, 1] - pose[:, 1, None, None]
        dx, dy = d[None, None, :, 0], d[None, None, :, 1]
        # ray p + r u meets a + s d: solve [u, -d] [r, s]^T = a - p by Cramer's rule
        den = ux * (-dy) - uy * (-dx)
        parallel = np.abs(den) < 1e-12
        den = np.where(parallel, 1.0, den)
        r = (ox * (-dy) - oy * (-dx)) / den
        s = (ux * oy - uy * ox) / den
        hit = ~parallel & (r >= 0.0) & (s >= 0.0) & (s <= 1.0)
        r = np.where(hit, r, np.inf).min(axis=2)
        return np.minimum(out, r)


def box_walls(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """The four sides of a rectangle as segments (4, 4)."""
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]], float)
