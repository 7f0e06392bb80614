"""Hand gesture benchmark (seed 13): finger count, gesture and keypoints for (a) the OpenCV
convexity method and (b) the learned 21-keypoint net, on held-out simulated scenes and on real
labelled photos.

Simulated: 128x128 scenes from seeds 0-999 (training uses 1000 onward; nothing was tuned on
these), ``--n`` per class. Pose classes (random framing, background, lighting, skin):
fist, point, thumb, victory spread (the "spread two"), victory together, L, three, four,
open; hard classes: forearm in view, hand touching/cut by the border, skin-coloured
background, two hands (the truth is the larger, front one), no hand (a hand must not be
found: count 0 and "none"). Keypoint error in px and PCK@0.2 (a keypoint within 0.2 palm
lengths, wrist to middle MCP, of the truth) over visible keypoints.

Real: ../shared/data/hands/sign_language_digits (Sign Language Digits Dataset, Arda Mavi and
Zeynep Dikle, Ayranci Anadolu High School, Apache-2.0; cite Mavi 2020, arXiv:2011.08927): 60
photos per digit, 100x100 on grey; digits 1-5 are raised-finger counts (1 point, 2 victory,
3 thumb+index+middle, 4, 5 open). Used for evaluation only; skipped cleanly when absent.

    python bench/hand_gesture.py [--n 40] [--json] [--png OUT.png]

``--json`` keys: count_acc_min_class, pck, ms_per_frame (the learned net, finger-state
head, on simulated scenes), then per method (convexity; learned head / geometry / fused)
and data set: count_acc / gesture_acc per class, zero_vs_one, kp_err_px,
pck, ms_per_frame; and goals (met or not).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.vision.hand_recognise import Recogniser  # noqa: E402
from sim.hand_render import SceneSpec, render_scene  # noqa: E402

REAL = Path(os.environ.get("TETHER_SHARED_DATA", REPO.parent / "shared" / "data")) / "hands" / "sign_language_digits"
CLASSES: dict[str, SceneSpec] = {
    "fist": SceneSpec(gesture="fist"), "point": SceneSpec(gesture="point"), "thumb": SceneSpec(gesture="thumb"),
    "victory_spread": SceneSpec(gesture="victory", spread=True),
    "victory_together": SceneSpec(gesture="victory", spread=False),
    "L": SceneSpec(gesture="L"), "three": SceneSpec(gesture="three"), "four": SceneSpec(gesture="four"),
    "open": SceneSpec(gesture="open"),
    "arm_in_view": SceneSpec(arm=True, framing="inside"), "border": SceneSpec(framing="border"),
    "skin_background": SceneSpec(background="skin"), "two_hands": SceneSpec(hands=2), "no_hand": SceneSpec(hands=0)}
REAL_GESTURES = {1: "point", 2: "victory", 3: "three", 4: "four", 5: "open"}
# (b) reads finger states from the net's finger-state head (the node's default), from the
# keypoints' geometry, or from both; all three run on the same images.
METHODS = {"convexity": ("convexity", "head"), "learned": ("learned", "head"),
           "learned_geometry": ("learned", "geometry"), "learned_fused": ("learned", "fused")}
GOALS = {"count_acc_min_class": 0.97, "pck": 0.9, "ms_per_frame": 15.0}


def sim_cases(n: int) -> list[tuple[str, np.ndarray, object]]:
    """(class, image, truth) for ``n`` scenes per class from seeds 0-999 (class k uses 50k + i)."""
    out = []
    for k, (cls, spec) in enumerate(CLASSES.items()):
        for i in range(n):
            rng = np.random.default_rng(50 * k + i)
            img, truth = render_scene(rng, spec)
            out.append((cls, img, truth))
    return out


def real_cases() -> list[tuple[int, np.ndarray]]:
    """(digit, image) for the real photos of digits 0-5 (0: the "O", loosely no finger)."""
    if not (REAL / "labels.csv").is_file():
        return []
    with open(REAL / "labels.csv") as f:
        rows = [r for r in csv.DictReader(f) if int(r["label_digit"]) <= 5]
    return [(int(r["label_digit"]), cv2.imread(str(REAL / r["file"]))) for r in rows]


def _score_sim(rec: Recogniser, cases: list) -> dict:
    per: dict[str, list[bool]] = {}
    gest: dict[str, list[bool]] = {}
    ms, errs, pck, zero_one = [], [], [], {"0_as_1": 0, "1_as_0": 0, "n0": 0, "n1": 0}
    for cls, img, t in cases:
        r = rec(img)
        ms.append(r.ms)
        want = t.count if t.present else 0
        ok = r.count == want and r.present == t.present
        per.setdefault(cls, []).append(ok)
        if rec.method == "learned":
            gest.setdefault(cls, []).append(r.gesture == (t.gesture if t.present else "none"))
        if t.present and t.count in (0, 1) and cls != "two_hands":
            zero_one[f"n{t.count}"] += 1
            zero_one["0_as_1"] += t.count == 0 and r.count == 1
            zero_one["1_as_0"] += t.count == 1 and r.count == 0
        if t.present and r.present and np.all(np.isfinite(r.keypoints_px)):
            h, w = img.shape[:2]
            vis = np.all((t.keypoints_px >= 0) & (t.keypoints_px <= [w - 1, h - 1]), axis=1)
            e = np.linalg.norm(r.keypoints_px - t.keypoints_px, axis=1)[vis]
            errs.append(e)
            pck.append(e <= 0.2 * t.palm_px)
    acc = {c: float(np.mean(v)) for c, v in per.items()}
    out = {"count_acc": acc, "count_acc_min_class": min(acc.values()),
           "count_acc_min_class_named": min(acc, key=acc.get), "zero_vs_one": zero_one,
           "ms_per_frame": float(np.median(ms))}
    if gest:
        out["gesture_acc"] = {c: float(np.mean(v)) for c, v in gest.items()}
    if errs:
        e = np.concatenate(errs)
        out.update(kp_err_px_median=float(np.median(e)), kp_err_px_mean=float(np.mean(e)),
                   pck=float(np.mean(np.concatenate(pck))))
    return out


def _score_real(rec: Recogniser, cases: list) -> dict:
    per: dict[int, list[bool]] = {}
    gest: dict[int, list[bool]] = {}
    found: dict[int, list[int]] = {}
    ms = []
    for digit, img in cases:
        r = rec(img)
        ms.append(r.ms)
        per.setdefault(digit, []).append(r.present and r.count == digit)
        found.setdefault(digit, []).append(r.count)
        if rec.method == "learned" and digit in REAL_GESTURES:
            gest.setdefault(digit, []).append(r.gesture == REAL_GESTURES[digit])
    acc = {str(d): float(np.mean(v)) for d, v in sorted(per.items())}
    counts = {str(d): np.bincount(v, minlength=6).tolist() for d, v in sorted(found.items())}
    out = {"count_acc": acc, "count_acc_min_class": min(acc[str(d)] for d in range(1, 6)),
           "count_histogram": counts, "ms_per_frame": float(np.median(ms)), "n": len(cases)}
    if gest:
        out["gesture_acc"] = {str(d): float(np.mean(v)) for d, v in sorted(gest.items())}
    return out


def _png(path: str, res: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [3, 1.2]})
    for ax, key in zip(axes, ("sim", "real")):
        for j, m in enumerate(METHODS):
            acc = res[m].get(key, {}).get("count_acc", {})
            if acc:
                x = np.arange(len(acc))
                ax.bar(x + 0.2 * j - 0.3, list(acc.values()), 0.2, label=f"({'abbb'[j]}) {m}")
                ax.set_xticks(x, list(acc), rotation=40, ha="right", fontsize=8)
        ax.axhline(GOALS["count_acc_min_class"], color="r", lw=0.8, ls="--")
        ax.set_ylim(0, 1.02)
        ax.set_title(f"finger-count accuracy, {'held-out simulated scenes' if key == 'sim' else 'real photos (digit)'}")
        ax.legend(fontsize=8, loc="lower left")
    save_figure(fig, path, dpi=90)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=40, help="simulated scenes per class")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--png", default=str(REPO / "out" / "bench_hand_gesture.png"))
    args = ap.parse_args(argv)
    log = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else print
    sims, reals = sim_cases(args.n), real_cases()
    if not reals:
        log(f"real photos not found at {REAL}: skipped")
    res: dict = {}
    for name, (method, fingers) in METHODS.items():
        rec = Recogniser(method, fingers=fingers)
        rec(sims[0][1])                                          # warm-up (jit)
        res[name] = {"sim": _score_sim(rec, sims)}
        if reals:
            res[name]["real"] = _score_real(rec, reals)
    log("finger-count accuracy per class (gesture accuracy of (b) head in the last column)")
    log(f"{'class':18s} {'(a) convex':>10s} {'(b) head':>10s} {'(b) geom':>10s} {'(b) fused':>10s} {'(b) gesture':>11s}")
    rows = [(c, "sim", c) for c in CLASSES] + [(f"real digit {d}", "real", d)
                                             for d in res["learned"].get("real", {}).get("count_acc", {})]
    for label, key, c in rows:
        accs = " ".join(f"{res[m][key]['count_acc'][c]:10.3f}" for m in METHODS)
        log(f"{label:18s} {accs} {res['learned'][key].get('gesture_acc', {}).get(c, float('nan')):11.3f}")
    for m in METHODS:
        s = res[m]["sim"]
        log(f"({m}) sim: min class {s['count_acc_min_class']:.3f} ({s['count_acc_min_class_named']}), "
            f"0 vs 1 {s['zero_vs_one']}, PCK@0.2 {s.get('pck', float('nan')):.3f}, "
            f"median kp error {s.get('kp_err_px_median', float('nan')):.2f} px, {s['ms_per_frame']:.2f} ms/frame"
            + (f"; real 1-5 min class {res[m]['real']['count_acc_min_class']:.3f}" if reals else ""))
    ls = res["learned"]["sim"]
    out = {"count_acc_min_class": ls["count_acc_min_class"], "pck": ls["pck"], "ms_per_frame": ls["ms_per_frame"],
           "real_count_acc_min_class": res["learned"].get("real", {}).get("count_acc_min_class"),
           "goals": {k: {"goal": g, "met": bool(ls[k] >= g if k != "ms_per_frame" else ls[k] <= g)}
                     for k, g in GOALS.items()},
           "n_per_class": args.n, "methods": res}
    _png(args.png, res)
    log(f"wrote {args.png}")
    if args.json:
        print(json.dumps(out, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
