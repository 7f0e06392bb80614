"""Autoencoder pre-training of a small convolutional classifier (seed 07), on JAX + Flax + Optax.

The seed's network: an encoder of two 3x3 convolutions with stride 2 (28x28x1 -> 14x14x16 ->
7x7x8, ReLU), then Flatten and Dense(10): 5,250 parameters (the seed's Fig. 3). Its
autoencoder adds a decoder of two 3x3 transposed convolutions with stride 2 (7x7x8 -> 14x14x8
-> 28x28x16) and a 3x3 convolution back to one channel (sigmoid), trained on the reconstruction
error (binary cross-entropy on pixels in [0, 1]). Pre-training copies the trained encoder into
the classifier, which is then fine-tuned whole on the labelled images; random initialisation is
the same classifier from its initialiser. The greedy, layer-wise variant trains one
convolution at a time, each with its own one-layer decoder, on the codes of the layers below
(frozen), as in the seed's section I.

Both arms get the same optimiser, steps and batches; only the encoder's starting point differs.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Any, Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

CHANNELS = (16, 8)


class Encoder(nn.Module):
    """(N, 28, 28, 1) -> (N, 7, 7, 8); ``upto`` layers only (greedy training)."""

    upto: int = len(CHANNELS)

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        for i, c in enumerate(CHANNELS[: self.upto]):
            x = nn.relu(nn.Conv(c, (3, 3), strides=(2, 2), padding="SAME", name=f"conv{i}")(x))
        return x


class Decoder(nn.Module):
    """(N, 7, 7, 8) -> (N, 28, 28, 1) logits: the seed's two transposed convolutions and a convolution."""

    @nn.compact
    def __call__(self, h: jnp.ndarray) -> jnp.ndarray:
        h = nn.relu(nn.ConvTranspose(8, (3, 3), strides=(2, 2), padding="SAME")(h))
        h = nn.relu(nn.ConvTranspose(16, (3, 3), strides=(2, 2), padding="SAME")(h))
        return nn.Conv(1, (3, 3), padding="SAME")(h)


class LayerDecoder(nn.Module):
    """One transposed convolution undoing one encoder layer (greedy training), to ``channels``."""

    channels: int

    @nn.compact
    def __call__(self, h: jnp.ndarray) -> jnp.ndarray:
        return nn.ConvTranspose(self.channels, (3, 3), strides=(2, 2), padding="SAME")(h)


class Classifier(nn.Module):
    """The seed's network: the encoder, Flatten, Dense(classes)."""

    classes: int = 10

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        h = Encoder(name="encoder")(x)
        return nn.Dense(self.classes, name="head")(h.reshape(h.shape[0], -1))


def _init(module: nn.Module, key: jax.Array, like: Any) -> Any:
    """``module``'s fresh parameters for a batch like ``like`` (an array or its shape), from an
    "rbg" key under one jit compiled once per module: the default threefry keys compiled one
    truncated-normal kernel per layer shape, eagerly, 1-3 s each on a 2-core CPU."""
    return _jitted_init(module)(key, jnp.zeros(like.shape, like.dtype))["params"]


@functools.lru_cache(maxsize=16)
def _jitted_init(module: nn.Module) -> Callable[..., Any]:
    return jax.jit(module.init)


@dataclass(frozen=True)
class Fit:
    """Hyper-parameters of one training run (shared by both arms of a comparison)."""

    steps: int = 400
    batch: int = 64
    lr: float = 1e-3


