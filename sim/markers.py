"""A 2-D robot among point markers with bounded errors (seed 03's SLAM scene and harder ones).

The seed's robot: ``x(k+1) = x(k) + 10 delta cos theta(k)``, ``y`` likewise with sin,
``theta(k+1) = theta(k) + delta (u(k) + n_u(k))`` with ``u(k) = 3 sin(k delta)**2``,
``delta = 0.1``, a compass ``theta_m = theta + n_theta`` and ``n_u, n_theta in [-0.03, 0.03]``;
markers (6, 12), (-2, -5), (-3, 20), (3, 4). The seed does not say how the markers are
measured; here each step gives the range (and bearing) to every marker within
``max_range_m`` (or only the nearest, ``nearest_only``), each error uniform in its bound.
``outlier_rate``: that fraction of ranges is replaced by a wrong one (off by 2-6 m), flagged
in the ground truth, so a method can be checked for detecting them.

Only what the scene needs: no collisions, no occlusion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SEED_MARKERS = ((6.0, 12.0), (-2.0, -5.0), (-3.0, 20.0), (3.0, 4.0))

#: Scenes: the seed's, and hard geometry for the benches.
SCENES = ("seed", "collinear", "at_marker", "single", "random")


@dataclass(frozen=True)
class Bounds:
    heading_rad: float = 0.03         # compass error bound
    turn_rad: float = 0.03            # n_u bound (enters the truth only)
    speed_frac: float = 0.0           # odometry distance error bound, fraction of the step
    range_m: float = 0.1
    bearing_rad: float = 0.02


@dataclass(frozen=True)
class Observed:
    marker: int
    range_m: tuple[float, float]
    bearing_rad: tuple[float, float]  # relative to the robot's heading
    outlier: bool = False


@dataclass
class Step:
    k: int
    truth_xy: np.ndarray              # position after the step
    truth_heading_rad: float
    heading_rad: tuple[float, float]  # compass interval of the heading the step was made with
    distance_m: tuple[float, float]   # odometry interval of the step length
    compass_rad: tuple[float, float]  # compass interval at the new pose (the bearings are relative to it)
    observed: list[Observed] = field(default_factory=list)


def scene_markers(scene: str, rng: np.random.Generator) -> np.ndarray:
    if scene not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {scene!r}")
    if scene == "seed":
        return np.array(SEED_MARKERS)
    if scene == "collinear":                       # all markers on one line: the mirror image is consistent
        return np.array([[-10.0, 8.0], [0.0, 8.0], [10.0, 8.0]])
    if scene == "at_marker":                       # the robot starts on a marker (range 0, bearing undefined)
        return np.array([[0.0, 0.0], *SEED_MARKERS])
    if scene == "single":
        return np.array([SEED_MARKERS[3]])
    return rng.uniform(-15, 25, size=(6, 2))


class MarkerWorld:
    """Steps the seed's robot and measures the markers; ``step()`` returns a :class:`Step`."""

    def __init__(self, scene: str = "seed", *, seed: int = 0, bounds: Bounds = Bounds(), delta: float = 0.1,
                 max_range_m: float = 15.0, nearest_only: bool = False, outlier_rate: float = 0.0,
                 start: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.rng = np.random.default_rng(seed)
        self.markers = scene_markers(scene, self.rng)
        self.bounds, self.delta = bounds, delta
        self.max_range_m, self.nearest_only, self.outlier_rate = max_range_m, nearest_only, outlier_rate
        self.xy = np.array(start[:2], dtype=np.float64)
        self.theta = float(start[2])
        self.k = 0
        self.compass = self._compass()

    def _compass(self) -> tuple[float, float]:
        m = self.theta + self._uniform(self.bounds.heading_rad)
        return (m - self.bounds.heading_rad, m + self.bounds.heading_rad)

    def _uniform(self, bound: float) -> float:
        return float(self.rng.uniform(-bound, bound)) if bound > 0 else 0.0

    def observe(self) -> list[Observed]:
        b = self.bounds
        d = self.markers - self.xy
        dist = np.hypot(d[:, 0], d[:, 1])
        seen = np.flatnonzero(dist <= self.max_range_m)
        if self.nearest_only and len(seen):
            seen = seen[[np.argmin(dist[seen])]]
        out = []
        for j in seen:
            r = dist[j] + self._uniform(b.range_m)
            outlier = self.outlier_rate > 0 and self.rng.random() < self.outlier_rate
            if outlier:
                r = dist[j] + float(self.rng.choice([-1, 1])) * float(self.rng.uniform(2.0, 6.0))
            r = max(r, 0.0)
            bearing = math.atan2(d[j, 1], d[j, 0]) - self.theta + self._uniform(b.bearing_rad)
            out.append(Observed(int(j), (r - b.range_m, r + b.range_m),
                                (bearing - b.bearing_rad, bearing + b.bearing_rad), outlier))
        return out

    def step(self) -> Step:
        """Move one step with the seed's dynamics (heading known to the robot by the last compass
        reading), then read the compass and measure the markers."""
        b = self.bounds
        heading = self.compass
        length = 10 * self.delta
        self.xy = self.xy + length * np.array([math.cos(self.theta), math.sin(self.theta)])
        u = 3 * math.sin(self.k * self.delta) ** 2
        theta_used = self.theta
        self.theta += self.delta * (u + self._uniform(b.turn_rad))
        self.k += 1
        d_err = b.speed_frac * length
        self.compass = self._compass()
        step = Step(self.k, self.xy.copy(), theta_used, heading, (length - d_err, length + d_err), self.compass)
        step.observed = self.observe()
        return step
