"""Pedestrian trajectory prediction: encoding, baselines, the learnt MLP on a synthetic turning walker, robustness."""
import numpy as np
import pytest

from nodes.nav.predict import (N_INPUTS, OBS_STEPS, PRED_STEPS, STEP_S, BaselinePredictor, MlpPredictor, encode,
                               errors, fill_history, positions_at, predict_cv, predict_damped, resample_scene,
                               scene_samples)
from sim.pedestrian_data import Tracks


def _turning_scene(rng, walkers=40, steps=60):
    """(T, P, 2) walkers at 0.4 s, each at 1.0-1.5 m/s turning at a constant rate of +-0.15-0.35 rad/s."""
    xy = np.zeros((steps, walkers, 2))
    for p in range(walkers):
        speed, rate = rng.uniform(1.0, 1.5), rng.choice([-1, 1]) * rng.uniform(0.15, 0.35)
        yaw0, start = rng.uniform(-np.pi, np.pi), rng.uniform(-40, 40, 2)
        yaw = yaw0 + rate * STEP_S * np.arange(steps)
        xy[:, p] = start + np.cumsum(speed * STEP_S * np.column_stack([np.cos(yaw), np.sin(yaw)]), axis=0)
    return xy


def _random_mlp(rng, hidden=8):
    layers = ((rng.normal(0, 0.1, (N_INPUTS, hidden)), np.zeros(hidden)),
              (rng.normal(0, 0.1, (hidden, 2 * PRED_STEPS)), np.zeros(2 * PRED_STEPS)))
    return MlpPredictor((layers,), np.zeros(N_INPUTS), np.ones(N_INPUTS), {"trained_on": []})


def test_mlp_learns_a_turning_walker_better_than_constant_velocity():
    pytest.importorskip("jax")
    from nodes.nav.predict_train import targets, train_mlp

    x, rot, hist, fut = scene_samples(_turning_scene(np.random.default_rng(0)), stride=3)
    model = train_mlp(x, targets(rot, hist, fut), hidden=(32,), steps=400, lr=5e-3, log_every=0,
                      meta={"trained_on": ["synthetic"]})
    xt, rt, ht, ft = scene_samples(_turning_scene(np.random.default_rng(1)), stride=5)
    mlp = errors(model.predict_encoded(xt, rt, ht), ft)
    cv = errors(predict_cv(ht), ft)
    assert mlp["fde_4.8s"] < 0.5 * cv["fde_4.8s"], (mlp, cv)
    assert model.meta["trained_on"] == ["synthetic"] and model.meta["samples"] == len(x)


def test_constant_velocity_is_exact_on_straight_walkers_and_damping_slows_them():
    t = np.arange(OBS_STEPS) * STEP_S
    hist = np.stack([np.column_stack([1.2 * t, 0.5 * t]), np.column_stack([-t, 2 + 0 * t])])
    pred = predict_cv(hist)
    ahead = t[-1] + STEP_S * np.arange(1, PRED_STEPS + 1)
    assert np.allclose(pred[0], np.column_stack([1.2 * ahead, 0.5 * ahead]))
    slow = predict_damped(hist, window=2, decay=0.9)
    assert np.all(np.linalg.norm(slow[:, -1] - hist[:, -1], axis=1) < np.linalg.norm(pred[:, -1] - hist[:, -1], axis=1))
    assert errors(pred[:1], pred[:1])["ade_4.8s"] == 0.0


