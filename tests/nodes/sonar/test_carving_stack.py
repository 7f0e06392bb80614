"""bench/sonar_carving_filter's second stage (``--stack``, measured, not shipped): the context it reads off the first
stage's probabilities -- an isolated confident voxel among doubtful neighbours looks isolated, a voxel inside a
confident surface looks surrounded, the most probable voxel up or down its column is its competitor, and nothing wraps
round the grid's faces; a voxel's arc rivals are the voted voxels its voting arcs also found near-best."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))

SHAPE = (20, 20, 30)


def _context(cells: dict[tuple[int, int, int], float]) -> dict[str, np.ndarray]:
    from sonar_carving_filter import CONTEXT_NAMES, neighbour_context

    voxels = np.ravel_multi_index(np.array(list(cells)).T, SHAPE)
    out = neighbour_context(voxels, SHAPE, np.array(list(cells.values())))
    assert out.shape == (len(cells), len(CONTEXT_NAMES))
    return {name: out[:, i] for i, name in enumerate(CONTEXT_NAMES)}


def test_an_isolated_confident_voxel_among_doubtful_ones_and_one_inside_a_confident_surface() -> None:
    ghost = {(5, 5, 10): 0.9} | {(5 + a, 5 + b, 10): 0.1 for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)}
    wall = {(12 + a, 12 + b, 10): 0.9 for a in (-2, -1, 0, 1, 2) for b in (-2, -1, 0, 1, 2)}
    c = _context(ghost | wall)
    g, w = 0, len(ghost) + 12                                     # the ghost; the wall's centre (12, 12, 10)
    assert c["p1"][g] == c["p1"][w] == 0.9                       # alike to the first stage
    assert c["b3_n"][g] == c["b3_n"][w] == 8
    assert np.isclose(c["b3_mean"][g], 0.1) and np.isclose(c["b3_max"][g], 0.1) and c["b3_above"][g] == 0
    assert np.isclose(c["b3_mean"][w], 0.9) and c["b3_above"][w] == 8
    assert c["b5_n"][w] == 24 and c["b5_above"][w] == 24 and c["b5_above"][g] == 0


def test_the_column_s_most_probable_other_voxel_is_the_competitor() -> None:
    cells = {(8, 8, 10): 0.6, (8, 9, 15): 0.9,     # in its column, 0.5 m up: the competitor
             (8, 8, 11): 0.99,                      # next to it: a neighbour, not a competitor
             (8, 8, 21): 0.99, (10, 8, 14): 0.99}   # beyond 1 m, outside the 3 x 3 column
    c = _context(cells)
    assert np.isclose(c["col_max"][0], 0.9) and c["col_n"][0] == 1 and c["col_above"][0] == 1
    assert np.isclose(c["p1_minus_col_max"][0], 0.6 - 0.9)
    assert c["b3_n"][0] == 1 and np.isclose(c["b3_max"][0], 0.99)


def test_nothing_wraps_round_the_grid_s_faces() -> None:
    nx, ny, nz = SHAPE
    cells = {(0, 0, 0): 0.8, (nx - 1, ny - 1, nz - 1): 0.8, (0, 0, nz - 1): 0.8, (nx - 1, 0, 0): 0.8}
    c = _context(cells)
    for name in ("b3_n", "b5_n", "col_n", "b5_max", "col_max"):
        assert np.all(c[name] == 0), name


def test_a_voxel_s_arc_rivals_are_the_voted_voxels_its_arcs_also_found_near_best() -> None:
    from sonar_carving_filter import RIVAL_NAMES, arc_rivals

    voxels = np.array([10, 20, 30, 40])                      # voted voxels (flat indices), first-stage probabilities:
    p1 = np.array([0.6, 0.9, 0.3, 0.8])
    pairs = np.array([[10, 20], [10, 30], [10, 99],          # 10's arcs also found 20, 30 and 99 (99 not voted)
                      [40, 30]])                             # 40 has one doubtful rival; 20 and 30 none
    r = {name: arc_rivals(voxels, pairs, p1)[:, i] for i, name in enumerate(RIVAL_NAMES)}
    assert np.allclose(r["rival_max"], [0.9, 0.0, 0.0, 0.3])
    assert np.array_equal(r["rival_voted"], [2, 0, 0, 1]) and np.array_equal(r["rivals"], [3, 0, 0, 1])
    assert np.array_equal(r["rival_above"], [1, 0, 0, 0])
    assert np.allclose(r["p1_minus_rival_max"], [0.6 - 0.9, 0.9, 0.3, 0.8 - 0.3])
