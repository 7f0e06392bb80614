"""Tripod ICP benchmark: rotation/translation error and single-thread CPU ms vs iterations and subsampling,
side by side with small_gicp (and Open3D when importable).

Second part, the simulated pass: 8 s of the boat's approach rendered by ``sim.fls`` (speckle,
256 beams), line scans built with a drifting navigation pose (0.4 m, -0.3 m, 3 deg), then the
drift recovered from lower-edge points (eq. 13) or from elevation arcs, with 6 DOF or x/y/yaw
(error of the corrected navigation pose at the last ping against the simulator's truth).

Scene: the paper's windmill tripod (``nodes.sonar.model.tripod_model``, pylons included). A view is
2,000 points: 1,900 surface samples facing a sonar 1 m below the surface about 14 m south of the
tripod (130 deg fan, no occlusion), with 3 cm range noise and 1 deg elevation noise, plus 100
outliers (5%) uniform in the view's bounding box. The view is offset by 10 deg yaw and 0.5 m;
every method starts from that offset. Errors are of (estimate o offset) at the tripod axis,
medians over trials. CPU time is ``time.process_time`` with one thread everywhere.

    python bench/sonar_icp.py [--quick] [--json]
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from nodes.sonar.arcs import arcs_from_scan  # noqa: E402
from nodes.sonar.highlight import extract_line_scan  # noqa: E402
from nodes.sonar.icp import IcpModel, IcpSettings, align  # noqa: E402
from nodes.sonar.model import tripod_model  # noqa: E402

YAW_OFFSET_DEG, SHIFT_M = 10.0, 0.5


def make_view(model_pts: np.ndarray, model_nrm: np.ndarray, seed: int, *, n: int = 2000,
              outlier_frac: float = 0.05, sonar=(1.0, -14.0, -1.0), range_sigma_m: float = 0.03,
              elevation_sigma_deg: float = 1.0) -> np.ndarray:
    """A partial noisy view (n, 3) of the model as a forward-looking sonar's cloud would give it."""
    rng = np.random.default_rng(seed)
    s = np.asarray(sonar, float)
    v = model_pts - s
    facing = np.einsum("ij,ij->i", -v, model_nrm) > 0
    azimuth = np.degrees(np.arctan2(v[:, 0], v[:, 1]))          # from north (the sonar looks north)
    cand = model_pts[facing & (np.abs(azimuth) < 65) & (np.linalg.norm(v, axis=1) < 30)]
    n_out = int(round(outlier_frac * n))
    pts = cand[rng.choice(len(cand), n - n_out, replace=False)]
    d = pts - s
    r = np.linalg.norm(d, axis=1) + rng.normal(0, range_sigma_m, len(d))
    az = np.arctan2(d[:, 1], d[:, 0])
    el = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) + np.radians(rng.normal(0, elevation_sigma_deg, len(d)))
    noisy = s + r[:, None] * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    lo, hi = noisy.min(axis=0) - 1.0, noisy.max(axis=0) + 1.0
    out = np.vstack([noisy, rng.uniform(lo, hi, (n_out, 3))])
    return out[rng.permutation(len(out))]


