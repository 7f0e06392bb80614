"""Per-cell robust motion (features.cell_motion) and the two predictions built on it: a few wrong flow
vectors on a person must not predict them where they are not going (group scene, t = 4.3 s)."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.features import GridSpec, cell_motion, conflict_cells
from nodes.nav.grid_frame import GridFrame
from nodes.nav.plan_geometry import predict_conflicts


def _walker_passing_behind(seed: int, n: int = 400, wrong_frac: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A person beside the robot (0.8 m ahead, 0.9 m left) walking backward at 0.85 m/s; a tenth of
    their flow vectors point forward-left together (what dense flow gave near the image edge in a turn)."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(0.70, 0.95, n), rng.uniform(0.80, 1.05, n), rng.uniform(0.3, 1.7, n)])
    vel = np.tile([-0.85, 0.05, 0.0], (n, 1)) + rng.normal(0.0, 0.03, (n, 3))
    bad = rng.random(n) < wrong_frac
    vel[bad, :2] = [0.5, 0.45] + rng.normal(0.0, 0.03, (bad.sum(), 2))
    return pts, vel


def test_cell_motion_takes_each_cells_median():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.uniform(0.0, 0.25, 50), rng.uniform(0.0, 0.25, 50)])
    b = np.column_stack([rng.uniform(1.0, 1.25, 30), rng.uniform(0.0, 0.25, 30)])
    va = np.tile([1.0, 0.0], (50, 1))
    va[:10] = [-5.0, 9.0]                                  # a fifth of the vectors are wrong
    vb = np.tile([0.0, -0.5], (30, 1))
    xy, v, n, of_point = cell_motion(np.vstack([a, b]), np.vstack([va, vb]), 0.25)
    order = np.argsort(xy[:, 0])
    assert n[order].tolist() == [50, 30]
    assert v[order].tolist() == [[1.0, 0.0], [0.0, -0.5]]
    assert np.all((xy[order[0]] >= 0) & (xy[order[0]] < 0.25))       # the median stays in its cell
    assert np.array_equal(of_point, np.r_[np.full(50, order[0]), np.full(30, order[1])])
    empty = cell_motion(np.zeros((0, 2)), np.zeros((0, 2)), 0.25)
    assert [x.shape[0] for x in empty] == [0, 0, 0, 0]
    with pytest.raises(ValueError, match="cell_m"):
        cell_motion(a, va, 0.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_few_wrong_vectors_predict_nothing_ahead(seed: int):
    pts, vel = _walker_passing_behind(seed)
    frame = GridFrame((24, 24), 0.25, -0.375, -2.875)
    mask = predict_conflicts(pts, vel, frame, robot_speed_mps=1.0, horizon_s=2.0)
    ahead = frame.xy_of(np.argwhere(mask))
    assert len(ahead) and ahead[:, 0].max() < 0.9            # they are predicted where they go: backward
    assert not predict_conflicts(pts[:4], vel[:4], frame, robot_speed_mps=1.0).any()   # too few points to trust
    grid = GridSpec(-0.5, 5.5, -3.0, 3.0, 0.25)
    hit = conflict_cells(pts, vel, grid, min_points=20)
    x, _ = grid.centres()
    assert hit.any() and x[hit].max() < 1.0


def test_every_vector_counted_as_before_when_flow_is_clean():
    """Clean flow: the per-cell median changes nothing (same cells as moving each point)."""
    pts, vel = _walker_passing_behind(4, wrong_frac=0.0)
    vel[:, :2] = [0.0, -1.0]                                  # now crossing to the right in front of the robot
    pts[:, 0] += 2.0
    grid = GridSpec(-0.5, 5.5, -3.0, 3.0, 0.25)
    hit = conflict_cells(pts, vel, grid, min_points=20)
    _, y = grid.centres()
    assert hit.any() and y[hit].min() < -1.0                  # marked on their way across
