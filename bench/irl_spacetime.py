"""Space-time IRL on recorded ETH/UCY walkers: held-out likelihood of learnt vs fixed crowd prices.

    python bench/irl_spacetime.py [--json] [--demos 60] [--horizons 6] [--paces 0.75] [--loso]
        [--others recorded|constant_velocity|predicted] [--predictor mlp|cv]

Model and demos: :mod:`nodes.nav.irl_spacetime` (cells x time steps, 8 moves + wait, MaxEnt)
and :func:`sim.irl_demos.spacetime_demos` (each walker's next ``horizon`` seconds, others'
recorded positions at each step; walkers with it at the start, a group, left out). Trained on
biwi_eth, biwi_hotel, uni_examples; scored on students003 and crowds_zara03 (the social_nav
bench's real crowds, never trained on). Models, all in the same space-time MDP, each with its
step and wait cost fitted on the training sets:

- ``learnt``: every near-another-walker weight learnt (Laplace prior);
- ``shortest_path``: every feature weight 0 (the baseline);
- ``hand_conflict``: the shipped spatial price, conflict 4.0 / step 2.0, as near_0.5 = 2.0 x c0;
- ``spatial_birl``: MAP-BIRL's best spatial price (hindsight conflict 0.77 / step 2.0, default.json
  ``conflict_weight.hindsight_experiment``) as near_0.5 = 0.385 x c0.

Reports NLL per demonstrated step (lower is better) and action agreement (the demo's action
is the model's most likely one) on the held-out sets, learnt ratios w / c0, the walkers' own
near counts against those expected of the shortest-path model, and the time each stage took.
``--horizons`` / ``--paces`` sweep the accuracy knobs (demo length in s; cells per step at the
walker's median speed, i.e. dt = pace x 0.25 m / speed).

Measured (60 demos per set, horizon 6 s, pace 0.75, 2-core machine shared, ~7.5 min with
``--loso``): learnt near_0.5 = 0.10 x c0 (LOSO 0.07-0.28; 0.06-0.16 over horizons 4 / 8 s and
paces 0.5 / 1.0); held-out NLL per step students003 / zara03: learnt 1.003 / 0.975, shortest
path 1.009 / 0.983, spatial_birl 1.056 / 0.976, hand_conflict 1.503 / 1.052. Walkers are
within 0.5 m of someone 1.5-21x less often than the shortest-path model, yet a small price
explains it: a one-step change of timing avoids most such moments. With ``--others
constant_velocity`` (the runtime feature's prediction) walkers are near predicted positions
about as often as the shortest path and the learnt ratio is 0.007. With ``--others predicted``
(a learnt predictor's view, from the others' last 3.2 s only; ``--predictor mlp``: the
ETH/UCY-trained MLP ensemble of :mod:`nodes.nav.predict` held out on the demo's scene) the
ratio is 0.020 (LOSO -0.004 to 0.038; constant velocity from the same observed history,
``--predictor cv``: 0.012): a better predictor does not bring the price back toward the 0.10 of
the recorded positions. Details and the bench comparison: nodes/nav/weights/default.json
``conflict_weight.spacetime_experiment`` and ``conflict_weight.predicted_experiment``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from nodes.nav.irl_spacetime import evaluate, feature_counts, learn_spacetime  # noqa: E402
from sim.irl_demos import spacetime_demos  # noqa: E402

TRAIN = ("biwi_eth", "biwi_hotel", "uni_examples")
HELD_OUT = ("students003", "crowds_zara03")
HAND_RATIO = 4.0 / 2.0          # shipped conflict weight / spatial step cost
SPATIAL_BIRL_RATIO = 0.77 / 2.0  # MAP-BIRL hindsight conflict / spatial step cost


def models(names: tuple[str, ...]) -> dict[str, dict[str, float] | None]:
    """Fixed ratios per model (None: all learnt)."""
    zero = {n: 0.0 for n in names}
    return {"learnt": None, "shortest_path": zero, "hand_conflict": zero | {names[0]: HAND_RATIO},
            "spatial_birl": zero | {names[0]: SPATIAL_BIRL_RATIO}}


def predictor_for(scene: str, kind: str) -> object:
    """The others' predictor of demos from ``scene``: the MLP that never saw ``scene`` (leave one scene
    out), or constant velocity from the observed history."""
    from nodes.nav.predict import BaselinePredictor, load_loso

    return load_loso(scene) if kind == "mlp" else BaselinePredictor()


def run_config(horizon_s: float, pace: float, n: int, radii: tuple[float, ...], lam: float, companions: str,
               loso: bool, others: str = "recorded", predictor: str = "mlp") -> dict:
    """Demos, fits and held-out scores of one (horizon, pace)."""
    names = tuple(f"near_{r:g}" for r in radii)
    t0 = time.perf_counter()
    sets = {ds: spacetime_demos(ds, n, horizon_s=horizon_s, pace=pace, seed=k, radii_m=radii, companions=companions,
                               others=others,
                               predictor=predictor_for(ds, predictor) if others == "predicted" else None)
            for k, ds in enumerate(TRAIN + HELD_OUT)}
    out: dict = {"horizon_s": horizon_s, "pace": pace, "names": list(names), "demo_s": round(time.perf_counter() - t0, 1),
                 "demos": {ds: {"demos": len(d), **c} for ds, (d, c) in sets.items()}}
    train = [x for ds in TRAIN for x in sets[ds][0]]
    fits = {}
    for model, fixed in models(names).items():
        t = time.perf_counter()
        res = learn_spacetime(train, names, lam=lam, fixed_ratios=fixed)
        fits[model] = res
        out[model] = {"theta": dict(zip(res.names, np.round(res.theta, 4).tolist())), "fit_s": round(time.perf_counter() - t, 1),
                      "converged": res.converged, "train_nll_per_step": round(res.nll_per_step, 4),
                      "ratios_to_step_cost": {nm: round(res.ratio(nm), 4) for nm in names}}
        for ds in HELD_OUT:
            out[model][ds] = evaluate(sets[ds][0], res.theta)
    for ds in TRAIN + HELD_OUT:                     # how near walkers come vs the shortest-path model
        emp, exp = feature_counts(sets[ds][0], fits["shortest_path"].theta)
        out["demos"][ds]["near_counts_expert_vs_shortest_path"] = {
            nm: [round(float(emp[2 + j]), 1), round(float(exp[2 + j]), 1)] for j, nm in enumerate(names)}
        out["demos"][ds]["waits_expert_vs_shortest_path"] = [round(float(emp[1]), 1), round(float(exp[1]), 1)]
    if loso:
        out["leave_one_scene_out"] = {}
        for held in TRAIN:
            tr = [x for ds in TRAIN if ds != held for x in sets[ds][0]]
            fold = {}
            for model in ("learnt", "shortest_path"):
                res = learn_spacetime(tr, names, lam=lam, fixed_ratios=models(names)[model])
                fold[model] = evaluate(sets[held][0], res.theta) | {
                    "ratios_to_step_cost": {nm: round(res.ratio(nm), 4) for nm in names}}
            out["leave_one_scene_out"][held] = fold
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--demos", type=int, default=60, help="demos drawn per data set")
    ap.add_argument("--horizons", type=float, nargs="*", default=[6.0], help="demo lengths (s) to sweep")
    ap.add_argument("--paces", type=float, nargs="*", default=[0.75], help="cells per step at median speed")
    ap.add_argument("--radii", type=float, nargs="*", default=[0.5, 1.0, 1.5], help="near bands (m)")
    ap.add_argument("--lam", type=float, default=0.5)
    ap.add_argument("--companions", choices=("exclude", "keep"), default="exclude")
    ap.add_argument("--others", choices=("recorded", "constant_velocity", "predicted"), default="recorded",
                    help="features from the others' recorded positions, their t0 constant-velocity prediction, or "
                         "--predictor's prediction from their last 3.2 s")
    ap.add_argument("--predictor", choices=("mlp", "cv"), default="mlp",
                    help="with --others predicted: the learnt MLP held out on the demo's scene "
                         "(nodes/nav/weights/predictor/loso_<scene>.npz), or constant velocity from the observed steps")
    ap.add_argument("--loso", action="store_true", help="also leave one training scene out (learnt vs shortest path)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    runs = [run_config(h, p, args.demos, tuple(args.radii), args.lam, args.companions, args.loso, args.others,
                       args.predictor)
            for h in args.horizons for p in args.paces]
    report = {"trained_on": list(TRAIN), "held_out": list(HELD_OUT), "demos_per_set": args.demos,
              "companions": args.companions, "others": args.others, "lam": args.lam, "runs": runs}
    if args.others == "predicted":
        report["predictor"] = args.predictor
    if args.json:
        print(json.dumps(report, indent=1))
        return
    for r in runs:
        print(f"horizon {r['horizon_s']} s, pace {r['pace']}: demos {r['demo_s']} s, total {r['total_s']} s")
        for model in models(tuple(r["names"])):
            m = r[model]
            held = "  ".join(f"{ds} nll {m[ds]['nll_per_step']:.4f} agree {m[ds]['action_agreement']:.3f}"
                             for ds in HELD_OUT)
            print(f"  {model:14s} fit {m['fit_s']:6.1f} s  ratios {m['ratios_to_step_cost']}  {held}")


if __name__ == "__main__":
    main()
