"""The interval kernel: enclosure of sampled truths, the hard cases of the issue, and codac as an oracle."""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from nodes.sets import interval as iv

from nodes.sets.codac_env import available, codac_calls, rounding_mode

pytestmark = pytest.mark.skipif(not available(), reason="codac is not installed")


def _random_intervals(rng, n, scale=10.0):
    a = rng.uniform(-scale, scale, (2, n))
    return iv.interval(a.min(axis=0), a.max(axis=0))


def _samples(a, rng, k=64):
    t = rng.random((k, len(a[0])))
    return a[0] + t * (a[1] - a[0])


@pytest.mark.parametrize("op,fn", [(iv.add, np.add), (iv.sub, np.subtract), (iv.mul, np.multiply)])
def test_binary_ops_enclose_every_sampled_result(op, fn):
    rng = np.random.default_rng(0)
    a, b = _random_intervals(rng, 500), _random_intervals(rng, 500)
    z = op(a, b)
    vals = fn(_samples(a, rng), _samples(b, rng))
    assert np.all((z[0] <= vals) & (vals <= z[1]))


@pytest.mark.parametrize("op,fn", [(iv.sin, np.sin), (iv.cos, np.cos), (iv.sqr, np.square)])
def test_unary_ops_enclose_and_match_codac(op, fn):
    rng = np.random.default_rng(1)
    a = _random_intervals(rng, 300)
    z = op(a)
    vals = fn(_samples(a, rng))
    assert np.all((z[0] <= vals) & (vals <= z[1]))
    with codac_calls() as codac:
        cfn = {iv.sin: codac.sin, iv.cos: codac.cos, iv.sqr: codac.sqr}[op]
        refs = [cfn(codac.Interval(float(a[0][k]), float(a[1][k]))) for k in range(0, 300, 7)]
        refs = [(r.lb(), r.ub(), r.diam()) for r in refs]
    for k, (ref_lo, ref_hi, ref_w) in zip(range(0, 300, 7), refs):
        assert z[0][k] <= ref_lo + 1e-14 and z[1][k] >= ref_hi - 1e-14         # ours encloses codac's
        assert (z[1][k] - z[0][k]) <= ref_w + 1e-13                            # and is as tight


def test_sin_cos_at_their_extrema_reach_plus_minus_one():
    lo, hi = iv.sin(iv.interval([math.pi / 2 - 1e-9, -math.pi / 2 - 1e-9, 0.0], [math.pi / 2 + 1e-9, -math.pi / 2 + 1e-9, 7.0]))
    assert hi[0] == 1.0 and lo[1] == -1.0 and (lo[2], hi[2]) == (-1.0, 1.0)
    lo, hi = iv.cos(iv.interval([-1e-9, math.pi - 1e-9], [1e-9, math.pi + 1e-9]))
    assert hi[0] == 1.0 and lo[1] == -1.0
    # a crest at a bound: pi/2 as a double is below pi/2, so the range must still reach 1 or get within 1e-15
    lo, hi = iv.sin(iv.interval(0.0, math.pi / 2))
    assert hi >= 1.0 - 1e-15 and lo <= 0.0
    lo, hi = iv.cos(iv.interval(-np.inf, 0.0))
    assert (lo, hi) == (-1.0, 1.0)


def test_atan2_across_the_branch_cut_is_the_whole_circle_and_quadrants_are_right():
    lo, hi = iv.atan2(iv.interval(-0.1, 0.1), iv.interval(-2.0, -1.0))       # straddles the cut
    assert (lo, hi) == (-math.pi, math.pi)
    lo, hi = iv.atan2(iv.interval(1.0, 2.0), iv.interval(-2.0, -1.0))         # second quadrant
    assert math.pi / 2 < lo < hi < math.pi
    assert lo <= math.atan2(2.0, -1.0) and hi >= math.atan2(1.0, -2.0)
    lo, hi = iv.atan2(iv.interval(-0.1, 0.1), iv.interval(1.0, 2.0))          # across +x: no cut
    assert lo < 0 < hi and hi - lo < 0.3
    lo, hi = iv.atan2(iv.interval(-1.0, 1.0), iv.interval(-1.0, 1.0))         # holds the origin
    assert (lo, hi) == (-math.pi, math.pi)


