"""Captcha solver: learns a tiny labelled set, scores correctly, resumes exactly, refuses bad labels, stays finite on flat images."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.learn.captcha_solver import SolverConfig, captcha_accuracy, captcha_logits, predict_captchas, train_solver

TINY = SolverConfig(n_chars=2, n_classes=3, features=(4,), hidden=16, batch=8, shift_px=0, lr=1e-2)


def _toy(n: int = 24, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Two characters per image; class c of slot k lights column band c of half k."""
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 3, (n, 2))
    x = np.full((n, 6, 12, 1), 20, np.uint8)
    for i, (a, b) in enumerate(y):
        x[i, :, 2 * a:2 * a + 2] = 230
        x[i, :, 6 + 2 * b:8 + 2 * b] = 230
    return x, y


def test_solver_learns_a_toy_captcha_set_and_resumes_exactly(tmp_path):
    x, y = _toy()
    state, hist = train_solver(x, y, TINY, steps=60, seed=0, log_every=20)
    full, per_char = captcha_accuracy(predict_captchas(state["params"], x, TINY), y)
    assert full == 1.0 and per_char.shape == (2,), hist["loss"]
    ck = tmp_path / "s.msgpack"
    train_solver(x, y, TINY, steps=30, seed=0, log_every=20, checkpoint=ck)
    resumed, _ = train_solver(x, y, TINY, steps=60, seed=0, log_every=20, checkpoint=ck)
    a = captcha_logits(state["params"], x, TINY)
    assert int(resumed["step"]) == 60 and np.array_equal(a, captcha_logits(resumed["params"], x, TINY))


@pytest.mark.parametrize("value", [0, 255])
def test_flat_images_give_finite_logits(value):
    x, y = _toy(8)
    state, _ = train_solver(x, y, TINY, steps=2, seed=0)
    logits = captcha_logits(state["params"], np.full((3, 6, 12, 1), value, np.uint8), TINY)
    assert logits.shape == (3, 2, 3) and np.all(np.isfinite(logits))


def test_accuracy_counts_whole_captchas_and_characters():
    full, per = captcha_accuracy(np.array([[1, 2], [1, 0], [0, 0]]), np.array([[1, 2], [1, 2], [2, 2]]))
    assert full == pytest.approx(1 / 3) and np.allclose(per, [2 / 3, 1 / 3])
    with pytest.raises(ValueError, match="equal"):
        captcha_accuracy(np.zeros((2, 2)), np.zeros((2, 3)))


def test_bad_labels_are_refused():
    x, y = _toy(8)
    with pytest.raises(ValueError, match=r"\[0, 3\)"):
        train_solver(x, y + 3, TINY, steps=1)
    with pytest.raises(ValueError, match="labels"):
        train_solver(x, y[:, :1], TINY, steps=1)
