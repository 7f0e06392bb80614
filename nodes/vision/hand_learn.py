"""Training the hand keypoint network (:mod:`nodes.vision.hand_keypoints`) on arrays: Optax
AdamW with a warm-up cosine schedule, an L1 loss on soft-argmax keypoints (visible ones of
images with a hand), a heatmap cross-entropy, a presence cross-entropy and a finger-state
cross-entropy (the auxiliary head), dihedral augmentation (flips and quarter
turns of image and keypoints together; a mirrored hand is still a hand), seeded throughout.
The images come from the simulator (``python -m sim.hand_train``); nothing here knows it.

    params, curve = train_keypoints(images, keypoints, present, steps=3000, seed=0,
                                    progress=lambda p: print(p))
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from nodes.vision.hand_keypoints import INPUT_PX, KeypointNet, init_params, soft_argmax

__all__ = ["Progress", "augment", "keypoint_loss", "train_keypoints"]


@dataclass(frozen=True)
class Progress:
    """One learning-curve point: ``step``, mean training ``loss`` since the last point,
    validation ``val_loss`` and ``val_px`` (median keypoint error, input pixels), seconds."""

    step: int
    loss: float
    val_loss: float
    val_px: float
    elapsed_s: float


def augment(rng: np.random.Generator, images: np.ndarray, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A random flip and quarter turn per batch: images (B, S, S, C), keypoints (B, K, 2) (x, y) px."""
    s = images.shape[1]
    img, kp = images, keypoints.copy()
    if rng.random() < 0.5:
        img, kp[..., 0] = img[:, :, ::-1], s - 1 - kp[..., 0]
    for _ in range(int(rng.integers(4))):                     # rot90 counter-clockwise: (x, y) -> (y, s-1-x)
        img = np.rot90(img, 1, axes=(1, 2))
        kp = np.stack([kp[..., 1], s - 1 - kp[..., 0]], -1)
    return np.ascontiguousarray(img), kp


def keypoint_loss(params: Any, net: KeypointNet, x: jnp.ndarray, kp: jnp.ndarray, present: jnp.ndarray,
                  extended: jnp.ndarray | None = None, *, presence_weight: float = 0.2, heat_weight: float = 0.05,
                  finger_weight: float = 0.2) -> jnp.ndarray:
    """Mean L1 keypoint error (in units of the input size) over visible keypoints of present
    hands, plus ``heat_weight`` times the cross-entropy of each heatmap against a Gaussian
    (one cell) at the true keypoint (strong gradients early, when the soft-argmax sits at the
    centre), plus ``presence_weight`` times the presence cross-entropy, plus ``finger_weight``
    times the finger-extension cross-entropy of present hands (when ``extended`` (B, 5) is given)."""
    heat, logit, fingers = net.apply({"params": params}, x)
    pred, _ = soft_argmax(heat)
    visible = (jnp.all((kp >= 0) & (kp <= INPUT_PX - 1), axis=-1) & present[:, None]).astype(jnp.float32)
    kp0 = jnp.nan_to_num(kp)
    err = jnp.abs(pred - kp0).sum(-1) / INPUT_PX
    n_vis = jnp.maximum(visible.sum(), 1.0)
    l1 = (err * visible).sum() / n_vis
    b, h, w, k = heat.shape
    cell = INPUT_PX / h
    centres = (jnp.arange(h) + 0.5) * cell - 0.5
    gx = jnp.exp(-0.5 * ((centres[None, :, None] - kp0[:, None, :, 0]) / cell) ** 2)      # (B, W, K)
    gy = jnp.exp(-0.5 * ((centres[None, :, None] - kp0[:, None, :, 1]) / cell) ** 2)      # (B, H, K)
    target = gy[:, :, None, :] * gx[:, None, :, :]
    target = target / jnp.maximum(target.sum(axis=(1, 2), keepdims=True), 1e-9)
    logp = jax.nn.log_softmax(heat.reshape(b, h * w, k), axis=1).reshape(b, h, w, k)
    ce = -(target * logp).sum(axis=(1, 2))
    bce = optax.sigmoid_binary_cross_entropy(logit, present.astype(jnp.float32)).mean()
    loss = l1 + heat_weight * (ce * visible).sum() / n_vis + presence_weight * bce
    if extended is not None:
        fce = optax.sigmoid_binary_cross_entropy(fingers, extended.astype(jnp.float32)).mean(-1)
        loss = loss + finger_weight * (fce * present).sum() / jnp.maximum(present.sum(), 1)
    return loss


