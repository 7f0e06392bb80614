"""Pose-graph benchmark: nodes.slam.pose_graph against GTSAM's Levenberg-Marquardt, in one run.

Every graph in ../shared/data/posegraphs, read once by our reader (so both solvers get the
very same measurements and information), initialised from the odometry chain, pose 0
anchored (GTSAM: a prior of sigma 1e-6). Both results are evaluated by the same function
(``nodes.slam.pose_graph.chi2``), in g2o's convention and in GTSAM's (see
../shared/specs/pose-graphs.md); CPU time is process time (all threads), median of repeats.

The accuracy knob is the relative-decrease stopping tolerance, swept alike for both
(GTSAM's ``relativeErrorTol``; its default 1e-5 is one of the points). Hard cases:

* ``M3500_rot0.2``: M3500 with every odometry rotation perturbed by N(0, 0.2 rad) -- the
  odometry start is far off; ours with ``initial='chordal'`` against GTSAM's defaults;
* ``intel_badscale``: intel with the translation information of a random half of the edges
  multiplied by 1e4 and of the other half divided by 1e2 -- ill-conditioned normal equations.

    python bench/pose_graph.py [--quick] [--json] [--png OUT.png]

``--json`` prints one object: ``graphs`` maps each graph to {chi2, chi2_gtsam, cpu_s,
cpu_s_gtsam, iterations, iterations_gtsam, chi2_gtsam_conv, chi2_gtsam_conv_gtsam}, and
``sweep`` the time-vs-error points.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")        # single-thread CPU time, for both solvers

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.slam.graph_io import read_graph  # noqa: E402
from nodes.slam.pose_graph import PoseGraph2D, chi2, initial_poses, optimize  # noqa: E402

DATA = Path(os.environ.get("TETHER_SHARED_DATA", REPO.parent / "shared" / "data")) / "posegraphs"
GRAPHS = {"M3500": "input_M3500_g2o.g2o", "intel": "sesync_intel.g2o", "FR079": "FR079_P_toro.graph"}


def gtsam_solve(graph: PoseGraph2D, start: np.ndarray, *, rel_tol: float = 1e-5,
                max_iterations: int = 100) -> tuple[np.ndarray, float, int]:
    """GTSAM LM from ``start``: (poses, CPU s, iterations). Graph construction is not timed."""
    import gtsam

    factors = gtsam.NonlinearFactorGraph()
    for (i, j), z, info in zip(graph.edges.tolist(), graph.z, graph.info):
        factors.add(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(info)))
    factors.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*start[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    values = gtsam.Values()
    for k, pose in enumerate(start):
        values.insert(k, gtsam.Pose2(*pose))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(rel_tol)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(max_iterations)
    t0 = time.process_time()
    optimizer = gtsam.LevenbergMarquardtOptimizer(factors, values, params)
    result = optimizer.optimize()
    cpu = time.process_time() - t0
    poses = np.array([[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(graph.n)])
    return poses, cpu, optimizer.iterations()


def ours(graph: PoseGraph2D, start: np.ndarray | str, *, rel_tol: float = 1e-5, **kw) -> tuple[np.ndarray, float, int]:
    result = optimize(graph, initial=start, rel_tol=rel_tol, **kw)
    return result.poses, result.time_s, result.iterations


def median_run(fn, repeats: int):
    runs = [fn() for _ in range(repeats)]
    return runs[0][0], statistics.median(r[1] for r in runs), runs[0][2]


def hard_cases(graphs: dict[str, PoseGraph2D], seed: int = 0) -> dict[str, PoseGraph2D]:
    rng = np.random.default_rng(seed)
    out = {}
    if "M3500" in graphs:
        g = graphs["M3500"]
        rot = PoseGraph2D(ids=g.ids, poses=g.poses.copy(), edges=g.edges, z=g.z.copy(), info=g.info, known=np.zeros_like(g.known))
        odo = rot.odometry_mask()
        rot.z[odo, 2] += rng.normal(scale=0.2, size=int(odo.sum()))
        out["M3500_rot0.2"] = rot
    if "intel" in graphs:
        g = graphs["intel"]
        info = g.info.copy()
        half = rng.random(len(info)) < 0.5
        info[half, :2, :] *= 1e2
        info[half, :, :2] *= 1e2
        info[~half, :2, :] /= 1e1
        info[~half, :, :2] /= 1e1
        out["intel_badscale"] = PoseGraph2D(ids=g.ids, poses=g.poses, edges=g.edges, z=g.z, info=info,
                                           known=np.zeros_like(g.known))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, a short sweep")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--png", default=str(REPO / "out" / "pose_graph_bench.png"), help="speed-vs-error figure")
    args = ap.parse_args()
    say = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else print
    if not DATA.is_dir():
        say(f"no pose graphs at {DATA}: nothing to measure")
        print(json.dumps({"graphs": {}, "skipped": str(DATA)}) if args.json else "")
        return
    repeats = 1 if args.quick else 5
    graphs = {name: read_graph(DATA / file) for name, file in GRAPHS.items() if (DATA / file).exists()}
    cases = {**graphs, **hard_cases(graphs)}
    report: dict[str, dict] = {}
    trajectories: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    say(f"{'graph':16s} {'chi2 ours':>12s} {'chi2 GTSAM':>12s} {'rel diff':>9s} {'CPU ours':>9s} {'CPU GTSAM':>9s} "
        f"{'ratio':>6s} {'it':>3s} {'it G':>4s}   (g2o convention; odometry start, relative tol 1e-5 both)")
    for name, graph in cases.items():
        start = initial_poses(graph, "odometry")
        hard = "_" in name
        ours_start = "chordal" if hard else start          # ours on hard cases: its robust start (GTSAM: its default)
        p_ours, t_ours, it_ours = median_run(lambda: ours(graph, ours_start), repeats)
        p_g, t_g, it_g = median_run(lambda: gtsam_solve(graph, start), repeats)
        c_ours, c_g = chi2(graph, p_ours), chi2(graph, p_g)
        row = {"chi2": round(c_ours, 6), "chi2_gtsam": round(c_g, 6), "cpu_s": round(t_ours, 4),
               "cpu_s_gtsam": round(t_g, 4), "iterations": it_ours, "iterations_gtsam": it_g,
               "chi2_gtsam_conv": round(chi2(graph, p_ours, convention="gtsam"), 6),
               "chi2_gtsam_conv_gtsam": round(chi2(graph, p_g, convention="gtsam"), 6),
               "start": "chordal" if hard else "odometry"}
        if hard:                                             # ours from the same odometry start, for the record
            p_same, t_same, _ = ours(graph, start)
            row["chi2_ours_odometry_start"] = round(chi2(graph, p_same), 6)
        report[name] = row
        trajectories[name] = (start, p_ours, p_g)
        say(f"{name:16s} {c_ours:12.4f} {c_g:12.4f} {(c_ours - c_g) / c_g:9.1e} {t_ours:9.3f} {t_g:9.3f} "
            f"{t_ours / max(t_g, 1e-9):6.2f} {it_ours:3d} {it_g:4d}" + (f"   (ours from odometry: "
                                                                           f"{row['chi2_ours_odometry_start']:.4f})" if hard else ""))
    # Speed against error: sweep the stopping tolerance for both on the published graphs.
    tolerances = [1e-2, 1e-3, 1e-5, 1e-8] if args.quick else [1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8, 1e-10]
    sweep: dict[str, list] = {}
    for name, graph in graphs.items():
        start = initial_poses(graph, "odometry")
        best = min(report[name]["chi2"], report[name]["chi2_gtsam"])
        points = []
        for tol in tolerances:
            p_ours, t_ours, _ = median_run(lambda: ours(graph, start, rel_tol=tol), repeats)
            p_g, t_g, _ = median_run(lambda: gtsam_solve(graph, start, rel_tol=tol), repeats)
            points.append({"rel_tol": tol, "cpu_s": round(t_ours, 4), "cpu_s_gtsam": round(t_g, 4),
                           "chi2_excess": (chi2(graph, p_ours) - best) / best,
                           "chi2_excess_gtsam": (chi2(graph, p_g) - best) / best})
        sweep[name] = points
        say(f"{name}: tol -> (CPU ours, chi2 excess ours | CPU GTSAM, chi2 excess GTSAM): " + "; ".join(
            f"{p['rel_tol']:.0e}: {p['cpu_s']:.3f} s {p['chi2_excess']:.1e} | {p['cpu_s_gtsam']:.3f} s "
            f"{p['chi2_excess_gtsam']:.1e}" for p in points))
    _figure(sweep, Path(args.png))
    traj_png = Path(args.png).with_name(Path(args.png).stem + "_trajectories.png")
    _trajectories(trajectories, traj_png)
    say(f"wrote {args.png} and {traj_png}")
    if args.json:
        print(json.dumps({"graphs": report, "sweep": sweep, "repeats": repeats}))


def _figure(sweep: dict[str, list], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, len(sweep), figsize=(5 * len(sweep), 4), squeeze=False)
    for ax, (name, points) in zip(axes[0], sweep.items()):
        floor = 1e-12
        ax.loglog([p["cpu_s"] for p in points], [max(p["chi2_excess"], floor) for p in points], "o-", label="tether")
        ax.loglog([p["cpu_s_gtsam"] for p in points], [max(p["chi2_excess_gtsam"], floor) for p in points], "s--",
                  label="GTSAM LM")
        ax.set_title(name)
        ax.set_xlabel("CPU s")
        ax.set_ylabel("chi2 above the best (relative)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle("pose graphs: time against g2o-convention chi2, tolerance swept (odometry start); GTSAM "
                 "minimises its own convention (Logmap), hence its floor on intel and FR079")
    save_figure(fig, path, dpi=110)


def _trajectories(trajectories: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, axes = plt.subplots(2, len(trajectories), figsize=(4.2 * len(trajectories), 8), squeeze=False)
    for col, (name, (start, mine, theirs)) in enumerate(trajectories.items()):
        top, bottom = axes[0, col], axes[1, col]
        top.plot(start[:, 0], start[:, 1], lw=0.5, color="0.6")
        top.set_title(f"{name}: start")
        bottom.plot(theirs[:, 0], theirs[:, 1], lw=1.6, color="tab:orange", label="GTSAM LM")
        bottom.plot(mine[:, 0], mine[:, 1], lw=0.6, color="tab:blue", label="tether")
        bottom.set_title(f"{name}: optimised")
        bottom.legend(fontsize=7)
        for ax in (top, bottom):
            ax.set_aspect("equal", adjustable="datalim")
            ax.tick_params(labelsize=7)
    save_figure(fig, path, dpi=100)


if __name__ == "__main__":
    main()
