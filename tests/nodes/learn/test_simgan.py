"""SimGAN hard cases: identity start, flat images, a discriminator that wins, mode collapse, seeded and resumable runs, checkpoint mismatch."""
from __future__ import annotations

import jax
import numpy as np
import pytest

from nodes.learn.checkpoint import load_checkpoint, save_checkpoint
from nodes.learn.simgan import (SimGANConfig, batch_diversity, detect_mode_collapse, init_simgan, refine_images,
                                train_simgan)

# one config for most tests: each distinct config compiles its own updates
TINY = SimGANConfig(features=4, blocks=1, disc_features=(4, 4, 4), batch=4, history=8, pretrain_d=1, lam=10.0, lr_r=1e-3)
SHAPE = (8, 12, 1)


def _data(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 0, (16, *SHAPE)).astype(np.float32), rng.uniform(0, 1, (16, *SHAPE)).astype(np.float32)


def test_refiner_starts_as_the_identity():
    syn, _ = _data()
    out = refine_images(init_simgan(TINY, SHAPE, seed=0)["r"], syn, TINY)
    assert out.shape == syn.shape and np.abs(out - syn).max() < 2e-3


@pytest.mark.parametrize("value", [-1.0, 1.0])
def test_all_black_or_all_white_images_stay_finite(value):
    flat = np.full((8, *SHAPE), value, np.float32)
    state, hist = train_simgan(init_simgan(TINY, SHAPE), flat, flat, TINY, steps=4, log_every=2)
    out = refine_images(state["r"], flat, TINY)
    assert np.all(np.isfinite(out)) and np.all(np.abs(out) <= 1)
    assert np.all(np.isfinite(hist["d_loss"])) and not hist["diverged"]


def test_a_discriminator_that_wins_completely_is_reported_without_nan():
    # real all white, synthetic all black, the refiner pinned by a huge self-regularisation
    cfg = SimGANConfig(features=4, blocks=1, disc_features=(4, 4, 4), batch=4, history=8, pretrain_d=0, lam=1e4,
                       lr_d=2e-2)
    black, white = np.full((8, *SHAPE), -1.0, np.float32), np.full((8, *SHAPE), 1.0, np.float32)
    _, hist = train_simgan(init_simgan(cfg, SHAPE), black, white, cfg, steps=40, log_every=5)
    assert hist["d_wins"], f"P(real|refined) {hist['p_fake']}"
    assert hist["p_fake"][-1] < cfg.win_prob and hist["p_real"][-1] > 1 - cfg.win_prob
    assert all(np.isfinite(hist[k]).all() for k in ("d_loss", "r_adv", "r_l1")) and not hist["diverged"]


def test_mode_collapse_is_flagged():
    syn, _ = _data()
    collapsed = np.repeat(syn[:1], len(syn), axis=0)
    assert detect_mode_collapse(collapsed, syn) and batch_diversity(collapsed, syn) == 0.0
    assert not detect_mode_collapse(syn * 0.9, syn)
    assert batch_diversity(syn, syn) == pytest.approx(1.0)


def test_training_is_reproducible_and_resumes_exactly(tmp_path):
    syn, real = _data()
    _, h1 = train_simgan(init_simgan(TINY, SHAPE, seed=1), syn, real, TINY, steps=6, seed=1, log_every=1)
    _, h2 = train_simgan(init_simgan(TINY, SHAPE, seed=1), syn, real, TINY, steps=6, seed=1, log_every=1)
    assert h1["d_loss"] == h2["d_loss"] and h1["r_l1"] == h2["r_l1"]
    ck = tmp_path / "g.msgpack"
    train_simgan(init_simgan(TINY, SHAPE, seed=1), syn, real, TINY, steps=3, seed=1, log_every=1, checkpoint=ck)
    state, h3 = train_simgan(init_simgan(TINY, SHAPE, seed=1), syn, real, TINY, steps=6, seed=1, log_every=1,
                             checkpoint=ck)
    assert int(state["step"]) == 6 and h3["d_loss"] == h1["d_loss"]


def test_self_regularisation_bounds_the_change():
    syn, real = _data()
    state, hist = train_simgan(init_simgan(TINY, SHAPE), syn, real, TINY, steps=15, log_every=5)
    out = refine_images(state["r"], syn, TINY)
    assert np.abs(out - syn).mean() < 0.1
    # the sign of every pixel (ink vs background in a binarised captcha) survives
    assert (np.sign(out) == np.sign(syn)).mean() > 0.99


def test_a_checkpoint_of_another_shape_is_refused(tmp_path):
    state = init_simgan(TINY, SHAPE)
    save_checkpoint(tmp_path / "g.msgpack", state)
    # the same model one refiner channel wider (first convolution's kernel 3x3x1x5)
    wider = jax.tree_util.tree_map(lambda a: a, state)
    wider["r"]["params"]["Conv_0"]["kernel"] = np.zeros((3, 3, 1, 5), np.float32)
    with pytest.raises(ValueError, match=r"Conv_0.*kernel.*shape \(3, 3, 1, 4\).*\(3, 3, 1, 5\)"):
        load_checkpoint(tmp_path / "g.msgpack", wider)
    loaded, _ = load_checkpoint(tmp_path / "g.msgpack", state)
    assert np.array_equal(loaded["buffer"], state["buffer"])


def test_mismatched_image_sets_are_refused():
    syn, _ = _data()
    with pytest.raises(ValueError, match="equal H, W, C"):
        train_simgan(init_simgan(TINY, SHAPE), syn, syn[:, :4], TINY, steps=1)
