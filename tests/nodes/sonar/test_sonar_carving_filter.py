"""Carving's evidence filter (nodes.sonar.carving_filter): the numpy tree ensemble gives scikit-learn's
probabilities, the shipped model loads, bad features and a model for other features are refused; a grid's voxels'
neighbours are counted right at its faces."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nodes.sonar import carving_filter
from nodes.sonar.carving import CarvingGrid, CarvingParams
from nodes.sonar.carving_filter import (FEATURES, export_model, feature_matrix, load_model, neighbours,
                                        surface_probability)


def test_the_exported_ensemble_gives_sklearn_s_probabilities(tmp_path) -> None:
    ensemble = pytest.importorskip("sklearn.ensemble")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, len(FEATURES)))
    y = x[:, 0] + x[:, 3] * x[:, 7] - 0.5 * np.abs(x[:, 11]) > 0          # interactions: the trees need depth
    clf = ensemble.HistGradientBoostingClassifier(max_depth=3, max_iter=20, random_state=0).fit(x, y)
    path = tmp_path / "model.json"
    export_model(clf, path, threshold_p=0.7, trained_on=["synthetic"], max_depth=3)
    model = load_model.__wrapped__(path)
    test = rng.normal(size=(500, len(FEATURES)))
    assert np.allclose(surface_probability(test, model), clf.predict_proba(test)[:, 1], atol=1e-9)
    assert model["threshold_p"] == 0.7 and model["trained_on"] == ["synthetic"]


def test_the_shipped_model_loads_and_scores_every_row() -> None:
    model = load_model()
    assert 0.5 <= model["threshold_p"] < 1 and model["trees"] > 0 and model["value"].shape[1] == 2 ** model["depth"]
    evidence = {k: np.linspace(0.0, 20.0, 7) for k in FEATURES}
    p = surface_probability(feature_matrix(evidence), model)
    assert p.shape == (7,) and np.all((p >= 0) & (p <= 1))
    assert surface_probability(np.zeros((0, len(FEATURES))), model).shape == (0,)


def test_missing_features_and_a_model_for_other_features_are_refused(tmp_path) -> None:
    with pytest.raises(ValueError, match="lacks"):
        feature_matrix({"hits": np.ones(3)})
    path = tmp_path / "other.json"
    path.write_text(json.dumps(dict(features=["hits"], baseline=0.0, threshold_p=0.5, trees=[])))
    with pytest.raises(ValueError, match="trained on features"):
        load_model.__wrapped__(path)
    assert carving_filter.MODEL_PATH.is_file()


def test_voted_neighbours_are_counted_over_the_3x3x3_block_also_at_the_grid_s_faces() -> None:
    grid = CarvingGrid(((0, 0, 0), (0.5, 0.4, 0.3)), CarvingParams(voxel_m=0.1))      # 5 x 4 x 3 voxels
    voxels = np.random.default_rng(0).choice(60, 25, replace=False)
    ijk = np.stack(np.unravel_index(voxels, grid.shape), axis=1)
    brute = (np.abs(ijk[:, None, :] - ijk[None, :, :]).max(axis=2) <= 1).sum(axis=1)
    assert np.array_equal(neighbours(grid, voxels), brute)
    assert np.array_equal(neighbours(grid, voxels), brute)                          # the scratch is clean again
    among = np.union1d(voxels, np.arange(0, 60, 7))                                 # counted among a larger set
    other = np.stack(np.unravel_index(among, grid.shape), axis=1)
    assert np.array_equal(neighbours(grid, voxels, among),
                          (np.abs(ijk[:, None, :] - other[None, :, :]).max(axis=2) <= 1).sum(axis=1))
