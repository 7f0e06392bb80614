"""Proximal Policy Optimization (Schulman et al. 2017) on JAX + Flax + Optax, for Gymnasium vector envs.

The clipped surrogate objective, generalised advantage estimation, a (clipped) value loss,
an entropy bonus, per-minibatch advantage normalisation, running observation normalisation
and optional return-based reward scaling, global gradient clipping, a linearly annealed
learning rate and an optional early stop of an update's epochs at a target approximate KL
(``target_kl``): the choices of the PPO2 the paper ran (OpenAI baselines) and of CleanRL.
Truncated episodes are bootstrapped with the value of their final observation (a time
limit is not a terminal state). Box actions are diagonal Gaussians (sampled unclipped, clipped
for the env as in CleanRL; ``squash="tanh"`` maps them through tanh onto the bounds instead, as
Brax's PPO does), Discrete ones categorical, MultiBinary ones independent Bernoulli.

>>> agent = PPO(env.single_observation_space, env.single_action_space, PPOConfig(), seed=0)
>>> history = agent.learn(env, 200_000)
>>> agent.save("car.ppo")                      # msgpack: parameters, normaliser, optimiser, spaces
>>> PPO.load("car.ppo").act(obs)               # deterministic actions for a batch

Everything random is seeded (the env through ``reset(seed=...)``, the policy through
``seed``); on one thread two runs give identical returns.
"""
from __future__ import annotations

import functools
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import flax.linen as nn
import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PPOConfig:
    """Hyper-parameters (defaults: the usual continuous-control set of PPO2 / CleanRL)."""

    n_steps: int = 256             # steps per env per update
    epochs: int = 10
    minibatches: int = 8
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    clip_value: bool = False
    lr: float = 3e-4
    anneal_lr: bool = True
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    hidden: tuple[int, ...] = (64, 64)
    init_log_std: float = 0.0
    norm_obs: bool = True
    norm_reward: bool = True
    obs_clip: float = 10.0
    # Box actions to the env: "clip" (CleanRL) clips the Gaussian sample to the bounds, where a mean
    # that has drifted past a bound gets no gradient back (every sample near it is the same action);
    # "tanh" (Brax) maps it onto the bounds by low + (tanh(u) + 1) (high - low) / 2. The ratio of
    # PPO needs no tanh Jacobian: both policies are scored on the same stored u, so it cancels.
    # Measured on the car's reach task (bench/rl_car.py protocol, 4M steps, checkpoint picked on
    # validation seeds, mean over 100 held-out episodes), clip -> tanh: seed 0 13.96 -> 0.29 mm,
    # seed 1 395 -> 669 mm, seed 2 5145 -> 9044 mm: not every seed is better, clip stays the default.
    # (Those seeds failed from the reward, not the squashing: eq. (5)'s constant -1 per step made unvisited
    # far states look best to a critic starting at 0; without it clip gives 1.05, 0.06, 0.89 mm: bench/rl_car.py.)
    squash: str = "clip"
    # Stop an update's epochs early once the policy has moved this far from the one that collected
    # the data (approximate KL of the epoch's last minibatch, checked after each epoch: CleanRL's
    # rule; Stable-Baselines3 checks 1.5 x target_kl per minibatch). 0: off, every epoch runs.
    target_kl: float = 0.0


class _MLP(nn.Module):
    hidden: tuple[int, ...]
    out: int
    out_scale: float

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        for h in self.hidden:
            x = nn.tanh(nn.Dense(h, kernel_init=nn.initializers.orthogonal(np.sqrt(2)))(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(self.out_scale))(x)


@dataclass
class RunningMeanStd:
    """Mean and variance of a stream of batches (Chan et al.'s parallel update), in float64."""

    mean: np.ndarray
    var: np.ndarray
    count: float = 1e-4

    @classmethod
    def of(cls, shape: tuple[int, ...]) -> "RunningMeanStd":
        return cls(np.zeros(shape), np.ones(shape))

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, np.float64).reshape(-1, *self.mean.shape)
        n, mean, var = len(x), x.mean(0), x.var(0)
        delta, total = mean - self.mean, self.count + n
        self.mean = self.mean + delta * n / total
        self.var = (self.var * self.count + var * n + delta**2 * self.count * n / total) / total
        self.count = total


