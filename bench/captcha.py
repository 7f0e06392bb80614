"""Captcha benchmark (seed 04): a solver trained on synthetic, on SimGAN-refined synthetic and (upper
bound) on real labelled captchas, all judged on held-out real ones.

Real set: ../shared/data/captcha/gtzhang_digits4, from GT-ZhangAcer/CaptchaDataset (MIT,
(c) 2020 GT-Zhang; https://github.com/GT-ZhangAcer/CaptchaDataset, credit asked by its author).
Fixed split by file (sim/captcha.py SPLIT): images 0-599 train the refiner's discriminator and
the real upper-bound solver, 600-699 are validation (reported, nothing is tuned on test),
700-999 are the test set every figure below comes from.

The synthesiser style is ``default`` (sim/captcha.py's imitation of the real set);
``--styles default,plain`` adds ``plain`` (Hershey digits, black on white, no noise: a crude
simulator with a wide gap for the refiner to close). The headline keys are the default style's.
Solvers train 2000 steps of 32 (the real one 2400: 600 images, ~128 epochs), the SimGAN 500
steps (1 D + 2 R updates each) on 4000 synthetic and the 600 real training captchas.

    nice python bench/captcha.py [--json] [--fresh] [--styles default,plain]

Models are cached under out/captcha/ (checkpoints resume; ``--fresh`` retrains). ``--json``
prints one object last: acc_synthetic, acc_refined, acc_real, train_minutes (wall),
cpu_minutes, per-character accuracies, per style the GAN's diagnostics, and the goal
(refined - synthetic >= 10 points of full-captcha accuracy).
"""
from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.learn.captcha_solver import SolverConfig, captcha_accuracy, predict_captchas, train_solver  # noqa: E402
from nodes.learn.plots import image_grid, plot_curves  # noqa: E402
from nodes.learn.simgan import SimGANConfig, init_simgan, refine_images, to_signed, train_simgan  # noqa: E402
from sim.captcha import PLAIN, CaptchaStyle, load_real_captchas, synthesize_captchas  # noqa: E402

STYLES = {"default": (CaptchaStyle(), None), "plain": (PLAIN, ())}
GOAL_POINTS = 10.0


def _score(state: dict, images: np.ndarray, labels: np.ndarray, cfg: SolverConfig) -> dict:
    full, per_char = captcha_accuracy(predict_captchas(state["params"], images, cfg), labels)
    return {"acc": round(full, 4), "char_acc": [round(float(a), 4) for a in per_char]}


def _timed(clock: dict, fn, *args, **kw):
    """Call ``fn`` and add its time to ``clock``. A call whose ``checkpoint`` was already complete
    (resumed, nothing left to train) adds the time recorded when it was trained, so a rerun from
    the cache reports the training minutes, not the seconds of loading."""
    ck = kw.get("checkpoint")
    book = Path(ck).with_suffix(".time.json") if ck is not None else None
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args, **kw)
    spent = {"wall": time.perf_counter() - w, "cpu": time.process_time() - c}
    if book is not None:
        if book.exists():
            before = json.loads(book.read_text())
            spent = {k: before[k] + spent[k] for k in spent}
        book.write_text(json.dumps(spent))
    clock["wall"] += spent["wall"]
    clock["cpu"] += spent["cpu"]
    return out


