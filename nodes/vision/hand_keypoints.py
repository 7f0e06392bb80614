"""A small learned 21-keypoint hand model (seed 13, its reference [1] in miniature): a
four-level convolutional encoder-decoder (196 k parameters) in Flax over a 96x96 colour
image, 21 heatmaps at 24x24 read out by a soft-argmax (sub-cell keypoints, differentiable),
and from the bottleneck a hand-presence logit and five finger-extension logits (an auxiliary
head: the gesture can be read from the keypoints' geometry or from it). CPU-trainable in minutes on simulator images
(``python -m sim.hand_train``); weights are a flax.serialization msgpack file, never a pickle.

    model = KeypointModel.load()                      # the committed weights
    est = model.predict(image_bgr)                    # any size; resized to 96x96
    est.keypoints_px (21, 2) in the image's pixels, est.presence in [0, 1], est.finger_prob (5,)
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import flax.linen as nn
import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["HEAT_PX", "INPUT_PX", "WEIGHTS", "KeypointEstimate", "KeypointModel", "KeypointNet", "init_params",
           "soft_argmax", "to_input"]

INPUT_PX = 96
HEAT_PX = 24
WEIGHTS = Path(__file__).resolve().parent / "weights" / "hand_keypoints.msgpack"


def _up2(x: jnp.ndarray) -> jnp.ndarray:
    """Nearest-neighbour upsampling by 2 (B, H, W, C) -> (B, 2H, 2W, C)."""
    return jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)


class KeypointNet(nn.Module):
    """(B, 96, 96, 3) float in [0, 1] -> heatmap logits (B, 24, 24, 21), presence logit (B,),
    finger-extension logits (B, 5) thumb..pinky."""

    width: int = 16

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
        w = self.width

        def conv(h: jnp.ndarray, ch: int, stride: int = 1) -> jnp.ndarray:
            h = nn.Conv(ch, (3, 3), strides=(stride, stride), use_bias=False)(h)
            return nn.relu(nn.LayerNorm()(h))              # per-pixel channel norm: no batch statistics

        x = x - 0.5
        c1 = conv(x, w, 2)                                   # 48
        c2 = conv(c1, 2 * w, 2)                              # 24
        c3 = conv(conv(c2, 3 * w, 2), 3 * w)                 # 12
        c4 = conv(conv(c3, 4 * w, 2), 4 * w)                 # 6
        u3 = conv(jnp.concatenate([_up2(c4), c3], -1), 3 * w)
        u2 = conv(jnp.concatenate([_up2(u3), c2], -1), 2 * w)
        heat = nn.Conv(21, (1, 1))(u2)
        pooled = jnp.concatenate([c4.mean(axis=(1, 2)), c4.max(axis=(1, 2))], -1)
        presence = nn.Dense(1)(nn.relu(nn.Dense(32)(pooled)))[:, 0]
        pooled3 = jnp.concatenate([pooled, u3.mean(axis=(1, 2)), u3.max(axis=(1, 2))], -1)
        fingers = nn.Dense(5)(nn.relu(nn.Dense(64)(pooled3)))
        return heat, presence, fingers


def soft_argmax(heat: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Heatmap logits (B, H, W, K) -> keypoints (B, K, 2) in input pixels (x, y) and the peak
    probability (B, K) (a per-keypoint confidence)."""
    b, h, w, k = heat.shape
    p = jax.nn.softmax(heat.reshape(b, h * w, k), axis=1).reshape(b, h, w, k)
    cell = INPUT_PX / h
    xs = (jnp.arange(w) + 0.5) * cell - 0.5
    ys = (jnp.arange(h) + 0.5) * cell - 0.5
    x = jnp.einsum("bhwk,w->bk", p, xs)
    y = jnp.einsum("bhwk,h->bk", p, ys)
    return jnp.stack([x, y], -1), p.reshape(b, h * w, k).max(axis=1)


def init_params(seed: int = 0, width: int = 16) -> Any:
    """Fresh parameters of :class:`KeypointNet`, drawn with XLA's RngBitGenerator ("rbg" keys): the
    default threefry keys cost this net's initialisation 20-30 s of XLA compilation on this CPU
    (one truncated-normal kernel per layer shape), rbg keys 3 s; seeded and reproducible alike."""
    return _init(width)(jax.random.key(seed, impl="rbg"), jnp.zeros((1, INPUT_PX, INPUT_PX, 3)))["params"]


@functools.lru_cache(maxsize=4)
def _init(width: int) -> Any:
    """The jitted initialiser of one width, compiled once per process (each new ``jax.jit`` of a
    fresh module's ``init`` compiled again: 4-6 s here)."""
    return jax.jit(KeypointNet(width).init)


