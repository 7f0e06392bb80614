"""Pedestrian trajectory prediction: each walker's next 4.8 s from its last 3.2 s and its neighbours.

A small MLP learnt from ETH/UCY walkers (trained by :mod:`nodes.nav.predict_train`, JAX +
Flax + Optax) and two baselines, all with one calling convention: ``hist`` (P, 8, 2) m holds
the last 8 positions of every walker seen now, one row each, 0.4 s apart, the last one now
(NaN where a walker was not seen); each walker's neighbours are the other rows. Prediction
runs in plain numpy (no JAX at run time): encoding a frame of 20 walkers and one forward
pass take well under a millisecond.

- :func:`predict_cv`: constant velocity (the last observed step, as the runtime conflict
  feature assumes);
- :func:`predict_damped`: the hand baseline, the mean velocity of the last ``m`` steps,
  each later step ``decay`` times the one before (walkers slow down, turn and stop);
- :class:`MlpPredictor`: the learnt model. It predicts a correction to constant velocity in
  the walker's own frame (x along its recent heading), from its relative history and, for
  each of 8 sectors around it, the nearest neighbour within 4 m (proximity, relative
  position and velocity).

>>> pred = load_loso("students003")      # the MLP trained on the other four scenes
>>> future = pred.predict(hist)          # (P, 12, 2) m at 0.4, 0.8, ... 4.8 s from now
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OBS_STEPS = 8            # observed positions, the last one now
PRED_STEPS = 12          # predicted positions, 0.4 .. 4.8 s ahead
STEP_S = 0.4             # seconds between two positions
SECTORS = 8              # neighbour sectors around the walker (the first centred straight ahead)
NEIGHBOUR_RANGE_M = 4.0  # neighbours farther than this are not encoded
N_INPUTS = 2 * (OBS_STEPS - 1) + (OBS_STEPS - 1) + 5 * SECTORS
#: metric horizons (s) and the step index they end on
HORIZONS_S = (1.2, 2.4, 4.8)


def fill_history(hist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill the NaN positions of ``hist`` (P, T, 2): a missing one takes the next seen position
    (a gap or an unseen start reads as standing still). Returns filled positions and the
    (P, T) mask of seen ones. A row whose last position is NaN stays NaN (nobody knows where
    that walker is now)."""
    h = np.array(hist, dtype=np.float64, copy=True)
    if h.ndim != 3 or h.shape[2] != 2 or h.shape[1] < 2:
        raise ValueError(f"hist must be (P, T >= 2, 2) positions in metres, got shape {h.shape}")
    seen = np.isfinite(h).all(axis=2)
    h[~seen] = np.nan
    for k in range(h.shape[1] - 2, -1, -1):
        gap = ~np.isfinite(h[:, k, 0])
        h[gap, k] = h[gap, k + 1]
    return h, seen