def _synth(out: Path, style_name: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    cache = out / f"synthetic_{style_name}_{n}_{seed}.npz"
    if cache.exists():
        d = np.load(cache)
        return d["images"], d["labels"]
    style, fonts = STYLES[style_name]
    images, labels = synthesize_captchas(n, seed=seed, style=style, fonts=fonts)
    np.savez_compressed(cache, images=images, labels=labels)
    return images, labels


def run_style(name: str, args: argparse.Namespace, real: dict, clock: dict, scfg: SolverConfig) -> dict:
    out = Path(args.out)
    syn, syn_labels = _synth(out, name, args.n_synth, args.seed)
    solver_syn, _ = _timed(clock, train_solver, syn, syn_labels, scfg, steps=args.solver_steps, seed=args.seed,
                           checkpoint=out / f"solver_{name}_synthetic.msgpack")
    gcfg = SimGANConfig()
    gan, hist = _timed(clock, train_simgan, init_simgan(gcfg, syn.shape[1:], seed=args.seed), syn, real["train"][0],
                       gcfg, steps=args.gan_steps, seed=args.seed, checkpoint=out / f"simgan_{name}.msgpack")
    refined = _timed(clock, refine_images, gan["r"], syn, gcfg)
    solver_ref, _ = _timed(clock, train_solver, refined, syn_labels, scfg, steps=args.solver_steps, seed=args.seed,
                           checkpoint=out / f"solver_{name}_refined.msgpack")
    test, val = real["test"], real["validation"]
    res = {"synthetic": _score(solver_syn, *test, scfg), "refined": _score(solver_ref, *test, scfg),
           "val_synthetic": _score(solver_syn, *val, scfg)["acc"], "val_refined": _score(solver_ref, *val, scfg)["acc"],
           # labels kept: the synthetic-trained solver reads the refined captchas (first 1000)
           "label_kept": _score(solver_syn, refined[:1000], syn_labels[:1000], scfg)["acc"],
           "label_ref_on_synthetic": _score(solver_syn, syn[:1000], syn_labels[:1000], scfg)["acc"]}
    res["gan"] = {"p_real": round(hist["p_real"][-1], 3), "p_refined": round(hist["p_fake"][-1], 3),
                  "l1": round(float(np.abs(refined - to_signed(syn)).mean()), 4),
                  "diversity": round(hist["diversity"][-1], 3), "d_wins_logged": len(hist["d_wins"]),
                  "collapse_logged": len(hist["collapse"]), "diverged": bool(hist["diverged"]),
                  "steps_per_s": round(float(np.median(hist["steps_per_s"])), 2)}
    s = hist["step"]
    plot_curves({"R adversarial": (s, hist["r_adv"]), "R L1": (s, hist["r_l1"]), "D loss": (s, hist["d_loss"]),
                 "P(real|refined)": (s, hist["p_fake"])}, out / f"simgan_{name}_curves.png",
                title=f"SimGAN on captchas ({name} synthesiser)")
    grid = np.concatenate([syn[:8], (refined[:8] + 1) * 127.5, real["test"][0][:8]]).astype(np.float64)
    image_grid(grid, out / f"simgan_{name}_samples.png", cols=8, rows_label=["synthetic", "refined", "real"])
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--fresh", action="store_true", help="retrain everything (delete the cached models)")
    ap.add_argument("--out", default=str(REPO / "out" / "captcha"))
    ap.add_argument("--styles", default="default")
    ap.add_argument("--n-synth", type=int, default=4000)
    ap.add_argument("--gan-steps", type=int, default=500)
    ap.add_argument("--solver-steps", type=int, default=2000)
    ap.add_argument("--real-steps", type=int, default=2400, help="the real solver's steps (600 images: more epochs)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    out = Path(args.out)
    if args.fresh and out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    real = {k: load_real_captchas(split=k)[:2] for k in ("train", "validation", "test")}
    clock = {"wall": 0.0, "cpu": 0.0}
    scfg = SolverConfig()
    solver_real, _ = _timed(clock, train_solver, *real["train"], scfg, steps=args.real_steps, seed=args.seed,
                            checkpoint=out / "solver_real.msgpack")
    acc_real = _score(solver_real, *real["test"], scfg)
    acc_real["val"] = _score(solver_real, *real["validation"], scfg)["acc"]
    styles = {name: run_style(name, args, real, clock, scfg) for name in args.styles.split(",")}
    head = styles.get("default") or next(iter(styles.values()))
    gain = 100 * (head["refined"]["acc"] - head["synthetic"]["acc"])
    result = {"acc_synthetic": head["synthetic"]["acc"], "acc_refined": head["refined"]["acc"], "acc_real": acc_real["acc"],
              "train_minutes": round(clock["wall"] / 60, 2), "cpu_minutes": round(clock["cpu"] / 60, 2),
              "char_acc_synthetic": head["synthetic"]["char_acc"], "char_acc_refined": head["refined"]["char_acc"],
              "char_acc_real": acc_real["char_acc"], "gain_points": round(gain, 1),
              "goal_gain_points": GOAL_POINTS, "goal_met": bool(gain >= GOAL_POINTS),
              "styles": styles, "test_n": len(real["test"][1]), "seed": args.seed}
    print(f"{'style':8s} {'trained on':10s} {'test acc':>8s} {'val acc':>8s}  per character")
    print(f"{'-':8s} {'real':10s} {acc_real['acc']:8.3f} {acc_real['val']:8.3f}  {acc_real['char_acc']}")
    for name, r in styles.items():
        for kind in ("synthetic", "refined"):
            print(f"{name:8s} {kind:10s} {r[kind]['acc']:8.3f} {r['val_' + kind]:8.3f}  {r[kind]['char_acc']}")
        print(f"{name:8s} GAN: {r['gan']}  labels kept {r['label_kept']:.3f} (synthetic {r['label_ref_on_synthetic']:.3f})")
    print(f"refined - synthetic = {gain:+.1f} points (goal >= {GOAL_POINTS:.0f}): "
          f"{'met' if gain >= GOAL_POINTS else 'not met'}; training {result['train_minutes']} min wall, "
          f"{result['cpu_minutes']} CPU min")
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
