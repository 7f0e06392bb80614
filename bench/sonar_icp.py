"""Sonar ICP benchmark: our localizer against small_gicp (and KISS-ICP) on clouds from simulated pings,
and the localizer on structures it was not tuned to.

Part 1, registration (speed against error). Sources are what the pipeline gives, not samples of
the model: 512-beam pings of the tripod rendered by ``sim.fls`` (speckle, elevation ambiguity,
seabed returns), line scans by ``nodes.sonar.highlight`` placed in the world with a drifting
navigation pose (0.4 m, -0.3 m, 3 deg), in windows of the last 4 s taken every second. Every
method starts each window from the navigation pose and is scored by the error of the corrected
navigation pose at the window's last ping against the simulator's truth. Targets are built once:
our model (KD-tree, nearest grid and yaw-symmetry search) and small_gicp's per downsampling
(voxel grid, covariances, KD-tree); the build times are reported beside. small_gicp solves 6 DOF
on the lower-edge points; ours runs on the same points (6 DOF and x/y/yaw) and on elevation arcs
(x/y/yaw, what the launched localizer uses). KISS-ICP (point-to-point, Geman-McClure kernel, its
adaptive threshold carried from window to window) runs when installed. CPU time is
``time.process_time``, one thread everywhere; medians over windows.

Part 2, structures: the localizer as launched (highlight cloud -> arcs -> IcpLocalizer) on 8-16 s
passes of the tripod, a square pier (exact four-fold), the same with one column 5 cm taller, two
piles, a single pile, a wall, and the tripod on a sloping seabed, with heading errors of 3 and
20 deg. A trusted correction wrong by more than 0.5 m or 5 deg counts in ``wrong_trusted``.

    python bench/sonar_icp.py [--quick] [--json]
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from msgs.geometry import Pose3D  # noqa: E402
from msgs.sonar import SonarPing  # noqa: E402
from nodes.sonar.arcs import arcs_from_scan  # noqa: E402
from nodes.sonar.highlight_cloud import HighlightCloud  # noqa: E402
from nodes.sonar.icp_localizer import IcpLocalizer  # noqa: E402
from nodes.sonar.highlight import extract_line_scan  # noqa: E402
from nodes.sonar.icp import IcpModel, IcpSettings, align  # noqa: E402
from nodes.sonar.icp_gate import gate_threshold, mahalanobis_to_prior  # noqa: E402
from nodes.sonar.model import tripod_model  # noqa: E402
from sim.fls import PingSettings, load_scene, render_ping  # noqa: E402
from sim.nav_drift import drift_matrix  # noqa: E402
from tether.testing import Harness  # noqa: E402

WINDOW_S, EVERY_S = 4.0, 1.0
WRONG_M, WRONG_DEG = 0.5, 5.0
STRUCTURES = {   # name: (scene, localizer model, pass window s)
    "tripod": ("tripod", "tripod", (6.0, 22.0)),
    "pier4": ("pier4", str(ROOT / "sim/scenes/fls_pier4.yaml"), (6.0, 22.0)),
    "pier4_near": ("pier4_near", str(ROOT / "sim/scenes/fls_pier4_near.yaml"), (6.0, 22.0)),
    "piles2": ("piles2", str(ROOT / "sim/scenes/fls_piles2.yaml"), (6.0, 22.0)),
    "pile": ("cylinder", str(ROOT / "sim/scenes/fls_cylinder.yaml"), (6.0, 22.0)),
    "wall": ("wall", str(ROOT / "sim/scenes/fls_wall.yaml"), (2.0, 18.0)),
    "tripod_slope": ("tripod_slope", "tripod", (6.0, 22.0)),
}


def pose_error(est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    dh = math.atan2(est[1, 0], est[0, 0]) - math.atan2(truth[1, 0], truth[0, 0])
    return float(np.linalg.norm(est[:3, 3] - truth[:3, 3])), abs(math.degrees(math.remainder(dh, 2 * math.pi)))


def structure_pass(name: str, *, yaw_deg: float = 3.0, shift=(0.4, -0.3), rate_hz: float = 8.0, seed: int = 0,
                   beams: int = 256, nan_beams: bool = False, zero_gains: bool = False) -> dict:
    """The localizer as launched over one structure's pass, navigation off by ``shift`` and ``yaw_deg``.

    Rendered pings -> HighlightCloud (navigation pose) -> scans -> IcpLocalizer (arcs, x/y/yaw, a fit
    every 5 scans); every correction scored against the simulator's truth at its ping.
    """
    scene_name, model, (t0, t1) = STRUCTURES[name]
    scene = load_scene(scene_name)
    drift = drift_matrix(shift[0], shift[1], math.radians(yaw_deg))
    rng = np.random.default_rng(seed)
    settings = PingSettings(n_beams=beams, range_m=20.0)
    floor = getattr(scene.seafloor, "z_m", -6.0)
    cloud = Harness(HighlightCloud, params={"seafloor_z_m": floor, "include_seafloor": False, "publish_scan": True})
    loc = Harness(IcpLocalizer, params={"model": model, "source": "arcs", "dof": "xy_yaw", "arc_samples": 9,
                                        "window_s": 8.0, "align_every": 5})
    truth_at, nav_at = {}, {}
    begin = time.perf_counter()
    for k, t in enumerate(np.arange(t0, t1, 1.0 / rate_hz)):
        stamp = int(round(t * 1e9))
        truth = scene.sonar_pose(float(t))
        r = render_ping(scene, truth, settings, rng=rng)
        img = r.intensities
        gains = np.ones(img.shape[0], np.float32)
        if zero_gains and k % 3 == 0:
            gains = np.zeros(img.shape[0], np.float32)
        bearings = r.bearings_rad.astype(np.float32)
        if nan_beams and k % 3 == 1:
            img = img.astype(np.float32) / 255.0          # a float image (full scale 1) with NaN beams
            img[:, ::17] = np.nan
        nav = drift @ truth
        truth_at[stamp], nav_at[stamp] = truth, nav
        ping = SonarPing(stamp_ns=stamp, intensities=img, bearings_rad=bearings, range_resolution_m=r.range_resolution_m,
                         range_m=r.range_m, vertical_aperture_rad=r.vertical_aperture_rad, gamma=0.5, row_gains=gains)
        pose = Pose3D.from_matrix(nav, stamp_ns=stamp, frame_id="world")
        outs = cloud.feed([(t, "pose", pose), (t + 1e-4, "ping", ping)])
        events = [(t + 2e-4, "pose", pose)]
        events += [(t + 3e-4, "scan", o.msg) for o in outs if o.output == "scan"]
        loc.feed(events)
    cloud.close()
    loc.close()
    rows = []
    last_trusted = None
    for res in loc.of("correction"):
        if res.iterations == 0:
            continue
        truth, nav = truth_at[res.stamp_ns], nav_at[res.stamp_ns]
        trusted = res.converged and not res.degenerate and not res.ambiguous
        e_m, e_deg = pose_error(res.correction.matrix() @ nav, truth)
        rows.append((trusted, e_m, e_deg, res.ambiguous, res.gated))
        if trusted:
            last_trusted = res.correction.matrix()
    last = max(truth_at)
    final = (last_trusted if last_trusted is not None else np.eye(4)) @ nav_at[last]
    wrong = [(round(e, 2), round(h, 1)) for t, e, h, _, _ in rows if t and (e > WRONG_M or h > WRONG_DEG)]
    return dict(trusted=sum(r[0] for r in rows), wrong_trusted=len(wrong), ambiguous=sum(r[3] for r in rows),
                gated=sum(r[4] for r in rows), alignments=len(rows),
                final_err_m=pose_error(final, truth_at[last])[0], nav_err_m=pose_error(nav_at[last], truth_at[last])[0],
                poor_fit=loc.node.flags["poor_fit"], worst_wrong=wrong[:3], flags=loc.node.flags,
                cloud_drops=cloud.node.dropped,
                gain_problems=cloud.node.gain_problems, seconds=time.perf_counter() - begin)


def simulated_windows(quick: bool) -> list[dict]:
    """Source windows from rendered pings: lower-edge points (world, by navigation), arcs, truth."""
    scene = load_scene("tripod")
    rng = np.random.default_rng(0)
    drift = drift_matrix(0.4, -0.3, math.radians(3.0))
    rate = 4.0 if quick else 8.0
    scans = []
    for t in np.arange(10.0, 20.0 if quick else 22.0, 1.0 / rate):
        truth = scene.sonar_pose(float(t))
        ping = render_ping(scene, truth, PingSettings(n_beams=512, range_m=20.0), rng=rng)
        nav = drift @ truth
        down = nav[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        scan = extract_line_scan(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                 altitude_m=float(nav[2, 3] + 6.0), tilt_rad=math.asin(down[0]),
                                 spread_rad=ping.vertical_aperture_rad, down_frd=down, include_seafloor=False)
        scans.append((float(t), truth, nav, scan.points_m))
    windows = []
    for end in np.arange(scans[0][0] + WINDOW_S, scans[-1][0] + 1e-9, EVERY_S):
        part = [s for s in scans if end - WINDOW_S < s[0] <= end + 1e-9]
        points = np.concatenate([p @ n[:3, :3].T + n[:3, 3] for _, _, n, p in part])
        arcs = np.concatenate([arcs_from_scan(p, n, 9) for _, _, n, p in part])
        if len(points) >= 200:
            windows.append(dict(points=points, arcs=arcs, truth=part[-1][1], nav=part[-1][2]))
    return windows


def _score(windows: list[dict], estimates: list[np.ndarray], ms: list[float]) -> dict:
    errs = [pose_error(c @ w["nav"], w["truth"]) for c, w in zip(estimates, windows)]
    m, d = np.array([e[0] for e in errs]), np.array([e[1] for e in errs])
    return dict(err_m=float(np.median(m)), err_deg=float(np.median(d)), err_m_max=float(m.max()),
                err_deg_max=float(d.max()), ms=float(np.median(ms)))


def run_ours(windows, model: IcpModel, settings: IcpSettings, source: str) -> dict:
    """Our align on each window; ``trusted``/``wrong`` as the localizer would judge them (its default
    navigation gate and residual limit), wrong = more than 0.5 m or 5 deg off."""
    est, ms, amb, trusted, wrong = [], [], 0, 0, 0
    limit = gate_threshold(0.99)
    for w in windows:
        t0 = time.process_time()
        out = align(w[source], model, settings=settings)
        ms.append((time.process_time() - t0) * 1e3)
        est.append(out.transform)
        amb += out.ambiguous
        d2 = mahalanobis_to_prior(out.transform, out.covariance, model.centroid, sigma_m=2.0,
                                  sigma_yaw_rad=math.radians(15.0))
        if out.converged and not out.degenerate and not out.ambiguous and d2 <= limit and out.rmse_m <= 0.08:
            trusted += 1
            e_m, e_deg = pose_error(out.transform @ w["nav"], w["truth"])
            wrong += e_m > WRONG_M or e_deg > WRONG_DEG
    return {**_score(windows, est, ms), "ambiguous": amb, "trusted": trusted, "wrong": wrong}


def small_gicp_targets(model_pts: np.ndarray, resolutions) -> dict:
    """small_gicp's target per downsampling resolution, built once: (cloud, tree, build ms)."""
    import small_gicp

    out = {}
    for ds in resolutions:
        t0 = time.process_time()
        cloud, tree = small_gicp.preprocess_points(model_pts, downsampling_resolution=ds, num_threads=1)
        out[ds] = (cloud, tree, (time.process_time() - t0) * 1e3)
    return out


