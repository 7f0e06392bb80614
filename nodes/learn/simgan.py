"""SimGAN refiner (Shrivastava et al. 2017, seed 04) on JAX + Flax + Optax: make synthetic images look
real while keeping their labels.

A fully convolutional ResNet refiner R changes the synthetic image pixel by pixel (it starts as
the identity: its last convolution is zero-initialised inside ``tanh(atanh(x) + delta)``); a
local patch discriminator D scores every receptive-field patch real or refined; R minimises
the adversarial loss plus ``lam`` times the L1 self-regularisation ``|R(x) - x|`` that keeps the
annotation; D sees half current refined images and half from a history buffer of earlier ones.

>>> state = init_simgan(SimGANConfig(), (30, 70, 3), seed=0)
>>> state, hist = train_simgan(state, synthetic, real, SimGANConfig(), steps=2000, seed=0,
...                            checkpoint="out/captcha/simgan.msgpack")     # resumes if present
>>> refined = refine_images(state["r"], synthetic, SimGANConfig())        # float32 in [-1, 1]

Diagnostics logged every ``log_every`` steps: D's mean probability on real and refined
patches, a flag when D wins completely (the refiner gets no useful gradient), and the refined
batch's diversity relative to its inputs (a flag on mode collapse). A non-finite loss stops
training with the last finite parameters kept and ``diverged`` set.
"""
from __future__ import annotations

import functools
import logging
import time
from dataclasses import asdict, dataclass
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
class SimGANConfig:
    """Hyper-parameters (the paper's recipe at captcha scale)."""

    features: int = 16             # refiner width
    blocks: int = 2                # refiner ResNet blocks
    disc_features: tuple[int, ...] = (16, 32, 32)
    lam: float = 30.0              # weight of the L1 self-regularisation (per pixel mean)
    lr_r: float = 1e-4
    lr_d: float = 5e-4
    batch: int = 16
    history: int = 512             # refined images kept for D (the paper's buffer)
    k_g: int = 2                   # refiner updates per step
    k_d: int = 1                   # discriminator updates per step
    pretrain_d: int = 50           # D-only steps against the identity refiner
    win_prob: float = 0.02         # D wins when P(real|refined) < this and P(real|real) > 1 - this
    collapse_ratio: float = 0.3    # refined diversity / input diversity below this = collapse
    space_to_depth: int = 1        # refiner works on s x s pixel blocks as channels (s = 1: per pixel)
    residual: str = "tanh"         # "tanh": tanh(atanh(x) + d); "add": clip(x + d, -1, 1) (see Refiner)


def to_signed(images: np.ndarray) -> np.ndarray:
    """uint8 images -> float32 in [-1, 1]; float images are taken as already in [-1, 1]."""
    a = np.asarray(images)
    return a.astype(np.float32) / 127.5 - 1.0 if a.dtype == np.uint8 else a.astype(np.float32)


def to_uint8(images: np.ndarray) -> np.ndarray:
    """float images in [-1, 1] -> uint8."""
    return np.clip((np.asarray(images) + 1.0) * 127.5 + 0.5, 0, 255).astype(np.uint8)


class _Block(nn.Module):
    features: int

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        h = nn.relu(nn.Conv(self.features, (3, 3))(x))
        return nn.relu(x + nn.Conv(self.features, (3, 3))(h))


class Refiner(nn.Module):
    """(B, H, W, C) in [-1, 1] -> same shape in (-1, 1); the identity at initialisation.

    With ``space_to_depth`` s > 1 the ResNet runs on s x s pixel blocks stacked as channels (the
    image padded by edge replication to a multiple of s, then cropped back) and writes a per-pixel
    correction: s^2 fewer positions with wider layers, which XLA's CPU convolutions run far
    faster than one-channel full-resolution layers (a 1024 x 512 sonar image: 12 ms instead of
    105 ms at equal receptive field in pixels).


    ``residual`` "tanh" writes ``tanh(atanh(x) + d)``, smooth and bounded, but its gradient
    vanishes on saturated pixels (black in a sonar image: the derivative at x = -0.999 is 0.002,
    so a refiner cannot learn to lift a black shadow to a real sonar's noise floor); "add" writes
    ``clip(x + d, -1, 1)``, whose gradient is 1 wherever the result is inside the range.
    """

    features: int = 16
    blocks: int = 2
    space_to_depth: int = 1
    residual: str = "tanh"

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        s = self.space_to_depth
        b, h0, w0, c = x.shape
        z = x
        if s > 1:
            z = jnp.pad(x, ((0, 0), (0, -h0 % s), (0, -w0 % s), (0, 0)), mode="edge")
            hh, ww = z.shape[1] // s, z.shape[2] // s
            z = z.reshape(b, hh, s, ww, s, c).transpose(0, 1, 3, 2, 4, 5).reshape(b, hh, ww, s * s * c)
        h = nn.relu(nn.Conv(self.features, (3, 3))(z))
        for _ in range(self.blocks):
            h = _Block(self.features)(h)
        delta = nn.Conv(z.shape[-1], (1, 1), kernel_init=nn.initializers.zeros)(h)
        if s > 1:
            delta = delta.reshape(b, hh, ww, s, s, c).transpose(0, 1, 3, 2, 4, 5).reshape(b, hh * s, ww * s, c)
            delta = delta[:, :h0, :w0]
        if self.residual == "add":
            return jnp.clip(x + delta, -1.0, 1.0)
        if self.residual != "tanh":
            raise ValueError(f"residual must be 'tanh' or 'add', got {self.residual!r}")
        return jnp.tanh(jnp.arctanh(jnp.clip(x, -0.999, 0.999)) + delta)