def _dense_layers(tree: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """A Flax MLP's (kernel, bias) pairs in order, as float64 numpy arrays."""
    layers = tree["params"]
    return [(np.asarray(layers[f"Dense_{i}"]["kernel"], np.float64), np.asarray(layers[f"Dense_{i}"]["bias"], np.float64))
            for i in range(len(layers))]


def _forward(layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
    """The MLP in numpy: rollouts and deployed policies call it per step, where a JAX dispatch
    (~0.3 ms) would cost more than the arithmetic of a 64 x 64 network on a few rows."""
    for w, b in layers[:-1]:
        x = np.tanh(x @ w + b)
    w, b = layers[-1]
    return x @ w + b


def _kind(space: gymnasium.spaces.Space) -> tuple[str, int]:
    if isinstance(space, gymnasium.spaces.Box):
        return "box", int(np.prod(space.shape))
    if isinstance(space, gymnasium.spaces.Discrete):
        return "discrete", int(space.n)
    if isinstance(space, gymnasium.spaces.MultiBinary):
        return "multibinary", int(np.prod(space.shape))
    raise TypeError(f"PPO supports Box, Discrete and MultiBinary action spaces, not {space}")


def _space_doc(space: gymnasium.spaces.Space) -> dict[str, Any]:
    doc: dict[str, Any] = {"type": type(space).__name__, "shape": list(space.shape or ())}
    if isinstance(space, gymnasium.spaces.Box):
        doc.update(low=np.asarray(space.low, np.float64).ravel().tolist(),
                   high=np.asarray(space.high, np.float64).ravel().tolist(), dtype=str(space.dtype))
    elif isinstance(space, gymnasium.spaces.Discrete):
        doc.update(n=int(space.n), start=int(space.start))
    return doc


def _space_from(doc: dict[str, Any]) -> gymnasium.spaces.Space:
    shape = tuple(doc["shape"])
    if doc["type"] == "Box":
        dtype = np.dtype(doc["dtype"])
        low = np.asarray(doc["low"], dtype).reshape(shape)
        high = np.asarray(doc["high"], dtype).reshape(shape)
        return gymnasium.spaces.Box(low, high, shape, dtype)
    if doc["type"] == "Discrete":
        return gymnasium.spaces.Discrete(doc["n"], start=doc["start"])
    if doc["type"] == "MultiBinary":
        return gymnasium.spaces.MultiBinary(shape)
    raise ValueError(f"unknown space type {doc['type']!r} in checkpoint")


def _logp_entropy(kind: str, out: jnp.ndarray, log_std: jnp.ndarray, a: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    if kind == "box":
        z = (a - out) / jnp.exp(log_std)
        logp = -0.5 * (z**2).sum(-1) - log_std.sum() - 0.5 * out.shape[-1] * jnp.log(2 * jnp.pi)
        ent = (log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e)).sum() * jnp.ones(out.shape[:-1])
        return logp, ent
    if kind == "discrete":
        lp = jax.nn.log_softmax(out)
        logp = jnp.take_along_axis(lp, a[..., None].astype(jnp.int32), -1)[..., 0]
        return logp, -(jnp.exp(lp) * lp).sum(-1)
    lp1, lp0 = jax.nn.log_sigmoid(out), jax.nn.log_sigmoid(-out)
    logp = (a * lp1 + (1 - a) * lp0).sum(-1)
    return logp, -(jnp.exp(lp1) * lp1 + jnp.exp(lp0) * lp0).sum(-1)


def _networks(cfg: PPOConfig, act_dim: int) -> tuple[_MLP, _MLP]:
    return _MLP(tuple(cfg.hidden), act_dim, 0.01), _MLP(tuple(cfg.hidden), 1, 1.0)


def _optimizer(cfg: PPOConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm),
                       optax.inject_hyperparams(optax.adam)(learning_rate=cfg.lr, eps=1e-5))


@functools.lru_cache(maxsize=16)
def _compiled_init(act_dim: int, cfg: PPOConfig, obs_dim: int) -> Callable[..., Any]:
    """Fresh actor and critic weights from an "rbg" key, under one jit compiled once per shape: the
    default threefry keys compiled an orthogonal initialiser (a QR) per layer shape, eagerly."""
    actor, critic = _networks(cfg, act_dim)
    dummy = jnp.zeros((1, obs_dim))

    def init(key: jax.Array) -> tuple[Any, Any]:
        ka, kc = jax.random.split(key)
        return actor.init(ka, dummy), critic.init(kc, dummy)

    return jax.jit(init)


@functools.lru_cache(maxsize=16)
def _compiled_update(kind: str, act_dim: int, cfg: PPOConfig) -> Callable[..., Any]:
    """The jitted PPO update for a policy shape and hyper-parameters: compiled once per process,
    shared by every agent of that shape (compiling costs seconds; agents are made by the dozen
    in self-play and tests)."""
    actor, critic = _networks(cfg, act_dim)
    tx = _optimizer(cfg)

    def loss(params: Any, b: dict[str, jnp.ndarray]) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
        out = actor.apply(params["actor"], b["obs"])
        logp, ent = _logp_entropy(kind, out, params["log_std"], b["act"])
        ratio = jnp.exp(logp - b["logp"])
        adv = (b["adv"] - b["adv"].mean()) / (b["adv"].std() + 1e-8)
        pg = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv).mean()
        v = critic.apply(params["critic"], b["obs"])[:, 0]
        if cfg.clip_value:
            v_clip = b["val"] + jnp.clip(v - b["val"], -cfg.clip, cfg.clip)
            vl = 0.5 * jnp.maximum((v - b["ret"]) ** 2, (v_clip - b["ret"]) ** 2).mean()
        else:
            vl = 0.5 * ((v - b["ret"]) ** 2).mean()
        total = pg + cfg.vf_coef * vl - cfg.ent_coef * ent.mean()
        approx_kl = ((ratio - 1) - jnp.log(ratio)).mean()
        return total, {"policy_loss": pg, "value_loss": vl, "entropy": ent.mean(), "approx_kl": approx_kl,
                       "clip_frac": (jnp.abs(ratio - 1) > cfg.clip).mean()}

    def update(params: Any, opt_state: Any, batch: dict[str, jnp.ndarray], key: jnp.ndarray, lr: float
               ) -> tuple[Any, Any, dict[str, jnp.ndarray]]:
        n = batch["obs"].shape[0]
        mb = n // cfg.minibatches
        opt_state[1].hyperparams["learning_rate"] = lr

        def epoch(carry: Any, k: jnp.ndarray) -> tuple[Any, dict[str, jnp.ndarray]]:
            perm = jax.random.permutation(k, n)[: mb * cfg.minibatches].reshape(cfg.minibatches, mb)

            def minibatch(carry: Any, idx: jnp.ndarray) -> tuple[Any, dict[str, jnp.ndarray]]:
                p, s = carry
                (_, stats), grads = jax.value_and_grad(loss, has_aux=True)(p, {k_: v[idx] for k_, v in batch.items()})
                upd, s = tx.update(grads, s, p)
                return (optax.apply_updates(p, upd), s), stats

            return jax.lax.scan(minibatch, carry, perm)

        if cfg.target_kl <= 0:
            (params, opt_state), stats = jax.lax.scan(epoch, (params, opt_state), jax.random.split(key, cfg.epochs))
            stats = jax.tree_util.tree_map(jnp.mean, stats)
            return params, opt_state, {**stats, "epochs_run": jnp.float32(cfg.epochs)}

        def epoch_or_skip(carry: Any, k: jnp.ndarray) -> tuple[Any, tuple[dict[str, jnp.ndarray], jnp.ndarray]]:
            p, s, stopped = carry
            no_stats = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(epoch, (p, s), k)[1])
            (p, s), st = jax.lax.cond(stopped, lambda c, k_: (c, no_stats), epoch, (p, s), k)
            return (p, s, stopped | (st["approx_kl"][-1] > cfg.target_kl)), (st, ~stopped)

        (params, opt_state, _), (stats, ran) = jax.lax.scan(
            epoch_or_skip, (params, opt_state, jnp.asarray(False)), jax.random.split(key, cfg.epochs))
        w = ran.astype(jnp.float32)[:, None]                      # the skipped epochs' statistics are not the update's
        stats = jax.tree_util.tree_map(lambda a: (a * w).sum() / (w.sum() * a.shape[1]), stats)
        return params, opt_state, {**stats, "epochs_run": w.sum()}

    return jax.jit(update)