def offset(seed: int) -> np.ndarray:
    """10 deg yaw about the tripod axis and a 0.5 m horizontal shift in a seeded direction."""
    a = np.radians(YAW_OFFSET_DEG) * (1 if seed % 2 == 0 else -1)
    d = np.random.default_rng(1000 + seed).uniform(0, 2 * np.pi)
    t = np.eye(4)
    t[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    t[:3, 3] = [SHIFT_M * np.cos(d), SHIFT_M * np.sin(d), 0.0]
    return t


def errors(estimate: np.ndarray, off: np.ndarray) -> tuple[float, float]:
    """Rotation (deg) and translation (m, at the tripod axis, mid-depth) of estimate o offset."""
    c = estimate @ off
    rot = np.degrees(np.arccos(np.clip((np.trace(c[:3, :3]) - 1) / 2, -1, 1)))
    pivot = np.array([0.0, 0.0, -4.0])
    return float(rot), float(np.linalg.norm(c[:3, :3] @ pivot + c[:3, 3] - pivot))


def summary(rot: list[float], tr: list[float], ms: list[float], ambiguous: int = 0) -> dict:
    """Median and worst rotation (deg) / translation (m) errors and median time (ms) over the views."""
    return dict(rot=float(np.median(rot)), trans=float(np.median(tr)), ms=float(np.median(ms)),
                rot_max=float(np.max(rot)), trans_max=float(np.max(tr)), ambiguous=ambiguous)


def run_ours(views, model, settings: IcpSettings) -> dict:
    rot, tr, ms, amb = [], [], [], 0
    for cloud, off in views:
        t0 = time.process_time()
        out = align(cloud, model, settings=settings)
        ms.append((time.process_time() - t0) * 1e3)
        r, t = errors(out.transform, off)
        rot.append(r)
        tr.append(t)
        amb += out.ambiguous
    return summary(rot, tr, ms, amb)


def run_small_gicp(views, target_pts, kind: str, downsample_m: float, iterations: int) -> dict | None:
    try:
        import small_gicp
    except ImportError:
        return None
    rot, tr, ms = [], [], []
    for cloud, off in views:
        t0 = time.process_time()
        res = small_gicp.align(target_pts, cloud, registration_type=kind, downsampling_resolution=downsample_m,
                               max_correspondence_distance=1.0, num_threads=1, max_iterations=iterations)
        ms.append((time.process_time() - t0) * 1e3)
        r, t = errors(res.T_target_source, off)
        rot.append(r)
        tr.append(t)
    return summary(rot, tr, ms)


def run_small_gicp_prebuilt(views, target_pts, downsample_m: float) -> dict | None:
    """small_gicp with the target (model) preprocessed once, like our cached model tree."""
    try:
        import small_gicp
    except ImportError:
        return None
    target, tree = small_gicp.preprocess_points(target_pts, downsampling_resolution=downsample_m, num_threads=1)
    rot, tr, ms = [], [], []
    for cloud, off in views:
        t0 = time.process_time()
        src, _ = small_gicp.preprocess_points(cloud, downsampling_resolution=downsample_m, num_threads=1)
        res = small_gicp.align(target, src, tree, registration_type="GICP", max_correspondence_distance=1.0,
                               num_threads=1)
        ms.append((time.process_time() - t0) * 1e3)
        r, t = errors(res.T_target_source, off)
        rot.append(r)
        tr.append(t)
    return summary(rot, tr, ms)


def run_open3d(views, model_pts, model_nrm) -> dict | None:
    try:
        import open3d as o3d
    except ImportError:
        return None
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model_pts))
    target.normals = o3d.utility.Vector3dVector(model_nrm)
    rot, tr, ms = [], [], []
    for cloud, off in views:
        t0 = time.process_time()
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
        res = o3d.pipelines.registration.registration_icp(
            src, target, 1.0, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane())
        ms.append((time.process_time() - t0) * 1e3)
        r, t = errors(res.transformation, off)
        rot.append(r)
        tr.append(t)
    return summary(rot, tr, ms)


