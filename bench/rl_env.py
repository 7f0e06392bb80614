"""Bus environment benchmark (seed 14): what serving a simulator over Tether costs per env step.

The reach-the-point car, stepped with the same seeded random actions, served five ways:

- plain:   a Gymnasium env written the usual way (one car, no bus) over the same dynamics and
           reward functions (``sim.diff_car.integrate``, ``sim.car_env.reward``);
- core:    the batched simulator core (``ReachCar``, N = 1) called directly;
- inproc:  ``BusEnv`` in-process: the simulator node's handlers called with messages, no sockets;
- ipc:     ``BusVecEnv`` with the node in its own process on ZeroMQ ipc sockets (one round trip
           per step, lockstep);
- vectorised: the same with N instances per message (in-process and over ipc, 1 and 2 node
           processes): steps/s counts every instance's step.

Medians over ``--repeats`` runs of ``--steps`` steps (timings are noisy on a shared machine).

    python bench/rl_env.py [--quick] [--json]

``--json`` keys: steps_per_s_inproc, steps_per_s_ipc, steps_per_s_plain (all N = 1), and
steps_per_s_core, ratio_plain_over_inproc, vectorised {name: steps/s}.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import gymnasium
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.learn.bus_env import BusEnv, BusVecEnv  # noqa: E402
from sim.car_env import ACTIONS, ReachCar, reward  # noqa: E402
from sim.diff_car import V_MAX_MPS, W_MAX_RADPS, integrate  # noqa: E402


class PlainReachCar(gymnasium.Env):
    """The reach scenario as a user would write it without Tether: one car, one class."""

    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (11,), np.float32)
    action_space = ACTIONS

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        r, b, yaw = self.np_random.uniform(0.3, 1.5), self.np_random.uniform(-np.pi, np.pi), self.np_random.uniform(-np.pi, np.pi)
        self.pose = np.array([[0.0, 0.0, yaw]])
        self.target = np.array([r * np.cos(b), r * np.sin(b)])
        self.last = np.zeros(2)
        self.t = 0
        return self._obs(), {}

    def _obs(self) -> np.ndarray:
        x, y, th = self.pose[0]
        dx, dy = self.target[0] - x, self.target[1] - y
        c, s = np.cos(th), np.sin(th)
        return np.array([x, y, c, s, *self.target, c * dx + s * dy, -s * dx + c * dy, np.hypot(dx, dy), *self.last],
                        np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        a = np.clip(action, -1.0, 1.0)
        self.last = a.astype(np.float64)
        self.pose = integrate(self.pose, np.array([a[0] * V_MAX_MPS]), np.array([a[1] * W_MAX_RADPS]), 0.1)
        dist = float(np.hypot(*(self.target - self.pose[0, :2])))
        self.t += 1
        return self._obs(), float(reward(np.array([dist]))[0]), False, self.t >= 100, {"distance_m": dist}


def _rate(step, reset, actions: np.ndarray, n: int) -> float:
    reset()
    t0 = time.perf_counter()
    for a in actions:
        if step(a):
            reset()
    return len(actions) * n / (time.perf_counter() - t0)


def measure(steps: int, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    single = rng.uniform(-1.2, 1.2, (steps, 2)).astype(np.float32)
    out: dict[str, list[float]] = {}

    def add(name: str, value: float) -> None:
        out.setdefault(name, []).append(value)

    for _ in range(repeats):
        plain = PlainReachCar()
        add("plain", _rate(lambda a: any(plain.step(a)[2:4]), lambda: plain.reset(seed=1), single, 1))
        core = ReachCar(1)
        add("core", _rate(lambda a: core.step(a) and False, lambda: core.reset([1]), single[:, None], 1))  # autoresets
        env = BusEnv("sim.car_env:ReachCar")
        add("inproc", _rate(lambda a: any(env.step(a)[2:4]), lambda: env.reset(seed=1), single, 1))
        env.close()
        ipc = BusVecEnv("sim.car_env:ReachCar", 1, mode="ipc")
        ipc.reset(seed=1)
        for a in single[:200]:
            ipc.step(a[None])                       # warm the sockets and the node
        add("ipc", _rate(lambda a: ipc.step(a) and False, lambda: ipc.reset(seed=1), single[:, None], 1))
        ipc.close()
        for n, mode, shards in ((16, "inproc", 1), (64, "inproc", 1), (16, "ipc", 1), (64, "ipc", 1), (64, "ipc", 2)):
            many = rng.uniform(-1.2, 1.2, (max(steps // 8, 200), n, 2)).astype(np.float32)
            venv = BusVecEnv("sim.car_env:ReachCar", n, mode=mode, shards=shards)
            venv.reset(seed=1)
            add(f"{mode}_n{n}_shards{shards}", _rate(lambda a: venv.step(a) and False, lambda: venv.reset(seed=1), many, n))
            venv.close()
    return {k: statistics.median(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2,000 steps, 2 repeats")
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    steps, repeats = (2_000, 2) if args.quick else (args.steps, args.repeats)
    r = measure(steps, repeats)
    print(f"{'served as':<26}{'steps/s':>12}{'vs plain':>10}")
    for name, value in r.items():
        print(f"{name:<26}{value:>12.0f}{value / r['plain']:>10.2f}")
    print(f"goal: in-process within 1.5x of plain: {r['plain'] / r['inproc']:.2f}x "
          f"({'met' if r['plain'] / r['inproc'] <= 1.5 else 'NOT met'}); "
          f"ipc >= 5,000 steps/s at N = 1: {r['ipc']:.0f} ({'met' if r['ipc'] >= 5000 else 'NOT met'}); "
          f"vectorised over ipc (N = 64): {r['ipc_n64_shards1']:.0f}")
    if args.json:
        print(json.dumps({"steps_per_s_inproc": r["inproc"], "steps_per_s_ipc": r["ipc"], "steps_per_s_plain": r["plain"],
                          "steps_per_s_core": r["core"], "ratio_plain_over_inproc": r["plain"] / r["inproc"],
                          "vectorised": {k: v for k, v in r.items() if "_n" in k}, "steps": steps, "repeats": repeats}))


if __name__ == "__main__":
    main()
