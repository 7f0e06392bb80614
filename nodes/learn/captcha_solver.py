"""Captcha solver (seed 04): a small CNN with one softmax head per character, on JAX + Flax + Optax.

>>> params, hist = train_solver(images, labels, SolverConfig(), steps=3000, seed=0,
...                             checkpoint="out/captcha/solver_synthetic.msgpack")   # resumes if present
>>> pred = predict_captchas(params, test_images, SolverConfig())                  # (N, 4) digits
>>> full, per_char = captcha_accuracy(pred, test_labels)

Images are (N, H, W, C) uint8 or float in [-1, 1] (a refiner's output). Training draws batch ``t``
from ``default_rng([seed, t])`` and shifts each image by up to ``shift_px`` pixels (edge
padded), so a resumed run repeats an uninterrupted one.
"""
from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from nodes.learn.checkpoint import load_checkpoint, save_checkpoint

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SolverConfig:
    """Network and training hyper-parameters."""

    n_chars: int = 4
    n_classes: int = 10
    features: tuple[int, ...] = (16, 32, 32)
    hidden: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-4
    batch: int = 32
    shift_px: int = 2


class CaptchaNet(nn.Module):
    """(B, H, W, C) in [-1, 1] -> (B, n_chars, n_classes) logits."""

    n_chars: int = 4
    n_classes: int = 10
    features: tuple[int, ...] = (16, 32, 32)
    hidden: int = 64

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        for f in self.features:
            x = nn.relu(nn.Conv(f, (3, 3))(x))
            x = nn.max_pool(x, (2, 2), strides=(2, 2), padding="SAME")
        x = nn.relu(nn.Dense(self.hidden)(x.reshape(x.shape[0], -1)))
        return nn.Dense(self.n_chars * self.n_classes)(x).reshape(-1, self.n_chars, self.n_classes)


def _signed(images: np.ndarray) -> np.ndarray:
    a = np.asarray(images)
    return a.astype(np.float32) / 127.5 - 1.0 if a.dtype == np.uint8 else a.astype(np.float32)


