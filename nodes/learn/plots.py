"""Training figures: loss curves and image grids (PNG), for the learning tools to write and people to open."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> None:
    """Lay out, write (the folder made if missing) and close a figure."""
    plt = _plt()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_curves(curves: Mapping[str, tuple[Sequence[float], Sequence[float]]], path: str | Path, *,
                xlabel: str = "step", ylabel: str = "loss", title: str = "", logy: bool = False) -> None:
    """One line per ``name -> (x, y)``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for name, (x, y) in curves.items():
        ax.plot(np.asarray(x), np.asarray(y), label=name)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)


def image_grid(images: np.ndarray, path: str | Path, *, cols: int = 8, titles: Sequence[str] | None = None,
               rows_label: Sequence[str] | None = None) -> None:
    """A grid of (N, H, W) or (N, H, W, 3) images scaled to [0, 1] per image; optional titles."""
    plt = _plt()
    images = np.asarray(images, np.float64)
    n = len(images)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(1.4 * cols, 1.4 * rows), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if i >= n:
            continue
        im = images[i]
        lo, hi = np.nanmin(im), np.nanmax(im)
        ax.imshow((im - lo) / (hi - lo) if hi > lo else np.zeros_like(im), cmap="gray" if im.ndim == 2 else None)
        if titles is not None:
            ax.set_title(titles[i], fontsize=7)
    if rows_label is not None:
        for r, label in enumerate(rows_label[:rows]):
            axes[r, 0].text(-0.1, 0.5, label, transform=axes[r, 0].transAxes, ha="right", va="center", fontsize=7)
    _save(fig, path)


def draw_episodes(episodes: Mapping[int, tuple[np.ndarray, np.ndarray]], finals: Mapping[int, Mapping[str, float]],
                  path: str | Path, *, walls: Sequence[Sequence[float]] = ()) -> None:
    """Paths of the simple car's episodes and their distance to the target over time.

    ``episodes``: episode -> (times (T,) s, observations (T, >= 6): x, y, cos, sin, target x, y);
    ``finals``: episode -> metrics at its end (``distance_m`` labels the line); ``walls``: segments.
    """
    plt = _plt()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.6))
    for seg in walls:
        ax.plot([seg[0], seg[2]], [seg[1], seg[3]], "k-", lw=2)
    for k, (t, o) in sorted(episodes.items()):
        line, = ax.plot(o[:, 0], o[:, 1], "-", lw=1.2)
        ax.plot(o[0, 0], o[0, 1], "o", color=line.get_color(), ms=4)
        ax.plot(o[0, 4], o[0, 5], "x", color=line.get_color(), ms=9, mew=2)
        dist = np.hypot(o[:, 4] - o[:, 0], o[:, 5] - o[:, 1])
        label = f"episode {k}"
        if "distance_m" in finals.get(k, {}):
            label += f": final {finals[k]['distance_m'] * 1000:.1f} mm"
        bx.semilogy(t, np.maximum(dist, 1e-4), color=line.get_color(), label=label)
    ax.set_aspect("equal")
    ax.set_title("paths (o start, x target)")
    bx.axhline(0.008, color="grey", ls="--", lw=1, label="paper's 8 mm")
    bx.set_xlabel("time (s)")
    bx.set_ylabel("straight-line distance to target (m)")
    bx.legend(fontsize=8)
    for a in (ax, bx):
        a.grid(alpha=0.3)
    _save(fig, path)