class PPO:
    """A PPO agent for one observation and action space (see the module docstring)."""

    def __init__(self, observation_space: gymnasium.spaces.Space, action_space: gymnasium.spaces.Space,
                 config: PPOConfig | None = None, *, seed: int = 0) -> None:
        self.config = config or PPOConfig()
        self.observation_space, self.action_space = observation_space, action_space
        self.kind, self.act_dim = _kind(action_space)
        self.obs_shape = tuple(observation_space.shape)
        self.obs_dim = int(np.prod(self.obs_shape))
        cfg = self.config
        if cfg.squash not in ("clip", "tanh"):
            raise ValueError(f"squash must be 'clip' or 'tanh', got {cfg.squash!r}")
        if not (np.isfinite(cfg.target_kl) and cfg.target_kl >= 0):
            raise ValueError(f"target_kl must be >= 0 (0: off), got {cfg.target_kl}")
        if cfg.squash == "tanh" and self.kind == "box" and not (
                np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
            raise ValueError("squash='tanh' needs finite Box bounds: the action space has an infinite one")
        self.actor, self.critic = _networks(cfg, self.act_dim)
        self.key = jax.random.split(jax.random.PRNGKey(seed), 3)[0]
        actor, critic = _compiled_init(self.act_dim, cfg, self.obs_dim)(jax.random.key(seed, impl="rbg"))
        self.params = {"actor": actor, "critic": critic, "log_std": jnp.full((self.act_dim,), cfg.init_log_std, jnp.float32)}
        # (float32 explicitly: a weak-typed log_std made the second update compile again, 4-7 s)
        self.opt_state = _optimizer(cfg).init(self.params)
        self.obs_rms = RunningMeanStd.of((self.obs_dim,))
        self.ret_rms = RunningMeanStd.of(())
        self.steps_done = 0
        self.train_seconds = 0.0          # across calls and resumed runs
        self.history: list[dict[str, float]] = []

    # -- acting -----------------------------------------------------------------------------
    def _numpy_policy(self) -> None:
        self._np_actor = _dense_layers(self.params["actor"])
        self._np_critic = _dense_layers(self.params["critic"])
        self._np_log_std = np.asarray(self.params["log_std"], np.float64)

    def _np_value(self, x: np.ndarray) -> np.ndarray:
        return _forward(self._np_critic, x)[:, 0]

    def _np_sample(self, x: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Actions and their log-probabilities (the same densities as the JAX loss)."""
        out = _forward(self._np_actor, x)
        if self.kind == "box":
            std = np.exp(self._np_log_std)
            noise = rng.standard_normal(out.shape)
            a = out + std * noise
            logp = -0.5 * (noise**2).sum(-1) - self._np_log_std.sum() - 0.5 * out.shape[-1] * np.log(2 * np.pi)
            return a, logp
        if self.kind == "discrete":
            lp = out - out.max(-1, keepdims=True)
            lp = lp - np.log(np.exp(lp).sum(-1, keepdims=True))
            a = np.argmax(lp + rng.gumbel(size=lp.shape), -1)
            return a[:, None].astype(np.float64), lp[np.arange(len(a)), a]
        p1 = 1.0 / (1.0 + np.exp(-out))
        a = (rng.random(out.shape) < p1).astype(np.float64)
        logp = (a * -np.logaddexp(0, -out) + (1 - a) * -np.logaddexp(0, out)).sum(-1)
        return a, logp

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, np.float64).reshape(-1, self.obs_dim)
        if not self.config.norm_obs:
            return obs.astype(np.float32)
        z = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + 1e-8)
        return np.clip(z, -self.config.obs_clip, self.config.obs_clip).astype(np.float32)

    def to_env(self, a: np.ndarray) -> np.ndarray:
        """Policy outputs to env actions: Box clipped to its bounds (or squashed onto them by tanh,
        ``squash="tanh"``), others cast to the space's dtype."""
        a = np.asarray(a)
        if self.kind == "box":
            sp = self.action_space
            lo, hi = sp.low.ravel().astype(np.float64), sp.high.ravel().astype(np.float64)
            if self.config.squash == "tanh":
                a = lo + (np.tanh(a) + 1.0) * (hi - lo) / 2.0
            return np.clip(a, lo, hi).reshape(-1, *sp.shape).astype(sp.dtype)   # tanh: rounding at the ends only
        if self.kind == "discrete":
            return (a.reshape(-1) + self.action_space.start).astype(np.int64)
        return a.astype(np.int8).reshape(-1, *self.action_space.shape)

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Env actions for a batch of raw observations (N, *obs_shape)."""
        obs = np.asarray(obs)
        if obs.shape[1:] != self.obs_shape and obs.shape != self.obs_shape:
            raise ValueError(f"observations of shape {obs.shape[1:]} given to a policy trained on {self.obs_shape}")
        x = self.normalize(obs).astype(np.float64)
        if not hasattr(self, "_np_actor"):
            self._numpy_policy()
        if not deterministic:
            self.key, k = jax.random.split(self.key)
            return self.to_env(self._np_sample(x, np.random.default_rng(np.asarray(k)))[0])
        out = _forward(self._np_actor, x)
        if self.kind == "box":
            return self.to_env(out)
        if self.kind == "discrete":
            return self.to_env(np.argmax(out, -1))
        return self.to_env(out > 0)

    # -- learning ---------------------------------------------------------------------------
    def learn(self, env: Any, steps: int, *, seed: int | None = 0,
              callback: Callable[[dict[str, float]], bool | None] | None = None,
              progress: Callable[[str], None] | None = None, total_steps: int | None = None) -> list[dict[str, float]]:
        """Train on a Gymnasium vector env (same-step autoreset, ``infos["final_obs"]``) for ``steps``
        more env steps (all instances counted). The learning rate anneals to zero at ``total_steps``
        (default: the end of this call; give the whole run's length when training in chunks).
        ``callback(entry)`` after each update may return False to stop. Returns the history."""
        cfg, n = self.config, env.num_envs
        if tuple(env.single_observation_space.shape) != self.obs_shape:
            raise ValueError(f"env observations {env.single_observation_space.shape} != policy's {self.obs_shape}")
        per_update = cfg.n_steps * n
        if per_update % cfg.minibatches:
            raise ValueError(f"n_steps x n_envs ({per_update}) must divide into {cfg.minibatches} minibatches")
        updates = max(1, steps // per_update)
        target_updates = (total_steps or self.steps_done + steps) // per_update
        obs, _ = env.reset(seed=seed)
        ep_ret = np.zeros(n)
        disc_ret = np.zeros(n)
        finished: list[float] = []
        t0 = time.perf_counter()
        shape = (cfg.n_steps, n)
        for u in range(updates):
            self._numpy_policy()
            self.key, k = jax.random.split(self.key)
            rng = np.random.default_rng(np.asarray(k))
            buf = {"obs": np.zeros((*shape, self.obs_dim), np.float32), "act": np.zeros((*shape, self.act_dim), np.float32),
                   "logp": np.zeros(shape, np.float32), "val": np.zeros(shape, np.float32), "rew": np.zeros(shape),
                   "done": np.zeros(shape, bool)}
            for t in range(cfg.n_steps):
                if cfg.norm_obs:
                    self.obs_rms.update(np.asarray(obs).reshape(n, -1))
                x = self.normalize(obs)
                x64 = x.astype(np.float64)
                a, logp = self._np_sample(x64, rng)
                val = self._np_value(x64)
                obs, rew, term, trunc, info = env.step(self.to_env(a))
                rew = np.asarray(rew, np.float64)
                ep_ret += rew
                if cfg.norm_reward:
                    disc_ret = disc_ret * cfg.gamma + rew
                    self.ret_rms.update(disc_ret)
                    rew = rew / np.sqrt(self.ret_rms.var + 1e-8)
                done = np.asarray(term) | np.asarray(trunc)
                if np.any(trunc):
                    # a time limit is not an end: bootstrap with the value of the final observation
                    idx = np.flatnonzero(trunc)
                    final = _rows(info["final_obs"], idx)
                    rew[idx] += cfg.gamma * self._np_value(self.normalize(final).astype(np.float64))
                for i in np.flatnonzero(done):
                    finished.append(float(ep_ret[i]))
                ep_ret[done], disc_ret[done] = 0.0, 0.0
                buf["obs"][t], buf["act"][t] = x, a.reshape(n, -1)
                buf["logp"][t], buf["val"][t], buf["rew"][t], buf["done"][t] = logp, val, rew, done
            last_val = self._np_value(self.normalize(obs).astype(np.float64))
            adv, ret = gae(buf["rew"], buf["val"], buf["done"], last_val, cfg.gamma, cfg.gae_lambda)
            batch = {"obs": buf["obs"].reshape(-1, self.obs_dim), "act": buf["act"].reshape(-1, self.act_dim),
                     "logp": buf["logp"].ravel(), "val": buf["val"].ravel(), "adv": adv.ravel().astype(np.float32),
                     "ret": ret.ravel().astype(np.float32)}
            if self.kind != "box":
                batch["act"] = batch["act"][:, 0] if self.kind == "discrete" else batch["act"]
            done_updates = self.steps_done // per_update
            frac = 1.0 - done_updates / max(target_updates, 1) if cfg.anneal_lr else 1.0
            self.key, k = jax.random.split(self.key)
            lr = jnp.asarray(cfg.lr * max(frac, 0.0), jnp.float32)
            self.params, self.opt_state, stats = _compiled_update(self.kind, self.act_dim, cfg)(self.params, self.opt_state, batch, k, lr)
            self._numpy_policy()
            self.steps_done += per_update
            elapsed = time.perf_counter() - t0
            entry = {"steps": float(self.steps_done), "seconds": self.train_seconds + elapsed,
                     "return_mean": float(np.mean(finished[-20:])) if finished else float("nan"),
                     "episodes": float(len(finished)), "steps_per_s": (u + 1) * per_update / elapsed,
                     **{k_: float(v) for k_, v in stats.items()}}
            self.history.append(entry)
            if progress is not None:
                progress(f"steps {self.steps_done:>9d}  return {entry['return_mean']:9.2f}  "
                         f"{entry['steps_per_s']:7.0f} steps/s  kl {entry['approx_kl']:.4f}"
                         + (f"  epochs {entry['epochs_run']:.0f}" if cfg.target_kl > 0 else ""))
            if callback is not None and callback(entry) is False:
                break
        self.train_seconds += time.perf_counter() - t0
        return self.history

    # -- checkpoints ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        cfg = asdict(self.config)
        cfg["hidden"] = list(cfg["hidden"])
        return {"format": "tether.ppo/1", "config": cfg,
                "observation_space": _space_doc(self.observation_space), "action_space": _space_doc(self.action_space),
                "params": serialization.to_state_dict(self.params),
                "opt_state": serialization.to_state_dict(self.opt_state),
                "obs_rms": {"mean": self.obs_rms.mean, "var": self.obs_rms.var, "count": self.obs_rms.count},
                "ret_rms": {"mean": self.ret_rms.mean, "var": self.ret_rms.var, "count": self.ret_rms.count},
                "key": np.asarray(self.key),
                "steps_done": self.steps_done, "train_seconds": self.train_seconds,
                "history": {k: [h[k] for h in self.history] for k in (self.history[0] if self.history else {})}}

    def save(self, path: str | Path) -> None:
        """Write a msgpack checkpoint (never pickle): enough to act, and to resume training."""
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(serialization.msgpack_serialize(self.state_dict()))

    @classmethod
    def load(cls, path: str | Path, *, observation_space: gymnasium.spaces.Space | None = None) -> "PPO":
        """Read a checkpoint. Given ``observation_space`` (the env's), refuse one of another shape."""
        if not Path(path).exists():
            raise FileNotFoundError(f"{path}: no such checkpoint (tether learn train -o writes one)")
        try:
            doc = serialization.msgpack_restore(Path(path).read_bytes())
        except (ValueError, TypeError) as exc:        # msgpack's ExtraData, FormatError, StackError ...
            raise ValueError(f"{path}: not a tether PPO checkpoint (not msgpack: {type(exc).__name__}: {exc})") from None
        if not isinstance(doc, dict) or doc.get("format") != "tether.ppo/1":
            raise ValueError(f"{path}: not a tether PPO checkpoint (format {doc.get('format') if isinstance(doc, dict) else None!r})")
        missing = [k for k in ("observation_space", "action_space", "config", "params", "obs_rms", "ret_rms", "key",
                               "steps_done") if k not in doc]
        if missing:
            raise ValueError(f"{path}: an incomplete tether PPO checkpoint (no {', '.join(missing)})")
        obs_space, act_space = _space_from(doc["observation_space"]), _space_from(doc["action_space"])
        if observation_space is not None and tuple(observation_space.shape) != tuple(obs_space.shape):
            raise ValueError(f"{path}: the policy was trained on observations of shape {tuple(obs_space.shape)}, "
                             f"this environment gives {tuple(observation_space.shape)}: retrain or use the matching scenario")
        cfg = dict(doc["config"])
        cfg["hidden"] = tuple(cfg["hidden"])
        cfg.setdefault("squash", "clip")            # checkpoints from before the option were all clipped
        cfg.setdefault("target_kl", 0.0)            # ... and ran every epoch
        agent = cls(obs_space, act_space, PPOConfig(**cfg))
        agent.params = serialization.from_state_dict(agent.params, doc["params"])
        if doc.get("opt_state") is not None:            # None in an exported policy
            agent.opt_state = serialization.from_state_dict(agent.opt_state, doc["opt_state"])
        for name in ("obs_rms", "ret_rms"):
            r = doc[name]
            setattr(agent, name, RunningMeanStd(np.asarray(r["mean"]), np.asarray(r["var"]), float(r["count"])))
        agent.key = jnp.asarray(doc["key"], jnp.uint32)
        agent._numpy_policy()
        agent.steps_done = int(doc["steps_done"])
        agent.train_seconds = float(doc.get("train_seconds", 0.0))
        hist = doc.get("history") or {}
        keys = list(hist)
        agent.history = [{k: float(hist[k][i]) for k in keys} for i in range(len(hist[keys[0]]))] if keys else []
        return agent


def _rows(batch: Any, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` of a batched array, or of Gymnasium's object array of per-env observations."""
    arr = np.asarray(batch)
    if arr.dtype == object:
        return np.stack([np.asarray(arr[i], np.float64).ravel() for i in idx])
    return arr[idx]


def gae(rew: np.ndarray, val: np.ndarray, done: np.ndarray, last_val: np.ndarray, gamma: float, lam: float
        ) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimates and returns over (T, N) arrays; ``done[t]`` ends the episode after step t
    (truncated steps already carry their bootstrapped value in ``rew``)."""
    T = len(rew)
    adv = np.zeros_like(rew, dtype=np.float64)
    last = np.zeros(rew.shape[1])
    for t in range(T - 1, -1, -1):
        nxt = last_val if t == T - 1 else val[t + 1]
        live = ~done[t]
        delta = rew[t] + gamma * nxt * live - val[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv, adv + val
