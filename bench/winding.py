"""Winding-number benchmark: our 2-D and 3-D evaluators against libigl and OpenCV.

2-D: a 2,000-segment closed contour (a five-petal flower) and 512 x 512 queries at the
pixel centres.

* ``direct``: the seed's formula, the sum of subtended angles (float64, chunked); on a
  quarter of the rows unless ``--full-direct``, time scaled by 4;
* ``exact``: nodes.shapes.winding.winding_numbers (crossings in bands + chord angles);
* ``tree``: the dipole tree (nodes.shapes.fast_winding), beta swept: time against the max
  error more than 2 px from the curve;
* ``libigl``: ``igl.winding_number`` on the same segments (2-D), same quarter of rows;
* ``cv2``: ``cv2.pointPolygonTest`` per point (closed contours only: in / out).

Open contours: 5, 10 and 25 % of the arc removed in one gap or in four; the mislabelled
area (pixels) of ``w >= 1/2`` against the closed shape's inside, beside closing each piece
by its own chord (what ``pointPolygonTest`` does with each contour a detector returns). With
one gap the two are the same set (w >= 1/2 of one open curve is its chord-closed polygon);
with several pieces they are not.

3-D: a bumpy sphere of ~100,000 triangles and 1,000,000 random queries in its box:
our dipole tree (beta = 2) against ``igl.fast_winding_number`` (both on all cores), error
against the exact solid-angle sum on 2,000 of the queries.

    python bench/winding.py [--quick] [--json] [--png OUT.png] [--full-direct]

``--json`` keys: exact_s, fast_s (the fastest 2-D evaluator within 1e-3: see fast_method),
fast_max_err, libigl_s (2-D, on all queries), mesh_s, mesh_libigl_s, mesh_ratio,
mesh_max_err, mesh_libigl_max_err, gaps, tree_sweep.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.shapes.fast_winding import build_tree, fast_winding, mesh_tree, winding_mesh  # noqa: E402
from nodes.shapes.winding import segments_of, winding_direct, winding_numbers  # noqa: E402


def flower(n: int = 2000, centre=(256.0, 256.0), r: float = 170.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rr = r * (1 + 0.3 * np.cos(5 * t))
    return np.stack([centre[0] + rr * np.cos(t), centre[1] + rr * np.sin(t)], 1)


def broken(curve: np.ndarray, frac: float, n_gaps: int) -> list[np.ndarray]:
    """The curve with ``frac`` of its points removed in ``n_gaps`` equal gaps, as open pieces."""
    n = len(curve)
    per = n // n_gaps
    gap = int(round(frac * n / n_gaps))
    return [curve[k * per: (k + 1) * per - gap + 1] for k in range(n_gaps)]


def bumpy_sphere(nu: int = 224, nv: int = 224) -> tuple[np.ndarray, np.ndarray]:
    u = np.linspace(0, np.pi, nu)
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = 1 + 0.15 * np.sin(5 * uu) * np.cos(4 * vv)
    pts = np.stack([r * np.sin(uu) * np.cos(vv), r * np.sin(uu) * np.sin(vv), r * np.cos(uu)], -1).reshape(-1, 3)
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b = idx[:-1], np.roll(idx, -1, axis=1)[:-1]
    c, d = idx[1:], np.roll(idx, -1, axis=1)[1:]
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    area = np.linalg.norm(np.cross(pts[faces[:, 1]] - pts[faces[:, 0]], pts[faces[:, 2]] - pts[faces[:, 0]]), axis=1)
    return pts, faces[area > 1e-12]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def bench_2d(args) -> dict:
    import igl

    curve = flower()
    ys, xs = np.mgrid[0:512, 0:512]
    q = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)
    a, b, _, _ = segments_of([curve])
    dense = np.concatenate([a + (b - a) * s for s in np.linspace(0, 1, 16)])
    from scipy.spatial import cKDTree
    dist = cKDTree(dense).query(q)[0]
    away = dist > 2.0
    part = slice(None) if args.full_direct else slice(0, len(q) // 4)
    scale = 1 if args.full_direct else 4
    t_direct, w_direct = timed(lambda: winding_direct(q[part], [curve]))
    t_exact, w = timed(lambda: winding_numbers(q, [curve]))
    v2 = np.concatenate([a, b]).astype(np.float64)
    e2 = np.stack([np.arange(len(a)), np.arange(len(a), 2 * len(a))], 1).astype(np.int64)
    t_igl, w_igl = timed(lambda: igl.winding_number(v2, e2, q[part]))
    contour = curve.astype(np.float32).reshape(-1, 1, 2)
    t_cv, inside_cv = timed(lambda: np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), False) for x, y in q[part]]))
    exact_err = float(np.abs(w[part] - w_direct).max())
    igl_err = float(np.abs(w_igl - w_direct).max())
    cv_disagree = int(((inside_cv > 0) != (w[part] >= 0.5))[away[part]].sum())
    tree = build_tree(np.stack([a, b], 1))
    sweep = []
    for beta in ((2.0, 4.0) if args.quick else (1.5, 2.0, 3.0, 4.0, 6.0)):
        t, wf = timed(lambda: fast_winding(tree, q, beta=beta))
        sweep.append({"beta": beta, "s": t, "max_err_away": float(np.abs(wf - w)[away].max())})
        print(f"  tree beta {beta}: {t:.2f} s, max error {sweep[-1]['max_err_away']:.1e}", file=sys.stderr)
    candidates = [("exact", t_exact, 0.0)] + [(f"tree beta {s['beta']}", s["s"], s["max_err_away"]) for s in sweep]
    ok = [c for c in candidates if c[2] <= 1e-3]
    fast = min(ok, key=lambda c: c[1])
    gaps = []
    inside_true = (w >= 0.5).reshape(512, 512)
    for frac in (0.05, 0.10, 0.25):
        for n_gaps in (1, 4):
            pieces = broken(curve, frac, n_gaps)
            wo = winding_numbers(q, pieces, closed=False).reshape(512, 512)
            # the baseline: every piece closed by its own chord (pointPolygonTest on each contour), inside any
            chord = np.zeros(len(q), bool)
            for p in pieces:
                chord |= winding_numbers(q, [p], closed=True) != 0
            gaps.append({"removed": frac, "gaps": n_gaps, "mislabelled_px_winding": int(((wo >= 0.5) != inside_true).sum()),
                         "mislabelled_px_chord": int((chord.reshape(512, 512) != inside_true).sum()),
                         "inside_px": int(inside_true.sum())})
    return {"queries": len(q), "segments": len(a), "direct_s": t_direct * scale, "exact_s": t_exact,
            "exact_max_err_vs_direct": exact_err, "libigl_s": t_igl * scale, "libigl_max_err_vs_direct": igl_err,
            "cv2_s": t_cv * scale, "cv2_disagree_away": cv_disagree, "fast_method": fast[0], "fast_s": fast[1],
            "fast_max_err": fast[2], "tree_sweep": sweep, "gaps": gaps, "_maps": (w, curve)}


def bench_3d(args) -> dict:
    import igl

    v, f = bumpy_sphere(*((110, 110) if args.quick else (224, 224)))
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.4, 1.4, (100_000 if args.quick else 1_000_000, 3))
    t_igl, w_igl = timed(lambda: igl.fast_winding_number(v, f.astype(np.int64), q))
    t_build, tree = timed(lambda: mesh_tree(v, f))
    t_ours, w_ours = timed(lambda: fast_winding(tree, q, beta=2.0))
    sub = slice(0, 2000)
    t_exact, w_exact = timed(lambda: winding_mesh(q[sub], v, f))
    return {"triangles": len(f), "queries": len(q), "mesh_s": t_ours, "mesh_build_s": t_build,
            "mesh_libigl_s": t_igl, "mesh_ratio": t_ours / t_igl,
            "mesh_max_err": float(np.abs(w_ours[sub] - w_exact).max()),
            "mesh_libigl_max_err": float(np.abs(w_igl[sub] - w_exact).max()),
            "exact_s_per_2000": t_exact, "inside_agree": float(np.mean((w_ours >= 0.5) == (w_igl >= 0.5)))}


def plot(r2: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    w, curve = r2["_maps"]
    cut = broken(curve, 0.10, 4)
    ys, xs = np.mgrid[0:512, 0:512]
    q = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)
    wo = winding_numbers(q, cut, closed=False).reshape(512, 512)
    g = next(x for x in r2["gaps"] if x["removed"] == 0.10 and x["gaps"] == 4)
    fig, ax = plt.subplots(1, 3, figsize=(16, 5))
    im = ax[0].imshow(wo, cmap="magma", vmin=0, vmax=1, origin="upper")
    for p in cut:
        ax[0].plot(p[:, 0], p[:, 1], "c-", lw=0.8)
    ax[0].set_title("w of the contour with 10 % of its arc removed in 4 gaps", fontsize=10)
    fig.colorbar(im, ax=ax[0], fraction=0.046)
    ax[1].imshow((wo >= 0.5).astype(float) - (w.reshape(512, 512) >= 0.5), cmap="bwr", vmin=-1, vmax=1)
    ax[1].set_title(f"w >= 1/2 minus the closed inside: {g['mislabelled_px_winding']} px wrong\n"
                    f"(each piece closed by its chord: {g['mislabelled_px_chord']} px)", fontsize=10)
    s = r2["tree_sweep"]
    ax[2].loglog([x["s"] for x in s], [max(x["max_err_away"], 1e-16) for x in s], "o-", label="dipole tree (beta)")
    for x in s:
        ax[2].annotate(f"{x['beta']:g}", (x["s"], max(x["max_err_away"], 1e-16)), fontsize=8)
    ax[2].plot([r2["exact_s"]], [1e-15], "g*", ms=14, label=f"exact banded ({r2['exact_max_err_vs_direct']:.0e} vs direct)")
    ax[2].plot([r2["libigl_s"]], [max(r2["libigl_max_err_vs_direct"], 1e-15)], "rs", label="libigl winding_number")
    ax[2].plot([r2["direct_s"]], [1e-15], "k^", label="direct angle sum")
    ax[2].set_xlabel("time for 512 x 512 queries (s)")
    ax[2].set_ylabel("max error > 2 px from the curve")
    ax[2].legend(fontsize=8)
    ax[2].grid(alpha=0.3)
    save_figure(fig, path, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller 3-D mesh and query set, shorter sweep")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--full-direct", action="store_true", help="the direct and libigl passes on every query")
    ap.add_argument("--png", default=str(REPO / "out" / "bench_winding.png"))
    args = ap.parse_args()
    r2 = bench_2d(args)
    print(f"2-D: direct {r2['direct_s']:.2f} s, exact {r2['exact_s']:.3f} s (err {r2['exact_max_err_vs_direct']:.1e}), "
          f"libigl {r2['libigl_s']:.2f} s, cv2 {r2['cv2_s']:.2f} s; fast: {r2['fast_method']} {r2['fast_s']:.3f} s",
          file=sys.stderr)
    r3 = bench_3d(args)
    print(f"3-D: ours {r3['mesh_s']:.2f} s (+ build {r3['mesh_build_s']:.2f} s), libigl {r3['mesh_libigl_s']:.2f} s, "
          f"ratio {r3['mesh_ratio']:.1f}, err ours {r3['mesh_max_err']:.1e} / libigl {r3['mesh_libigl_max_err']:.1e}",
          file=sys.stderr)
    if args.png:
        plot(r2, args.png)
    r2.pop("_maps")
    result = {**r2, **r3}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for k in ("exact_s", "fast_s", "fast_max_err", "libigl_s", "mesh_s", "mesh_libigl_s", "mesh_ratio"):
            print(f"{k:14s} {result[k]:.4g}")
        for g in result["gaps"]:
            print(f"{g['removed']:.0%} removed in {g['gaps']} gap(s): mislabelled px {g['mislabelled_px_winding']} "
                  f"(chords: {g['mislabelled_px_chord']}) of {g['inside_px']} inside")


if __name__ == "__main__":
    main()