def test_predictions_finite_with_one_observed_point_gaps_and_a_walker_standing_still():
    rng = np.random.default_rng(3)
    model = _random_mlp(rng)
    hist = np.full((4, OBS_STEPS, 2), np.nan)
    hist[0, -1] = (1.0, 2.0)                                  # seen once: now
    hist[1] = np.linspace((0, 0), (2.8, 0), OBS_STEPS)
    hist[1, 2:5] = np.nan                                     # a gap in the history
    hist[2] = (0.5, -1.0)                                     # standing still
    hist[3, :-1] = np.linspace((0, 3), (2, 3), OBS_STEPS - 1)  # left the view just now
    for predictor in (model, BaselinePredictor(), BaselinePredictor(window=3, decay=0.95)):
        out = predictor.predict(hist)
        assert out.shape == (4, PRED_STEPS, 2)
        assert np.isfinite(out[:3]).all() and np.isnan(out[3]).all()
    cv = predict_cv(hist)
    assert np.allclose(cv[0], (1.0, 2.0)) and np.allclose(cv[2], (0.5, -1.0))     # nothing seen moving: stays
    filled, seen = fill_history(hist)
    assert seen[1].sum() == OBS_STEPS - 3 and np.isfinite(filled[:3]).all()
    assert model.predict(np.zeros((0, OBS_STEPS, 2))).shape == (0, PRED_STEPS, 2)
    with pytest.raises(ValueError, match="hist must"):
        encode(np.zeros((2, 3)))


def test_encoding_sees_a_neighbour_in_the_right_sector_and_rotates_with_the_walker():
    t = np.arange(OBS_STEPS) * STEP_S
    walker = np.column_stack([t, 0 * t])                      # walks along +x, now at (2.8, 0)
    ahead = walker + (1.0, 0.0)                               # 1 m straight ahead, same velocity
    x, _, _ = encode(np.stack([walker, ahead]))
    nb = x[0, 3 * (OBS_STEPS - 1):].reshape(-1, 5)
    assert np.isclose(nb[0, 0], 1 - 1 / 4) and np.allclose(nb[0, 1:], (0.25, 0, 0, 0)) and not nb[1:].any()
    turn = np.array([[0, -1], [1, 0]])                        # the same two walkers rotated by 90 degrees
    x_rot, _, _ = encode(np.stack([walker @ turn.T, ahead @ turn.T]))
    assert np.allclose(x, x_rot, atol=1e-9)


def test_save_load_round_trip(tmp_path):
    model = _random_mlp(np.random.default_rng(4))
    model.save(tmp_path / "m.npz")
    back = MlpPredictor.load(tmp_path / "m.npz")
    hist = np.cumsum(np.random.default_rng(5).normal(0, 0.3, (6, OBS_STEPS, 2)), axis=1)
    assert np.allclose(back.predict(hist), model.predict(hist), atol=1e-4)
    assert back.meta == {"trained_on": []}
    with pytest.raises(ValueError, match="retrain"):
        MlpPredictor((((np.zeros((3, 4)), np.zeros(4)),),), np.zeros(3), np.ones(3), {})
    other = _random_mlp(np.random.default_rng(6))
    both = MlpPredictor.ensemble([model, other])
    assert both.meta["members"] == 2
    assert np.allclose(both.forward(np.ones((2, N_INPUTS))),
                       0.5 * (model.forward(np.ones((2, N_INPUTS))) + other.forward(np.ones((2, N_INPUTS)))))
    both.save(tmp_path / "e.npz")
    assert np.allclose(MlpPredictor.load(tmp_path / "e.npz").predict(hist), both.predict(hist), atol=1e-4)


def test_positions_at_interpolates_then_extrapolates():
    now = np.array([[0.0, 0.0]])
    fut = (np.arange(1, PRED_STEPS + 1) * STEP_S)[None, :, None] * np.array([1.0, 0.0])   # 1 m/s along x
    out = positions_at(now, fut, np.array([0.0, 0.2, 4.8, 6.0]))
    assert np.allclose(out[0, :, 0], [0.0, 0.2, 4.8, 6.0]) and np.allclose(out[0, :, 1], 0)


def test_resample_scene_leaves_gaps_empty():
    t = np.array([0.0, 0.4, 0.8, 4.0, 4.4])                   # a 3.2 s gap: out of sight
    xy = np.column_stack([t, 0 * t])
    scene = resample_scene(Tracks("toy", np.array([7]), (t,), (xy,), 0.4, 1.0))
    assert scene.shape == (12, 1, 2)
    assert np.isfinite(scene[[0, 1, 2, 10, 11], 0]).all() and np.isnan(scene[3:10, 0]).all()
