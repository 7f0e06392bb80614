"""Polar -> Cartesian fan: ms per ping against error, numpy LUT (nearest, bilinear) vs cv2.remap, one core.

The ping is an analytic field f(r, theta) = 127 + 100 sin(2 pi r / (10 dr)) cos(2 pi theta / (10 dtheta))
sampled at the beam centres (float32, so only interpolation error is measured); each fan pixel is
compared with f at its own (r, theta), between the outermost beam centres. Errors are in
intensity levels of a 0-255 image. Times are medians of single-threaded runs with the lookup
table already cached (its build time is reported separately).

    python bench/sonar_polar.py [--quick] [--json]
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

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from nodes.sonar.polar import FanGeometry, build_lut, render_fan  # noqa: E402

MODES = [("nearest", "numpy", "numpy LUT nearest"), ("bilinear", "numpy", "numpy LUT bilinear"),
         ("nearest", "cv2", "cv2.remap nearest"), ("bilinear", "cv2", "cv2.remap bilinear")]
N_RANGES, DR = 1000, 0.02


def bearing_table(n_beams: int) -> np.ndarray:
    """An Oculus-like non-uniform 130 deg table: beams denser at the centre (as the real M1200d's)."""
    k = np.linspace(-1.0, 1.0, n_beams)
    return np.deg2rad(65.0 * (0.85 * k + 0.15 * k ** 3))


def field(r: np.ndarray, th: np.ndarray, dth: float) -> np.ndarray:
    return 127.0 + 100.0 * np.sin(2 * np.pi * r / (10 * DR)) * np.cos(2 * np.pi * th / (10 * dth))


def measure(n_beams: int, width: int, height: int, reps: int) -> list[dict]:
    bearings = bearing_table(n_beams)
    dth = float(np.mean(np.diff(bearings)))
    r = (np.arange(N_RANGES) + 0.5) * DR
    ping = field(r[:, None], bearings[None, :], dth).astype(np.float32)
    ping8 = np.clip(np.rint(ping), 0, 255).astype(np.uint8)
    t0 = time.perf_counter()
    lut = build_lut(FanGeometry.of(ping, bearings, DR), width_px=width, height_px=height)
    build_ms = (time.perf_counter() - t0) * 1e3
    rows, cols = np.indices(lut.shape)
    x, y = (cols - lut.origin_col_px) * lut.m_per_px, (lut.origin_row_px - rows) * lut.m_per_px
    rr, th = np.hypot(x, y), np.arctan2(x, y)
    inner = (lut.mask > 0) & (rr >= r[0]) & (rr <= r[-1]) & (th >= bearings[0]) & (th <= bearings[-1])
    truth = field(rr, th, dth)[inner]
    out = []
    for interp, backend, label in MODES:
        render_fan(ping8, lut, interpolation=interp, backend=backend)     # warm the per-mode tables
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            render_fan(ping8, lut, interpolation=interp, backend=backend)
            times.append((time.perf_counter() - t0) * 1e3)
        err = np.abs(render_fan(ping, lut, interpolation=interp, backend=backend)[inner] - truth)
        out.append(dict(beams=n_beams, size=f"{lut.shape[1]}x{lut.shape[0]}", mode=label,
                        ms=float(np.median(times)), max_abs_err=float(err.max()),
                        rms_err=float(np.sqrt(np.mean(err ** 2))), lut_build_ms=build_ms,
                        fan_fraction=float(lut.mask.mean())))
    return out


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, (ax, ax_img) = plt.subplots(1, 2, figsize=(13, 5))
    markers = {"numpy LUT nearest": "o", "numpy LUT bilinear": "s", "cv2.remap nearest": "^",
               "cv2.remap bilinear": "D"}
    for res in results:
        colour = "C0" if res["beams"] == 256 else "C1"
        ax.scatter(res["ms"], res["rms_err"], marker=markers[res["mode"]], color=colour,
                   s=30 + 40 * (res["size"].startswith("1024")))
    for label, m in markers.items():
        ax.scatter([], [], marker=m, color="gray", label=label)
    ax.scatter([], [], color="C0", label="256 beams")
    ax.scatter([], [], color="C1", label="512 beams")
    ax.axvline(1.5, ls="--", color="k", lw=0.8, label="goal 1.5 ms (1024x1024)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ms per ping (median, 1 core)")
    ax.set_ylabel("RMS error vs analytic fan (levels)")
    ax.set_title("Polar -> Cartesian: time vs error (big markers: 1024 px)")
    ax.legend(fontsize=8)
    bearings = bearing_table(256)
    r = (np.arange(N_RANGES) + 0.5) * DR
    ping = field(r[:, None], bearings[None, :], float(np.mean(np.diff(bearings))))
    lut = build_lut(FanGeometry.of(ping, bearings, DR), width_px=800)
    ax_img.imshow(render_fan(ping.astype(np.float32), lut, interpolation="bilinear"), cmap="gray",
                  extent=[-lut.origin_col_px * lut.m_per_px, (lut.shape[1] - lut.origin_col_px) * lut.m_per_px,
                          (lut.origin_row_px - lut.shape[0]) * lut.m_per_px, lut.origin_row_px * lut.m_per_px])
    ax_img.set_title("analytic test field, 256 non-uniform beams, bilinear")
    ax_img.set_xlabel("x starboard (m)")
    ax_img.set_ylabel("y ahead (m)")
    save_figure(fig, path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sizes and repetitions")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the headline figures")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    reps = 7 if args.quick else 25
    sizes = [(1024, 1024)] if args.quick else [(512, 512), (1024, 1024), (1024, 0), (2048, 2048)]
    results = [res for beams in (256, 512) for (w, h) in sizes for res in measure(beams, w, h, reps)]
    out_dir = ROOT / "out"
    out_dir.mkdir(exist_ok=True)
    plot(results, out_dir / "sonar_polar.png")

    def pick(mode: str, beams: int = 512, size: str = "1024x1024") -> dict:
        return next(r for r in results if r["mode"] == mode and r["beams"] == beams and r["size"] == size)

    near, bil, cv_bil = pick("numpy LUT nearest"), pick("numpy LUT bilinear"), pick("cv2.remap bilinear")
    headline = dict(fan1024_ms=near["ms"], fan1024_ms_bilinear=bil["ms"], fan1024_ms_cv2=cv_bil["ms"],
                    fan1024_ms_cv2_nearest=pick("cv2.remap nearest")["ms"],
                    max_abs_err=bil["max_abs_err"], max_abs_err_nearest=near["max_abs_err"],
                    max_abs_err_cv2=cv_bil["max_abs_err"], rms_err=bil["rms_err"],
                    rms_err_nearest=near["rms_err"], lut_build_ms=near["lut_build_ms"],
                    ratio_nearest_vs_cv2=near["ms"] / cv_bil["ms"], goal_fan1024_ms=1.5,
                    plot=str(out_dir / "sonar_polar.png"))
    if args.json:
        print(json.dumps(headline))
        return
    print(f"{'beams':>5} {'size':>10} {'mode':<20} {'ms':>7} {'max err':>8} {'rms err':>8} {'fan %':>6}")
    for r in results:
        print(f"{r['beams']:>5} {r['size']:>10} {r['mode']:<20} {r['ms']:7.2f} {r['max_abs_err']:8.2f} "
              f"{r['rms_err']:8.3f} {100 * r['fan_fraction']:6.1f}")
    print(f"\n512 beams, 1024x1024: numpy nearest {near['ms']:.2f} ms (goal <= 1.5), numpy bilinear "
          f"{bil['ms']:.2f} ms, cv2.remap bilinear {cv_bil['ms']:.2f} ms; nearest/cv2 = "
          f"{headline['ratio_nearest_vs_cv2']:.2f}; LUT build (once per geometry) {near['lut_build_ms']:.0f} ms")
    print(f"plot: {headline['plot']}")


if __name__ == "__main__":
    main()