def _check_images(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float32)
    if x.ndim != 4 or x.shape[1:] != (28, 28, 1):
        raise ValueError(f"images must be (N, 28, 28, 1) in [0, 1], got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("images contain NaN or infinity")
    return x


def _batches(n: int, batch: int, steps: int, rng: np.random.Generator) -> np.ndarray:
    """(steps, batch) indices: epochs of shuffled data, a batch never larger than the data."""
    b = min(batch, n)
    per_epoch = n // b
    order = np.concatenate([rng.permutation(n)[: per_epoch * b] for _ in range(-(-steps // per_epoch))])
    return order[: steps * b].reshape(steps, b)


@functools.lru_cache(maxsize=8)
def _ae_step(upto: int, greedy: bool, lr: float) -> Callable[..., Any]:
    """The jitted autoencoder update (full, or the top layer of a greedy stack over frozen layers)."""
    tx = optax.adam(lr)

    def loss(params: Any, frozen: Any, x: jnp.ndarray) -> jnp.ndarray:
        if greedy:
            below = Encoder(upto=upto - 1).apply({"params": frozen}, x) if upto > 1 else x
            top = nn.relu(nn.Conv(CHANNELS[upto - 1], (3, 3), strides=(2, 2), padding="SAME")
                          .apply({"params": params["conv"]}, below))
            rec = LayerDecoder(below.shape[-1]).apply({"params": params["dec"]}, top)
            if upto == 1:                       # pixels: cross-entropy, as the full autoencoder
                return optax.sigmoid_binary_cross_entropy(rec, below).mean()
            return ((rec - below) ** 2).mean()  # codes: least squares (ReLU codes are not in [0, 1])
        h = Encoder().apply({"params": params["enc"]}, x)
        return optax.sigmoid_binary_cross_entropy(Decoder().apply({"params": params["dec"]}, h), x).mean()

    def step(params: Any, opt: Any, frozen: Any, x: jnp.ndarray) -> tuple[Any, Any, jnp.ndarray]:
        value, grads = jax.value_and_grad(loss)(params, frozen, x)
        upd, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, upd), opt, value

    return jax.jit(step)


def train_autoencoder(images: np.ndarray, *, seed: int = 0, fit: Fit = Fit(steps=1500, batch=128), greedy: bool = False,
                      progress: Callable[[str], None] | None = None
                      ) -> tuple[dict[str, Any], dict[str, Any] | None, list[tuple[int, float]]]:
    """Pre-train the encoder on unlabelled ``images`` (N, 28, 28, 1) in [0, 1].

    Returns the encoder's parameters (``{"conv0": ..., "conv1": ...}``, ready for
    :func:`train_classifier`), the decoder's (None for the greedy variant, whose decoders undo
    one layer each) and the loss history ``[(step, loss)]``; the greedy variant gives
    ``fit.steps`` to each layer.
    """
    x = _check_images(images)
    rng = np.random.default_rng(seed)
    key = jax.random.key(seed, impl="rbg")
    history: list[tuple[int, float]] = []
    t0 = time.perf_counter()
    if not greedy:
        k1, k2 = jax.random.split(key)
        params = {"enc": _init(Encoder(), k1, x[:1]), "dec": _init(Decoder(), k2, jnp.zeros((1, 7, 7, CHANNELS[-1])))}
        step = _ae_step(0, False, fit.lr)
        opt = optax.adam(fit.lr).init(params)
        for i, idx in enumerate(_batches(len(x), fit.batch, fit.steps, rng)):
            params, opt, value = step(params, opt, {}, x[idx])
            _log(history, progress, "autoencoder", i, fit.steps, value, t0)
        return dict(params["enc"]), dict(params["dec"]), history
    encoder: dict[str, Any] = {}
    for layer in range(1, len(CHANNELS) + 1):
        key, k1, k2 = jax.random.split(key, 3)
        below = jax.eval_shape(lambda v: Encoder(upto=layer - 1).apply({"params": encoder}, v), x[:1])   # shapes only
        conv = nn.Conv(CHANNELS[layer - 1], (3, 3), strides=(2, 2), padding="SAME")
        conv_p = _init(conv, k1, below)
        top = jax.eval_shape(lambda v: conv.apply({"params": conv_p}, v), below)
        params = {"conv": conv_p, "dec": _init(LayerDecoder(below.shape[-1]), k2, top)}
        step = _ae_step(layer, True, fit.lr)
        opt = optax.adam(fit.lr).init(params)
        for i, idx in enumerate(_batches(len(x), fit.batch, fit.steps, rng)):
            params, opt, value = step(params, opt, encoder, x[idx])
            _log(history, progress, f"layer {layer}", (layer - 1) * fit.steps + i, len(CHANNELS) * fit.steps, value, t0)
        encoder = {**encoder, f"conv{layer - 1}": params["conv"]}
    return encoder, None, history


def _log(history: list, progress: Callable[[str], None] | None, what: str, i: int, total: int, value: Any,
         t0: float) -> None:
    if i % 50 == 0 or i == total - 1:
        v = float(value)
        if not np.isfinite(v):
            raise FloatingPointError(f"{what}: loss became {v} at step {i}; lower the learning rate")
        history.append((i, v))
        if progress is not None and (i % 250 == 0 or i == total - 1):
            progress(f"{what}: step {i + 1}/{total}  loss {v:.4f}  {(i + 1) / (time.perf_counter() - t0):.0f} steps/s")


def _cls_optimizer(lr: float, freeze_encoder: bool) -> optax.GradientTransformation:
    if not freeze_encoder:
        return optax.adam(lr)
    return optax.multi_transform({"train": optax.adam(lr), "frozen": optax.set_to_zero()},
                                 lambda params: {k: ("frozen" if k == "encoder" else "train") for k in params})


@functools.lru_cache(maxsize=8)
def _cls_step(classes: int, lr: float, freeze_encoder: bool) -> Callable[..., Any]:
    tx = _cls_optimizer(lr, freeze_encoder)
    model = Classifier(classes)

    def loss(params: Any, x: jnp.ndarray, y: jnp.ndarray) -> jnp.ndarray:
        return optax.softmax_cross_entropy_with_integer_labels(model.apply({"params": params}, x), y).mean()

    def step(params: Any, opt: Any, x: jnp.ndarray, y: jnp.ndarray) -> tuple[Any, Any, jnp.ndarray]:
        value, grads = jax.value_and_grad(loss)(params, x, y)
        upd, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, upd), opt, value

    return jax.jit(step)


def train_classifier(images: np.ndarray, labels: np.ndarray, *, classes: int = 10, encoder: dict[str, Any] | None = None,
                     seed: int = 0, fit: Fit = Fit(), freeze_encoder: bool = False,
                     progress: Callable[[str], None] | None = None) -> tuple[dict[str, Any], list[tuple[int, float]]]:
    """Train the seed's classifier on labelled images; ``encoder`` (from :func:`train_autoencoder`)
    replaces the random initial encoder. The head is initialised the same way in both cases.
    ``freeze_encoder``: train the head only (a linear probe of the encoder's features)."""
    x = _check_images(images)
    y = np.asarray(labels, np.int32)
    if y.shape != (len(x),) or y.min(initial=0) < 0 or y.max(initial=0) >= classes:
        raise ValueError(f"labels must be (N,) integers in [0, {classes}), one per image")
    if len(x) == 0:
        raise ValueError("no labelled images to train on")
    params = dict(_init(Classifier(classes), jax.random.key(seed, impl="rbg"), x[:1]))
    if encoder is not None:
        params["encoder"] = encoder
    step = _cls_step(classes, fit.lr, freeze_encoder)
    opt = _cls_optimizer(fit.lr, freeze_encoder).init(params)
    history: list[tuple[int, float]] = []
    t0 = time.perf_counter()
    for i, idx in enumerate(_batches(len(x), fit.batch, fit.steps, np.random.default_rng(seed))):
        params, opt, value = step(params, opt, x[idx], y[idx])
        _log(history, progress, "classifier", i, fit.steps, value, t0)
    return params, history


@functools.lru_cache(maxsize=8)
def _predict(classes: int) -> Callable[..., Any]:
    return jax.jit(lambda p, x: jnp.argmax(Classifier(classes).apply({"params": p}, x), -1))


def accuracy(params: dict[str, Any], images: np.ndarray, labels: np.ndarray, *, classes: int = 10) -> float:
    """Fraction of ``images`` classified as ``labels``."""
    x = _check_images(images)
    pred = np.concatenate([np.asarray(_predict(classes)(params, x[i:i + 512])) for i in range(0, len(x), 512)])
    return float(np.mean(pred == np.asarray(labels)))


def reconstruct(encoder: dict[str, Any], decoder: dict[str, Any], images: np.ndarray) -> np.ndarray:
    """The autoencoder's reconstruction in [0, 1] (for the sample grid)."""
    h = Encoder().apply({"params": encoder}, _check_images(images))
    return np.asarray(jax.nn.sigmoid(Decoder().apply({"params": decoder}, h)))


def label_subset(labels: np.ndarray, fraction: float, rng: np.random.Generator, *, classes: int = 10) -> np.ndarray:
    """Indices of a class-balanced subset holding ``fraction`` of the labels, at least one per class
    (1 % of a few hundred images is fewer labels than classes: one each is the least that can learn)."""
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    labels = np.asarray(labels)
    per_class = max(1, int(round(fraction * len(labels) / classes)))
    out = [rng.permutation(np.flatnonzero(labels == c))[:per_class] for c in range(classes)]
    return np.sort(np.concatenate(out))
