"""The small tanh MLP that estool's GA self-play evolves for SlimeVolley, batched over games.

``slimevolleygym.mlp``'s ``'slimevolleylite'`` game: 12 inputs, two hidden layers of 10, 3
outputs, tanh on every layer, a button pressed where its output is > 0 (``Agent.setAction``).
The flat parameter layout is that of ``mlp.Model.set_model_params``: for each layer, the
(in, out) weight matrix row-major, then the bias -- 273 numbers, so a vector from estool's
``ga.json`` loads unchanged. (``mlp.Model`` itself calls ``np.product``, gone in NumPy 2.)

Checkpoints are ``.npz`` files read with ``allow_pickle=False``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

INPUTS = 12
OUTPUTS = 3
HIDDEN_LITE = (10, 10)      # mlp.games['slimevolleylite'], what train_ga_selfplay.py evolves


def layer_shapes(hidden: tuple[int, ...] = HIDDEN_LITE) -> list[tuple[int, int]]:
    sizes = (INPUTS, *hidden, OUTPUTS)
    return [(a, b) for a, b in zip(sizes[:-1], sizes[1:])]


def param_count(hidden: tuple[int, ...] = HIDDEN_LITE) -> int:
    """273 for the default (10, 10) hidden layers."""
    return sum(a * b + b for a, b in layer_shapes(hidden))


def unpack(params: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE) -> list[tuple[np.ndarray, np.ndarray]]:
    """Flat parameters (..., D) -> [(W (..., in, out), b (..., out)) per layer] (views)."""
    params = np.asarray(params, np.float64)
    d = param_count(hidden)
    if params.shape[-1] != d:
        raise ValueError(f"an MLP with hidden layers {hidden} has {d} parameters, got {params.shape[-1]}: "
                         "build the policy with the hidden sizes it was trained with")
    layers, k = [], 0
    for a, b in layer_shapes(hidden):
        w = params[..., k:k + a * b].reshape(*params.shape[:-1], a, b)
        k += a * b
        layers.append((w, params[..., k:k + b]))
        k += b
    return layers


def mlp_forward(params: np.ndarray, obs: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE) -> np.ndarray:
    """Outputs in (-1, 1).

    Parameters
    ----------
    params : ndarray, shape (D,) or (G, D)
        One parameter vector for every observation, or one per observation.
    obs : ndarray, shape (G, 12)
    """
    h = np.asarray(obs, np.float64)
    shared = np.ndim(params) == 1
    for w, b in unpack(params, hidden):
        h = np.tanh((h @ w if shared else np.matmul(h[:, None, :], w)[:, 0, :]) + b)
    return h


def mlp_act(params: np.ndarray, obs: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE) -> np.ndarray:
    """Buttons (G, 3) int8: pressed where the output is > 0."""
    return (mlp_forward(params, obs, hidden) > 0).astype(np.int8)


class PerGameMlp:
    """A batch policy with its own parameter vector per game: ``policy(obs (k, 12), idx (k,))``.

    The weights of the games ``idx`` are gathered once per distinct ``idx`` array (a match
    loop passes the same array until a game ends), not at every step.
    """

    def __init__(self, params: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE) -> None:
        self.layers = unpack(np.asarray(params, np.float64), hidden)
        self._idx: np.ndarray | None = None
        self._live = self.layers

    def __call__(self, obs: np.ndarray, idx: np.ndarray) -> np.ndarray:
        if idx is not self._idx:
            self._idx = idx
            self._live = [(w[idx], b[idx]) for w, b in self.layers]
        h = obs
        for w, b in self._live:
            h = np.tanh(np.matmul(h[:, None, :], w)[:, 0, :] + b)
        return (h > 0).astype(np.int8)


class MlpPolicy:
    """One parameter vector as a policy: ``policy(obs (G, 12)) -> (G, 3)``; ``predict(obs (12,))``
    for the original env's single-game loop (estool's ``Model.predict`` interface)."""

    def __init__(self, params: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE) -> None:
        self.hidden = tuple(hidden)
        self.params = np.array(params, np.float64).reshape(-1)
        unpack(self.params, self.hidden)    # size check

    def __call__(self, obs: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        return mlp_act(self.params, np.atleast_2d(obs), self.hidden)

    def predict(self, obs: np.ndarray) -> np.ndarray:
        return mlp_act(self.params, np.asarray(obs, np.float64)[None, :], self.hidden)[0]


def save_policy(path: str | Path, params: np.ndarray, hidden: tuple[int, ...] = HIDDEN_LITE, **meta: float) -> None:
    """Write one MLP policy (parameters, layer sizes, numeric metadata) as ``.npz``."""
    params = np.asarray(params, np.float64).reshape(-1)
    unpack(params, hidden)
    np.savez(path, params=params, hidden=np.asarray(hidden, np.int64),
             **{k: np.asarray(v, np.float64) for k, v in meta.items()})


def load_policy(path: str | Path, hidden: tuple[int, ...] | None = None) -> MlpPolicy:
    """Read a policy written by :func:`save_policy`; ``hidden`` (optional) is what the caller expects.

    Raises
    ------
    ValueError
        If the file's parameter count does not match its layer sizes, or the layer sizes do
        not match ``hidden`` -- a checkpoint of another network is refused, never reshaped.
    """
    with np.load(path, allow_pickle=False) as f:
        params = f["params"]
        saved = tuple(int(h) for h in f["hidden"])
    if hidden is not None and tuple(hidden) != saved:
        raise ValueError(f"{path}: a policy with hidden layers {saved} ({param_count(saved)} parameters), "
                         f"expected {tuple(hidden)} ({param_count(tuple(hidden))})")
    if params.size != param_count(saved):
        raise ValueError(f"{path}: {params.size} parameters where hidden layers {saved} need "
                         f"{param_count(saved)}: the file is corrupt or from another network")
    return MlpPolicy(params, saved)
