"""IrlCost node: cost = c0 + w . phi per cell, weights matched by feature name, bad grids dropped."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.nav import CostGrid, FeatureGrid
from nodes.nav.irl import CostWeights
from nodes.nav.irl_cost import DEFAULT_WEIGHTS, IrlCost, load_weights
from tether.testing import Harness

NAMES = ["density_high", "density_low", "speed_high"]


@pytest.fixture
def weights_file(tmp_path):
    path = tmp_path / "w.json"
    path.write_text(CostWeights(tuple(NAMES), np.array([3.0, 0.0, 1.0]), 2.5).to_json())
    return str(path)


def grid(features, names=NAMES, **kw) -> FeatureGrid:
    return FeatureGrid(features=np.asarray(features, np.uint8), names=list(names), resolution_m=0.25,
                       origin_x_m=0.5, origin_y_m=-1.0, frame_id="base", stamp_ns=7, **kw)


def test_cost_is_step_cost_plus_weighted_features(weights_file):
    f = np.zeros((4, 5, 3), np.uint8)
    f[1, 2, 0] = 1
    f[3, 4, 2] = 1
    f[0, 0, :] = 1
    with Harness(IrlCost, params={"weights_path": weights_file}) as h:
        out = h.feed([(0.0, "features", grid(f))])
    msg = out[0].msg
    assert isinstance(msg, CostGrid) and msg.cost.shape == (4, 5) and msg.stamp_ns == 7
    assert (msg.resolution_m, msg.origin_x_m, msg.origin_y_m, msg.frame_id) == (0.25, 0.5, -1.0, "base")
    expected = np.full((4, 5), 2.5)
    expected[1, 2] += 3.0
    expected[3, 4] += 1.0
    expected[0, 0] += 4.0
    np.testing.assert_allclose(msg.cost, expected)
    assert np.all(msg.cost > 0)


def test_weights_follow_feature_names_not_positions(weights_file):
    f = np.zeros((1, 1, 2), np.uint8)
    f[0, 0, 0] = 1                                    # first column is speed_high here
    with Harness(IrlCost, params={"weights_path": weights_file}) as h:
        out = h.feed([(0.0, "features", grid(f, names=["speed_high", "density_high"]))])
    assert out[0].msg.cost[0, 0] == pytest.approx(2.5 + 1.0)


def test_unknown_feature_and_wrong_shape_are_dropped_and_counted(weights_file):
    with Harness(IrlCost, params={"weights_path": weights_file}) as h:
        out = h.feed([(0.0, "features", grid(np.zeros((2, 2, 1)), names=["mystery"])),
                      (0.1, "features", grid(np.zeros((2, 2, 4)), names=[])),
                      (0.2, "features", grid(np.ones((2, 2, 3))))])
        assert h.node.bad_inputs == 2
    assert len(out) == 1 and out[0].msg.cost[0, 0] == pytest.approx(6.5)


def test_empty_grid_gives_an_empty_cost_grid(weights_file):
    with Harness(IrlCost, params={"weights_path": weights_file, "step_cost": 4.0}) as h:
        out = h.feed([(0.0, "features", grid(np.zeros((0, 0, 3))))])
    assert out[0].msg.cost.shape == (0, 0)


def test_shipped_default_weights_load_and_are_strictly_positive():
    w = load_weights()
    assert DEFAULT_WEIGHTS.is_file() and len(w.names) == len(w.weights) == 13 and w.names[-1] == "conflict"
    assert w.step_cost > 0 and np.all(w.weights >= 0)
    with pytest.raises(FileNotFoundError, match="irl_learn"):
        load_weights("/nonexistent/weights.json")


def test_weights_learnt_before_the_conflict_feature_price_it_zero(weights_file):
    f = np.zeros((1, 2, 4), np.uint8)
    f[0, 0, 3] = 1                                    # a conflict cell: the old cost, unchanged
    f[0, 1, 0] = 1
    with Harness(IrlCost, params={"weights_path": weights_file}) as h:
        out = h.feed([(0.0, "features", grid(f, names=NAMES + ["conflict"]))])
        assert h.node.bad_inputs == 0
    np.testing.assert_allclose(out[0].msg.cost[0], [2.5, 5.5])