def run_small_gicp(windows, target, kind: str, ds: float, iterations: int) -> dict:
    import small_gicp

    cloud, tree, _ = target
    est, ms = [], []
    for w in windows:
        t0 = time.process_time()
        src, _ = small_gicp.preprocess_points(w["points"], downsampling_resolution=ds, num_threads=1)
        res = small_gicp.align(cloud, src, tree, registration_type=kind, max_correspondence_distance=1.0,
                               num_threads=1, max_iterations=iterations)
        ms.append((time.process_time() - t0) * 1e3)
        est.append(res.T_target_source)
    return _score(windows, est, ms)


def run_kiss(windows, model_pts: np.ndarray, voxel_m: float) -> tuple[dict, float] | None:
    """KISS-ICP's registration against a voxel map of the model, threshold adapted window to window."""
    try:
        from kiss_icp.config import KISSConfig
        from kiss_icp.mapping import VoxelHashMap
        from kiss_icp.registration import Registration
        from kiss_icp.threshold import AdaptiveThreshold
    except ImportError:
        return None
    t0 = time.process_time()
    voxel_map = VoxelHashMap(voxel_size=voxel_m, max_distance=100.0, max_points_per_voxel=20)
    voxel_map.add_points(model_pts)
    build_ms = (time.process_time() - t0) * 1e3
    config = KISSConfig()
    config.data.max_range = 40.0
    threshold = AdaptiveThreshold(config)
    reg = Registration(max_num_iterations=500, convergence_criterion=1e-4, max_num_threads=1)
    est, ms, last = [], [], np.eye(4)
    for w in windows:
        t0 = time.process_time()
        sigma = threshold.get_threshold()
        t = reg.align_points_to_map(w["points"], voxel_map, np.eye(4), 3 * sigma, sigma)
        ms.append((time.process_time() - t0) * 1e3)
        threshold.update_model_deviation(np.linalg.inv(last) @ t)
        last = t
        est.append(t)
    return _score(windows, est, ms), build_ms


