"""Train :class:`nodes.nav.predict.MlpPredictor` with JAX + Flax + Optax (CPU; the ``learn`` extra).

Loss: ADE over the 12 predicted steps (mean Euclidean error, m) of the CV-corrected
prediction in each walker's frame; Adam with a cosine-decayed step size, minibatches drawn
with a seeded generator. Training is for benches and scripts (seconds to minutes), never
the test suite beyond tiny problems.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from nodes.nav.predict import N_INPUTS, PRED_STEPS, MlpPredictor, cv_offsets

log = logging.getLogger("nodes.nav.predict_train")


def targets(rot: np.ndarray, hist: np.ndarray, future: np.ndarray) -> np.ndarray:
    """(N, 12, 2) what the MLP should output: the true future minus constant velocity, in each walker's frame."""
    now = hist[:, -1]
    resid = future - now[:, None] - cv_offsets(hist)
    return np.einsum("pij,ptj->pti", rot, resid)


def train_mlp(x: np.ndarray, y: np.ndarray, *, hidden: tuple[int, ...] = (64, 64), steps: int = 3000,
              batch: int = 256, lr: float = 2e-3, weight_decay: float = 1e-4, seed: int = 0,
              log_every: int = 500, meta: dict | None = None) -> MlpPredictor:
    """Fit the MLP on inputs ``x`` (N, N_INPUTS) and targets ``y`` (N, 12, 2) (:func:`targets`).

    Parameters
    ----------
    hidden : widths of the hidden ReLU layers.
    steps, batch, lr, weight_decay : Adam(W) with cosine decay from ``lr`` over ``steps`` minibatches.
    seed : initialisation and minibatch order.
    log_every : a progress line (step, minibatch ADE in m, elapsed s) every this many steps.
    meta : provenance stored with the parameters (trained_on, ...); the training settings are added.
    """
    import flax.linen as nn
    import jax
    import jax.numpy as jnp
    import optax

    x = np.asarray(x, np.float32)
    y = np.asarray(y, np.float32).reshape(len(x), -1)
    if x.ndim != 2 or x.shape[1] != N_INPUTS or len(x) != len(y) or y.shape[1] != 2 * PRED_STEPS:
        raise ValueError(f"x must be (N, {N_INPUTS}) and y (N, {PRED_STEPS}, 2) with the same N; got {x.shape}, "
                         f"{y.shape}")
    if len(x) == 0:
        raise ValueError("no training samples; give scenes with walkers seen for 20 consecutive steps")
    mean = x.mean(axis=0)
    std = np.maximum(x.std(axis=0), 1e-3)
    xs = (x - mean) / std

    class Mlp(nn.Module):
        @nn.compact
        def __call__(self, a):
            for width in hidden:
                a = nn.relu(nn.Dense(width)(a))
            return nn.Dense(2 * PRED_STEPS, kernel_init=nn.initializers.zeros)(a)   # starts as constant velocity

    model = Mlp()
    params = model.init(jax.random.PRNGKey(seed), jnp.zeros((1, N_INPUTS)))
    opt = optax.adamw(optax.cosine_decay_schedule(lr, steps), weight_decay=weight_decay)
    state = opt.init(params)

    def loss_fn(p, xb, yb):
        d = (model.apply(p, xb) - yb).reshape(len(xb), PRED_STEPS, 2)
        return jnp.mean(jnp.sqrt(jnp.sum(d * d, axis=-1) + 1e-6))

    @jax.jit
    def step(p, s, xb, yb):
        loss, g = jax.value_and_grad(loss_fn)(p, xb, yb)
        upd, s = opt.update(g, s, p)
        return optax.apply_updates(p, upd), s, loss

    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    run = []
    for k in range(1, steps + 1):
        idx = rng.integers(0, len(xs), size=min(batch, len(xs)))
        params, state, loss = step(params, state, xs[idx], y[idx])
        run.append(float(loss))
        if log_every and (k % log_every == 0 or k == steps):
            log.info("step %d/%d  minibatch ADE %.3f m (mean of last %d)  %.1f s", k, steps,
                     float(np.mean(run[-log_every:])), min(log_every, len(run)), time.perf_counter() - t0)
    dense = [params["params"][f"Dense_{i}"] for i in range(len(hidden) + 1)]
    layers = tuple((np.asarray(d["kernel"], np.float64), np.asarray(d["bias"], np.float64)) for d in dense)
    info = dict(meta or {}) | {"hidden": list(hidden), "steps": steps, "batch": batch, "lr": lr,
                               "weight_decay": weight_decay, "seed": seed, "samples": int(len(x)),
                               "train_s": round(time.perf_counter() - t0, 1)}
    return MlpPredictor((layers,), mean.astype(np.float64), std.astype(np.float64), info)
