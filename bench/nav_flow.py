"""RGB-D flow benchmark: flow method and resolution vs end-point error vs ms per frame; perception rate.

(a) Synthetic warps with known flow on a rendered 640x480 crowd image: a smooth field
    (turn + zoom + local waves, up to ~12 px) and a piecewise one (background shift plus
    moving blobs with sharp borders). End-point error (px, mean over interior pixels) and
    ms per frame for Farneback presets (the paper's method) vs DIS presets (cv2), at full and
    reduced resolution, side by side; OpenCV's TV-L1 as a slow accuracy reference (full run).
(b) Scene-flow velocity error (m/s) on the crowd simulator (hallway, robot driving and
    turning), per method: a point's truth is its pedestrian's velocity (points within the
    body radius) or zero; medians on pedestrian points and on static points.
(c) Perception rate at 640x480: render + flow + features per frame (the default node setup).
(d) Moving points during fast turns (issue 18: phantom predicted obstacles), the node's default
    settings ("before": no forward-backward check, holes not depth edges) and with both options on
    ("now": fb_max_px 1, hole_edges; off by default, see nodes/nav/rgbd_flow.py), on the same frames: the
    robot weaves (yaw rate 1.2 cos(2 pi t / 1.6 s) rad/s at 0.5 m/s) through a static room, the
    hallway and students003 (needs ../shared/data). Within the guard's reach (3.5 m), a point is
    "moving" at >= 0.3 m/s (the guard's moving_mps); precision = moving points on a walker that
    walks (>= 0.3 m/s) with a velocity within 0.5 m/s of its; wrong = the other moving points, per
    frame (phantom max: the fastest moving point not on a walker); walker recall = walkers
    (0.8-3.5 m, inside the view) with >= 3 moving points (the guard's hold_min_points); velocity
    error (m/s, median and p95) on walker points.

    python bench/nav_flow.py [--quick] [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.nav.features import GridSpec, extract_features, goal_in_robot_frame  # noqa: E402
from nodes.nav.flow import FlowTracker, Intrinsics, Mount, OpticalFlow, to_gray  # noqa: E402
from nodes.nav.rgbd_flow import Config as FlowConfig  # noqa: E402
from sim.crowd import CrowdWorld  # noqa: E402

DT = 1 / 15


def base_image() -> np.ndarray:
    world = CrowdWorld("hallway")
    world.step(0.5, 0.0, 3.0)
    return to_gray(world.render()[0])


def smooth_field(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    cx, cy = w / 2, h / 2
    a, zoom = rng.uniform(-0.01, 0.01), rng.uniform(-0.02, 0.02)
    fx = rng.uniform(-4, 4) + zoom * (x - cx) - a * (y - cy) + 3 * np.sin(2 * np.pi * y / 180 + rng.uniform(0, 6))
    fy = rng.uniform(-2, 2) + zoom * (y - cy) + a * (x - cx) + 2 * np.cos(2 * np.pi * x / 240 + rng.uniform(0, 6))
    return np.stack([fx, fy], axis=2).astype(np.float32)


def piecewise_field(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    field = np.zeros((h, w, 2), np.float32)
    field[..., 0] = rng.uniform(-6, 6)
    y, x = np.mgrid[0:h, 0:w]
    for _ in range(5):
        cx, cy, rx, ry = rng.uniform(80, w - 80), rng.uniform(100, h - 60), rng.uniform(25, 60), rng.uniform(60, 150)
        inside = ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 < 1
        field[inside] = rng.uniform(-8, 8, 2)
    return field


def warp_pairs(quick: bool) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(first, second, truth) with first(q) = second(q + truth(q)), i.e. truth is the flow first -> second."""
    img = base_image()
    h, w = img.shape
    rng = np.random.default_rng(4)
    pairs = []
    for make in (smooth_field, piecewise_field) * (1 if quick else 2):
        g = make(h, w, rng)
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        second = cv2.remap(img, x - g[..., 0], y - g[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        pairs.append((second, img, -g))        # second(q) = img(q - g(q)): flow second -> img is -g
    return pairs


def epe_table(methods: list[tuple[str, float]], pairs, repeats: int) -> dict[str, tuple[float, float]]:
    """Mean EPE (px) and median ms per method; methods are timed round-robin so load hits all alike."""
    ests = {f"{p}@{s:g}": OpticalFlow(p, s) for p, s in methods}
    times: dict[str, list[float]] = {k: [] for k in ests}
    errs: dict[str, list[float]] = {k: [] for k in ests}
    border = 16
    for first, second, truth in pairs:
        for name, est in ests.items():
            flow = est(first, second)                # warm-up and the accuracy sample
            err = np.linalg.norm(flow.full() - truth, axis=2)[border:-border, border:-border]
            errs[name].append(float(err.mean()))
        for _ in range(repeats):
            for name, est in ests.items():
                t = time.perf_counter()
                est(first, second)
                times[name].append(time.perf_counter() - t)
    return {k: (float(np.mean(errs[k])), 1e3 * float(np.median(times[k]))) for k in ests}


def tvl1_reference(pairs) -> tuple[float, float]:
    tvl1 = cv2.optflow.DualTVL1OpticalFlow_create()
    first, second, truth = pairs[0]
    t = time.perf_counter()
    flow = tvl1.calc(first, second, None)
    ms = 1e3 * (time.perf_counter() - t)
    return float(np.linalg.norm(flow - truth, axis=2)[16:-16, 16:-16].mean()), ms


def velocity_errors(methods: list[tuple[str, float]], frames: int) -> dict[str, tuple[float, float]]:
    """Median |v_est - v_true| (m/s, xy) on pedestrian points and on static points of a hallway drive."""
    world = CrowdWorld("hallway")
    world.step(0.5, 0.0, 2.0)
    recs = []
    for _ in range(frames + 1):
        rgb, depth = world.render()
        recs.append((world.t_s, rgb, depth, world.pose, world.pedestrians()))
        world.step(0.5, 0.15, DT)
    cam = world.camera
    intr, mount = Intrinsics(cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px), Mount(cam.x_m, cam.y_m, cam.z_m)
    out = {}
    for preset, scale in methods:
        tracker = FlowTracker(mount, preset=preset, scale=scale)
        moving, still = [], []
        for t, rgb, depth, pose, peds in recs:
            sf = tracker.update(t, rgb, depth, intr, pose)
            if sf is None:
                continue
            truth, on_ped = true_velocity(sf.points_m, pose, peds)
            err = np.linalg.norm(sf.velocity_mps[:, :2] - truth, axis=1)
            moving.append(err[on_ped])
            still.append(err[~on_ped])
        out[f"{preset}@{scale:g}"] = (float(np.median(np.concatenate(moving))), float(np.median(np.concatenate(still))))
    return out


def true_velocity(points: np.ndarray, pose, peds) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth (vx, vy) in the robot frame of each point (its pedestrian's velocity, else 0), and on-pedestrian mask."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, s], [-s, c]])                    # world -> robot
    truth = np.zeros((len(points), 2))
    on_ped = np.zeros(len(points), bool)
    for k in range(len(peds.ids)):
        centre = rot @ (peds.xy_m[k] - np.asarray(pose[:2]))
        near = np.linalg.norm(points[:, :2] - centre, axis=1) < peds.radius_m[k] + 0.05
        truth[near] = rot @ peds.vel_mps[k]
        on_ped |= near
    return truth, on_ped


ROOM = {"name": "room", "walls": [{"points": [[-6, -6], [6, -6], [6, 6], [-6, 6], [-6, -6]], "height_m": 2.5}],
        "robot": {"x_m": -2.0, "y_m": 0.5, "yaw_rad": 0.3},
        "obstacles": [{"cylinder": {"x_m": 1.0, "y_m": 0.6, "radius_m": 0.3}, "height_m": 2.0},
                      {"box": {"x_m": 0.0, "y_m": -1.5, "length_m": 1.0, "width_m": 1.0}, "height_m": 1.2},
                      {"cylinder": {"x_m": -2.0, "y_m": 2.2, "radius_m": 0.25}, "height_m": 1.8},
                      {"box": {"x_m": -3.5, "y_m": -0.5, "length_m": 0.6, "width_m": 0.6}, "height_m": 1.0}]}
REACH_M, MOVING_MPS, HOLD_POINTS = 3.5, 0.3, 3     # the collision guard's check_m + 1, moving_mps, hold_min_points
RIGHT_MPS = 0.5                                      # a moving point on a walker is right when this near its velocity
FLOW_SETTINGS = {"before": {"fb_max_px": 0.0, "hole_edges": False}, "now": {"fb_max_px": 1.0, "hole_edges": True}}


def weave_frames(scene, frames: int, camera) -> list:
    """(t, rgb, depth, pose, pedestrians) of a robot weaving at 0.5 m/s, yaw rate 1.2 cos(2 pi t / 1.6 s)."""
    world = CrowdWorld(scene, camera=camera)
    out = []
    for k in range(frames + 1):
        world.step(0.5, 1.2 * np.cos(2 * np.pi * k * DT / 1.6), DT)
        rgb, depth = world.render()
        out.append((world.t_s, rgb, depth, world.pose, world.pedestrians()))
    return out


def moving_points(recs, camera) -> dict[str, dict[str, float]]:
    """Per flow setting: moving-point precision, phantoms per frame, walker recall, walker velocity errors."""
    intr = Intrinsics(camera.fx_px, camera.fy_px, camera.cx_px, camera.cy_px)
    cfg = FlowConfig()
    half_fov = np.arctan2(camera.cx_px, camera.fx_px) - np.radians(5)
    out = {}
    for name, over in FLOW_SETTINGS.items():
        knobs = {"fb_max_px": cfg.fb_max_px, "hole_edges": cfg.hole_edges, **over}
        tracker = FlowTracker(Mount(camera.x_m, camera.y_m, camera.z_m), preset=cfg.method, border_px=cfg.border_px,
                              max_vertical_mps=cfg.max_vertical_mps, max_speed_mps=cfg.max_speed_mps, **knobs)
        n_frames, n_moving, n_true, n_points, walkers, found, errs, worst = 0, 0, 0, 0, 0, 0, [], 0.0
        for t, rgb, depth, pose, peds in recs:
            sf = tracker.update(t, rgb, depth, intr, pose)
            if sf is None:
                continue
            n_frames += 1
            truth, on_ped = true_velocity(sf.points_m, pose, peds)
            speed = np.hypot(sf.velocity_mps[:, 0], sf.velocity_mps[:, 1])
            near = np.hypot(sf.points_m[:, 0], sf.points_m[:, 1]) <= REACH_M
            walking = on_ped & (np.hypot(truth[:, 0], truth[:, 1]) >= MOVING_MPS)
            moving = near & (speed >= MOVING_MPS)
            n_points += int(near.sum())
            n_moving += int(moving.sum())
            err = np.linalg.norm(sf.velocity_mps[:, :2] - truth, axis=1)
            n_true += int((moving & walking & (err < RIGHT_MPS)).sum())
            worst = max(worst, float(speed[moving & ~walking].max(initial=0.0)))
            errs.append(err[walking & near])
            c, s = np.cos(pose[2]), np.sin(pose[2])
            for k in range(len(peds.ids)):
                rel = np.array([[c, s], [-s, c]]) @ (peds.xy_m[k] - np.asarray(pose[:2]))
                rng = float(np.hypot(*rel))
                if (np.hypot(*peds.vel_mps[k]) < MOVING_MPS or not 0.8 <= rng <= REACH_M
                        or abs(np.arctan2(rel[1], rel[0] - camera.x_m)) > half_fov):
                    continue
                walkers += 1
                mine = np.linalg.norm(sf.points_m[:, :2] - rel, axis=1) < peds.radius_m[k] + 0.05
                found += int((mine & moving).sum() >= HOLD_POINTS)
        e = np.concatenate(errs) if errs else np.zeros(0)
        out[name] = {"frames": n_frames, "points_per_frame": round(n_points / max(n_frames, 1), 1),
                     "precision": round(n_true / n_moving, 4) if n_moving else None,
                     "wrong_per_frame": round((n_moving - n_true) / max(n_frames, 1), 2),
                     "phantom_max_mps": round(worst, 2),
                     "walker_recall": round(found / walkers, 4) if walkers else None, "walkers": walkers,
                     "walker_vel_err_mps": round(float(np.median(e)), 3) if len(e) else None,
                     "walker_vel_err_p95_mps": round(float(np.percentile(e, 95)), 3) if len(e) else None}
    return out


def turn_scenes(frames: int) -> dict[str, dict[str, dict[str, float]]]:
    from sim.irl_demos import sim_camera
    cam = sim_camera()
    scenes = {"static room": ROOM, "hallway": "hallway"}
    if (REPO.parent / "shared" / "data" / "pedestrians").is_dir():
        scenes["students003"] = "students003"
    else:
        print("students003 skipped: ../shared/data/pedestrians is absent", file=sys.stderr)
    out = {}
    for name, scene in scenes.items():
        print(f"(d) fast turns: {name} ...", file=sys.stderr, flush=True)
        out[name] = moving_points(weave_frames(scene, frames, cam), cam)
    return out


def perception_rate(frames: int, preset: str = "dis_fast", scale: float = 1.0) -> dict[str, float]:
    """Median ms per stage of render -> flow (FlowTracker, what RgbdFlow runs) -> features on a hallway drive."""
    world = CrowdWorld("hallway")
    cam = world.camera
    intr = Intrinsics(cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px)
    tracker = FlowTracker(Mount(cam.x_m, cam.y_m, cam.z_m), preset=preset, scale=scale)
    grid = GridSpec()
    stages: dict[str, list[float]] = {"render": [], "flow": [], "features": [], "total": [], "total_cpu": []}
    for _ in range(frames + 1):
        world.step(0.6, 0.1, DT)
        c0 = time.process_time()
        t0 = time.perf_counter()
        rgb, depth = world.render()
        t1 = time.perf_counter()
        sf = tracker.update(world.t_s, rgb, depth, intr, world.pose)
        t2 = time.perf_counter()
        if sf is None:
            continue
        extract_features(sf.points_m, sf.velocity_mps, goal_in_robot_frame(world.goal[:2], world.pose), grid)
        t3 = time.perf_counter()
        stages["total_cpu"].append(1e3 * (time.process_time() - c0))     # all threads: load-independent-ish
        for k, v in (("render", t1 - t0), ("flow", t2 - t1), ("features", t3 - t2), ("total", t3 - t0)):
            stages[k].append(1e3 * v)
    return {k: float(np.median(v)) for k, v in stages.items()}


def plot(table: dict[str, tuple[float, float]], ref: tuple[float, float] | None, stages: dict[str, float],
         path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw={"width_ratios": [2, 1]})
    for name, (epe, ms) in table.items():
        colour = "tab:red" if name.startswith("farneback") else "tab:blue"
        ax.scatter(ms, epe, c=colour, marker="o" if name.endswith("@1") else "s")
        ax.annotate(name, (ms, epe), fontsize=8, xytext=(4, 3), textcoords="offset points")
    if ref is not None:
        ax.scatter(ref[1], ref[0], c="k", marker="*", s=90)
        ax.annotate("tv-l1 (reference)", (ref[1], ref[0]), fontsize=8, xytext=(4, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (640x480, log)")
    ax.set_ylabel("mean end-point error (px)")
    ax.set_title("optical flow: time vs error (red Farneback, blue DIS; circle full res, square reduced)")
    ax.grid(True, which="both", alpha=0.3)
    names = ["render", "flow", "features"]
    bx.bar(names, [stages[n] for n in names], color=["tab:gray", "tab:blue", "tab:green"])
    bx.set_ylabel("ms per frame (median)")
    bx.set_title(f"perception at 640x480:\n{1e3 / stages['total']:.1f} Hz wall clock, "
                 f"{1e3 / stages['total_cpu']:.1f} Hz by CPU time")
    save_figure(fig, path, dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer methods, warps and frames")
    ap.add_argument("--json", action="store_true", help="print one JSON object with the headline figures")
    args = ap.parse_args()
    cv2.setRNGSeed(0)
    if args.quick:
        methods = [("farneback", 1.0), ("farneback", 0.5), ("dis_fast", 1.0), ("dis_medium", 1.0), ("dis_fast", 0.5)]
    else:
        methods = [(p, s) for s in (1.0, 0.5) for p in ("farneback_fast", "farneback", "farneback_accurate",
                                                        "dis_ultrafast", "dis_fast", "dis_medium")]
    pairs = warp_pairs(args.quick)
    table = epe_table(methods, pairs, repeats=2 if args.quick else 5)
    ref = None if args.quick else tvl1_reference(pairs)
    vel = velocity_errors(methods, frames=4 if args.quick else 12)
    stages = perception_rate(frames=15 if args.quick else 60)
    turns = turn_scenes(frames=24 if args.quick else 90)
    plot(table, ref, stages, REPO / "out" / "nav_flow.png")
    hz = 1e3 / stages["total"]
    if args.json:
        print(json.dumps({"flow_epe_px": {k: round(v[0], 4) for k, v in table.items()},
                          "flow_ms": {k: round(v[1], 2) for k, v in table.items()},
                          "velocity_err_mps": {k: round(v[0], 4) for k, v in vel.items()},
                          "static_velocity_err_mps": {k: round(v[1], 4) for k, v in vel.items()},
                          "perception_hz": round(hz, 2),
                          "perception_hz_cpu": round(1e3 / stages["total_cpu"], 2),
                          "perception_ms": {k: round(v, 2) for k, v in stages.items()},
                          "fast_turn_moving_points": turns,
                          "load_average": round(os.getloadavg()[0], 2)}))
        return
    fb = table.get("farneback@1")
    print(f"{'method@scale':22s} {'EPE px':>8s} {'ms/frame':>9s} {'vs farneback@1':>15s} "
          f"{'ped vel err':>12s} {'static err':>11s}  (m/s, medians)")
    for name, (epe, ms) in sorted(table.items(), key=lambda kv: kv[1][1]):
        speedup = f"{fb[1] / ms:6.1f}x faster" if fb else ""
        print(f"{name:22s} {epe:8.3f} {ms:9.2f} {speedup:>15s} {vel[name][0]:12.3f} {vel[name][1]:11.3f}")
    if ref is not None:
        print(f"{'tv-l1@1 (reference)':22s} {ref[0]:8.3f} {ref[1]:9.1f}")
    print(f"perception at 640x480 (render + dis_fast flow + features): {hz:.1f} Hz wall clock "
          f"({1e3 / stages['total_cpu']:.1f} Hz by CPU time); median ms "
          + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()))
    print(f"\nfast turns (moving >= {MOVING_MPS} m/s within {REACH_M} m; flow settings before: no forward-backward "
          "check, holes not edges)")
    print(f"{'scene':12s} {'flow':7s} {'pts/frame':>9s} {'precision':>9s} {'wrong/frame':>11s} {'phantom max':>11s} "
          f"{'walker recall':>13s} "
          f"{'walker vel err med/p95 (m/s)':>29s}")
    for scene, rows in turns.items():
        for name, r in rows.items():
            rec = f"{r['walker_recall']:.3f} of {r['walkers']}" if r["walker_recall"] is not None else "-"
            prec = f"{r['precision']:.3f}" if r["precision"] is not None and r["walkers"] else "-"
            err = (f"{r['walker_vel_err_mps']:.3f} / {r['walker_vel_err_p95_mps']:.3f}"
                   if r["walker_vel_err_mps"] is not None else "-")
            print(f"{scene:12s} {name:7s} {r['points_per_frame']:9.0f} {prec:>9s} {r['wrong_per_frame']:11.2f} "
                  f"{r['phantom_max_mps']:11.2f} "
                  f"{rec:>13s} {err:>29s}")
    if os.getloadavg()[0] > os.cpu_count():
        print(f"note: load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores while measuring; "
              "times are inflated, compare ratios")
    print("plot: out/nav_flow.png")


if __name__ == "__main__":
    main()
