"""How far simulated sonar images are from real ones: three gap statistics and the patch sampler.

A refiner (nodes/learn/simgan.py) is judged by whether its output is harder to tell from real
pings than the simulator's raw output. Three measures, each comparing a set of images with a
set of real ones (uint8, any shape):

* :func:`intensity_gap` -- Wasserstein-1 distance between the two pixel-intensity distributions
  (grey levels; 0 = same histogram).
* :func:`speckle_gap` -- Wasserstein-1 distance between the distributions of the local speckle
  contrast (std / mean in ``win`` x ``win`` windows whose mean is above ``min_mean``): fully
  developed speckle has contrast 1, smoothed or correlated speckle less.
* :func:`discriminator_gap` -- a convolutional classifier trained *from scratch* on one split
  (real against the candidate images) and scored on another: ``|2 AUC - 1|``, 0 when it cannot
  tell them apart and 1 when it always can. Unlike the SimGAN's own discriminator, it has never
  seen the refiner being trained against it.

Pure: numpy in, floats out (the discriminator trains with JAX + Optax, seeded).
"""
from __future__ import annotations

import functools
from typing import Sequence

import cv2
import numpy as np


def _as_images(images: np.ndarray | Sequence[np.ndarray]) -> list[np.ndarray]:
    out = [np.asarray(a) for a in (images if isinstance(images, (list, tuple)) else list(np.asarray(images)))]
    if not out or any(a.ndim != 2 or a.dtype != np.uint8 or a.size == 0 for a in out):
        raise ValueError("expected a non-empty set of non-empty 2-D uint8 images")
    return out


def _w1_hist(a: np.ndarray, b: np.ndarray, edges: np.ndarray) -> float:
    """Wasserstein-1 distance of two samples, binned on ``edges`` (in the edges' units)."""
    ha = np.histogram(a, edges)[0].astype(float)
    hb = np.histogram(b, edges)[0].astype(float)
    if ha.sum() == 0 or hb.sum() == 0:
        return float("nan")
    cdf = np.cumsum(ha / ha.sum()) - np.cumsum(hb / hb.sum())
    return float(np.sum(np.abs(cdf[:-1]) * np.diff(edges)[:-1]))


def intensity_gap(images: np.ndarray | Sequence[np.ndarray], real: np.ndarray | Sequence[np.ndarray]) -> float:
    """Wasserstein-1 distance (grey levels) between the pixel values of ``images`` and ``real``."""
    a = np.concatenate([x.ravel() for x in _as_images(images)])
    b = np.concatenate([x.ravel() for x in _as_images(real)])
    return _w1_hist(a, b, np.arange(257, dtype=float) - 0.5)


def speckle_contrast(image: np.ndarray, *, win: int = 7, min_mean: float = 8.0) -> np.ndarray:
    """Local contrast std / mean of every ``win`` x ``win`` window whose mean is at least ``min_mean``.

    Dark windows (the noise floor, the shadow) are left out: their contrast is that of the
    quantisation, not of the echo. An all-dark image gives an empty array.
    """
    x = np.asarray(image, np.float32)
    mean = cv2.blur(x, (win, win), borderType=cv2.BORDER_REFLECT)
    sq = cv2.blur(x * x, (win, win), borderType=cv2.BORDER_REFLECT)
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    h = win // 2
    mean, std = mean[h:-h or None, h:-h or None], std[h:-h or None, h:-h or None]
    keep = mean >= min_mean
    return (std[keep] / mean[keep]).astype(np.float64)


def speckle_gap(images: np.ndarray | Sequence[np.ndarray], real: np.ndarray | Sequence[np.ndarray], *,
                win: int = 7, min_mean: float = 8.0) -> float:
    """Wasserstein-1 distance between the local-contrast distributions (NaN if either has no bright window)."""
    a = np.concatenate([speckle_contrast(x, win=win, min_mean=min_mean) for x in _as_images(images)])
    b = np.concatenate([speckle_contrast(x, win=win, min_mean=min_mean) for x in _as_images(real)])
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    return _w1_hist(a, b, np.linspace(0.0, 3.0, 301))


