"""The evidence filter's per-cloud keep rule (nodes.sonar.carving_filter.keep_calibrated / select): keep voxels in
decreasing calibrated probability while the kept set's mean stays >= the target -- a cloud of high probabilities keeps
more, nothing usable keeps nothing and says why, the stored calibration map is monotone and checked."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nodes.sonar.carving_filter import (FEATURES, MODEL_PATH, calibrate, export_model, keep_calibrated, load_model,
                                        select)

# a monotone map that says the model is over-confident below 0.5 and about right above
CAL = (np.array([0.0, 0.5, 0.8, 1.0]), np.array([0.0, 0.3, 0.8, 0.99]))


def brute_force(q: np.ndarray, target: float) -> np.ndarray:
    """The largest set of the most probable voxels (whole runs of equal calibrated values) whose mean >= target."""
    best = np.zeros(q.size, bool)
    for t in np.unique(q):
        s = q >= t
        if q[s].mean() >= target and s.sum() > best.sum():
            best = s
    return best


def test_a_cloud_whose_probabilities_are_high_keeps_more_and_the_kept_mean_meets_the_target() -> None:
    rng = np.random.default_rng(0)
    high = rng.beta(8.0, 1.0, 4000)           # a pass the model finds mostly on the surface
    low = rng.beta(2.0, 2.0, 4000)            # one it finds mostly unsure
    k_high = keep_calibrated(high, CAL, target_precision=0.9)
    k_low = keep_calibrated(low, CAL, target_precision=0.9)
    assert k_high.keep.sum() > 2 * k_low.keep.sum() > 0
    assert k_high.threshold_p < k_low.threshold_p          # the threshold follows the cloud, not a constant
    for p, k in ((high, k_high), (low, k_low)):
        q = calibrate(p, CAL)
        assert k.expected_precision == pytest.approx(q[k.keep].mean()) and k.expected_precision >= 0.9
        assert np.array_equal(k.keep, brute_force(q, 0.9))               # and no larger set would do
        assert k.threshold_p == pytest.approx(p[k.keep].min()) and k.note == ""


def test_equal_calibrated_probabilities_are_kept_or_dropped_together() -> None:
    flat = (np.array([0.0, 0.6, 0.7, 1.0]), np.array([0.0, 0.9, 0.9, 1.0]))    # 0.6-0.7 all calibrate to 0.9
    p = np.array([0.95, 0.65, 0.62, 0.68, 0.1])
    k = keep_calibrated(p, flat, target_precision=0.92)
    assert k.keep.tolist() == [True, True, True, True, False]     # the 0.9 run kept whole: (0.975 + 3 x 0.9) / 4
    k = keep_calibrated(p, flat, target_precision=0.94)
    assert k.keep.tolist() == [True, False, False, False, False]  # ... or dropped whole


@pytest.mark.parametrize("p, says", [(np.zeros(0), "no voxels"), (np.full(50, np.nan), "NaN"),
                                     (np.zeros(50), "nothing kept")])
def test_empty_nan_or_zero_probabilities_keep_nothing_and_say_so(p: np.ndarray, says: str) -> None:
    k = keep_calibrated(p, CAL, target_precision=0.9)
    assert k.keep.shape == p.shape and not k.keep.any()
    assert k.threshold_p is None and k.expected_precision is None and says in k.note
    t = select(p, {"threshold_p": 0.85, "calibration": CAL})          # the global threshold too
    assert not t.keep.any() and t.note


def test_nan_probabilities_are_never_kept() -> None:
    p = np.array([0.99, np.nan, 0.98, np.nan, 0.97])
    for k in (keep_calibrated(p, CAL, target_precision=0.5), select(p, {"threshold_p": 0.5, "calibration": None})):
        assert k.keep.tolist() == [True, False, True, False, True]


def test_the_exported_calibration_map_is_monotone_and_reproduces_sklearn(tmp_path) -> None:
    ensemble = pytest.importorskip("sklearn.ensemble")
    isotonic = pytest.importorskip("sklearn.isotonic")
    rng = np.random.default_rng(2)
    x = rng.normal(size=(3000, len(FEATURES)))
    y = x[:, 0] + 0.8 * rng.normal(size=3000) > 0
    clf = ensemble.HistGradientBoostingClassifier(max_depth=3, max_iter=20, random_state=0).fit(x[:2000], y[:2000])
    q = clf.predict_proba(x[2000:])[:, 1]
    iso = isotonic.IsotonicRegression(y_min=0.0, y_max=1.0, out_of_bounds="clip").fit(q, y[2000:])
    path = tmp_path / "model.json"
    export_model(clf, path, threshold_p=0.8, trained_on=["synthetic"], max_depth=3, calibration=iso,
                 target_precision=0.9)
    model = load_model.__wrapped__(path)
    cp, on = model["calibration"]
    assert np.all(np.diff(cp) > 0) and np.all(np.diff(on) >= 0) and model["target_precision"] == 0.9
    test = np.r_[rng.random(500), -0.1, 1.1]
    assert np.allclose(calibrate(test, model["calibration"]), iso.predict(test))
    k = select(q, model, keep_rule="calibrated")
    assert np.array_equal(k.keep, keep_calibrated(q, model["calibration"], target_precision=0.9).keep)
    assert k.expected_precision >= 0.9


def test_a_non_monotone_map_and_a_model_without_one_are_refused(tmp_path) -> None:
    data = json.loads(MODEL_PATH.read_text())
    data["calibration"] = {"p": [0.0, 0.5, 1.0], "on_frac": [0.1, 0.8, 0.6]}         # would reorder voxels
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="non-decreasing"):
        load_model.__wrapped__(path)
    with pytest.raises(ValueError, match="no calibration map"):
        select(np.ones(3), {"threshold_p": 0.8, "calibration": None}, keep_rule="calibrated")
    with pytest.raises(ValueError, match="keep_rule"):
        select(np.ones(3), {"threshold_p": 0.8, "calibration": None}, keep_rule="best")
    with pytest.raises(ValueError, match="target_precision"):
        keep_calibrated(np.ones(3), CAL, target_precision=1.5)


def test_the_shipped_model_carries_a_monotone_calibration_and_its_target() -> None:
    model = load_model()
    assert model["calibration"] is not None, "retrain with bench/sonar_carving_filter.py --write"
    cp, on = model["calibration"]
    assert np.all(np.diff(cp) > 0) and np.all(np.diff(on) >= 0) and 0.5 < model["target_precision"] < 1
