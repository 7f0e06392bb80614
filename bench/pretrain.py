"""Autoencoder pre-training benchmark (seed 07): accuracy against the fraction of labels, pre-trained
against randomly initialised, over seeds.

Data: scikit-learn's 1,797 handwritten digits (8x8, upsampled to 28x28) and, when
../shared/data/hands is present, the 600 sign-language digit photos (100x100, grey, 28x28;
Arda Mavi's Sign-Language-Digits-Dataset, Apache-2.0). Each is split 70/30 by class (the split
seed is fixed; the test images are never seen in training, labelled or not). Per seed: the
autoencoder (the seed's, and its greedy layer-wise variant) is trained on all training images
without labels; then the seed's classifier is trained on 1 %, 10 % and 100 % of the training
labels (class-balanced, at least one per class) from the pre-trained encoder and from a random
one, with the same optimiser, steps and batches. Fine-tuned (every layer trains) and frozen
(the head alone: how good the features are) are both reported.

    python bench/pretrain.py [--quick] [--seeds 5] [--json]

``--json`` keys: gain_at_1pct, gain_std_at_1pct, gain_at_100pct (digits, seed autoencoder,
fine-tuned: mean and std over seeds of the per-seed accuracy difference), and table
{dataset: {fraction: {method: [accuracy per seed]}}}, minutes.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.learn.datasets import digits28, hand_digits28, split  # noqa: E402
from nodes.learn.plots import image_grid, plot_curves  # noqa: E402
from nodes.learn.pretrain import Fit, accuracy, label_subset, reconstruct, train_autoencoder, train_classifier  # noqa: E402

HANDS = REPO.parent / "shared" / "data" / "hands" / "sign_language_digits"
FRACTIONS = (0.01, 0.1, 1.0)
METHODS = ("random", "autoencoder", "greedy")


def run_dataset(name: str, x: np.ndarray, y: np.ndarray, seeds: int, ae_fit: Fit, cls_fit: Fit,
                curves: dict) -> dict:
    tr, te = split(y, 0.3, seed=1234)
    table: dict = {f: {f"{m}/{mode}": [] for m in METHODS for mode in ("tuned", "frozen")} for f in FRACTIONS}
    for s in range(seeds):
        t0 = time.perf_counter()
        enc, dec, hist = train_autoencoder(x[tr], seed=s, fit=ae_fit)
        greedy, _, ghist = train_autoencoder(x[tr], seed=s, fit=ae_fit, greedy=True)
        if s == 0:
            curves[f"{name} autoencoder"] = tuple(zip(*hist))
            curves[f"{name} greedy (per layer)"] = tuple(zip(*ghist))
            rec = reconstruct(enc, dec, x[te[:8]])
            image_grid(np.concatenate([x[te[:8], :, :, 0], rec[:, :, :, 0]]), REPO / "out" / f"pretrain_{name}_recon.png",
                       cols=8, rows_label=["input", "reconstructed"])
        pre = time.perf_counter() - t0
        for f in FRACTIONS:
            idx = tr[label_subset(y[tr], f, np.random.default_rng(100 + s))]
            for method, encoder in (("random", None), ("autoencoder", enc), ("greedy", greedy)):
                for mode in ("tuned", "frozen"):
                    params, _ = train_classifier(x[idx], y[idx], encoder=encoder, seed=s, fit=cls_fit,
                                                 freeze_encoder=mode == "frozen")
                    table[f][f"{method}/{mode}"].append(accuracy(params, x[te], y[te]))
        print(f"  [{name}] seed {s}: pre-training {pre:.0f} s, " + ", ".join(
            f"{int(100 * f)} %: random {table[f]['random/tuned'][-1]:.3f} ae {table[f]['autoencoder/tuned'][-1]:.3f}"
            for f in FRACTIONS), file=sys.stderr, flush=True)
    return {"train": len(tr), "test": len(te), "table": table}


def gains(table: dict, f: float, method: str = "autoencoder", mode: str = "tuned") -> np.ndarray:
    return np.array(table[f][f"{method}/{mode}"]) - np.array(table[f][f"random/{mode}"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 seeds, short training (a smoke run)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    seeds = 2 if args.quick else args.seeds
    ae_fit = Fit(steps=100 if args.quick else 800, batch=32, lr=1e-3)
    cls_fit = Fit(steps=60 if args.quick else 300, batch=32, lr=1e-3)
    t0 = time.perf_counter()
    data = {"digits": digits28()}
    if HANDS.exists():
        data["hands"] = hand_digits28(HANDS)
    curves: dict = {}
    results = {name: run_dataset(name, x, y, seeds, ae_fit, cls_fit, curves) for name, (x, y) in data.items()}
    minutes = (time.perf_counter() - t0) / 60
    for name, r in results.items():
        print(f"\n{name}: {r['train']} training images ({r['test']} test), accuracy on the test images, "
              f"mean +- std over {seeds} seeds")
        print(f"{'labels':>7}" + "".join(f"{m + '/' + mode:>22}" for m in METHODS for mode in ("tuned", "frozen")))
        for f in FRACTIONS:
            row = r["table"][f]
            print(f"{int(100 * f):>6}%" + "".join(f"{np.mean(row[k]):>15.3f} +- {np.std(row[k]):.3f}" for k in row))
        for f in FRACTIONS:
            g = gains(r["table"], f)
            gg = gains(r["table"], f, "greedy")
            gf = gains(r["table"], f, mode="frozen")
            print(f"  gain of pre-training at {int(100 * f)} % labels: fine-tuned {g.mean():+.3f} +- {g.std():.3f} "
                  f"(greedy {gg.mean():+.3f} +- {gg.std():.3f}); frozen features {gf.mean():+.3f} +- {gf.std():.3f}")
    g1, g100 = gains(results["digits"]["table"], 0.01), gains(results["digits"]["table"], 1.0)
    print(f"\ngoal: a gain larger than 2 std at 1 % labels (digits, fine-tuned): {g1.mean():+.3f} vs 2 x {g1.std():.3f} "
          f"({'met' if g1.mean() > 2 * g1.std() else 'NOT met'}); at 100 %: {g100.mean():+.3f}; {minutes:.1f} minutes")
    plot_curves(curves, REPO / "out" / "pretrain_loss.png", title="autoencoder pre-training (seed 0)",
                ylabel="reconstruction loss")
    if args.json:
        tables = {n: {str(f): v for f, v in r["table"].items()} for n, r in results.items()}
        print(json.dumps({"gain_at_1pct": float(g1.mean()), "gain_std_at_1pct": float(g1.std()),
                          "gain_at_100pct": float(g100.mean()), "seeds": seeds, "minutes": minutes,
                          "sizes": {n: {"train": r["train"], "test": r["test"]} for n, r in results.items()},
                          "table": tables}))


if __name__ == "__main__":
    main()