def simulated_pass(model: IcpModel, quick: bool) -> list[dict]:
    """Lower-edge points vs elevation arcs, 6 DOF vs x/y/yaw, on a rendered approach of the tripod."""
    import math

    from sim.fls import PingSettings, load_scene, render_ping

    scene = load_scene("tripod")
    rng = np.random.default_rng(0)
    a = math.radians(3.0)
    drift = np.eye(4)
    drift[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    drift[:2, 3] = (0.4, -0.3)
    scans = []
    for t in np.arange(10.5, 18.5, 0.5 if quick else 0.25):
        truth = scene.sonar_pose(float(t))
        ping = render_ping(scene, truth, PingSettings(n_beams=256, range_m=20.0), rng=rng)
        nav = drift @ truth
        down = nav[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        scan = extract_line_scan(ping.intensities, ping.bearings_rad, ping.range_resolution_m,
                                 altitude_m=float(nav[2, 3] + 6.0), tilt_rad=math.asin(down[0]),
                                 spread_rad=ping.vertical_aperture_rad, down_frd=down, include_seafloor=False)
        scans.append((truth, nav, scan.points_m))
    truth, nav = scans[-1][0], scans[-1][1]

    def error(correction: np.ndarray) -> tuple[float, float]:
        est = correction @ nav
        dh = math.atan2(est[1, 0], est[0, 0]) - math.atan2(truth[1, 0], truth[0, 0])
        return float(np.linalg.norm(est[:3, 3] - truth[:3, 3])), abs(math.degrees(math.remainder(dh, 2 * math.pi)))

    rows = []
    nav_err = error(np.eye(4))
    rows.append(dict(source="navigation alone", dof="-", n=0, err_m=nav_err[0], err_deg=nav_err[1], ms=0.0))
    points = np.concatenate([p @ n[:3, :3].T + n[:3, 3] for _, n, p in scans])
    cases = [("lower-edge points", 1, dof) for dof in ("all", "xy_yaw")]
    cases += [(f"arcs K={k}", k, dof) for k in ((5, 9) if quick else (5, 9, 15)) for dof in ("all", "xy_yaw")]
    for name, k, dof in cases:
        src = points if k == 1 else np.concatenate([arcs_from_scan(p, n, k) for _, n, p in scans])
        settings = IcpSettings(dof=dof)
        t0 = time.process_time()
        out = align(src, model, settings=settings)
        ms = (time.process_time() - t0) * 1e3
        e = error(out.transform)
        rows.append(dict(source=name, dof=dof, n=len(src), err_m=e[0], err_deg=e[1], ms=ms,
                         trusted=out.converged and not out.degenerate and not out.ambiguous))
    return rows


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_r, ax_t) = plt.subplots(1, 2, figsize=(13, 5))
    for row in rows:
        colour = {"ours": "C0", "ours+yaw": "C2", "small_gicp": "C1", "open3d": "C3"}[row["family"]]
        for ax, key in ((ax_r, "rot"), (ax_t, "trans")):
            ax.scatter(row["ms"], row[key] * (100 if key == "trans" else 1), color=colour, s=25)
            ax.annotate(row["label"], (row["ms"], row[key] * (100 if key == "trans" else 1)), fontsize=6)
    for ax, goal, unit in ((ax_r, 0.5, "deg"), (ax_t, 3.0, "cm")):
        ax.axhline(goal, ls="--", color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("single-thread CPU ms per alignment (median)")
        ax.set_ylabel(f"median error ({unit})")
        for fam, c in (("ours", "C0"), ("ours+yaw", "C2"), ("small_gicp", "C1"), ("open3d", "C3")):
            ax.scatter([], [], color=c, label=fam)
        ax.legend(fontsize=8)
    ax_r.set_title("rotation error vs CPU time (dashed: goal)")
    ax_t.set_title("translation error vs CPU time (dashed: goal)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer trials and settings")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the headline figures")
    args = parser.parse_args()
    trials = 4 if args.quick else 12
    pts, nrm = tripod_model(spacing_m=0.1)
    t0 = time.process_time()
    model = IcpModel.build(pts, nrm, grid_m=0.1)
    build_ms = (time.process_time() - t0) * 1e3
    kd_model = IcpModel.build(pts, nrm)
    views = []
    for seed in range(trials):
        off = offset(seed)
        cloud = make_view(pts, nrm, seed)
        views.append((cloud @ off[:3, :3].T + off[:3, 3], off))
    rows: list[dict] = []

    def add(family: str, label: str, res: dict | None) -> None:
        if res is not None:
            rows.append(dict(family=family, label=label, **res))

    subsamples = [400, 800] if args.quick else [200, 400, 800, 1600]
    iterations = [10, 30] if args.quick else [5, 10, 20, 30]
    for n in subsamples:
        for it in iterations:
            add("ours", f"grid n={n} it={it}", run_ours(views, model, IcpSettings(yaw_hypotheses=0, max_points=n,
                                                                                 max_iterations=it)))
    add("ours", "kdtree n=800", run_ours(views, kd_model, IcpSettings(yaw_hypotheses=0)))
    add("ours", "kdtree p2p n=800", run_ours(views, kd_model, IcpSettings(yaw_hypotheses=0, method="point_to_point")))
    add("ours+yaw", "grid n=800 +6 yaw restarts", run_ours(views, model, IcpSettings()))
    for kind in ("GICP", "PLANE_ICP", "ICP"):
        for ds in ((0.25,) if args.quick else (0.1, 0.25)):
            for it in ((20,) if args.quick else (10, 20)):
                add("small_gicp", f"{kind} ds={ds} it={it}", run_small_gicp(views, pts, kind, ds, it))
    add("small_gicp", "GICP prebuilt target ds=0.25", run_small_gicp_prebuilt(views, pts, 0.25))
    add("open3d", "open3d point-to-plane", run_open3d(views, pts, nrm))
    out_dir = ROOT / "out"
    out_dir.mkdir(exist_ok=True)
    plot(rows, out_dir / "sonar_icp.png")
    pass_rows = simulated_pass(model, args.quick)
    arc_row = next(r for r in pass_rows if r["source"] == "arcs K=9" and r["dof"] == "xy_yaw")
    pt_row = next(r for r in pass_rows if r["source"] == "lower-edge points" and r["dof"] == "xy_yaw")
    pt6_row = next(r for r in pass_rows if r["source"] == "lower-edge points" and r["dof"] == "all")

    ours = next(r for r in rows if r["label"] == "grid n=800 it=30")
    ours_yaw = next(r for r in rows if r["family"] == "ours+yaw")
    ref = next((r for r in rows if r["label"] == "GICP ds=0.25 it=20"), None)
    ref_plane = next((r for r in rows if r["label"] == "PLANE_ICP ds=0.25 it=20"), None)
    headline = dict(rot_err_deg=ours["rot"], trans_err_m=ours["trans"], cpu_ms=ours["ms"],
                    cpu_ms_with_ambiguity_check=ours_yaw["ms"],
                    cpu_ms_small_gicp=ref["ms"] if ref else None,
                    rot_err_deg_small_gicp=ref["rot"] if ref else None,
                    trans_err_m_small_gicp=ref["trans"] if ref else None,
                    cpu_ms_small_gicp_plane=ref_plane["ms"] if ref_plane else None,
                    rot_err_deg_small_gicp_plane=ref_plane["rot"] if ref_plane else None,
                    trans_err_m_small_gicp_plane=ref_plane["trans"] if ref_plane else None,
                    ratio_cpu_vs_small_gicp=ours["ms"] / ref["ms"] if ref else None,
                    model_build_ms=build_ms, trials=trials, goal_rot_deg=0.5, goal_trans_m=0.03,
                    pass_arcs_err_m=arc_row["err_m"], pass_arcs_err_deg=arc_row["err_deg"],
                    pass_arcs_cpu_ms=arc_row["ms"], pass_points_err_m=pt_row["err_m"],
                    pass_points_err_deg=pt_row["err_deg"], pass_points_6dof_err_m=pt6_row["err_m"],
                    pass_nav_err_m=pass_rows[0]["err_m"],
                    plot=str(out_dir / "sonar_icp.png"))
    if args.json:
        print(json.dumps(headline))
        return
    print(f"tripod view: 2000 pts (5% outliers), offset {YAW_OFFSET_DEG:.0f} deg / {SHIFT_M} m, {trials} trials, medians")
    print(f"{'method':<34} {'cpu ms':>7} {'rot deg':>8} {'trans cm':>9} {'max rot':>8} {'max cm':>7} {'amb':>4}")
    for r in rows:
        print(f"{r['family'] + ' ' + r['label']:<34} {r['ms']:7.1f} {r['rot']:8.3f} {100 * r['trans']:9.2f} "
              f"{r['rot_max']:8.2f} {100 * r['trans_max']:7.1f} {r['ambiguous']:4d}")
    if ref:
        print(f"\nours (grid, 800 pts): {ours['ms']:.1f} ms, {ours['rot']:.3f} deg, {100 * ours['trans']:.2f} cm; "
              f"with 6 yaw restarts {ours_yaw['ms']:.1f} ms; small_gicp GICP {ref['ms']:.1f} ms "
              f"({ref['rot']:.2f} deg, {100 * ref['trans']:.1f} cm); ratio {headline['ratio_cpu_vs_small_gicp']:.2f}; "
              f"model + grid build once: {build_ms:.0f} ms")
    print("\nsimulated pass (8 s approach, drifting navigation): error of the corrected pose at the last ping")
    print(f"{'source':<20} {'dof':<7} {'n':>6} {'err m':>7} {'err deg':>8} {'cpu ms':>7} {'trusted':>8}")
    for r in pass_rows:
        print(f"{r['source']:<20} {r['dof']:<7} {r['n']:6d} {r['err_m']:7.3f} {r['err_deg']:8.3f} {r['ms']:7.1f} "
              f"{str(r.get('trusted', '-')):>8}")
    print(f"plot: {headline['plot']}")


if __name__ == "__main__":
    main()