@functools.lru_cache(maxsize=8)
def _compiled(cfg: SolverConfig) -> dict[str, Any]:
    """Network, optimiser, jitted update and logits for ``cfg``: compiled once per process."""
    net = CaptchaNet(cfg.n_chars, cfg.n_classes, cfg.features, cfg.hidden)
    tx = optax.adamw(cfg.lr, weight_decay=cfg.weight_decay)

    def loss(p: Any, x: jnp.ndarray, y: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        logits = net.apply(p, x)
        ce = optax.softmax_cross_entropy_with_integer_labels(logits, y).mean()
        return ce, (logits.argmax(-1) == y).mean()

    @jax.jit
    def step(p: Any, opt: Any, x: jnp.ndarray, y: jnp.ndarray) -> tuple[Any, Any, jnp.ndarray, jnp.ndarray]:
        (ce, acc), g = jax.value_and_grad(loss, has_aux=True)(p, x, y)
        updates, opt = tx.update(g, opt, p)
        return optax.apply_updates(p, updates), opt, ce, acc

    return {"net": net, "tx": tx, "step": step, "logits": jax.jit(net.apply), "init": jax.jit(net.init)}


def init_solver(cfg: SolverConfig, image_shape: tuple[int, int, int], *, seed: int = 0) -> dict[str, Any]:
    """Fresh parameters (from an "rbg" key under one jit: threefry keys compiled a kernel per layer
    shape), optimiser state and step 0."""
    c = _compiled(cfg)
    params = c["init"](jax.random.key(seed, impl="rbg"), jnp.zeros((1, *image_shape), jnp.float32))
    return {"params": params, "opt": c["tx"].init(params), "step": np.zeros((), np.int64)}


def _shifted(x: np.ndarray, rng: np.random.Generator, shift_px: int) -> np.ndarray:
    """Each image moved by up to ``shift_px`` in x and y, edges repeated."""
    if shift_px <= 0:
        return x
    s = shift_px
    padded = np.pad(x, ((0, 0), (s, s), (s, s), (0, 0)), mode="edge")
    dy, dx = rng.integers(0, 2 * s + 1, (2, len(x)))
    h, w = x.shape[1:3]
    return np.stack([padded[i, dy[i]:dy[i] + h, dx[i]:dx[i] + w] for i in range(len(x))])


def train_solver(images: np.ndarray, labels: np.ndarray, cfg: SolverConfig, *, steps: int, seed: int = 0,
                 checkpoint: str | Path | None = None, log_every: int = 200,
                 checkpoint_every: int = 1000) -> tuple[dict[str, Any], dict[str, list[float]]]:
    """Train until ``state["step"] == steps`` (resuming from ``checkpoint`` when it exists).

    Parameters
    ----------
    images : numpy.ndarray
        (N, H, W, C) uint8 or float in [-1, 1].
    labels : numpy.ndarray
        (N, n_chars) ints in ``[0, n_classes)``.

    Returns
    -------
    state : dict
        ``params``, ``opt``, ``step``.
    history : dict
        ``step``, ``loss``, ``char_acc`` (training batch), ``steps_per_s`` per logged step.
    """
    x, y = _signed(images), np.asarray(labels, np.int32)
    if x.ndim != 4 or y.shape != (len(x), cfg.n_chars):
        raise ValueError(f"expected (N, H, W, C) images and (N, {cfg.n_chars}) labels, got {x.shape} and {y.shape}")
    if y.size and (y.min() < 0 or y.max() >= cfg.n_classes):
        raise ValueError(f"labels must lie in [0, {cfg.n_classes}), got [{y.min()}, {y.max()}]")
    c = _compiled(cfg)
    state = init_solver(cfg, x.shape[1:], seed=seed)
    hist: dict[str, list[float]] = {"step": [], "loss": [], "char_acc": [], "steps_per_s": []}
    if checkpoint is not None and Path(checkpoint).exists():
        state, meta = load_checkpoint(checkpoint, state)
        hist = meta.get("history", hist)
        log.info("solver: resumed %s at step %d", checkpoint, int(state["step"]))
    t0, s0 = time.perf_counter(), int(state["step"])
    while int(state["step"]) < steps:
        t = int(state["step"])
        rng = np.random.default_rng([seed, t])
        idx = rng.integers(len(x), size=cfg.batch)
        state["params"], state["opt"], ce, acc = c["step"](state["params"], state["opt"],
                                                            _shifted(x[idx], rng, cfg.shift_px), y[idx])
        if not np.isfinite(float(ce)):
            raise FloatingPointError(f"solver: non-finite loss at step {t}; lower lr ({cfg.lr})")
        state["step"] = np.asarray(t + 1, np.int64)
        if (t + 1) % log_every == 0 or t + 1 == steps:
            rate = (t + 1 - s0) / (time.perf_counter() - t0)
            for k, v in (("step", t + 1), ("loss", float(ce)), ("char_acc", float(acc)), ("steps_per_s", rate)):
                hist[k].append(v)
            log.info("solver %5d  %.1f steps/s  loss %.4f  char acc %.3f", t + 1, rate, float(ce), float(acc))
        if checkpoint is not None and ((t + 1) % checkpoint_every == 0 or t + 1 == steps):
            save_checkpoint(checkpoint, state, meta={"history": hist})
    return state, hist


def captcha_logits(params: Any, images: np.ndarray, cfg: SolverConfig, *, batch: int = 512) -> np.ndarray:
    """(N, n_chars, n_classes) logits."""
    x = _signed(images)
    f: Callable[..., Any] = _compiled(cfg)["logits"]
    if not len(x):
        return np.zeros((0, cfg.n_chars, cfg.n_classes), np.float32)
    return np.concatenate([np.asarray(f(params, x[i:i + batch])) for i in range(0, len(x), batch)])


def predict_captchas(params: Any, images: np.ndarray, cfg: SolverConfig) -> np.ndarray:
    """(N, n_chars) predicted class indices."""
    return captcha_logits(params, images, cfg).argmax(-1)


def captcha_accuracy(pred: np.ndarray, labels: np.ndarray) -> tuple[float, np.ndarray]:
    """Full-captcha accuracy (every character right) and per-character-position accuracy (n_chars,)."""
    pred, labels = np.asarray(pred), np.asarray(labels)
    if pred.shape != labels.shape or pred.ndim != 2:
        raise ValueError(f"pred {pred.shape} and labels {labels.shape} must be equal (N, n_chars)")
    if not len(pred):
        raise ValueError("no captchas to score")
    right = pred == labels
    return float(right.all(1).mean()), right.mean(0)
