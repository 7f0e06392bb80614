"""Train the hand keypoint network on simulator images, reproducibly (seeded), and write the
weights (flax msgpack) and a learning-curve PNG.

    python -m sim.hand_train --images 2000 --steps 200 -o /tmp/w.msgpack              # a quick look

The committed weights came from two runs of under 10 minutes each on 2 shared cores:

    nice python -m sim.hand_train -o /tmp/stage1.msgpack           # 10,000 scenes, 3,000 steps of 16
    nice python -m sim.hand_train --init /tmp/stage1.msgpack --images 15000 --steps 4000 --lr 2e-3 \
        --seed 1 --heat-weight 0.2 -o nodes/vision/weights/hand_keypoints.msgpack

(the first run predates the finger-state head, which the second added from a fresh start
(``KeypointModel.warm_start``); rerunning both today trains the head in the first run too, so
the result is comparable, not bit-identical).

The training scenes are drawn from seeds ``--seed`` onward (:func:`training_scenes`); the
benchmark evaluates on a disjoint seed range (``bench/hand_gesture.py``), and no real photo is
used for training or tuning.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from nodes.vision.hand_keypoints import INPUT_PX, WEIGHTS, KeypointModel
from nodes.vision.hand_learn import Progress, train_keypoints
from sim.hand_render import SceneSpec, render_scene

log = logging.getLogger("hand_train")

TRAIN_SEED = 1000            # training scenes: seeds TRAIN_SEED + i; the bench uses seeds below 1000


def random_training_spec(rng: np.random.Generator, size: int = INPUT_PX) -> SceneSpec:
    """A scene for training: 8 % without a hand, 10 % with two, 10 % mono, the rest random."""
    u = rng.random()
    hands = 0 if u < 0.08 else (2 if u < 0.18 else 1)
    return SceneSpec(hands=hands, width_px=size, height_px=size, mono=bool(rng.random() < 0.1))


def training_scenes(n: int, seed: int = TRAIN_SEED, size: int = INPUT_PX
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``n`` scenes: images (n, size, size, 3) uint8 RGB, keypoints (n, 21, 2), present (n,),
    extended fingers (n, 5)."""
    images = np.zeros((n, size, size, 3), np.uint8)
    kps = np.full((n, 21, 2), np.nan, np.float32)
    present = np.zeros(n, bool)
    extended = np.zeros((n, 5), bool)
    for i in range(n):
        rng = np.random.default_rng(seed + i)
        img, truth = render_scene(rng, random_training_spec(rng, size))
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img
        images[i] = img[..., ::-1]
        kps[i], present[i], extended[i] = truth.keypoints_px, truth.present, truth.extended
    return images, kps, present, extended


def plot_curve(curve: list[Progress], path: str | Path) -> None:
    """Training loss, validation loss and median keypoint error against step, as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [p.step for p in curve]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    ax[0].semilogy(steps, [p.loss for p in curve], label="train")
    ax[0].semilogy(steps, [p.val_loss for p in curve], label="validation")
    ax[0].set_xlabel("step")
    ax[0].set_ylabel("loss (L1/96 + 0.05 heat CE + 0.2 BCE)")
    ax[0].legend()
    ax[1].plot(steps, [p.val_px for p in curve])
    ax[1].set_xlabel("step")
    ax[1].set_ylabel("median keypoint error, px of 96")
    ax[1].grid(alpha=0.3)
    fig.suptitle("hand keypoint net on simulated hands")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", default=str(WEIGHTS), help="weights file (flax msgpack)")
    ap.add_argument("--images", type=int, default=10000, help="training scenes rendered")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--seed", type=int, default=0, help="seeds the training; scenes are TRAIN_SEED + i")
    ap.add_argument("--heat-weight", type=float, default=0.05, help="weight of the heatmap cross-entropy")
    ap.add_argument("--init", default="", help="start from these weights (fine-tuning) instead of fresh ones")
    ap.add_argument("--curve", default="out/hand_train_curve.png")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    t0 = time.perf_counter()
    images, kps, present, extended = training_scenes(args.images)
    log.info("rendered %d scenes in %.0f s", args.images, time.perf_counter() - t0)

    def show(p: Progress) -> None:
        log.info("step %5d/%d  loss %.4f  val %.4f  val median %.2f px  %.0f s", p.step, args.steps, p.loss,
                 p.val_loss, p.val_px, p.elapsed_s)

    init = KeypointModel.warm_start(args.init).params if args.init else None
    params, curve = train_keypoints(images, kps, present, extended, steps=args.steps, batch=args.batch, lr=args.lr,
                                    seed=args.seed, progress=show, params=init,
                                    heat_weight=args.heat_weight)
    size = KeypointModel(params).save(args.out)
    plot_curve(curve, args.curve)
    log.info("wrote %s (%.0f kB) and %s", args.out, size / 1024, args.curve)
    return 0


if __name__ == "__main__":
    sys.exit(main())
