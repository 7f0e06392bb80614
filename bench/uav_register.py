"""UAV registration benchmark (seed 11): nadir frames registered to a geo-referenced map.

Real: the 18 frames of ../shared/data/uav/brighton_beach registered to its ortho render (search
mode: the whole image, two scales); the ortho georeferenced from the other 17 frames' GPS
(leave one out), the held-out frame's registered position against its own GPS (so the
figure includes GPS error, metres), its heading against the gimbal's yaw.

Simulated: 640x480 views of the procedural map (seed 0; the sweeps use seeds 100+ for the
poses) in localisation mode (window around a prediction 5 m off, altitude known to 3 %), swept
over the scale ratio (frame ground resolution / map resolution, 0.25-4), rotation (0-180 deg),
blur and exposure, for SIFT, ORB and AKAZE (the detectors in pip OpenCV; SURF is not).
Success: a fix within 3 map px of the truth; a fix further off counts as wrong (the worst
outcome). Closed loop: 10 seeded starts outside the map's footprint, INS drifting, homing to a
target inside; success = within 1 m in 150 s.

    python bench/uav_register.py [--quick] [--json] [--png OUT.png]

``--json`` keys: success_frac (SIFT, 0.5x-2x, any rotation), pos_err_px (median on success),
ms_per_frame (SIFT, localisation mode, median), homing_success_frac, by_method, sweeps, real,
homing.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.control.uav_homing import Homing  # noqa: E402
from nodes.vision.geolocate import GeoLocator  # noqa: E402
from nodes.vision.geomap import DATA, georeference, procedural_map, register_brighton  # noqa: E402
from nodes.vision.georegister import MapFeatures  # noqa: E402
from sim.aerial import CAMERA, Command, Look, Uav, UavState, render_nadir  # noqa: E402

METHODS = ("sift", "orb", "akaze")


def alt_for_ratio(ratio: float, m_per_px: float) -> float:
    return ratio * m_per_px * CAMERA.width_px / (2 * math.tan(math.radians(CAMERA.hfov_deg) / 2))


def trial(gm, mf, rng, *, ratio: float, yaw: float, look: Look) -> dict:
    alt = alt_for_ratio(ratio, gm.m_per_px)
    b = gm.world_bounds()
    e, n = rng.uniform(b[0] * 0.6, b[1] * 0.6)
    st = UavState(float(e), float(n), yaw, alt)
    img = render_nadir(gm, st, look=look, rng=rng)
    loc = GeoLocator(gm, mf)
    loc.mode = "localise"
    pred = (st.e + 5 * math.cos(yaw + 1), st.n + 5 * math.sin(yaw + 1))
    t0 = time.perf_counter()
    f = loc.locate(img, alt_m=alt * float(rng.uniform(0.97, 1.03)), predicted_en=pred)
    ms = 1000 * (time.perf_counter() - t0)
    err_px = math.hypot(f.e_m - st.e, f.n_m - st.n) / gm.m_per_px if f.ok else math.nan
    yaw_err = abs(math.degrees(math.remainder(f.yaw_rad - yaw, 2 * math.pi))) if f.ok else math.nan
    return dict(ok=f.ok and err_px <= 3, wrong=f.ok and err_px > 3, err_px=err_px, yaw_err_deg=yaw_err, ms=ms)


def summarise(rows: list[dict]) -> dict:
    ok = [r for r in rows if r["ok"]]
    return dict(success_frac=len(ok) / len(rows), wrong_frac=sum(r["wrong"] for r in rows) / len(rows),
                pos_err_px=float(np.median([r["err_px"] for r in ok])) if ok else None,
                yaw_err_deg=float(np.median([r["yaw_err_deg"] for r in ok])) if ok else None,
                ms=float(np.median([r["ms"] for r in rows])))


def real(log, methods) -> dict:
    if not DATA.exists():
        log("real data absent (../shared/data/uav): skipped")
        return {}
    out = {}
    for method in methods:
        t0 = time.perf_counter()
        _, fixes, rows, enu = register_brighton(method)
        ms = 1000 * (time.perf_counter() - t0) / len(fixes)
        ok = [k for k, f in enumerate(fixes) if f.ok]
        errs, head = [], []
        if len(ok) >= 4:
            C = np.array([fixes[k].centre_px for k in ok])
            for i in range(len(ok)):
                keep = [j for j in range(len(ok)) if j != i]
                G = georeference(C[keep], enu[ok][keep])
                errs.append(float(np.linalg.norm(C[i] @ G[:, :2].T + G[:, 2] - enu[ok][i])))
                up = G[:, :2] @ (fixes[ok[i]].T[:, :2] @ np.array([0.0, -1.0]))
                head.append(abs(math.degrees(math.remainder(
                    math.atan2(up[0], up[1]) - math.radians(float(rows[ok[i]]["xmp_gimbal_yaw"])), 2 * math.pi))))
        out[method] = dict(registered=len(ok), frames=len(fixes), pos_err_m_median=float(np.median(errs)) if errs else None,
                           pos_err_m_max=float(np.max(errs)) if errs else None,
                           heading_err_deg_median=float(np.median(head)) if head else None, ms_per_frame=ms)
        r = out[method]
        log(f"  real {method:5s}: {r['registered']}/{r['frames']} frames registered (search mode, 1000x562); "
            + (f"held-out position vs GPS {r['pos_err_m_median']:.2f} m median ({r['pos_err_m_max']:.2f} max), "
               f"heading vs gimbal {r['heading_err_deg_median']:.1f} deg; " if errs else "")
            + f"{ms:.0f} ms per frame")
    return out


def homing(gm, mf, seed: int, *, duration_s: float = 150.0) -> dict:
    """In-process closed loop: the locator and homing law the launch file's nodes run."""
    rng = np.random.default_rng(seed)
    b = gm.world_bounds()
    ang = rng.uniform(0, 2 * math.pi)
    r = (b[1, 0] - b[0, 0]) / 2 * 1.3                      # outside the footprint
    uav = Uav(UavState(r * math.cos(ang), r * math.sin(ang), rng.uniform(-math.pi, math.pi), 45.0))
    target = (float(rng.uniform(-40, 40)), float(rng.uniform(-40, 40)), float(rng.uniform(-3, 3)), 40.0)
    loc, home = GeoLocator(gm, mf), Homing(target)
    drift = np.zeros(2)
    dt, t, reached = 0.1, 0.0, None
    while t < duration_s:
        s = uav.state
        drift += rng.normal(0, 0.5 * math.sqrt(dt), 2)
        ins = np.array([s.e, s.n]) + drift
        if round(t / dt) % 2 == 0:                          # camera at 5 Hz
            f = loc.locate(render_nadir(gm, s, rng=rng), alt_m=s.alt + float(rng.normal(0, 0.5)), ins_en=ins)
            home.on_fix(f.ok, t, (f.e_m, f.n_m), tuple(ins))
        cmd = home.command(t, (ins[0], ins[1], s.yaw, s.alt), dt)
        uav.step(Command(*cmd), dt)
        t += dt
        d = math.hypot(uav.state.e - target[0], uav.state.n - target[1])
        if reached is None and d < 1.0:
            reached = t
    final = math.hypot(uav.state.e - target[0], uav.state.n - target[1])
    return dict(seed=seed, reached_s=reached, final_m=final, success=final < 1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer trials, SIFT and ORB only, 4 homing runs")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--png", default=str(REPO / "out" / "bench_uav_register.png"))
    args = ap.parse_args()
    log = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else print
    methods = METHODS[:2] if args.quick else METHODS
    n = 6 if args.quick else 16
    gm = procedural_map(rng=np.random.default_rng(0))
    ratios = (0.25, 0.5, 0.7, 1.0, 1.4, 2.0, 4.0)
    yaws = (0.0, 45.0, 90.0, 135.0, 180.0)
    sweeps, by_method = {}, {}
    for method in methods:
        mf = MapFeatures.of(gm.image, method=method)
        rng = np.random.default_rng(100)
        core = []
        sw = {"ratio": {}, "rotation": {}, "blur": {}, "exposure": {}}
        for ratio in ratios:
            rows = [trial(gm, mf, rng, ratio=ratio, yaw=math.radians(float(rng.choice(yaws))), look=Look()) for _ in range(n)]
            sw["ratio"][str(ratio)] = summarise(rows)
            if 0.5 <= ratio <= 2.0:
                core += rows
        for yaw in yaws:
            rows = [trial(gm, mf, rng, ratio=1.0, yaw=math.radians(yaw), look=Look()) for _ in range(n)]
            sw["rotation"][str(yaw)] = summarise(rows)
            core += rows
        for blur in (0.0, 1.5, 3.0):
            sw["blur"][str(blur)] = summarise([trial(gm, mf, rng, ratio=1.0, yaw=0.5, look=Look(blur_px=blur)) for _ in range(n)])
        for gain, gamma in ((0.5, 1.0), (1.6, 1.0), (1.0, 2.0)):
            sw["exposure"][f"gain {gain} gamma {gamma}"] = summarise(
                [trial(gm, mf, rng, ratio=1.0, yaw=0.5, look=Look(gain=gain, gamma=gamma)) for _ in range(n)])
        sweeps[method] = sw
        by_method[method] = summarise(core)
        m = by_method[method]
        log(f"{method:5s}: 0.5x-2x, any rotation: success {100 * m['success_frac']:.1f} % (wrong {100 * m['wrong_frac']:.1f} %), "
            f"position {m['pos_err_px']:.2f} px, yaw {m['yaw_err_deg']:.2f} deg, {m['ms']:.0f} ms per frame")
        for key, cells in sw.items():
            log(f"   {key:9s}: " + "; ".join(f"{k}: {100 * v['success_frac']:.0f} %" for k, v in cells.items()))
    log("")
    real_out = real(log, methods)
    log("\nclosed loop, 10 starts outside the map:")
    mf = MapFeatures.of(gm.image, method="sift")
    runs = [homing(gm, mf, s) for s in range(200, 204 if args.quick else 210)]
    for r in runs:
        log(f"  seed {r['seed']}: " + (f"within 1 m at {r['reached_s']:.0f} s" if r["reached_s"] else "never within 1 m")
            + f", final {r['final_m']:.2f} m")
    s = by_method["sift"]
    out = dict(success_frac=s["success_frac"], pos_err_px=s["pos_err_px"], ms_per_frame=s["ms"],
               homing_success_frac=float(np.mean([r["success"] for r in runs])), by_method=by_method, sweeps=sweeps,
               real=real_out, homing=runs, map_m_per_px=gm.m_per_px)
    log(f"\ngoals (SIFT): >= 95 % success over 0.5x-2x, any rotation: {'met' if out['success_frac'] >= 0.95 else 'NOT met'} "
        f"({100 * out['success_frac']:.1f} %); <= 1 px: {'met' if (out['pos_err_px'] or 99) <= 1 else 'NOT met'} "
        f"({out['pos_err_px']:.2f}); <= 50 ms: {'met' if out['ms_per_frame'] <= 50 else 'NOT met'} ({out['ms_per_frame']:.0f} ms); "
        f"homing >= 9/10: {'met' if out['homing_success_frac'] >= 0.9 else 'NOT met'} ({sum(r['success'] for r in runs)}/{len(runs)})")
    draw(args.png, sweeps, ratios)
    log(f"wrote {args.png}")
    if args.json:
        print(json.dumps(out, default=float))


def draw(path: str, sweeps: dict, ratios) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    for method, sw in sweeps.items():
        axes[0].semilogx(ratios, [100 * sw["ratio"][str(r)]["success_frac"] for r in ratios], "o-", label=method)
        rot = sw["rotation"]
        axes[1].plot([float(k) for k in rot], [100 * v["success_frac"] for v in rot.values()], "o-", label=method)
        cells = [v for cat in sw.values() for v in cat.values() if v["pos_err_px"] is not None]
        axes[2].plot([v["ms"] for v in cells], [v["pos_err_px"] for v in cells], "o", label=method, alpha=0.7)
    axes[0].set_xlabel("scale ratio (frame / map ground resolution)")
    axes[1].set_xlabel("rotation (deg)")
    for a in axes[:2]:
        a.set_ylabel("success (%)")
        a.axhline(95, color="r", lw=0.8)
    axes[2].set_xlabel("ms per frame")
    axes[2].set_ylabel("position error (map px), median on success")
    axes[2].set_title("speed against error")
    for a in axes:
        a.grid(alpha=0.3, which="both")
        a.legend(fontsize=8)
    save_figure(fig, path, dpi=80)


if __name__ == "__main__":
    main()
