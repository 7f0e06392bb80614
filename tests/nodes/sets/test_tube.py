"""Whole-history contractors: the vectorised chain against a sequential interval loop, SLAM
containment and the effect of revisiting a marker, graph edges to a fixpoint."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.sets import interval as iv
from nodes.sets.localize import displacement
from nodes.sets.tube import SetSlam, contract_chain, contract_edges
from sim.markers import MarkerWorld


def _sequential_chain(lo, hi, dlo, dhi):
    lo, hi = lo.copy(), hi.copy()
    for k in range(len(dlo)):                       # forward, one interval addition per step
        a = iv.add((lo[k], hi[k]), (dlo[k], dhi[k]))
        lo[k + 1], hi[k + 1] = np.maximum(lo[k + 1], a[0]), np.minimum(hi[k + 1], a[1])
    for k in range(len(dlo) - 1, -1, -1):
        a = iv.sub((lo[k + 1], hi[k + 1]), (dlo[k], dhi[k]))
        lo[k], hi[k] = np.maximum(lo[k], a[0]), np.minimum(hi[k], a[1])
    return lo, hi


def test_vectorised_chain_matches_the_sequential_loop_and_encloses_it():
    rng = np.random.default_rng(0)
    k = 500
    d = rng.normal(0, 1, (k, 2))
    w = rng.uniform(0.01, 0.1, (k, 2))
    lo, hi = np.full((k + 1, 2), -np.inf), np.full((k + 1, 2), np.inf)
    lo[0] = hi[0] = 0.0
    lo[300], hi[300] = [5.0, -3.0], [5.5, -2.0]           # a fix in the middle
    lo[300] = np.minimum(lo[300], d[:300].sum(0) - 0.5)
    hi[300] = np.maximum(hi[300], d[:300].sum(0) + 0.5)
    a = contract_chain(lo, hi, d - w, d + w)
    b = _sequential_chain(lo, hi, d - w, d + w)
    assert np.allclose(a[0], b[0], atol=1e-9) and np.allclose(a[1], b[1], atol=1e-9)
    assert np.all(a[0] <= b[0] + 1e-15) or np.all(a[0] <= b[0] + 1e-9)          # never tighter than rigorous
    truth = np.concatenate([[np.zeros(2)], np.cumsum(d, 0)])
    assert np.all((a[0] <= truth) & (truth <= a[1]))


def test_chain_refuses_unbounded_steps():
    with pytest.raises(ValueError, match="finite"):
        contract_chain(np.zeros((2, 2)), np.zeros((2, 2)), np.full((1, 2), -np.inf), np.zeros((1, 2)))


def _run_slam(steps, seed=1, **kw):
    world = MarkerWorld("seed", seed=seed, nearest_only=True, **kw)
    slam = SetSlam(np.zeros((2, 2)), len(world.markers))
    truth = [np.zeros(2)]
    widths = []
    for _ in range(steps):
        s = world.step()
        truth.append(s.truth_xy)
        slam.add_step(displacement(s.distance_m, s.heading_rad), [(o.marker, *o.range_m) for o in s.observed])
        slam.contract()
        widths.append((slam.x_hi - slam.x_lo).max(1).copy())
    return world, slam, np.array(truth), widths


def test_slam_tube_and_markers_hold_the_truth_and_markers_get_bounded():
    world, slam, truth, _ = _run_slam(100)
    assert slam.consistent
    assert np.all((slam.x_lo <= truth) & (truth <= slam.x_hi))
    seen = np.isfinite(slam.m_lo).all(1)
    assert seen.sum() >= 2
    m = world.markers[seen]
    assert np.all((slam.m_lo[seen] <= m) & (m <= slam.m_hi[seen]))
    assert np.sum((slam.m_hi - slam.m_lo).max(1)[seen] < 3.0) >= 2


def test_a_later_observation_contracts_the_past():
    _, slam, _, widths = _run_slam(100)
    final = (slam.x_hi - slam.x_lo).max(1)
    shrink = [(widths[k][:k + 2] - final[:k + 2]) for k in range(100)]   # the tube as known at step k, then at the end
    assert all(s.min() >= -1e-9 for s in shrink)                          # boxes never grow
    assert max(s.max() for s in shrink) > 0.1                             # later ranges shrank earlier boxes


def test_a_broken_bound_empties_the_tube_instead_of_returning_a_wrong_one():
    world = MarkerWorld("seed", seed=4, nearest_only=True)
    slam = SetSlam(np.zeros((2, 2)), 4)
    for k in range(30):
        s = world.step()
        obs = [(o.marker, *o.range_m) for o in s.observed]
        if k == 20 and obs:
            j, r0, r1 = obs[0]
            obs[0] = (j, r0 + 8.0, r1 + 8.0)
        slam.add_step(displacement(s.distance_m, s.heading_rad), obs)
        slam.contract()
    assert not slam.consistent


def test_edges_reach_a_fixpoint_and_hold_the_truth():
    rng = np.random.default_rng(2)
    n = 8
    x = rng.uniform(0, 100, (n, 2))
    i = np.array([0, 1, 2, 3, 4, 5, 6, 0, 1, 2])
    j = np.array([1, 2, 3, 4, 5, 6, 7, 7, 6, 5])
    err = 1.0
    z = x[j] - x[i] + rng.uniform(-err, err, (len(i), 2))
    lo, hi = np.full((n, 2), -np.inf), np.full((n, 2), np.inf)
    lo[0] = hi[0] = x[0]
    lo, hi, sweeps = contract_edges(lo, hi, i, j, z - err, z + err)
    assert np.all((lo <= x) & (x <= hi)) and sweeps < 100
    chain_only = contract_edges(np.where(np.arange(n)[:, None] == 0, x[0], -np.inf),
                                np.where(np.arange(n)[:, None] == 0, x[0], np.inf), i[:7], j[:7], z[:7] - err, z[:7] + err)
    assert np.all((hi - lo)[7] < (chain_only[1] - chain_only[0])[7])     # the loop closure shrinks the end