def registration(quick: bool, say) -> tuple[list[dict], dict]:
    pts, nrm = tripod_model(spacing_m=0.1)
    t0 = time.process_time()
    model = IcpModel.build(pts, nrm, grid_m=0.1, symmetry=True)
    build_ms = (time.process_time() - t0) * 1e3
    t0 = time.process_time()
    IcpModel.build(pts, nrm, grid_m=0.1)
    no_sym_ms = (time.process_time() - t0) * 1e3
    say(f"our model: {len(pts)} samples, build {build_ms:.0f} ms ({build_ms - no_sym_ms:.0f} ms of it the symmetry "
        f"search: {model.symmetry.describe()})")
    windows = simulated_windows(quick)
    say(f"{len(windows)} source windows from rendered pings ({np.median([len(w['points']) for w in windows]):.0f} "
        f"points each, median)")
    rows: list[dict] = []

    def add(family: str, label: str, res: dict | None, **extra) -> None:
        if res is not None:
            rows.append(dict(family=family, label=label, **res, **extra))
            judged = f", {res['trusted']} trusted ({res['wrong']} wrong)" if "trusted" in res else ""
            say(f"  {family:<11} {label:<32} {res['ms']:8.1f} ms  {res['err_m']:6.3f} m  {res['err_deg']:6.2f} deg"
                f"  (worst {res['err_m_max']:.2f} m, {res['err_deg_max']:.1f} deg{judged})")

    for n in ((400, 1600) if quick else (200, 400, 800, 1600)):
        for it in ((10, 30) if quick else (5, 10, 30)):
            add("ours", f"points 6dof n={n} it={it}", run_ours(windows, model, IcpSettings(
                yaw_hypotheses=0, max_points=n, max_iterations=it), "points"), dof="all")
    add("ours", "points xy_yaw n=800", run_ours(windows, model, IcpSettings(dof="xy_yaw", yaw_hypotheses=0), "points"),
        dof="xy_yaw")
    add("ours arcs", "arcs xy_yaw n=800", run_ours(windows, model, IcpSettings(dof="xy_yaw", yaw_hypotheses=0), "arcs"),
        dof="xy_yaw")
    add("ours+yaw", "arcs xy_yaw + whole-circle check", run_ours(windows, model, IcpSettings(dof="xy_yaw"), "arcs"),
        dof="xy_yaw")
    builds: dict[str, float] = {"ours": build_ms, "ours_without_symmetry": no_sym_ms, "windows": len(windows)}
    try:
        resolutions = (0.1, 0.25, 0.5) if quick else (0.05, 0.1, 0.25, 0.5)
        targets = small_gicp_targets(pts, resolutions)
    except ImportError:
        targets = {}
    for ds, target in targets.items():
        builds[f"small_gicp ds={ds}"] = target[2]
        for kind in ("GICP", "PLANE_ICP", "ICP"):
            for it in ((20,) if quick else (10, 30)):
                add("small_gicp", f"{kind} ds={ds} it={it}", run_small_gicp(windows, target, kind, ds, it), dof="all")
    kiss = run_kiss(windows, pts, 0.25)
    if kiss is not None:
        add("kiss_icp", "point-to-point, adaptive threshold", kiss[0], dof="all")
        builds["kiss_icp voxel map 0.25"] = kiss[1]
    return rows, builds


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    colours = {"ours": "C0", "ours arcs": "C4", "ours+yaw": "C2", "small_gicp": "C1", "kiss_icp": "C3"}
    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(13, 5))
    for fam, colour in colours.items():
        fam_rows = sorted((r for r in rows if r["family"] == fam), key=lambda r: r["ms"])
        if not fam_rows:
            continue
        for ax, key, scale in ((ax_t, "err_m", 100.0), (ax_r, "err_deg", 1.0)):
            xs, ys = [r["ms"] for r in fam_rows], [max(r[key] * scale, 1e-3) for r in fam_rows]
            ax.scatter(xs, ys, color=colour, s=22, label=fam)
            front, best = [], float("inf")                 # the speed/error front of each family
            for x, y in zip(xs, ys):
                if y < best:
                    front.append((x, y))
                    best = y
            ax.plot(*zip(*front), color=colour, lw=1)
            for r, x, y in zip(fam_rows, xs, ys):
                ax.annotate(r["label"], (x, y), fontsize=5)
    for ax, unit in ((ax_t, "position error at the last ping (cm)"), (ax_r, "heading error (deg)")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("single-thread CPU ms per registration (median over windows)")
        ax.set_ylabel(f"median {unit}")
        ax.legend(fontsize=8)
    ax_t.set_title("tripod, sources from simulated pings: position error vs CPU time")
    ax_r.set_title("heading error vs CPU time")
    save_figure(fig, path, dpi=110)


def structures(quick: bool, say) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for yaw in (3.0, 20.0):
        for name in STRUCTURES:
            r = structure_pass(name, yaw_deg=yaw, rate_hz=4.0 if quick else 8.0, beams=256)
            out[f"{name}@{yaw:.0f}deg"] = r
            say(f"  {name:<13} heading error {yaw:4.0f} deg: {r['trusted']:3d} trusted ({r['wrong_trusted']} wrong), "
                f"{r['ambiguous']:3d} ambiguous, {r['gated']} gated, {r['poor_fit']} poor fits; final error "
                f"{r['final_err_m']:.3f} m (navigation alone {r['nav_err_m']:.3f} m)  [{r['seconds']:.0f} s]")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer windows, settings and pings")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the headline figures last")
    args = parser.parse_args()
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if args.json else (lambda msg: print(msg, flush=True))
    say("part 1: registration on clouds from simulated pings of the tripod")
    rows, builds = registration(args.quick, say)
    out_dir = ROOT / "out"
    out_dir.mkdir(exist_ok=True)
    plot(rows, out_dir / "sonar_icp.png")
    say("part 2: the localizer on structures it was not tuned to")
    passes = structures(args.quick, say)

    ours = next(r for r in rows if r["label"] == "points 6dof n=800 it=30") if not args.quick else \
        next(r for r in rows if r["label"] == "points 6dof n=1600 it=30")
    arcs = next(r for r in rows if r["label"] == "arcs xy_yaw n=800")
    sg = [r for r in rows if r["family"] == "small_gicp"]
    best = min(sg, key=lambda r: (r["err_m"], r["ms"])) if sg else None
    fastest = min(sg, key=lambda r: r["ms"]) if sg else None
    kiss = next((r for r in rows if r["family"] == "kiss_icp"), None)
    keys = ("trusted", "wrong_trusted", "ambiguous", "final_err_m", "nav_err_m")
    headline = dict(
        structures={k: {key: v[key] for key in keys} for k, v in passes.items()},
        wrong_trusted_total=sum(v["wrong_trusted"] for v in passes.values()),
        final_worse_than_nav=[k for k, v in passes.items() if v["final_err_m"] > v["nav_err_m"] + 1e-6],
        icp_ms=ours["ms"], icp_err_m=ours["err_m"], icp_err_deg=ours["err_deg"],
        icp_arcs_ms=arcs["ms"], icp_arcs_err_m=arcs["err_m"], icp_arcs_err_deg=arcs["err_deg"],
        small_gicp_ms_best=best["ms"] if best else None, small_gicp_best=best["label"] if best else None,
        small_gicp_err_m_best=best["err_m"] if best else None, small_gicp_err_deg_best=best["err_deg"] if best else None,
        small_gicp_ms_fastest=fastest["ms"] if fastest else None,
        small_gicp_fastest=fastest["label"] if fastest else None,
        small_gicp_err_m_fastest=fastest["err_m"] if fastest else None,
        small_gicp_err_deg_fastest=fastest["err_deg"] if fastest else None,
        icp_arcs_check_ms=next(r for r in rows if r["family"] == "ours+yaw")["ms"],
        icp_arcs_check_trusted=next(r for r in rows if r["family"] == "ours+yaw")["trusted"],
        icp_arcs_check_wrong=next(r for r in rows if r["family"] == "ours+yaw")["wrong"],
        kiss_icp_ms=kiss["ms"] if kiss else None, kiss_icp_err_m=kiss["err_m"] if kiss else None,
        kiss_icp_err_deg=kiss["err_deg"] if kiss else None,
        model_build_ms=builds["ours"],
        ratio_icp_vs_small_gicp_best=ours["ms"] / best["ms"] if best else None,
        sources="simulated pings (tripod, 512 beams, speckle), lower-edge points / elevation arcs, 4 s windows",
        # the README formatter's keys, now from the fair measurement (ours 6 DOF on the same points as
        # small_gicp's best-accuracy setting)
        rot_err_deg=ours["err_deg"], trans_err_m=ours["err_m"], cpu_ms=ours["ms"],
        cpu_ms_with_ambiguity_check=next(r for r in rows if r["family"] == "ours+yaw")["ms"],
        cpu_ms_small_gicp=best["ms"] if best else None, rot_err_deg_small_gicp=best["err_deg"] if best else None,
        trans_err_m_small_gicp=best["err_m"] if best else None,
        cpu_ms_small_gicp_plane=fastest["ms"] if fastest else None,
        rot_err_deg_small_gicp_plane=fastest["err_deg"] if fastest else None,
        trans_err_m_small_gicp_plane=fastest["err_m"] if fastest else None,
        trials=int(builds.pop("windows")), goal_rot_deg=0.5, goal_trans_m=0.03, plot=str(out_dir / "sonar_icp.png"))
    headline["build_ms"] = builds
    if args.json:
        print(json.dumps(headline))
        return
    print(f"\n{'method':<46} {'dof':<7} {'cpu ms':>7} {'err m':>7} {'err deg':>8} {'max m':>7} {'max deg':>8} "
          f"{'trusted (wrong)':>16}")
    for r in sorted(rows, key=lambda r: (r["family"], r["ms"])):
        judged = f"{r['trusted']} ({r['wrong']})" if "trusted" in r else "-"
        print(f"{r['family'] + ' ' + r['label']:<46} {r['dof']:<7} {r['ms']:7.1f} {r['err_m']:7.3f} {r['err_deg']:8.2f} "
              f"{r['err_m_max']:7.3f} {r['err_deg_max']:8.2f} {judged:>16}")
    print("\nbuilt once: " + ", ".join(f"{k} {v:.0f} ms" for k, v in builds.items()))
    print(f"{headline['trials']} windows")
    print(f"\n{'structure @ heading error':<26} {'trusted':>7} {'wrong':>5} {'ambig':>5} {'gated':>5} {'final m':>8} "
          f"{'nav m':>7}")
    for k, v in passes.items():
        print(f"{k:<26} {v['trusted']:7d} {v['wrong_trusted']:5d} {v['ambiguous']:5d} {v['gated']:5d} "
              f"{v['final_err_m']:8.3f} {v['nav_err_m']:7.3f}")
    print(f"wrong trusted corrections, all structures: {headline['wrong_trusted_total']}; plot: {headline['plot']}")


if __name__ == "__main__":
    main()
