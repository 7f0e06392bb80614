"""Separators, SIVIA and the set-membership localiser: the truth stays inside, both engines
agree, and the hard geometry (outliers, unbounded start, a marker at the robot, a mirror map)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.sets import contract
from nodes.sets.localize import Observation, SetLocalizer, displacement, pave, predict
from nodes.sets.paving import box_diff, sivia
from sim.markers import MarkerWorld

from nodes.sets.codac_env import available

pytestmark = pytest.mark.skipif(not available(), reason="codac is not installed")

BIG = np.array([[-30.0, -30.0], [30.0, 30.0]])


def _obs(p, markers, rng, r_err=0.1, b_err=0.05, bearings=True):
    out = []
    for m in markers:
        r = math.hypot(*(m - p)) + rng.uniform(-r_err, r_err)
        b = math.atan2(m[1] - p[1], m[0] - p[0]) + rng.uniform(-b_err, b_err)
        out.append(Observation(tuple(m), (r - r_err, r + r_err), (b - b_err, b + b_err) if bearings else None))
    return out


def _inside(box, p):
    return bool(np.all(box[0] <= p) and np.all(p <= box[1]))


def _in_paving(paving, p):
    boxes = np.concatenate([paving.inner, paving.boundary])
    return bool(np.any(np.all((boxes[:, 0] <= p) & (p <= boxes[:, 1]), axis=1)))


def test_separator_parts_are_proven_outside_and_inside():
    rng = np.random.default_rng(0)
    lo = rng.uniform(-10, 10, (400, 2))
    b = (lo, lo + rng.uniform(0.1, 3, (400, 2)))
    m = np.array([1.0, 2.0])
    outer, inner = contract.separate_range(b, m, 3.0, 4.0)
    pts = b[0][:, None] + rng.random((400, 50, 2)) * (b[1] - b[0])[:, None]
    d = np.hypot(*(pts - m).transpose(2, 0, 1))
    in_outer = np.all((outer[0][:, None] <= pts) & (pts <= outer[1][:, None]), axis=2)
    in_inner = np.all((inner[0][:, None] <= pts) & (pts <= inner[1][:, None]), axis=2)
    assert np.all(in_outer[(d >= 3) & (d <= 4)])          # no point of the set is removed by the outer part
    assert np.all(in_inner[(d < 3) | (d > 4)])            # no point of the complement by the inner part
    assert (~in_outer).sum() > 1000 and (~in_inner).sum() > 100    # both contract something


def test_box_diff_tiles_the_removed_part():
    x = (np.array([[0.0, 0.0]]), np.array([[4.0, 3.0]]))
    y = (np.array([[1.0, 1.0]]), np.array([[2.0, 2.0]]))
    lo, hi = box_diff(x, y)
    assert len(lo) == 4 and math.isclose(float(np.prod(hi - lo, axis=1).sum()), 12.0 - 1.0)
    lo, hi = box_diff(x, (np.array([[np.inf, np.inf]]), np.array([[-np.inf, -np.inf]])))   # y empty: x itself
    assert len(lo) == 1 and np.array_equal(lo, x[0]) and np.array_equal(hi, x[1])


@pytest.mark.parametrize("bearings", [False, True])
def test_both_engines_hold_the_truth_and_agree(bearings):
    rng = np.random.default_rng(3)
    for _ in range(15):
        p = rng.uniform(-8, 8, 2)
        obs = _obs(p, rng.uniform(-15, 15, (3, 2)), rng, bearings=bearings)
        pc = pave(BIG, obs, 0.05, engine="codac")
        pn = pave(BIG, obs, 0.05, engine="numpy")
        assert _in_paving(pc, p) and _in_paving(pn, p)
        ic, oc = pc.area()
        inn, on = pn.area()
        assert abs(oc - on) <= 0.25 * max(oc, on) + 0.01 and abs(ic - inn) <= 0.25 * max(ic, inn) + 0.01
        # both hulls hold every sampled point of the set (codac may keep an extra boundary box
        # its contractors did not remove: both are valid outer approximations)
        h = pc.hull()
        xs, ys = np.meshgrid(np.linspace(h[0, 0], h[1, 0], 300), np.linspace(h[0, 1], h[1, 1], 300))
        ok = np.ones_like(xs, bool)
        for o in obs:
            ok &= np.abs(np.hypot(xs - o.marker[0], ys - o.marker[1]) - sum(o.range_m) / 2) <= (o.range_m[1] - o.range_m[0]) / 2
            if o.bearing_rad is not None:
                a = np.arctan2(o.marker[1] - ys, o.marker[0] - xs)
                ok &= (a - o.bearing_rad[0]) % (2 * math.pi) <= o.bearing_rad[1] - o.bearing_rad[0]
        pts = np.stack([xs[ok], ys[ok]], -1)
        assert len(pts) > 0
        for hull in (pc.hull(), pn.hull()):
            assert np.all((hull[0] <= pts) & (pts <= hull[1]))


def test_inner_boxes_are_inside_the_set():
    rng = np.random.default_rng(5)
    p = np.array([1.0, -2.0])
    obs = _obs(p, np.array([[5.0, 5.0], [-6.0, 1.0]]), rng, bearings=True)
    for engine in ("codac", "numpy"):
        paving = pave(BIG, obs, 0.02, engine=engine)
        assert len(paving.inner) > 10
        pts = paving.inner[:, 0][:, None] + rng.random((len(paving.inner), 20, 2)) * (paving.inner[:, 1] - paving.inner[:, 0])[:, None]
        for o in obs:
            d = np.hypot(*(pts - np.array(o.marker)).transpose(2, 0, 1))
            assert np.all((d >= o.range_m[0] - 1e-9) & (d <= o.range_m[1] + 1e-9))
            a = np.arctan2(o.marker[1] - pts[..., 1], o.marker[0] - pts[..., 0])
            diff = (a - o.bearing_rad[0]) % (2 * math.pi)
            assert np.all(diff <= o.bearing_rad[1] - o.bearing_rad[0] + 1e-6)


def test_localiser_over_the_seed_run_never_loses_the_truth_and_flags_outliers():
    world = MarkerWorld("seed", seed=2, outlier_rate=0.05)
    f = SetLocalizer(np.zeros((2, 2)), eps=0.05, max_outliers=0)
    flagged, hidden = 0, 0
    for _ in range(100):
        s = world.step()
        obs = [Observation(tuple(world.markers[o.marker]), o.range_m, None) for o in s.observed]
        r = f.step(displacement(s.distance_m, s.heading_rad), obs)
        bad = any(o.outlier for o in s.observed)
        if not r.consistent:
            flagged += 1
            assert bad                                      # inconsistency only when a bound was broken
        elif not bad:
            assert _inside(r.box, s.truth_xy)
        if r.consistent and bad and not _inside(r.box, s.truth_xy):
            hidden += 1
            f.box = predict(f.box, np.array([[-5.0, -5.0], [5.0, 5.0]]))  # a caller would re-widen
    assert flagged >= 1
    assert f.inconsistent_steps == flagged


def test_q_relaxed_intersection_recovers_a_set_holding_the_truth():
    rng = np.random.default_rng(7)
    p = np.array([2.0, 1.0])
    obs = _obs(p, np.array([[8.0, 3.0], [-5.0, 4.0], [0.0, -9.0], [6.0, -6.0]]), rng, bearings=False)
    m, (r0, r1) = obs[1].marker, obs[1].range_m
    obs[1] = Observation(m, (r0 + 3.0, r1 + 3.0))                                  # one wrong range
    f = SetLocalizer(BIG.copy(), eps=0.05, max_outliers=1)
    r = f.step(None, obs)
    assert not r.consistent and r.outliers_allowed == 1 and _inside(r.box, p)
    strict = SetLocalizer(BIG.copy(), eps=0.05, max_outliers=0).step(None, obs)
    assert strict.paving.empty and np.array_equal(strict.box, BIG)               # no guess: the prediction


def test_unbounded_start_is_bounded_by_the_first_ranges():
    rng = np.random.default_rng(9)
    p = np.array([-3.0, 4.0])
    f = SetLocalizer(np.array([[-np.inf, -np.inf], [np.inf, np.inf]]), eps=0.05)
    r = f.step(None, _obs(p, np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 12.0]]), rng, bearings=False))
    assert r.consistent and np.all(np.isfinite(r.box)) and _inside(r.box, p) and r.width_m < 1.0


def test_marker_exactly_at_the_robot():
    p = np.array([3.0, 4.0])
    obs = [Observation((3.0, 4.0), (0.0, 0.05)), Observation((10.0, 4.0), (6.95, 7.05))]
    for engine in ("codac", "numpy"):
        paving = pave(BIG, obs, 0.01, engine=engine)
        assert _in_paving(paving, p) and paving.hull()[1, 0] - paving.hull()[0, 0] <= 0.11
    with pytest.raises(ValueError, match="wedge"):              # a bearing to a marker you stand on is no wedge
        pave(BIG, [Observation((3.0, 4.0), (0.0, 0.05), (-math.pi, math.pi))], 0.01, engine="numpy")


def test_mirror_symmetric_map_keeps_both_solutions():
    # markers on a line: the robot and its mirror image explain the ranges equally well
    p = np.array([2.0, 3.0])
    markers = np.array([[-6.0, 0.0], [0.0, 0.0], [7.0, 0.0]])
    obs = [Observation(tuple(m), (math.hypot(*(m - p)) - 0.05, math.hypot(*(m - p)) + 0.05)) for m in markers]
    paving = pave(BIG, obs, 0.02)
    assert _in_paving(paving, p) and _in_paving(paving, p * [1, -1])
    h = paving.hull()
    assert h[0, 1] < -2.5 and h[1, 1] > 2.5                     # the hull spans both lobes ...
    assert paving.area()[1] < 0.1 * float(np.prod(h[1] - h[0]))  # ... the paving does not fill it


def test_sivia_rejects_a_bad_eps_and_paves_empty_boxes_to_nothing():
    sep = lambda b: contract.separate_range(b, np.zeros(2), 1.0, 2.0)   # noqa: E731
    with pytest.raises(ValueError, match="eps"):
        sivia(BIG, sep, 0.0)
    assert sivia(np.array([[1.0, 1.0], [0.0, 0.0]]), sep, 0.1).empty
    assert pave(np.array([[1.0, 1.0], [0.0, 0.0]]), [], 0.1).empty
