"""Learn IRL cost weights from recorded logs and from real pedestrian tracks; write the weights file.

    python -m nodes.nav.irl_learn --demos run1.mcap run2.mcap -o weights.json
    python -m sim.irl_demos --demos run1.mcap --tracks students003 crowds_zara03 \\
        --holdout biwi_hotel -o nodes/nav/weights/default.json     # with real pedestrians (the simulator's camera)

A demonstration is a feature grid plus the path the expert then took across it
(:mod:`nodes.nav.demos` builds them):

- logs (a driven robot): every ``nav.FeatureGrid`` of the log, with the robot's odometry
  over the next ``--horizon-s`` seconds moved into that grid's frame;
- real pedestrians (ETH/UCY): a chosen pedestrian is taken out of the replayed crowd and
  the simulated robot's RGB-D camera is carried along its recorded track through the very
  nodes of the live pipeline (``RgbdFlow`` -> ``CrowdFeatures``, in-process), so the
  features are what the robot itself would have seen; its next seconds of track are the
  expert path and its last position the goal.

Held-out scenes (``--holdout`` data sets, or the last fifth of the log demos) are scored
by action agreement (expert moves that are optimal under the learnt cost) against the
shortest-path baseline (all weights 0); logs recorded by ``--record-oracle`` come from a
driver that plans on known weights, so their expected value difference is reported too.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

from nodes.nav.demos import DemoSet, load_demos, read_log_demos, save_demos, widen_demo
from nodes.nav.irl import CostWeights, Demo, action_agreement, expected_value_difference, learn

log = logging.getLogger("nodes.nav.irl_learn")


#: the oracle driver of --record-oracle: the paper's table, each group shifted to >= 0
ORACLE_WEIGHTS = np.array([2.2, 0.7, 0.0, 0.0, 0.0, 0.0, 4.0, 3.5, 0.0, 0.7, 0.3, 0.0])


def oracle_weights(k: int) -> np.ndarray:
    """ORACLE_WEIGHTS for a K-feature layout (the appended 'conflict' feature weighs 0: the paper has no such row)."""
    return np.concatenate([ORACLE_WEIGHTS, np.zeros(max(k - len(ORACLE_WEIGHTS), 0))])[:k]


def evaluate(weights: np.ndarray, step_cost: float, demos: list[Demo], *, oracle: bool = False) -> dict[str, float]:
    """Held-out scores of learnt weights next to the shortest-path baseline."""
    out = {"demos": len(demos), "moves": int(sum(len(d.path) - 1 for d in demos))}
    if not demos:
        return out
    out["action_agreement"] = round(action_agreement(demos, weights, step_cost=step_cost), 4)
    out["action_agreement_shortest_path"] = round(action_agreement(demos, np.zeros_like(weights)), 4)
    if oracle:
        truth = oracle_weights(len(weights))
        out["evd"] = round(expected_value_difference(demos, weights, truth, step_cost=step_cost), 4)
        out["evd_shortest_path"] = round(expected_value_difference(demos, np.zeros_like(weights), truth), 4)
    return out


def fit_and_report(demos: DemoSet, *, holdout: set[str], oracle_scenes: set[str], method: str = "birl",
                   prior: str = "laplace", lam: float = 0.5, widen_m: float = 0.0, cell_m: float = 0.25,
                   use: list[str] | tuple[str, ...] = ()) -> tuple[CostWeights, dict]:
    """Learn weights from ``demos`` (held-out scenes scored, not trained on); returns the weights file's
    content and the scores. ``holdout`` empty: the last fifth of the scenes."""
    from nodes.nav.features import CONFLICT, FEATURE_NAMES

    if use:
        demos = DemoSet({k: v for k, v in demos.scenes.items() if k in set(use) | set(holdout)})
    if widen_m > 0:
        demos = DemoSet({k: [widen_demo(d, widen_m / cell_m) for d in v] for k, v in demos.scenes.items()})
    held = set(holdout) or {n for n in list(demos.scenes)[-max(1, len(demos.scenes) // 5):]}
    train_names = [n for n in demos.scenes if n not in held]
    train = demos.pick(train_names)
    if not train:
        raise ValueError("no training demonstrations (everything is held out?)")
    res = learn(train, method=method, prior=prior, lam=lam)
    report = {"train": evaluate(res.weights, res.step_cost, train)}
    for name in sorted(held & set(demos.scenes)):
        report[name] = evaluate(res.weights, res.step_cost, demos.scenes[name], oracle=name in oracle_scenes)
    extra = {"method": method, "prior": prior, "lam": lam, "widen_m": widen_m, "trained_on": train_names,
             "held_out": sorted(held), "converged": res.converged, "scores": report}
    names = list(FEATURE_NAMES) + [CONFLICT] * (len(res.weights) - len(FEATURE_NAMES))
    return CostWeights(tuple(names), res.weights, res.step_cost, extra), report


def leave_one_scene_out(demos: DemoSet, scenes: list[str] | tuple[str, ...] = (), *, method: str = "birl",
                        prior: str = "laplace", lam: float = 0.5) -> dict[str, dict]:
    """One fold per scene of ``scenes`` (default: all): learn on the others, score the held-out one.

    Scores: action agreement of the learnt weights, of the shortest path (all weights 0) and of the
    paper's table (``oracle_weights``, the weights an oracle driver plans with). Real walkers have no
    true cost, so no expected value difference is defined for them; an oracle-driven log scene
    (``oracle-*``) held out also gets its EVD against the oracle. A single scene cannot be held out
    against nothing: it raises a ValueError naming the problem.
    """
    names = [n for n in (scenes or list(demos.scenes)) if demos.scenes.get(n)]
    if len(names) < 2:
        raise ValueError(f"leave-one-scene-out needs demos from at least 2 scenes, got {names or 'none'}")
    folds = {}
    for held in names:
        train = demos.pick([n for n in names if n != held])
        res = learn(train, method=method, prior=prior, lam=lam)
        test = demos.scenes[held]
        score = evaluate(res.weights, res.step_cost, test, oracle=held.startswith("oracle-"))
        if score.get("moves"):
            score["action_agreement_oracle"] = round(action_agreement(test, oracle_weights(len(res.weights))), 4)
        folds[held] = {"weights": [round(float(v), 4) for v in res.weights], "step_cost": round(res.step_cost, 4),
                       "scores": score}
        log.info("fold %s: agreement %.3f (shortest path %.3f, oracle %.3f)", held, score.get("action_agreement", np.nan),
                 score.get("action_agreement_shortest_path", np.nan), score.get("action_agreement_oracle", np.nan))
    return folds


def add_learning_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of learning itself (shared with ``python -m sim.irl_demos``, which also makes demos)."""
    ap.add_argument("--demos", nargs="*", default=[], help="MCAP logs with FeatureGrid + Odometry2D")
    ap.add_argument("--holdout", nargs="*", default=[], help="data sets / log files kept for scoring")
    ap.add_argument("--method", choices=("birl", "maxent"), default="birl")
    ap.add_argument("--prior", choices=("laplace", "gaussian"), default="laplace")
    ap.add_argument("--lam", type=float, default=0.5)
    ap.add_argument("--horizon-s", type=float, default=8.0, help="expert path length (s) after each feature grid")
    ap.add_argument("--rim-m", type=float, default=4.0,
                    help="demos leave the grid by the local planner's rim this far ahead (its subgoal_m; 0 = "
                         "a demo ends at its own last cell)")
    ap.add_argument("--cache", default="", help="npz file to save / reuse the extracted demos")
    ap.add_argument("--use", nargs="*", default=[], help="only these scenes (log stems / data sets) of the cache")
    ap.add_argument("--widen-m", type=float, default=0.0,
                    help="learn on crowd features widened by this radius (the planner's footprint view; 0 = as seen)")
    ap.add_argument("--cell-m", type=float, default=0.25, help="feature grid cell size (for --widen-m)")
    ap.add_argument("--loso", action="store_true",
                    help="also run leave-one-scene-out folds over every scene of the demos (not only --use) and "
                         "store them in the weights file")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--debug", action="store_true")


