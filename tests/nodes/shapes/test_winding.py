"""Winding numbers: the direct formula, the banded exact method and the dipole tree against
each other and against closed-form answers, with the issue's hard cases."""
from __future__ import annotations


import numpy as np
import pytest

from nodes.shapes.fast_winding import build_tree, fast_winding, mesh_tree, winding_mesh
from nodes.shapes.winding import segments_of, winding_direct, winding_numbers

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _flower(n=400, r=1.0):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rr = r * (1 + 0.3 * np.cos(5 * t))
    return np.stack([rr * np.cos(t), rr * np.sin(t)], 1)


def test_inside_outside_and_orientation():
    q = np.array([[0.5, 0.5], [2.0, 0.5], [-1.0, -1.0], [0.5, 3.0]])
    assert np.array_equal(winding_numbers(q, [SQUARE]), [1, 0, 0, 0])
    assert np.array_equal(winding_numbers(q, [SQUARE[::-1]]), [-1, 0, 0, 0])          # clockwise: -1
    twice = np.vstack([SQUARE, SQUARE])                                                # wound twice: 2
    assert np.allclose(winding_numbers(q[:1], [twice]), [2]) and np.allclose(winding_direct(q[:1], [twice]), [2])


def test_on_the_curve_is_the_mean_of_both_sides_and_near_it_is_the_side():
    on = np.array([[1.0, 0.5], [0.5, 0.0], [0.0, 0.0], [1.0, 1.0]])
    for f in (winding_numbers, winding_direct):
        assert np.allclose(f(on, [SQUARE]), [0.5, 0.5, 0.25, 0.25])                  # edge 1/2, corner 90/360
    near = np.array([[1.0 - 1e-12, 0.5], [1.0 + 1e-12, 0.5], [0.5, 1e-12], [0.5, -1e-12]])
    assert np.allclose(winding_numbers(near, [SQUARE]), [1, 0, 1, 0])
    assert np.allclose(winding_direct(near, [SQUARE]), [1, 0, 1, 0], atol=1e-9)


def test_degenerate_inputs():
    q = np.array([[0.5, 0.5], [5.0, 5.0]])
    dup = np.array([[0, 0], [1, 0], [1, 0], [1, 1], [1, 1], [0, 1]], float)           # zero-length segments
    assert np.allclose(winding_numbers(q, [dup]), [1, 0])
    assert np.array_equal(winding_numbers(q, [np.array([[0.3, 0.3]])]), [0, 0])       # a one-point contour
    assert np.array_equal(winding_numbers(q, []), [0, 0])
    cut = np.array([[0, 0], [1, 0], [np.nan, np.nan], [1, 1], [0, 1]], float)         # NaN cuts into open pieces
    w_cut = winding_numbers(q, [cut])
    assert np.all(np.isfinite(w_cut)) and np.allclose(w_cut, winding_direct(q, [cut]))
    assert 0 < w_cut[0] < 1
    assert np.isnan(winding_numbers(np.array([[np.nan, 0.0]]), [SQUARE]))[0]
    a, b, ca, _ = segments_of([cut], closed=True)
    assert len(a) == 2 and len(ca) == 2


def test_banded_method_equals_the_angle_sum_on_open_and_closed_curves():
    rng = np.random.default_rng(0)
    f = _flower()
    q = rng.uniform(-1.6, 1.6, (3000, 2))
    for curves, closed in (([f], True), ([f[:300]], False), ([f[::-1], 0.3 * f], True),
                           ([f[:150], f[200:380]], [False, False])):
        assert np.allclose(winding_numbers(q, curves, closed), winding_direct(q, curves, closed), atol=1e-9)


def test_gaps_lower_the_winding_number_smoothly():
    f = _flower(1000)
    q = np.array([[0.0, 0.0]])
    ws = [winding_numbers(q, [f[:int(1000 * (1 - g))]], closed=False)[0] for g in (0.0, 0.05, 0.1, 0.25)]
    assert ws[0] == pytest.approx(1.0, abs=2e-3)
    assert ws[0] > ws[1] > ws[2] > ws[3] > 0.5                # still inside at 25 % removed


@pytest.mark.parametrize("beta", [2.0, 3.0])
def test_dipole_tree_2d_error_falls_with_beta_away_from_the_curve(beta):
    f = 100 * _flower(2000)
    a, b, _, _ = segments_of([f])
    tree = build_tree(np.stack([a, b], 1))
    rng = np.random.default_rng(1)
    q = rng.uniform(-160, 160, (4000, 2))
    d = np.min(np.hypot(*(q[:, None] - f[None]).transpose(2, 0, 1)), axis=1)
    exact = winding_numbers(q, [f])
    err = np.abs(fast_winding(tree, q, beta=beta) - exact)[d > 3]
    assert err.max() < (0.03 if beta == 2.0 else 0.006)


def _sphere(n=25):
    u, v = np.linspace(0, np.pi, n), np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    pts = np.stack([np.sin(uu) * np.cos(vv), np.sin(uu) * np.sin(vv), np.cos(uu)], -1).reshape(-1, 3)
    idx = np.arange(len(pts)).reshape(n, 2 * n)
    faces = []
    for i in range(n - 1):
        for j in range(2 * n):
            a, b, c, d = idx[i, j], idx[i, (j + 1) % (2 * n)], idx[i + 1, j], idx[i + 1, (j + 1) % (2 * n)]
            faces += [[a, c, b], [b, c, d]]
    return pts, np.array(faces)


def test_solid_angles_give_one_inside_a_closed_mesh_and_a_half_for_a_hemisphere():
    v, f = _sphere()
    q = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [2.0, 0.0, 0.0], [0.0, 0.0, -3.0]])
    assert np.allclose(winding_mesh(q, v, f), [1, 1, 0, 0], atol=1e-9)
    assert np.allclose(winding_mesh(q, v, f[:, ::-1]), [-1, -1, 0, 0], atol=1e-9)       # flipped faces: -1
    upper = f[np.all(v[f][:, :, 2] >= -1e-9, axis=1)]                                     # an open hemisphere
    assert winding_mesh(q[:1], v, upper)[0] == pytest.approx(0.5, abs=0.02)
    tree = mesh_tree(v, f)
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1.5, 1.5, (3000, 3))
    r = np.linalg.norm(pts, axis=1)
    pts = pts[np.abs(r - 1) > 0.1]
    assert np.abs(fast_winding(tree, pts, beta=2.0) - winding_mesh(pts, v, f)).max() < 0.02
    assert np.isnan(fast_winding(tree, np.array([[np.nan, 0, 0]]))[0])


def test_tree_rejects_bad_shapes_and_ignores_degenerate_elements():
    with pytest.raises(ValueError, match="segments"):
        build_tree(np.zeros((4, 3, 2)))
    segs = np.array([[[0, 0], [0, 0]], [[0, 0], [1, 0]], [[1, 0], [np.nan, 1]]], float)
    assert len(build_tree(segs).elems) == 1