def sample_patches(images: np.ndarray | Sequence[np.ndarray], n: int, size: int, *, seed: int,
                   beams: slice = slice(None)) -> np.ndarray:
    """``n`` random ``size`` x ``size`` crops (N, size, size, 1) uint8, from columns ``beams`` of the images."""
    ims = [x[:, beams] for x in _as_images(images)]
    if any(x.shape[0] < size or x.shape[1] < size for x in ims):
        raise ValueError(f"images smaller than the {size} px patch: {[x.shape for x in ims]}")
    rng = np.random.default_rng(seed)
    out = np.empty((n, size, size, 1), np.uint8)
    for i in range(n):
        x = ims[int(rng.integers(len(ims)))]
        r, c = rng.integers(x.shape[0] - size + 1), rng.integers(x.shape[1] - size + 1)
        out[i, ..., 0] = x[r:r + size, c:c + size]
    return out


def discriminator_gap(real_train: np.ndarray, fake_train: np.ndarray, real_test: np.ndarray, fake_test: np.ndarray,
                      *, steps: int = 400, batch: int = 64, seed: int = 0, lr: float = 1e-3) -> dict[str, float]:
    """Train a fresh real-vs-fake patch classifier on the train sets, score it on the test sets.

    Parameters are (N, H, W, 1) uint8 patch sets. Returns ``auc`` (held-out ROC AUC), ``gap``
    (``|2 auc - 1|``) and ``train_acc`` (on the last training batches: a classifier that cannot
    even fit its training data would make every gap look small).
    """
    import jax
    import jax.numpy as jnp
    from sklearn.metrics import roc_auc_score

    def signed(a: np.ndarray) -> np.ndarray:
        return np.asarray(a, np.float32) / 127.5 - 1.0

    for name, a in (("real_train", real_train), ("fake_train", fake_train), ("real_test", real_test),
                    ("fake_test", fake_test)):
        if np.asarray(a).ndim != 4 or len(a) == 0:
            raise ValueError(f"{name}: expected a non-empty (N, H, W, 1) patch set, got shape {np.shape(a)}")
    init, tx, step, score = _gap_classifier(lr)
    params = init(jax.random.key(seed, impl="rbg"), jnp.zeros((1, *real_train.shape[1:]), jnp.float32))
    opt = tx.init(params)

    rng = np.random.default_rng(seed)
    half = batch // 2
    y = np.concatenate([np.ones(half, np.float32), np.zeros(half, np.float32)])
    accs = []
    for _ in range(steps):
        x = np.concatenate([signed(real_train[rng.integers(len(real_train), size=half)]),
                            signed(fake_train[rng.integers(len(fake_train), size=half)])])
        params, opt, acc = step(params, opt, x, y)
        accs.append(float(acc))
    s_real = np.concatenate([np.asarray(score(params, signed(real_test[i:i + 256]))) for i in range(0, len(real_test), 256)])
    s_fake = np.concatenate([np.asarray(score(params, signed(fake_test[i:i + 256]))) for i in range(0, len(fake_test), 256)])
    labels = np.concatenate([np.ones(len(s_real)), np.zeros(len(s_fake))])
    auc = float(roc_auc_score(labels, np.concatenate([s_real, s_fake])))
    return {"auc": auc, "gap": abs(2.0 * auc - 1.0), "train_acc": float(np.mean(accs[-20:]))}


@functools.lru_cache(maxsize=4)
def _gap_classifier(lr: float) -> tuple:
    """The real-vs-fake patch classifier's jitted initialiser (for an "rbg" key: threefry keys
    compiled a kernel per layer shape), optimiser, jitted update and scorer: built once per
    process, so every :func:`discriminator_gap` call of a sweep (and of the tests) shares one compile."""
    import flax.linen as nn
    import jax
    import jax.numpy as jnp
    import optax

    class Classifier(nn.Module):
        @nn.compact
        def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
            for f in (16, 32, 32):
                x = nn.leaky_relu(nn.Conv(f, (3, 3), strides=(2, 2))(x), 0.2)
            return nn.Dense(1)(x.mean(axis=(1, 2)))[:, 0]

    net = Classifier()
    tx = optax.adam(lr)

    def loss_fn(p, x, y):
        logits = net.apply(p, x)
        return optax.sigmoid_binary_cross_entropy(logits, y).mean(), logits

    @jax.jit
    def step(p, o, x, y):
        (loss, logits), g = jax.value_and_grad(loss_fn, has_aux=True)(p, x, y)
        u, o = tx.update(g, o, p)
        return optax.apply_updates(p, u), o, jnp.mean((logits > 0) == (y > 0.5))

    return jax.jit(net.init), tx, step, jax.jit(net.apply)
