"""Leave-one-scene-out learning of the crowd cost with the space-time 'conflict' feature."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.demos import DemoSet
from nodes.nav.dijkstra import plan_dijkstra
from nodes.nav.irl import Demo, cell_costs
from nodes.nav.irl_learn import fit_and_report, leave_one_scene_out, oracle_weights

#: walkers who price a conflict cell at 3x the step cost and nothing else of the crowd
TRUE_W = np.zeros(13)
TRUE_W[12] = 6.0


def scene(rng: np.random.Generator, rows: int = 11, cols: int = 14) -> Demo:
    feats = np.zeros((rows, cols, 13), np.uint8)
    feats[..., 2] = feats[..., 5] = feats[..., 8] = feats[..., 10] = 1      # low crowd everywhere, goal medium
    for _ in range(3):                                                       # people who will be in the way
        r, c = int(rng.integers(2, rows - 2)), int(rng.integers(3, cols - 3))
        feats[r - 1:r + 2, c - 1:c + 2, 12] = 1
    start, goal = (rows // 2, 0), (int(rng.integers(0, rows)), cols - 1)
    return Demo(feats, plan_dijkstra(cell_costs(feats, TRUE_W), start, goal).cells)


def test_folds_learn_the_conflict_price_and_beat_the_shortest_path_on_the_held_out_scene():
    rng = np.random.default_rng(3)
    demos = DemoSet({name: [scene(rng) for _ in range(8)] for name in ("a", "b", "c")})
    folds = leave_one_scene_out(demos)
    assert set(folds) == {"a", "b", "c"}
    for fold in folds.values():
        s = fold["scores"]
        assert fold["weights"][12] > 1.0                                   # a conflict cell costs well above a free one
        assert s["action_agreement"] > s["action_agreement_shortest_path"]
        assert {"action_agreement_oracle", "moves", "demos"} <= set(s)


def test_a_demonstration_set_from_one_scene_only_is_a_clear_error():
    """Hard case: nothing to hold out against (and nothing left to train on when it is held out)."""
    rng = np.random.default_rng(4)
    one = DemoSet({"only": [scene(rng) for _ in range(3)]})
    with pytest.raises(ValueError, match="at least 2 scenes"):
        leave_one_scene_out(one)
    with pytest.raises(ValueError, match="no training demonstrations"):
        fit_and_report(one, holdout=set(), oracle_scenes=set())
    weights, report = fit_and_report(one, holdout={"elsewhere"}, oracle_scenes=set())    # trains on it, scores nothing else
    assert weights.names[-1] == "conflict" and list(report) == ["train"]


def test_the_oracle_table_gets_a_zero_conflict_weight():
    assert oracle_weights(13)[12] == 0 and len(oracle_weights(12)) == 12