def test_division_by_an_interval_with_zero_gives_two_pieces_or_their_hull():
    (p, q) = iv.div_pieces(iv.interval(1.0, 2.0), iv.interval(-1.0, 4.0))
    assert -1.0 <= p[1] < -1.0 + 1e-12 and p[0] == -np.inf                    # (-inf, -1], one ulp out
    assert 0.25 - 1e-12 < q[0] <= 0.25 and q[1] == np.inf                     # [0.25, inf)
    assert not (p[0] <= 0.0 <= p[1]) and not (q[0] <= 0.0 <= q[1])           # the gap around 0 is kept
    lo, hi = iv.div(iv.interval(1.0, 2.0), iv.interval(-1.0, 4.0))           # hull: the whole line
    assert (lo, hi) == (-np.inf, np.inf)
    lo, hi = iv.div(iv.interval(1.0, 2.0), iv.interval(0.0, 4.0))            # zero at an end: one half-line
    assert lo <= 0.25 and hi == np.inf
    lo, hi = iv.div(iv.interval(-1.0, 2.0), iv.interval(-1.0, 4.0))          # both hold 0: everything
    assert (lo, hi) == (-np.inf, np.inf)
    assert iv.is_empty(iv.div(iv.interval(1.0), iv.interval(0.0)))           # x / [0, 0]: no real number
    with codac_calls() as codac:                                              # codac returns the hull too
        ref = codac.Interval(1, 2) / codac.Interval(-1, 4)
        assert ref.lb() == -np.inf and ref.ub() == np.inf


def test_codac_leaves_the_process_rounding_to_nearest():
    before = rounding_mode()
    with codac_calls() as codac:
        codac.Interval(0.1) + codac.Interval(0.2)
    assert rounding_mode() == before
    a = np.array([1.0])
    assert (a + 1e-17)[0] == 1.0                     # upward rounding would give 1.0000000000000002


def test_decimal_constants_become_intervals_that_hold_them():
    lo, hi = iv.from_decimal("0.1")
    assert Fraction(float(lo)) < Fraction("0.1") < Fraction(float(hi))
    assert hi == math.nextafter(float(lo), math.inf)
    lo, hi = iv.from_decimal("0.5")                                           # exact: degenerate
    assert lo == hi == 0.5
    s = iv.add(iv.from_decimal("0.1"), iv.from_decimal("0.2"))
    assert s[0] <= Fraction("0.3") <= s[1] and not (0.1 + 0.2 <= s[0])       # 0.30000000000000004 inside, 0.3 too


def test_empty_sets_propagate_without_exceptions():
    e = iv.interval(np.inf, -np.inf)
    x = iv.interval(1.0, 2.0)
    for r in (iv.add(e, x), iv.sub(x, e), iv.mul(e, x), iv.sqr(e), iv.sqrt(e), iv.sin(e), iv.cos(e),
              iv.div(x, e), iv.atan2(e, x), iv.inter(x, iv.interval(3.0, 4.0))):
        assert iv.is_empty(r)
    assert iv.is_empty(iv.sqrt(iv.interval(-2.0, -1.0)))
    assert iv.width(e) == 0.0


def test_unbounded_intervals_and_zero_times_infinity():
    lo, hi = iv.mul(iv.interval(0.0, 0.0), iv.interval(-np.inf, np.inf))
    assert (lo, hi) == (0.0, 0.0) or (lo <= 0 <= hi and np.isfinite(lo) and np.isfinite(hi))
    lo, hi = iv.sqr(iv.interval(-np.inf, 2.0))
    assert lo == 0.0 and hi == np.inf


def test_backward_square_keeps_both_roots_hull():
    x = iv.bwd_sqr(iv.interval(4.0, 9.0), iv.interval(-10.0, 10.0))
    assert x[0] <= -3.0 and x[1] >= 3.0 and x[1] < 3.0 + 1e-12
    x = iv.bwd_sqr(iv.interval(4.0, 9.0), iv.interval(0.0, 10.0))
    assert 2.0 - 1e-12 < x[0] <= 2.0 and 3.0 <= x[1] < 3.0 + 1e-12