def to_input(image: np.ndarray) -> np.ndarray:
    """An image (H, W, 3) BGR uint8 or (H, W) mono -> (96, 96, 3) float32 RGB in [0, 1]."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 8 or img.shape[1] < 8:
        raise ValueError(f"need an image (H, W, 3) or (H, W) of at least 8x8 pixels, got shape {img.shape}")
    img = cv2.resize(img, (INPUT_PX, INPUT_PX), interpolation=cv2.INTER_AREA)
    return img[..., ::-1].astype(np.float32) / 255.0


@functools.partial(jax.jit, static_argnums=0)
def _forward(net: KeypointNet, params: Any, x: jnp.ndarray) -> tuple[jnp.ndarray, ...]:
    """Keypoints, their peak probabilities, presence and finger probabilities. One compiled
    function per net shape, shared by every model instance (nodes, tests, the bench)."""
    heat, presence, fingers = net.apply({"params": params}, x)
    kp, conf = soft_argmax(heat)
    return kp, conf, jax.nn.sigmoid(presence), jax.nn.sigmoid(fingers)


@dataclass(frozen=True)
class KeypointEstimate:
    """``keypoints_px`` (21, 2) in the input image's pixels; ``keypoint_conf`` (21,) peak heat
    probability; ``presence`` in [0, 1] (a hand in view); ``finger_prob`` (5,) thumb..pinky
    extended, from the auxiliary head."""

    keypoints_px: np.ndarray
    keypoint_conf: np.ndarray
    presence: float
    finger_prob: np.ndarray = field(default_factory=lambda: np.zeros(5))


class KeypointModel:
    """The network with its parameters and a jitted forward pass."""

    def __init__(self, params: Any, width: int = 16) -> None:
        self.params, self.net = params, KeypointNet(width)

    @classmethod
    def load(cls, path: str | Path = WEIGHTS, width: int = 16) -> "KeypointModel":
        """Parameters from a flax.serialization msgpack file (``ValueError`` if it does not fit the net)."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"no keypoint weights at {path}; train them with: python -m sim.hand_train -o {path}")
        template = jax.eval_shape(lambda: init_params(0, width))      # shapes only: nothing is computed
        try:
            params = flax.serialization.msgpack_restore(path.read_bytes())
            if jax.tree_util.tree_structure(params) != jax.tree_util.tree_structure(template):
                raise ValueError("the layers differ")
            if not all(np.shape(a) == b.shape for a, b in zip(jax.tree_util.tree_leaves(params),
                                                                  jax.tree_util.tree_leaves(template))):
                raise ValueError("array shapes differ")
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: weights do not fit a KeypointNet(width={width}): {exc}") from exc
        return cls(params, width)

    @classmethod
    def warm_start(cls, path: str | Path, width: int = 16) -> "KeypointModel":
        """Fresh parameters with every layer that ``path`` also has (same name and shape) taken
        from it: fine-tuning after the net gained a head."""
        fresh = init_params(0, width)
        old = flax.serialization.msgpack_restore(Path(path).read_bytes())
        merged = {k: (jax.tree_util.tree_map(np.asarray, old[k]) if k in old and jax.tree_util.tree_structure(old[k])
                      == jax.tree_util.tree_structure(fresh[k]) and all(np.shape(a) == np.shape(b) for a, b in zip(
                          jax.tree_util.tree_leaves(old[k]), jax.tree_util.tree_leaves(fresh[k]))) else v)
                  for k, v in fresh.items()}
        return cls(merged, width)

    def save(self, path: str | Path) -> int:
        """Write the parameters as msgpack; returns the byte count."""
        data = flax.serialization.to_bytes(jax.tree_util.tree_map(lambda a: np.asarray(a, np.float32), self.params))
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(data)
        return len(data)

    def predict_batch(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(B, 96, 96, 3) inputs -> keypoints (B, 21, 2) in input px, confidences (B, 21),
        presence (B,), finger-extension probabilities (B, 5)."""
        out = _forward(self.net, self.params, jnp.asarray(inputs, jnp.float32))
        return tuple(np.asarray(a) for a in out)  # type: ignore[return-value]

    def predict(self, image: np.ndarray, *, refine: bool = True) -> KeypointEstimate:
        """One image of any size -> keypoints in its own pixels. ``refine``: a second pass on a
        square crop around the first pass's keypoints (the hand filling ~65 % of it, as in
        training), which magnifies a hand that is small in the frame; presence is the first
        pass's (the whole view decides whether there is a hand)."""
        img = np.asarray(image)
        h, w = img.shape[:2]
        kp, conf, pres, fingers = self.predict_batch(to_input(img)[None])
        scale = np.array([w / INPUT_PX, h / INPUT_PX])
        est = KeypointEstimate((kp[0] + 0.5) * scale - 0.5, conf[0], float(pres[0]), fingers[0])
        if not refine or est.presence < 0.5:
            return est
        lo, hi = est.keypoints_px.min(axis=0), est.keypoints_px.max(axis=0)
        side = max(float((hi - lo).max()) / 0.65, 0.3 * min(h, w))
        if side >= 0.9 * max(h, w):
            return est
        x0, y0 = (lo + hi) / 2 - side / 2
        k = INPUT_PX / side
        crop = cv2.warpAffine(img, np.array([[k, 0, -k * x0], [0, k, -k * y0]]), (INPUT_PX, INPUT_PX),
                              flags=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        kp2, conf2, _, fingers2 = self.predict_batch(to_input(crop)[None])
        return KeypointEstimate(kp2[0] / k + np.array([x0, y0]), conf2[0], est.presence,
                                (est.finger_prob + fingers2[0]) / 2)
