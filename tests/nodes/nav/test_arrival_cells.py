"""Space-time occupancy from where people really go (learning from recorded walkers) against the running robot's
constant-velocity prediction of it: the same question, asked of different futures."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.features import GridSpec, arrival_cells, conflict_cells

GRID = GridSpec()
TAUS = np.arange(0.0, 6.0 + 1e-9, 0.25)


def _bodies(centres: np.ndarray, rng: np.random.Generator, n: int = 40) -> np.ndarray:
    return np.repeat(centres, n, axis=0) + rng.uniform(-0.2, 0.2, (len(centres) * n, 2))


def test_constant_velocity_futures_mark_exactly_the_conflict_cells():
    rng = np.random.default_rng(3)
    for _ in range(10):
        k = int(rng.integers(1, 4))
        centres = rng.uniform([0.5, -2.5], [5.0, 2.5], (k, 2))
        vel = rng.uniform(-1.3, 1.3, (k, 2)) * (rng.random((k, 1)) > 0.3)      # some stand still
        xy = _bodies(centres, rng)
        v = np.repeat(vel, 40, axis=0)
        want = conflict_cells(np.column_stack([xy, np.ones(len(xy))]), np.column_stack([v, np.zeros(len(v))]), GRID)
        got = arrival_cells(xy[:, None, :] + v[:, None, :] * TAUS[None, :, None], TAUS, GRID)
        np.testing.assert_array_equal(got, want)


def test_a_walker_who_turns_marks_where_they_went_not_where_they_were_heading():
    rng = np.random.default_rng(4)
    xy = _bodies(np.array([[2.0, -2.0]]), rng)
    # walking +y at 1 m/s toward the robot's line, then turning toward the robot (-x) after 1 s
    centre = np.where(TAUS[:, None] <= 1.0, [[2.0, -2.0]] + np.outer(TAUS, [0.0, 1.0]),
                      [[2.0, -1.0]] + np.outer(TAUS - 1.0, [-1.0, 0.0]))
    paths = (xy - [2.0, -2.0])[:, None, :] + centre[None]
    real = arrival_cells(paths, TAUS, GRID)
    straight = conflict_cells(np.column_stack([xy, np.ones(len(xy))]), np.tile([0.0, 1.0, 0.0], (len(xy), 1)), GRID)
    on_line = np.abs(GRID.centres()[1]) < 0.3
    assert (straight & on_line).any() and not (real & on_line).any()      # they never crossed the robot's line
    hit = np.argwhere(real)
    assert len(hit) and np.allclose(GRID.centres()[1][real], -1.0, atol=0.45)   # ... but are met where they did go


def test_unknown_futures_mark_nothing_and_bad_shapes_say_what_is_wrong():
    rng = np.random.default_rng(5)
    xy = _bodies(np.array([[3.0, -1.0]]), rng)
    paths = xy[:, None, :] + np.outer(TAUS, [0.0, 0.5])[None]
    paths[:, 2:] = np.nan                                  # left the data after 0.25 s: moving, but nowhere known
    assert not arrival_cells(paths, TAUS, GRID).any()
    assert arrival_cells(np.zeros((0, len(TAUS), 2)), TAUS, GRID).shape == GRID.shape
    with pytest.raises(ValueError, match="paths_m must be"):
        arrival_cells(np.zeros((3, 4, 2)), TAUS, GRID)
