"""Set-membership localisation from ranges (and bearings) to known markers (seed 03).

Each step the robot's set is the previous one moved by the odometry displacement (a box:
distance and heading intervals), intersected with every observation's set: an annulus
``|p - m| in [r]`` and, with a bearing, the wedge ``atan2(m - p) in [theta] + [b]``. The
set is paved (inner / boundary boxes to width ``eps``) and its hull is carried to the next
step, so every box provably holds the robot when the error bounds hold. An empty set
means the bounds did not hold (an outlier): it is reported, never replaced by a guess.

Two engines pave the same separators: ``"codac"`` (codac's ``SepInverse`` and ``pave``,
the reference: one box per C++ call, fastest for the small sets of tracking) and
``"numpy"`` (:func:`nodes.sets.paving.sivia`, a whole level of boxes per call: about
5-10x faster than codac on pavings of 10^4-10^5 boxes, such as a global start over the
whole map at a fine ``eps``; slower below about 10^3). ``bench/set_localize.py`` measures both.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from nodes.sets import contract
from nodes.sets import interval as iv
from nodes.sets.codac_env import codac_calls
from nodes.sets.paving import Paving, sep_inter, sivia

ENGINES = ("codac", "numpy")


@dataclass(frozen=True)
class Observation:
    """One marker seen: its position, the range interval (m) and, optionally, the world
    bearing interval from the robot to it (rad, width < pi; see :func:`world_bearing`)."""

    marker: tuple[float, float]
    range_m: tuple[float, float]
    bearing_rad: tuple[float, float] | None = None


def world_bearing(heading_rad: tuple[float, float], relative_rad: tuple[float, float]) -> tuple[float, float]:
    """[heading] + [relative bearing], outward rounded."""
    lo, hi = iv.add(iv.interval(heading_rad[0], heading_rad[1]), iv.interval(relative_rad[0], relative_rad[1]))
    return float(lo), float(hi)


def displacement(distance_m: tuple[float, float], heading_rad: tuple[float, float]) -> np.ndarray:
    """(2, 2) box of ``d (cos h, sin h)`` for d in ``distance_m``, h in ``heading_rad``."""
    d = iv.interval(distance_m[0], distance_m[1])
    h = iv.interval(heading_rad[0], heading_rad[1])
    dx, dy = iv.mul(d, iv.cos(h)), iv.mul(d, iv.sin(h))
    return np.array([[dx[0], dy[0]], [dx[1], dy[1]]], dtype=np.float64)


def predict(box: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Minkowski sum of two (2, 2) boxes, outward rounded (an empty box stays empty)."""
    lo, hi = iv.add((box[0], box[1]), (step[0], step[1]))
    return np.stack([lo, hi])


def numpy_separator(observations: list[Observation]):
    seps = []
    for o in observations:
        m = np.asarray(o.marker, np.float64)
        seps.append(lambda b, m=m, r=o.range_m: contract.separate_range(b, m, r[0], r[1]))
        if o.bearing_rad is not None:
            seps.append(lambda b, m=m, a=o.bearing_rad: contract.separate_bearing(b, m, a[0], a[1]))
    return sep_inter(seps)


def codac_separator(codac, observations: list[Observation], *, outliers: int = 0, functions: dict | None = None):
    """The same constraints as codac separators (q-relaxed intersection when ``outliers`` > 0:
    a point is kept when it satisfies all but ``outliers`` of the observations). Call it
    inside :func:`nodes.sets.codac_env.codac_calls`, which gives the ``codac`` module.
    ``functions``: a dict kept by the caller where the squared-distance function of each
    marker is built once (building one costs about as much as a separator call)."""
    functions = {} if functions is None else functions
    x = functions.get("x")
    if x is None:
        x = functions["x"] = codac.VectorVar(2)
    per_obs = []
    for o in observations:
        mx, my = float(o.marker[0]), float(o.marker[1])
        r = codac.Interval(max(0.0, o.range_m[0]), o.range_m[1])
        f = functions.get((mx, my))
        if f is None:
            f = functions[(mx, my)] = codac.AnalyticFunction([x], codac.sqr(x[0] - mx) + codac.sqr(x[1] - my))
        sep = codac.SepInverse(f, codac.sqr(r))
        if o.bearing_rad is not None:
            # the wedge as two half-planes through the marker (no branch cut; see contract._side)
            for a, c in _wedge(np.array([[mx, my]]), *o.bearing_rad):
                f = codac.AnalyticFunction([x], float(a[0]) * x[0] + float(a[1]) * x[1])
                sep = sep & codac.SepInverse(f, codac.Interval(-codac.oo, float(c)))
        per_obs.append(sep)
    if outliers > 0 and len(per_obs) > outliers:
        return codac.SepQInter(outliers, per_obs)
    out = per_obs[0]
    for s in per_obs[1:]:
        out = out & s
    return out


