"""Small labelled image sets for the learning benches, as (N, 28, 28, 1) float32 in [0, 1]."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def to28(images: np.ndarray) -> np.ndarray:
    """(N, H, W) grey images in [0, 1] resized to (N, 28, 28, 1) (area when shrinking, linear when growing)."""
    images = np.asarray(images, np.float32)
    out = np.empty((len(images), 28, 28, 1), np.float32)
    for i, im in enumerate(images):
        interp = cv2.INTER_AREA if im.shape[0] > 28 else cv2.INTER_LINEAR
        out[i, :, :, 0] = cv2.resize(im, (28, 28), interpolation=interp)
    return np.clip(out, 0.0, 1.0)


def digits28() -> tuple[np.ndarray, np.ndarray]:
    """scikit-learn's 1,797 handwritten 8x8 digits (UCI), upsampled to 28x28 like MNIST's frame."""
    from sklearn.datasets import load_digits

    d = load_digits()
    return to28(d.images / 16.0), d.target.astype(np.int32)


def hand_digits28(root: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The sign-language digit photos (``root/images/<digit>/*``), grey, 28x28; labels = the digit."""
    root = Path(root)
    images, labels = [], []
    for folder in sorted(p for p in (root / "images").iterdir() if p.is_dir() and p.name.isdigit()):
        for path in sorted(folder.iterdir()):
            im = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if im is None:
                continue                      # not an image: skipped (the folder holds only photos)
            images.append(im.astype(np.float32) / 255.0)
            labels.append(int(folder.name))
    if not images:
        raise FileNotFoundError(f"no images under {root / 'images'}")
    return to28(np.stack(images)), np.array(labels, np.int32)


def split(labels: np.ndarray, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Stratified (train, test) indices: ``test_fraction`` of every class held out."""
    rng = np.random.default_rng(seed)
    train, test = [], []
    for c in np.unique(labels):
        idx = rng.permutation(np.flatnonzero(labels == c))
        k = int(round(test_fraction * len(idx)))
        test.append(idx[:k])
        train.append(idx[k:])
    return np.sort(np.concatenate(train)), np.sort(np.concatenate(test))