def _frames(h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per walker: the rotation world -> walker frame (P, 2, 2), its smoothed and its last-step
    velocity (P, 2) m/s (world). x of the walker frame is its velocity over the last two steps
    (world x when it stands still)."""
    v_smooth = (h[:, -1] - h[:, -3]) / (2 * STEP_S) if h.shape[1] >= 3 else (h[:, -1] - h[:, -2]) / STEP_S
    v_last = (h[:, -1] - h[:, -2]) / STEP_S
    speed = np.hypot(v_smooth[:, 0], v_smooth[:, 1])
    yaw = np.where(speed > 0.05, np.arctan2(v_smooth[:, 1], v_smooth[:, 0]), 0.0)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)       # rows: walker x, y in world
    return np.nan_to_num(rot), v_smooth, v_last


def encode(hist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Model inputs of every walker of one frame.

    Parameters
    ----------
    hist : (P, 8, 2) m, the last 8 positions of each walker seen now (0.4 s apart), NaN where unseen.

    Returns
    -------
    x : (P, N_INPUTS) inputs (0 for a walker not seen now), rot : (P, 2, 2) world -> walker
    frame, now : (P, 2) m current positions (NaN for a walker not seen now).
    """
    h, seen = fill_history(hist)
    if h.shape[1] != OBS_STEPS:
        raise ValueError(f"hist must hold {OBS_STEPS} positions per walker, got {h.shape[1]}")
    p = len(h)
    rot, _, v_last = _frames(h)
    now = h[:, -1]
    here = np.isfinite(now).all(axis=1)
    rel = np.einsum("pij,ptj->pti", rot, h[:, :-1] - now[:, None])             # (P, 7, 2) walker frame
    x_hist = np.nan_to_num(rel).reshape(p, -1)
    x_mask = seen[:, :-1].astype(np.float64)
    nb = np.zeros((p, SECTORS, 5))
    if p > 1:
        d_world = now[None, :, :] - now[:, None, :]                            # (P, P, 2) other - me
        dv_world = np.nan_to_num(v_last[None, :, :] - v_last[:, None, :])
        d = np.einsum("pij,pqj->pqi", rot, d_world)
        dv = np.einsum("pij,pqj->pqi", rot, dv_world)
        dist = np.hypot(d[..., 0], d[..., 1])
        ok = np.isfinite(dist) & (dist < NEIGHBOUR_RANGE_M) & ~np.eye(p, dtype=bool)
        ang = np.nan_to_num(np.arctan2(d[..., 1], d[..., 0]))
        sector = np.mod(np.round(ang / (2 * np.pi / SECTORS)), SECTORS).astype(np.int64)
        dist = np.where(ok, dist, np.inf)
        for s in range(SECTORS):
            ds = np.where(sector == s, dist, np.inf)
            q = np.argmin(ds, axis=1)
            has = np.isfinite(ds[np.arange(p), q])
            r = np.arange(p)[has]
            nb[r, s, 0] = 1.0 - ds[r, q[has]] / NEIGHBOUR_RANGE_M
            nb[r, s, 1:3] = d[r, q[has]] / NEIGHBOUR_RANGE_M
            nb[r, s, 3:5] = dv[r, q[has]]
    x = np.concatenate([x_hist, x_mask, nb.reshape(p, -1)], axis=1)
    x[~here] = 0.0
    return x, rot, now


def cv_offsets(hist: np.ndarray, *, steps: int = PRED_STEPS, window: int = 1, decay: float = 1.0) -> np.ndarray:
    """(P, steps, 2) m displacements from now: the mean velocity of the last ``window`` observed steps,
    the k-th step scaled by ``decay ** k`` (world frame; 0 for a walker seen once)."""
    h, _ = fill_history(hist)
    window = int(np.clip(window, 1, h.shape[1] - 1))
    v = (h[:, -1] - h[:, -1 - window]) / (window * STEP_S)
    scale = np.cumsum(decay ** np.arange(1, steps + 1))                      # sum of decayed unit steps
    return v[:, None, :] * STEP_S * scale[None, :, None]


def predict_cv(hist: np.ndarray, *, steps: int = PRED_STEPS) -> np.ndarray:
    """Constant velocity: (P, steps, 2) m positions at 0.4 s, 0.8 s, ... from now (the last observed step)."""
    h, _ = fill_history(hist)
    return h[:, -1][:, None] + cv_offsets(h, steps=steps)


def predict_damped(hist: np.ndarray, *, window: int = 2, decay: float = 0.97, steps: int = PRED_STEPS) -> np.ndarray:
    """Hand baseline: the mean velocity of the last ``window`` steps, decaying by ``decay`` per step."""
    h, _ = fill_history(hist)
    return h[:, -1][:, None] + cv_offsets(h, steps=steps, window=window, decay=decay)


@dataclass(frozen=True)
class MlpPredictor:
    """The learnt predictor: ReLU MLPs on :func:`encode`'s inputs (standardised), out = a correction
    (walker frame, m) to constant velocity at each of the 12 steps, averaged over the members
    (an ensemble of MLPs trained on the same data from different seeds).

    members : (((W (n_in, n_out), b (n_out,)), ...), ...) one tuple of layers per member;
    x_mean, x_std : (N_INPUTS,); meta : provenance (data it was trained on, held-out scenes, ...).
    """

    members: tuple[tuple[tuple[np.ndarray, np.ndarray], ...], ...]
    x_mean: np.ndarray
    x_std: np.ndarray
    meta: dict

    def __post_init__(self) -> None:
        for layers in self.members or ((),):
            if not layers or layers[0][0].shape[0] != N_INPUTS or layers[-1][0].shape[1] != 2 * PRED_STEPS:
                raise ValueError(f"each MLP must map {N_INPUTS} inputs to {2 * PRED_STEPS} outputs; retrain it "
                                 "(nodes.nav.predict_train) after changing the encoding")

    @classmethod
    def ensemble(cls, models: list["MlpPredictor"], meta: dict | None = None) -> "MlpPredictor":
        """One predictor averaging ``models`` (trained on the same samples: the same standardisation)."""
        if not models or any(not np.allclose(m.x_mean, models[0].x_mean) for m in models):
            raise ValueError("give at least one model, all trained on the same samples")
        return cls(tuple(layers for m in models for layers in m.members), models[0].x_mean, models[0].x_std,
                   dict(meta if meta is not None else models[0].meta) | {"members": sum(len(m.members) for m in models)})

    def forward(self, x: np.ndarray) -> np.ndarray:
        """(P, N_INPUTS) raw inputs -> (P, PRED_STEPS, 2) corrections in the walker frame (m), member mean."""
        a0 = (np.asarray(x, np.float64) - self.x_mean) / self.x_std
        total = 0.0
        for layers in self.members:
            a = a0
            for i, (w, b) in enumerate(layers):
                a = a @ w + b
                if i < len(layers) - 1:
                    a = np.maximum(a, 0.0)
            total = total + a
        return (total / len(self.members)).reshape(len(a0), PRED_STEPS, 2)

    def predict(self, hist: np.ndarray) -> np.ndarray:
        """(P, 8, 2) observed -> (P, 12, 2) m predicted positions at 0.4 .. 4.8 s (NaN for a walker not seen now)."""
        hist = np.asarray(hist, np.float64)
        if len(hist) == 0:
            return np.zeros((0, PRED_STEPS, 2))
        x, rot, now = encode(hist)
        return self.predict_encoded(x, rot, hist)

    def predict_encoded(self, x: np.ndarray, rot: np.ndarray, hist: np.ndarray) -> np.ndarray:
        """:meth:`predict` from :func:`encode`'s (or :func:`scene_samples`') inputs ``x`` (N, N_INPUTS) and
        frames ``rot`` (N, 2, 2) of walkers observed ``hist`` (N, 8, 2): samples from many frames at once."""
        h, _ = fill_history(hist)
        world = np.einsum("pji,ptj->pti", rot, self.forward(x))              # walker frame -> world
        return h[:, -1][:, None] + cv_offsets(h) + world

    def save(self, path: str | Path) -> None:
        """npz (no pickle): W<member>_<layer>, b<member>_<layer>, x_mean, x_std, meta (JSON text)."""
        arrays = {}
        for m, layers in enumerate(self.members):
            for i, (w, b) in enumerate(layers):
                arrays[f"W{m}_{i}"], arrays[f"b{m}_{i}"] = w.astype(np.float32), b.astype(np.float32)
        np.savez_compressed(path, x_mean=self.x_mean.astype(np.float32), x_std=self.x_std.astype(np.float32),
                            meta=np.array(json.dumps(self.meta)), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "MlpPredictor":
        """Read :meth:`save`'s npz (``allow_pickle`` stays off)."""
        with np.load(path, allow_pickle=False) as z:
            keys = [k[1:].split("_") for k in z.files if k.startswith("W")]
            n_m, n_l = 1 + max(int(m) for m, _ in keys), 1 + max(int(i) for _, i in keys)
            members = tuple(tuple((z[f"W{m}_{i}"].astype(np.float64), z[f"b{m}_{i}"].astype(np.float64))
                                  for i in range(n_l)) for m in range(n_m))
            return cls(members, z["x_mean"].astype(np.float64), z["x_std"].astype(np.float64),
                       json.loads(str(z["meta"])))


def resample_scene(tracks: object, *, step_s: float = STEP_S) -> np.ndarray:
    """Every walker of a :class:`sim.pedestrian_data.Tracks` on one clock: (T, P, 2) m at t = 0, step_s, ...;
    NaN where a walker is not in the data (before, after, or inside a gap longer than the data's
    ``max_gap_s``: each gapless segment is interpolated on its own)."""
    n_t = int(np.floor(tracks.duration_s / step_s + 1e-9)) + 1
    out = np.full((n_t, len(tracks.ids), 2), np.nan)
    for i in range(len(tracks.ids)):
        for t, xy in tracks.segments(i):
            lo, hi = int(np.ceil(t[0] / step_s - 1e-9)), int(np.floor(t[-1] / step_s + 1e-9))
            if hi < lo:
                continue
            g = np.arange(lo, hi + 1) * step_s
            out[lo:hi + 1, i, 0] = np.interp(g, t, xy[:, 0])
            out[lo:hi + 1, i, 1] = np.interp(g, t, xy[:, 1])
    return out


def scene_samples(xy: np.ndarray, *, full_history: bool = True, stride: int = 1
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Training / test samples of one resampled scene (T, P, 2): every walker seen at frame j with its
    next 12 positions known (and, if ``full_history``, its last 8), neighbours = everybody seen at j.

    Returns x (N, N_INPUTS), rot (N, 2, 2), hist (N, 8, 2) m and future (N, 12, 2) m.
    """
    xs, rots, hists, futs = [], [], [], []
    for j in range(OBS_STEPS - 1, len(xy) - PRED_STEPS, stride):
        here = np.isfinite(xy[j]).all(axis=1)
        if not here.any():
            continue
        hist = xy[j - OBS_STEPS + 1:j + 1, here].transpose(1, 0, 2)
        fut = xy[j + 1:j + 1 + PRED_STEPS, here].transpose(1, 0, 2)
        keep = np.isfinite(fut).all(axis=(1, 2))
        if full_history:
            keep &= np.isfinite(hist).all(axis=(1, 2))
        if not keep.any():
            continue
        x, rot, _ = encode(hist)
        xs.append(x[keep]), rots.append(rot[keep]), hists.append(hist[keep]), futs.append(fut[keep])
    if not xs:
        return np.zeros((0, N_INPUTS)), np.zeros((0, 2, 2)), np.zeros((0, OBS_STEPS, 2)), np.zeros((0, PRED_STEPS, 2))
    return np.concatenate(xs), np.concatenate(rots), np.concatenate(hists), np.concatenate(futs)


def errors(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """ADE (mean displacement over the steps up to the horizon) and FDE (at the horizon), m, at 1.2 / 2.4 / 4.8 s."""
    d = np.linalg.norm(np.asarray(pred) - np.asarray(truth), axis=-1)         # (N, 12)
    out = {}
    for h in HORIZONS_S:
        k = int(round(h / STEP_S))
        out[f"ade_{h:g}s"] = float(np.mean(d[:, :k])) if len(d) else float("nan")
        out[f"fde_{h:g}s"] = float(np.mean(d[:, k - 1])) if len(d) else float("nan")
    return out


def positions_at(now: np.ndarray, future: np.ndarray, taus_s: np.ndarray) -> np.ndarray:
    """Predicted positions (P, len(taus), 2) m at ``taus_s`` s from now: linear between now and the 12
    predicted steps, then on at the last predicted step's velocity (beyond 4.8 s)."""
    now, future = np.asarray(now, float), np.asarray(future, float)
    path = np.concatenate([now[:, None], future], axis=1)                    # (P, 13, 2) at 0 .. 4.8 s
    grid = np.arange(path.shape[1]) * STEP_S
    taus = np.asarray(taus_s, float).reshape(-1)
    out = np.empty((len(now), len(taus), 2))
    v_end = (path[:, -1] - path[:, -2]) / STEP_S
    for k, tau in enumerate(taus):
        if tau <= grid[-1]:
            i = int(np.clip(np.searchsorted(grid, tau, side="right") - 1, 0, len(grid) - 2))
            a = (tau - grid[i]) / STEP_S
            out[:, k] = path[:, i] + a * (path[:, i + 1] - path[:, i])
        else:
            out[:, k] = path[:, -1] + v_end * (tau - grid[-1])
    return out


@dataclass(frozen=True)
class BaselinePredictor:
    """:func:`predict_damped` as a predictor object (``window=1, decay=1``: constant velocity from the
    last observed step, :func:`predict_cv`)."""

    window: int = 1
    decay: float = 1.0

    def predict(self, hist: np.ndarray) -> np.ndarray:
        """(P, 8, 2) observed -> (P, 12, 2) m predicted positions."""
        return predict_damped(np.asarray(hist, np.float64), window=self.window, decay=self.decay)


def load_loso(scene: str, directory: str | Path | None = None) -> MlpPredictor:
    """The MLP trained on every ETH/UCY scene but ``scene`` (``loso_<scene>.npz`` in ``directory``,
    default nodes/nav/weights/predictor/, written by ``bench/pedestrian_predict.py --save``)."""
    d = Path(directory) if directory is not None else Path(__file__).resolve().parent / "weights" / "predictor"
    path = d / f"loso_{scene}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"no predictor held out on {scene!r} at {path}; run bench/pedestrian_predict.py --save")
    return MlpPredictor.load(path)