def train_keypoints(images: np.ndarray, keypoints: np.ndarray, present: np.ndarray, extended: np.ndarray | None = None,
                    *, steps: int = 3000,
                    batch: int = 32, lr: float = 2e-3, seed: int = 0, width: int = 16, val_frac: float = 0.05,
                    log_every: int = 100, progress: Callable[[Progress], None] | None = None,
                    params: Any = None, heat_weight: float = 0.05) -> tuple[Any, list[Progress]]:
    """Fit the network; returns its parameters and the learning curve.

    Parameters
    ----------
    images : (N, 96, 96, 3) uint8 RGB
    keypoints : (N, 21, 2) float, input pixels (x, y); NaN where there is no hand
    present : (N,) bool
    extended : (N, 5) bool, the finger states (thumb first) for the auxiliary head, or None
    steps, batch, lr : optimisation (AdamW, warm-up then cosine decay to 5 % of ``lr``)
    seed : seeds the split, the batches, the augmentation and the initialisation
    val_frac : held out from training for the curve's validation points
    params : start from these instead of a fresh initialisation
    heat_weight : weight of the heatmap cross-entropy in :func:`keypoint_loss`
    """
    n = len(images)
    if images.shape[1:] != (INPUT_PX, INPUT_PX, 3) or keypoints.shape != (n, 21, 2) or present.shape != (n,):
        raise ValueError(f"need images (N, {INPUT_PX}, {INPUT_PX}, 3), keypoints (N, 21, 2), present (N,); got "
                         f"{images.shape}, {keypoints.shape}, {present.shape}")
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    n_val = min(int(round(val_frac * n)), n - 1)
    val, tr = order[:n_val], order[n_val:]
    net = KeypointNet(width)
    params = init_params(seed, width) if params is None else params
    sched = optax.warmup_cosine_decay_schedule(0.0, lr, min(200, steps // 10 + 1), max(steps, 2), lr * 0.05)
    opt = optax.chain(optax.clip_by_global_norm(1.0), optax.adamw(sched, weight_decay=1e-4))
    state = opt.init(params)

    @jax.jit
    def step(params: Any, state: Any, x: jnp.ndarray, kp: jnp.ndarray, pres: jnp.ndarray, ext: jnp.ndarray | None
             ) -> tuple[Any, Any, jnp.ndarray]:
        loss, grads = jax.value_and_grad(keypoint_loss)(params, net, x, kp, pres, ext, heat_weight=heat_weight)
        updates, state = opt.update(grads, state, params)
        return optax.apply_updates(params, updates), state, loss

    @jax.jit
    def evaluate(params: Any, x: jnp.ndarray, kp: jnp.ndarray, pres: jnp.ndarray, ext: jnp.ndarray | None
                 ) -> tuple[jnp.ndarray, jnp.ndarray]:
        heat, _, _ = net.apply({"params": params}, x)
        pred, _ = soft_argmax(heat)
        return keypoint_loss(params, net, x, kp, pres, ext, heat_weight=heat_weight), jnp.linalg.norm(pred - jnp.nan_to_num(kp), axis=-1)

    def validate(params: Any) -> tuple[float, float]:
        losses, errs = [], []
        for i in range(0, len(val), 128):
            idx = val[i:i + 128]
            loss, err = evaluate(params, images[idx].astype(np.float32) / 255, keypoints[idx], present[idx],
                                 None if extended is None else extended[idx])
            losses.append(float(loss) * len(idx))
            errs.append(np.asarray(err)[present[idx]].ravel())
        e = np.concatenate(errs) if errs else np.zeros(0)
        return sum(losses) / max(len(val), 1), float(np.median(e)) if len(e) else float("nan")

    curve: list[Progress] = []
    t0, acc = time.perf_counter(), []
    for k in range(1, steps + 1):
        idx = tr[rng.integers(0, len(tr), batch)]
        x, kp = augment(rng, images[idx], keypoints[idx])
        params, state, loss = step(params, state, x.astype(np.float32) / 255, kp, present[idx],
                                   None if extended is None else extended[idx])
        acc.append(float(loss))
        if k % log_every == 0 or k == steps:
            vl, vpx = validate(params) if n_val else (float("nan"), float("nan"))
            curve.append(Progress(k, float(np.mean(acc)), vl, vpx, time.perf_counter() - t0))
            acc = []
            if progress is not None:
                progress(curve[-1])
    return params, curve
