"""Swarm benchmark (seed 09): individual efficiency F/N against N with and without task partitioning,
interference measured directly, and the simulator's speed and time-step error.

* **Speed**: one world of N = 10, 30, 100 robots for the seed's 200 s mission; simulated
  seconds per wall second (``realtime_factor``) and robot-seconds per wall second.
* **Accuracy knob**: the time step. The 30-seed mean efficiency at N = 30 (one zone) for
  dt = 0.2, 0.1 (the seed's), 0.05 s against dt = 0.025 s; the difference is set beside
  the seeds' own standard error, since a different dt is a different random path.
  There is no reference simulator to run beside it on PyPI (ARGoS, which Pini et al.
  used, is a C++ application), so the reference here is the finer step.
* **Curves**: F/N against N = 1..60 for no zone, one and two exchange zones (direct
  hand-over), a cache, the adaptive choice, the seed's peer-to-peer transfer, and the arena
  with a wall and a 0.3 m gate at the zone (partitioning or never: theta = 0). 30 seeds
  each (0..29), mean and 95 % t-interval. The waiting threshold theta of each partitioning
  variant is chosen on other seeds (100..109) -- the curves are measured on seeds it was
  not tuned on -- and the no-zone baseline has no knob to tune.
* **Crossover** N*: the smallest N of the grid from which partitioning's mean efficiency
  stays above no partitioning's (``None`` if it never does).

    python bench/swarm.py [--quick] [--json] [--png OUT.png]

``--json`` keys: ``realtime_factor_n30``, ``nstar_one_zone``, ``eff_gain_one_zone_at_n30``
(relative: F/N one zone / F/N no zone - 1), plus ``nstar_gated``, ``eff_gain_gated_at_n30``,
``theta_s`` (chosen per variant), ``dt_sweep`` and ``curves``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from sim.swarm import SwarmScene, SwarmWorld, seed_scene  # noqa: E402

T_MAX_S = 200.0
THETAS = (5.0, 15.0, 30.0, 60.0)


def variants() -> dict[str, tuple[SwarmScene, bool]]:
    """name -> (scene, whether theta is tuned)."""
    return {
        "no zone": (seed_scene(0), False),
        "one zone": (seed_scene(1), True),
        "two zones": (seed_scene(2), True),
        "one zone, cache": (seed_scene(1, transfer="cache"), True),
        "one zone, adaptive": (seed_scene(1, policy="adaptive"), True),
        "peer to peer": (seed_scene(0, transfer="p2p"), False),
        "gate, no partition": (seed_scene(1, gate_width_m=0.3, theta_s=0.0), False),
        "gate, one zone": (seed_scene(1, gate_width_m=0.3), True),
        "gate, adaptive": (seed_scene(1, gate_width_m=0.3, policy="adaptive"), True),
    }


def run(scene: SwarmScene, n: int, seeds: range, dt_s: float = 0.1) -> SwarmWorld:
    world = SwarmWorld(scene, n, seeds=seeds)
    world.run(T_MAX_S, dt_s)
    return world


def interval(values: np.ndarray) -> tuple[float, float]:
    """Mean and half-width of the 95 % t-interval."""
    if len(values) < 2:
        return float(values.mean()), 0.0
    half = stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values))
    return float(values.mean()), float(half)


def speed(ns: tuple[int, ...]) -> dict[str, dict[str, float]]:
    out = {}
    for n in ns:
        world = SwarmWorld(seed_scene(1), n, seeds=[0])
        t0 = time.process_time()
        world.run(T_MAX_S)
        wall = max(time.process_time() - t0, 1e-9)
        out[str(n)] = {"realtime_factor": T_MAX_S / wall, "robot_s_per_s": n * T_MAX_S / wall, "cpu_s": wall}
        print(f"  N = {n:3d}: {T_MAX_S / wall:8.0f} x real time, {n * T_MAX_S / wall:9.0f} robot-s/s", flush=True)
    return out


def tune_theta(scene: SwarmScene, ns: tuple[int, ...], seeds: range) -> float:
    """The threshold with the best mean efficiency over ``ns`` on the tuning seeds."""
    score = {th: np.mean([run(_with(scene, th), n, seeds).efficiency().mean() for n in ns]) for th in THETAS}
    return max(score, key=score.get)


def _with(scene: SwarmScene, theta_s: float) -> SwarmScene:
    return replace(scene, theta_s=theta_s)


def crossover(ns: list[int], part: list[float], base: list[float]) -> int | None:
    """Smallest N from which ``part`` stays above ``base`` to the end of the grid."""
    above = [p > b for p, b in zip(part, base)]
    for i in range(len(ns)):
        if all(above[i:]):
            return ns[i]
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer N, 8 seeds, no dt sweep")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--png", default=str(REPO / "out" / "swarm_bench.png"), help="efficiency curves figure")
    args = ap.parse_args()
    ns = [1, 2, 5, 10, 20, 30, 45] if args.quick else [1, 2, 4, 6, 8, 10, 15, 20, 25, 30, 35, 40, 50, 60]
    seeds = range(8) if args.quick else range(30)
    tune_seeds, tune_ns = range(100, 104 if args.quick else 110), (10, 30)

    print("speed, one world, 200 s mission:", flush=True)
    spd = speed((10, 30, 100))

    dt_sweep = []
    if not args.quick:
        print("time step at N = 30, one zone (30 seeds):", flush=True)
        ref = run(seed_scene(1), 30, seeds, 0.025).efficiency()
        for dt in (0.2, 0.1, 0.05):
            t0 = time.process_time()
            eff = run(seed_scene(1), 30, seeds, dt).efficiency()
            cpu = time.process_time() - t0
            se = math.hypot(eff.std(ddof=1), ref.std(ddof=1)) / math.sqrt(len(seeds))
            dt_sweep.append({"dt_s": dt, "cpu_s": cpu, "eff": float(eff.mean()), "eff_ref": float(ref.mean()),
                             "abs_err": float(abs(eff.mean() - ref.mean())), "stderr": float(se)})
            print(f"  dt {dt:5.3f} s: {cpu:6.2f} s CPU, F/N {eff.mean():.3f} vs {ref.mean():.3f} at dt 0.025 "
                  f"(|diff| {abs(eff.mean() - ref.mean()):.3f}, noise {se:.3f})", flush=True)

    thetas, curves = {}, {}
    for name, (scene, tuned) in variants().items():
        if tuned:
            thetas[name] = tune_theta(scene, tune_ns, tune_seeds)
            scene = _with(scene, thetas[name])
        rows = []
        for n in ns:
            w = run(scene, n, seeds)
            m, h = interval(w.efficiency())
            robot_time = max(n, 1) * T_MAX_S
            rows.append({"n": n, "eff": m, "ci95": h, "contact_frac": float(w.contact_s.sum(1).mean() / robot_time),
                         "waiting_frac": float(w.wait_s.sum(1).mean() / robot_time),
                         "food": float(w.food.mean())})
        curves[name] = rows
        tag = f" (theta {thetas[name]:g} s, chosen on seeds {tune_seeds.start}-{tune_seeds.stop - 1})" if tuned else ""
        print(f"{name}{tag}:", flush=True)
        print("   " + "  ".join(f"N{r['n']}:{r['eff']:.2f}±{r['ci95']:.2f}" for r in rows), flush=True)

    def eff(name: str) -> list[float]:
        return [r["eff"] for r in curves[name]]

    at30 = ns.index(30)
    result = {
        "realtime_factor_n30": spd["30"]["realtime_factor"],
        "nstar_one_zone": crossover(ns, eff("one zone"), eff("no zone")),
        "eff_gain_one_zone_at_n30": eff("one zone")[at30] / eff("no zone")[at30] - 1,
        "nstar_gated": crossover(ns, eff("gate, one zone"), eff("gate, no partition")),
        "eff_gain_gated_at_n30": eff("gate, one zone")[at30] / eff("gate, no partition")[at30] - 1,
        "nstar_cache": crossover(ns, eff("one zone, cache"), eff("no zone")),
        "theta_s": thetas, "speed": spd, "dt_sweep": dt_sweep, "curves": curves, "seeds": len(seeds),
    }
    print(f"N* one zone {result['nstar_one_zone']}, gain at N=30 {100 * result['eff_gain_one_zone_at_n30']:+.1f} %; "
          f"gated arena N* {result['nstar_gated']}, gain at N=30 {100 * result['eff_gain_gated_at_n30']:+.1f} %; "
          f"cache N* {result['nstar_cache']}", flush=True)
    if args.png:
        plot(Path(args.png), curves, dt_sweep, len(seeds))
        print(f"figure: {args.png}")
    if args.json:
        print(json.dumps(result))


def plot(path: Path, curves: dict[str, list[dict]], dt_sweep: list[dict], n_seeds: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, axes = plt.subplots(2, 3, figsize=(17, 9))
    panels = [("Fig. 4: food delivered, no zone", ["no zone"], "food"),
              ("Figs. 5-7: F/N against N, exchange zones", ["no zone", "one zone", "two zones"], "eff"),
              ("Fig. 8 and beyond: transfer variants", ["no zone", "one zone, cache", "one zone, adaptive",
                                                        "peer to peer"], "eff"),
              ("wall with a 0.3 m gate at the zone", ["gate, no partition", "gate, one zone", "gate, adaptive"], "eff"),
              ("interference: time spent bouncing off others", list(curves), "contact_frac")]
    for ax, (title, names, key) in zip(axes.flat, panels):
        for name in names:
            rows = curves[name]
            n = [r["n"] for r in rows]
            y = [r[key] for r in rows]
            err = [r["ci95"] for r in rows] if key == "eff" else None
            ax.errorbar(n, y, yerr=err, marker="o", ms=3, capsize=3, label=name)
        ax.set_title(title)
        ax.set_xlabel("N robots")
        ax.set_ylabel({"eff": "F / N (items per robot, 200 s)", "food": "F (items, 200 s)",
                       "contact_frac": "fraction of robot-time bouncing"}[key])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes.flat[5]
    if dt_sweep:
        ax.errorbar([d["cpu_s"] for d in dt_sweep], [d["abs_err"] for d in dt_sweep],
                    yerr=[d["stderr"] for d in dt_sweep], marker="o", capsize=3)
        for d in dt_sweep:
            ax.annotate(f"dt {d['dt_s']} s", (d["cpu_s"], d["abs_err"]))
        ax.set_xlabel("CPU s (30 worlds x 200 s, N = 30)")
        ax.set_ylabel("|F/N - F/N at dt 0.025 s| (bars: seed noise)")
        ax.set_title("time step: speed against error")
        ax.grid(alpha=0.3)
    else:
        ax.axis("off")
    fig.suptitle(f"Swarm task partitioning (seed 09): {n_seeds} seeds per point, 95 % intervals")
    save_figure(fig, path, dpi=90)


if __name__ == "__main__":
    main()