def log_demos(paths: list[str], *, horizon_s: float, rim_m: float) -> tuple[dict[str, list[Demo]], set[str]]:
    """Demos from recorded logs by file stem, and which of them an oracle driver recorded."""
    scenes, oracle = {}, set()
    for path in paths:
        name = Path(path).stem
        scenes[name] = read_log_demos(path, horizon_s=horizon_s, rim_m=rim_m)
        oracle |= {name} if name.startswith("oracle-") else set()
        log.info("%s: %d demos", path, len(scenes[name]))
    return scenes, oracle


def learn_main(args: argparse.Namespace, collect) -> int:
    """Collect demos with ``collect(args)`` -> (DemoSet, oracle scene names), learn, write ``args.output``."""
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.INFO, format="%(message)s")
    try:
        demos, oracle_scenes = collect(args)
        weights, report = fit_and_report(demos, holdout=set(args.holdout), oracle_scenes=oracle_scenes,
                                         method=args.method, prior=args.prior, lam=args.lam, widen_m=args.widen_m,
                                         cell_m=args.cell_m, use=args.use)
        if getattr(args, "loso", False):
            weights.extra["leave_one_scene_out"] = leave_one_scene_out(    # every scene of the demos, held out in turn
                demos, list(demos.scenes), method=args.method, prior=args.prior, lam=args.lam)
    except (ValueError, FileNotFoundError) as exc:
        print(f"irl_learn: {exc}", file=sys.stderr)
        return 2
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    Path(args.output).write_text(weights.to_json() + "\n")
    print(json.dumps({"weights": dict(zip(weights.names, np.round(weights.weights, 3).tolist())),
                      "step_cost": round(weights.step_cost, 3), "scores": report}, indent=2))
    return 0


def collect_demos(args: argparse.Namespace, *, extra_logs=None, more=None,
                  hint: str = "give --demos logs or a --cache (real pedestrians and oracle drives: python -m sim.irl_demos)"
                  ) -> tuple[DemoSet, set[str]]:
    """Demos from the cache (``args.cache``, reused when it exists), else from ``args.demos`` plus
    ``extra_logs()`` (paths) and whatever ``more(scenes)`` adds; saved to the cache when named."""
    if args.cache and Path(args.cache).is_file():
        log.info("reusing demos from %s", args.cache)
        demos = load_demos(args.cache)
        return demos, {n for n in demos.scenes if n.startswith("oracle-")}
    logs = list(args.demos) + (list(extra_logs()) if extra_logs is not None else [])
    scenes, oracle = log_demos(logs, horizon_s=args.horizon_s, rim_m=args.rim_m)
    if more is not None:
        more(scenes)
    demos = DemoSet({k: v for k, v in scenes.items() if v})
    if not demos.scenes:
        raise ValueError(f"no demonstrations: {hint}")
    if args.cache:
        save_demos(args.cache, demos)
    return demos, oracle


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Learn IRL cost weights (MAP-BIRL or MaxEnt) from recorded logs "
                                             "(demos from real pedestrians or an oracle drive: python -m sim.irl_demos).")
    add_learning_arguments(ap)
    return learn_main(ap.parse_args(argv), collect_demos)


if __name__ == "__main__":
    sys.exit(main())
