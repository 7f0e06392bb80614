"""Autoencoder pre-training: the seed's shapes, reconstruction learned, encoder carried over, bad input."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.learn.pretrain import (Classifier, Fit, accuracy, label_subset, reconstruct, train_autoencoder,
                                  train_classifier)


# the learning rate is compiled into each update: the tests share one per kind of update
AE_FIT = Fit(steps=5, batch=16, lr=3e-3)


def _blobs(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Two classes: a bright square top-left or bottom-right, with noise."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 0.2, (n, 28, 28, 1)).astype(np.float32)
    y = rng.integers(0, 2, n)
    for i, c in enumerate(y):
        r = 4 if c == 0 else 16
        x[i, r:r + 8, r:r + 8, 0] = 0.9
    return x, y.astype(np.int32)


def test_the_seeds_classifier_has_5250_parameters():
    import jax

    x = jax.ShapeDtypeStruct((1, 28, 28, 1), np.float32)
    params = jax.eval_shape(lambda v: Classifier(10).init(jax.random.PRNGKey(0), v), x)["params"]     # shapes only
    assert sum(p.size for p in jax.tree_util.tree_leaves(params)) == 5250


def test_autoencoder_learns_to_reconstruct_and_greedy_runs_layer_by_layer():
    x, _ = _blobs(64)
    enc, dec, hist = train_autoencoder(x, seed=0, fit=Fit(steps=60, batch=16, lr=3e-3))
    assert hist[-1][1] < hist[0][1] * 0.7
    rec = reconstruct(enc, dec, x[:4])
    assert rec.shape == (4, 28, 28, 1) and np.all((rec >= 0) & (rec <= 1))
    greedy, none, ghist = train_autoencoder(x, seed=0, fit=Fit(steps=10, batch=16), greedy=True)
    assert none is None and set(greedy) == {"conv0", "conv1"} and ghist[-1][0] >= 10


def test_pretrained_encoder_is_the_starting_point_and_frozen_stays_put():
    x, y = _blobs(64)
    enc, _, _ = train_autoencoder(x, seed=0, fit=AE_FIT)
    params, _ = train_classifier(x, y, encoder=enc, seed=0, fit=Fit(steps=30, batch=16), freeze_encoder=True)
    assert np.array_equal(params["encoder"]["conv0"]["kernel"], enc["conv0"]["kernel"])
    tuned, _ = train_classifier(x, y, encoder=enc, seed=0, fit=Fit(steps=40, batch=16, lr=3e-3))
    assert not np.array_equal(tuned["encoder"]["conv0"]["kernel"], enc["conv0"]["kernel"])
    assert accuracy(tuned, *_blobs(64, seed=1)) > 0.9


def test_training_is_reproducible_for_a_seed():
    x, y = _blobs(32)
    a = train_classifier(x, y, seed=3, fit=Fit(steps=20, batch=16, lr=3e-3))[1]
    b = train_classifier(x, y, seed=3, fit=Fit(steps=20, batch=16, lr=3e-3))[1]
    assert a == b


def test_label_subset_is_balanced_with_one_per_class_at_least():
    labels = np.repeat(np.arange(10), 42)
    idx = label_subset(labels, 0.01, np.random.default_rng(0))
    assert np.array_equal(np.bincount(labels[idx]), np.ones(10, int))
    assert len(label_subset(labels, 1.0, np.random.default_rng(0))) == 420
    with pytest.raises(ValueError):
        label_subset(labels, 0.0, np.random.default_rng(0))


def test_bad_images_are_refused_and_blank_ones_stay_finite():
    with pytest.raises(ValueError, match=r"\(N, 28, 28, 1\)"):
        train_autoencoder(np.zeros((4, 8, 8)), fit=Fit(steps=1))
    with pytest.raises(ValueError, match="NaN"):
        train_classifier(np.full((2, 28, 28, 1), np.nan), np.zeros(2), fit=Fit(steps=1))
    for value in (0.0, 1.0):                  # all black, all white
        enc, dec, hist = train_autoencoder(np.full((16, 28, 28, 1), value, np.float32), fit=AE_FIT)
        assert np.all(np.isfinite([h[1] for h in hist])) and np.all(np.isfinite(reconstruct(enc, dec, np.zeros((1, 28, 28, 1)))))