def _wedge(m: np.ndarray, lo: float, hi: float) -> list[tuple[tuple[float, float], float]]:
    """The wedge's two half-planes ``a . p <= c`` as Python floats (see contract._side; the
    constant is bounded outward by the rounding-error bound of two products and a difference)."""
    if hi - lo >= math.pi - 2 * contract.BEARING_PAD:
        raise ValueError("a bearing interval of width >= pi is not a wedge; drop the bearing")
    mx, my = float(m[0][0]), float(m[0][1])
    out = []
    for theta, ccw in ((lo - contract.BEARING_PAD, True), (hi + contract.BEARING_PAD, False)):
        ux, uy = math.cos(theta), math.sin(theta)
        k = ux * my - uy * mx
        err = 3 * 2.0 ** -53 * (abs(ux * my) + abs(uy * mx)) + 5e-324
        out.append(((-uy, ux), k + err) if ccw else ((uy, -ux), -k + err))
    return out


def pave(box: np.ndarray, observations: list[Observation], eps: float, *, engine: str = "codac",
         outliers: int = 0, max_boxes: int = 200_000, functions: dict | None = None) -> Paving:
    """Pave ``box`` (2, 2) intersected with every observation's set to width ``eps``
    (``functions``: see :func:`codac_separator`)."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    box = np.asarray(box, np.float64)
    if not np.all(box[0] <= box[1]):
        return Paving(np.zeros((0, 2, 2)), np.zeros((0, 2, 2)))
    if not observations:
        return Paving(np.zeros((0, 2, 2)), box[None].copy())
    if engine == "numpy":
        if outliers:
            raise ValueError("the numpy engine has no q-relaxed intersection; use engine='codac'")
        return sivia(box, numpy_separator(observations), eps, max_boxes=max_boxes)
    with codac_calls() as codac:
        x0 = codac.IntervalVector([[float(box[0, 0]), float(box[1, 0])], [float(box[0, 1]), float(box[1, 1])]])
        p = codac.pave(x0, codac_separator(codac, observations, outliers=outliers, functions=functions), eps)
        inner, bound = p.boxes(codac.PavingInOut.inner), p.boxes(codac.PavingInOut.bound)
        lists = [[(b[0].lb(), b[1].lb(), b[0].ub(), b[1].ub()) for b in boxes] for boxes in (inner, bound)]
    return Paving(_as_boxes(lists[0]), _as_boxes(lists[1]))


def _as_boxes(boxes: list) -> np.ndarray:
    out = np.array(boxes, dtype=np.float64).reshape(-1, 2, 2)
    return out[np.all(out[:, 0] <= out[:, 1], axis=1)]          # codac gives the empty set as NaN boxes


@dataclass
class StepResult:
    box: np.ndarray                   # (2, 2) hull of the set (the predicted box when inconsistent)
    paving: Paving
    consistent: bool                  # False: the observations and the prediction share no point
    outliers_allowed: int = 0         # > 0: the set was found by a q-relaxed intersection
    seconds: float = 0.0

    @property
    def width_m(self) -> float:
        return float(np.max(self.box[1] - self.box[0]))


@dataclass
class SetLocalizer:
    """The recursive set-membership filter: :meth:`step` per odometry step and observations.

    ``box`` is the current hull; unbounded starts are allowed (``[-inf, inf]**2``: the first
    observations bound it). ``max_outliers``: when the set is empty, retry allowing up to
    this many observations to be wrong (codac engine), and flag it either way."""

    box: np.ndarray
    eps: float = 0.05
    engine: str = "codac"
    max_outliers: int = 0
    inconsistent_steps: int = 0
    _functions: dict = field(default_factory=dict, repr=False)

    def step(self, step_box: np.ndarray | None, observations: list[Observation]) -> StepResult:
        t0 = time.perf_counter()
        predicted = self.box if step_box is None else predict(self.box, step_box)
        start = _bounded(predicted, observations)
        paving = pave(start, observations, self.eps, engine=self.engine, functions=self._functions)
        result = StepResult(box=paving.hull(), paving=paving, consistent=not paving.empty)
        q = 1
        while result.paving.empty and q <= self.max_outliers and q < len(observations):
            paving = pave(start, observations, self.eps, engine="codac", outliers=q, functions=self._functions)
            result = StepResult(box=paving.hull(), paving=paving, consistent=False, outliers_allowed=q)
            if not paving.empty:
                break
            q += 1
        if result.paving.empty:
            result.box = predicted.copy()
        if not result.consistent:
            self.inconsistent_steps += 1
        self.box = result.box
        result.seconds = time.perf_counter() - t0
        return result


def _bounded(box: np.ndarray, observations: list[Observation]) -> np.ndarray:
    """An unbounded box made finite by the range discs of the observations (every point of
    the set lies within r_hi of each marker); SIVIA needs a finite box to bisect."""
    if np.all(np.isfinite(box)) or not observations:
        return box
    lo, hi = box[0].copy(), box[1].copy()
    for o in observations:
        m, r = np.asarray(o.marker, np.float64), o.range_m[1]
        lo = np.maximum(lo, iv.down(m - r))
        hi = np.minimum(hi, iv.up(m + r))
    return np.stack([lo, hi])
