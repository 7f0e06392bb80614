"""PPO's approximate-KL early stop (``PPOConfig.target_kl``): return and time against the bound.

    python bench/ppo_target_kl.py [--steps 50000] [--seeds 5] [--json]

CartPole-v1 (Gymnasium's own env) with CleanRL's settings (8 envs, 128 steps, 4 epochs of 4
minibatches, lr 2.5e-4, entropy 0.01, clipped value loss), and the same at 4x and 16x the
learning rate, where an update can move the policy too far: the case the early stop is for.
Swept: ``target_kl`` off, 0.03, 0.015 (CleanRL's suggestion) and 0.0075. Scored as
``bench/rl_car.py`` scores CartPole: the deterministic policy's mean return over 100 held-out
episodes (seeds 10,000+; the cap and the published figure is 500), for each training seed, and
the epochs each update ran. The reference is the bound off, in the same run, at each learning
rate: no bound is given information the others are not.

Measured (50k steps, 5 seeds, ~3.5 min on the shared 2-core machine; median (min) return):
lr 2.5e-4: 227 (155) with every bound, which never fires (median approximate KL per update ~1e-5);
lr 1e-3: off 147 (126), 0.015 172 (138), 0.0075 270 (114), stopping 1-6 % of updates;
lr 4e-3: off 469 (165), 0.015 500 (242), 0.0075 208 (154), stopping 7-18 %. The spread over
seeds (114-500 in one setting) is larger than any effect of the bound: no setting is better
on every learning rate, so the default stays off.

``--json`` keys: ``runs`` (lr, target_kl, seed, return, minutes, epochs median), and per
(lr, target_kl) the median return over seeds (``median_return``) and its minimum.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from nodes.learn.ppo import PPOConfig  # noqa: E402
from rl_car import CARTPOLE_PPO, cartpole  # noqa: E402


def run(steps: int, seed: int, lr: float, target_kl: float) -> dict:
    cfg = PPOConfig(**{**CARTPOLE_PPO.__dict__, "lr": lr, "target_kl": target_kl})
    c = cartpole(steps, seed, cfg)
    hist = c["history"]
    return {"lr": lr, "target_kl": target_kl, "seed": seed, "return": c["return_mean"], "minutes": c["minutes"],
            "epochs_median": float(np.median([h["epochs_run"] for h in hist])),
            "stopped_frac": float(np.mean([h["epochs_run"] < cfg.epochs for h in hist])),
            "kl_median": float(np.median([h["approx_kl"] for h in hist]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=float, default=5e4, help="env steps per run (CleanRL's full budget is 500k; "
                                                             "at 100k the default setting already scores 500)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    runs = []
    for mult in (1, 4, 16):
        for kl in (0.0, 0.03, 0.015, 0.0075):
            for seed in range(args.seeds):
                r = run(int(args.steps), seed, CARTPOLE_PPO.lr * mult, kl)
                runs.append(r)
                print(f"lr {r['lr']:.1e} target_kl {kl or 'off':>6}  seed {seed}: return {r['return']:6.1f}  "
                      f"{r['minutes'] * 60:5.1f} s  epochs {r['epochs_median']:.0f}  stopped {r['stopped_frac']:.0%} of updates  "
                      f"kl {r['kl_median']:.4f}",
                      file=sys.stderr, flush=True)
    table = {}
    for mult in (1, 4, 16):
        lr = CARTPOLE_PPO.lr * mult
        for kl in (0.0, 0.03, 0.015, 0.0075):
            rs = [r for r in runs if r["lr"] == lr and r["target_kl"] == kl]
            table[f"lr{mult}x_kl{kl}"] = {"median_return": float(np.median([r["return"] for r in rs])),
                                          "min_return": float(min(r["return"] for r in rs)),
                                          "median_seconds": float(np.median([r["minutes"] for r in rs]) * 60),
                                          "epochs_median": float(np.median([r["epochs_median"] for r in rs])),
                                          "stopped_frac": float(np.mean([r["stopped_frac"] for r in rs]))}
    print(f"\nCartPole-v1, {int(args.steps)} steps, {args.seeds} seeds: median (min) held-out return, median s, epochs")
    for key, t in table.items():
        print(f"  {key:<16} {t['median_return']:6.1f} ({t['min_return']:6.1f})  {t['median_seconds']:5.1f} s  "
              f"epochs {t['epochs_median']:.0f}, stopped early in {t['stopped_frac']:.0%} of updates")
    if args.json:
        print(json.dumps({"steps": int(args.steps), "seeds": args.seeds, "by_setting": table, "runs": runs}))


if __name__ == "__main__":
    main()