class PatchDiscriminator(nn.Module):
    """(B, H, W, C) -> (B, h, w) logits, one per local patch (real = 1)."""

    features: tuple[int, ...] = (16, 32, 32)

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        for i, f in enumerate(self.features):
            x = nn.leaky_relu(nn.Conv(f, (3, 3), strides=(2, 2) if i < 2 else (1, 1))(x), 0.2)
        return nn.Conv(1, (1, 1))(x)[..., 0]


@functools.lru_cache(maxsize=8)
def _compiled(cfg: SimGANConfig) -> dict[str, Callable[..., Any]]:
    """The jitted refiner and discriminator updates for ``cfg``: compiled once per process."""
    r_net, d_net = Refiner(cfg.features, cfg.blocks, cfg.space_to_depth, cfg.residual), PatchDiscriminator(cfg.disc_features)
    tx_r = optax.adam(cfg.lr_r, b1=0.5)
    tx_d = optax.adam(cfg.lr_d, b1=0.5)

    def r_loss(pr: Any, pd: Any, syn: jnp.ndarray) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
        ref = r_net.apply(pr, syn)
        logits = d_net.apply(pd, ref)
        adv = optax.sigmoid_binary_cross_entropy(logits, jnp.ones_like(logits)).mean()
        l1 = jnp.abs(ref - syn).mean()
        return adv + cfg.lam * l1, {"r_adv": adv, "r_l1": l1}

    def d_loss(pd: Any, real: jnp.ndarray, fake: jnp.ndarray) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
        lr, lf = d_net.apply(pd, real), d_net.apply(pd, fake)
        loss = (optax.sigmoid_binary_cross_entropy(lr, jnp.ones_like(lr)).mean()
                + optax.sigmoid_binary_cross_entropy(lf, jnp.zeros_like(lf)).mean())
        return loss, {"d_loss": loss, "p_real": jax.nn.sigmoid(lr).mean(), "p_fake": jax.nn.sigmoid(lf).mean()}

    @jax.jit
    def r_step(pr: Any, opt: Any, pd: Any, syn: jnp.ndarray) -> tuple[Any, Any, jnp.ndarray, dict[str, jnp.ndarray]]:
        (loss, info), g = jax.value_and_grad(r_loss, has_aux=True)(pr, pd, syn)
        updates, opt = tx_r.update(g, opt, pr)
        return optax.apply_updates(pr, updates), opt, r_net.apply(pr, syn), {**info, "r_loss": loss}

    @jax.jit
    def d_step(pd: Any, opt: Any, real: jnp.ndarray, fake: jnp.ndarray) -> tuple[Any, Any, dict[str, jnp.ndarray]]:
        (_, info), g = jax.value_and_grad(d_loss, has_aux=True)(pd, real, fake)
        updates, opt = tx_d.update(g, opt, pd)
        return optax.apply_updates(pd, updates), opt, info

    def init(key: jax.Array, x: jnp.ndarray) -> tuple[Any, Any]:
        kr, kd = jax.random.split(key)
        return r_net.init(kr, x), d_net.init(kd, x)

    return {"r_step": r_step, "d_step": d_step, "refine": jax.jit(r_net.apply), "init": jax.jit(init), "r_net": r_net,
            "d_net": d_net, "tx_r": tx_r, "tx_d": tx_d}


def init_simgan(cfg: SimGANConfig, image_shape: tuple[int, int, int], *, seed: int = 0) -> dict[str, Any]:
    """Fresh refiner, discriminator, optimiser states, an empty history buffer and step 0.

    The weights are drawn from an "rbg" key under one jit (threefry keys compiled one
    truncated-normal kernel per layer shape, eagerly: seconds each on a small CPU)."""
    c = _compiled(cfg)
    pr, pd = c["init"](jax.random.key(seed, impl="rbg"), jnp.zeros((1, *image_shape), jnp.float32))
    return {"r": pr, "d": pd, "opt_r": c["tx_r"].init(pr), "opt_d": c["tx_d"].init(pd),
            "buffer": np.zeros((cfg.history, *image_shape), np.float32), "buffer_n": np.zeros((), np.int64),
            "step": np.zeros((), np.int64)}


def batch_diversity(refined: np.ndarray, inputs: np.ndarray) -> float:
    """Mean pairwise L1 distance of ``refined`` over that of the ``inputs`` it came from (1 = as varied).

    Mode collapse (many inputs mapped to one output) drives it towards 0.
    """
    def spread(a: np.ndarray) -> float:
        a = np.asarray(a, np.float64).reshape(len(a), -1)
        return float(np.abs(a[:, None] - a[None]).mean()) if len(a) > 1 else 0.0

    base = spread(inputs)
    return spread(refined) / base if base > 0 else 1.0


def detect_mode_collapse(refined: np.ndarray, inputs: np.ndarray, *, ratio: float = 0.3) -> bool:
    """True when the refined batch is less than ``ratio`` as diverse as its inputs."""
    return batch_diversity(refined, inputs) < ratio


def _finite(tree: Any) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v)))) for v in jax.tree_util.tree_leaves(tree))


def _d_fake(state: dict[str, Any], refined: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Half current refined, half from the history buffer; then half the current batch enters the buffer."""
    buf, n = state["buffer"], int(state["buffer_n"])
    half = len(refined) // 2
    fake = refined.copy()
    if n >= half > 0:
        fake[half:] = buf[rng.choice(n, len(refined) - half, replace=False)]
    slots = np.arange(n, min(n + half, len(buf)))
    if len(slots) < half:
        slots = np.concatenate([slots, rng.choice(len(buf), half - len(slots), replace=False)])
    buf[slots] = refined[:half]
    state["buffer_n"] = np.asarray(min(n + half, len(buf)), np.int64)
    return fake


def train_simgan(state: dict[str, Any], synthetic: np.ndarray, real: np.ndarray, cfg: SimGANConfig, *,
                 steps: int, seed: int = 0, checkpoint: str | Path | None = None, log_every: int = 50,
                 checkpoint_every: int = 500) -> tuple[dict[str, Any], dict[str, Any]]:
    """Train until ``state["step"] == steps`` (resuming from ``checkpoint`` when it exists).

    Parameters
    ----------
    state : dict
        From ``init_simgan`` (replaced by the checkpoint's when resuming).
    synthetic, real : numpy.ndarray
        (N, H, W, C) uint8 or float in [-1, 1]; unpaired.
    steps : int
        Total steps (each ``k_d`` D updates and ``k_g`` R updates), counted across resumes.
    seed : int
        Batches of step ``t`` are drawn from ``default_rng([seed, t])``: a resumed run is the
        same as an uninterrupted one.

    Returns
    -------
    state : dict
    history : dict
        Lists per logged step (``step``, ``r_adv``, ``r_l1``, ``d_loss``, ``p_real``, ``p_fake``,
        ``diversity``, ``steps_per_s``) and the flags ``d_wins`` (steps where D won completely),
        ``collapse`` (steps where diversity fell below ``collapse_ratio``), ``diverged``.
    """
    syn, rl = to_signed(synthetic), to_signed(real)
    if syn.shape[1:] != rl.shape[1:] or syn.ndim != 4:
        raise ValueError(f"synthetic {syn.shape} and real {rl.shape} must both be (N, H, W, C) with equal H, W, C")
    c = _compiled(cfg)
    hist: dict[str, Any] = {k: [] for k in ("step", "r_adv", "r_l1", "d_loss", "p_real", "p_fake", "diversity",
                                            "steps_per_s")}
    hist.update(d_wins=[], collapse=[], diverged=False)
    if checkpoint is not None and Path(checkpoint).exists():
        state, meta = load_checkpoint(checkpoint, state)
        state = {**state, "buffer": np.array(state["buffer"]), "buffer_n": np.asarray(state["buffer_n"])}
        hist.update(meta.get("history", {}))
        log.info("simgan: resumed %s at step %d", checkpoint, int(state["step"]))
    t0, s0 = time.perf_counter(), int(state["step"])
    while int(state["step"]) < steps:
        t = int(state["step"])
        rng = np.random.default_rng([seed, t])
        b = cfg.batch
        prev = (state["r"], state["d"], state["opt_r"], state["opt_d"])
        for _ in range(cfg.k_d):
            xs = syn[rng.integers(len(syn), size=b)]
            refined = np.asarray(c["refine"](state["r"], xs))
            fake = _d_fake(state, refined, rng)
            state["d"], state["opt_d"], dinfo = c["d_step"](state["d"], state["opt_d"], rl[rng.integers(len(rl), size=b)], fake)
        if t >= cfg.pretrain_d:
            for _ in range(cfg.k_g):
                xs = syn[rng.integers(len(syn), size=b)]
                state["r"], state["opt_r"], refined, rinfo = c["r_step"](state["r"], state["opt_r"], state["d"], xs)
        else:
            rinfo = {"r_adv": np.nan, "r_l1": 0.0, "r_loss": 0.0}
        if not (_finite(dinfo) and np.isfinite(float(rinfo["r_loss"]))):
            state["r"], state["d"], state["opt_r"], state["opt_d"] = prev
            hist["diverged"] = True
            log.error("simgan: non-finite loss at step %d; stopped with the last finite parameters", t)
            break
        state["step"] = np.asarray(t + 1, np.int64)
        if (t + 1) % log_every == 0 or t + 1 == steps:
            _log_step(hist, cfg, t + 1, rinfo, dinfo, np.asarray(refined), xs, (t + 1 - s0) / (time.perf_counter() - t0))
        if checkpoint is not None and ((t + 1) % checkpoint_every == 0 or t + 1 == steps):
            save_checkpoint(checkpoint, state, meta={"history": hist, "config": _jsonable(asdict(cfg))})
    return state, hist


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def _log_step(hist: dict[str, Any], cfg: SimGANConfig, step: int, rinfo: dict, dinfo: dict, refined: np.ndarray,
              inputs: np.ndarray, rate: float) -> None:
    row = {"step": step, "r_adv": float(rinfo["r_adv"]), "r_l1": float(rinfo["r_l1"]), "d_loss": float(dinfo["d_loss"]),
           "p_real": float(dinfo["p_real"]), "p_fake": float(dinfo["p_fake"]),
           "diversity": batch_diversity(refined, inputs), "steps_per_s": rate}
    for k, v in row.items():
        hist[k].append(v)
    if row["p_fake"] < cfg.win_prob and row["p_real"] > 1 - cfg.win_prob:
        hist["d_wins"].append(step)
        log.warning("simgan: step %d: the discriminator wins completely (P(real|real) %.3f, P(real|refined) %.4f): "
                    "the refiner's adversarial gradient vanishes; lower lam or lr_d, or narrow D", step,
                    row["p_real"], row["p_fake"])
    if row["diversity"] < cfg.collapse_ratio:
        hist["collapse"].append(step)
        log.warning("simgan: step %d: mode collapse (refined batch %.2f as diverse as its inputs)", step, row["diversity"])
    log.info("simgan %5d  %.1f steps/s  R adv %.3f l1 %.4f  D %.3f  P(real|real) %.2f P(real|refined) %.2f  div %.2f",
             step, rate, row["r_adv"], row["r_l1"], row["d_loss"], row["p_real"], row["p_fake"], row["diversity"])


def refine_images(params_r: Any, images: np.ndarray, cfg: SimGANConfig, *, batch: int = 256) -> np.ndarray:
    """Refined images, float32 in [-1, 1], same shape as ``images`` (uint8 or float in [-1, 1])."""
    x = to_signed(images)
    if x.ndim != 4:
        raise ValueError(f"expected (N, H, W, C) images, got shape {x.shape}")
    f = _compiled(cfg)["refine"]
    return np.concatenate([np.asarray(f(params_r, x[i:i + batch])) for i in range(0, len(x), batch)]) if len(x) else x


def save_refiner(path: str | Path, params_r: Any, cfg: SimGANConfig, *, meta: dict[str, Any] | None = None) -> int:
    """The refiner alone (what a node serves), with the config that rebuilds it."""
    return save_checkpoint(path, params_r, meta={**(meta or {}), "config": _jsonable(asdict(cfg)), "kind": "simgan-refiner"})


def load_refiner(path: str | Path) -> tuple[Any, SimGANConfig, dict[str, Any]]:
    """``(params, config, meta)`` of a :func:`save_refiner` file; ``ValueError`` naming what does not fit."""
    from flax import serialization

    doc = serialization.msgpack_restore(Path(path).read_bytes())
    meta = doc.get("meta", {}) if isinstance(doc, dict) else {}
    if meta.get("kind") != "simgan-refiner":
        raise ValueError(f"{path}: not a SimGAN refiner checkpoint (kind {meta.get('kind')!r})")
    raw = dict(meta["config"])
    raw["disc_features"] = tuple(raw.get("disc_features", SimGANConfig.disc_features))
    try:
        cfg = SimGANConfig(**raw)
    except TypeError as exc:
        raise ValueError(f"{path}: refiner config does not fit this version: {exc}") from None
    net = Refiner(cfg.features, cfg.blocks, cfg.space_to_depth, cfg.residual)
    x = jax.ShapeDtypeStruct((1, 8, 8, int(meta.get("channels", 1))), jnp.float32)
    like = jax.eval_shape(lambda v: net.init(jax.random.PRNGKey(0), v), x)      # shapes only: no compile
    params, meta = load_checkpoint(path, like)
    return params, cfg, meta
