"""Pictures of guaranteed sets: pavings, box hulls along a trajectory, tubes and marker boxes."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _rects(ax, boxes: np.ndarray, **style) -> None:
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Rectangle

    finite = np.all(np.isfinite(boxes.reshape(len(boxes), -1)), axis=1) if len(boxes) else np.zeros(0, bool)
    rects = [Rectangle(tuple(b[0]), *(b[1] - b[0])) for b in boxes[finite]]
    if rects:
        ax.add_collection(PatchCollection(rects, **style))


def draw_sets(path: str | Path, *, truth: np.ndarray | None = None, boxes: np.ndarray | None = None,
              inner: np.ndarray | None = None, boundary: np.ndarray | None = None,
              markers: np.ndarray | None = None, marker_boxes: np.ndarray | None = None,
              tube: np.ndarray | None = None, title: str = "", inset: bool = True) -> None:
    """Write a PNG: ``truth`` (K, 2) path, ``boxes`` (K, 2, 2) step hulls (red where the truth
    at that step is outside), the last paving (``inner`` green, ``boundary`` yellow), known
    ``markers`` (M, 2), SLAM ``marker_boxes`` (M, 2, 2) and ``tube`` (K, 2, 2). With ``inset``,
    a second panel zooms on the last paving."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    have_paving = inset and inner is not None and boundary is not None and len(inner) + len(boundary) > 0
    have_slam = tube is not None and len(tube) > 0
    n = 1 + have_slam + have_paving
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 6.5), squeeze=False)
    panels = list(axes[0])
    ax = panels.pop(0)
    slam_ax = panels.pop(0) if have_slam else None
    zoom = panels.pop(0) if have_paving else None
    if boxes is not None and len(boxes):
        ok = np.ones(len(boxes), bool)
        if truth is not None and len(truth) == len(boxes):
            ok = np.all((boxes[:, 0] <= truth) & (truth <= boxes[:, 1]), axis=1)
        _rects(ax, boxes[ok], facecolor="none", edgecolor="tab:blue", linewidth=0.5, alpha=0.6)
        _rects(ax, boxes[~ok], facecolor="none", edgecolor="red", linewidth=1.2)
    if slam_ax is not None:
        _rects(slam_ax, tube, facecolor="none", edgecolor="tab:purple", linewidth=0.5, alpha=0.6)
        if marker_boxes is not None and len(marker_boxes):
            _rects(slam_ax, marker_boxes, facecolor="magenta", edgecolor="purple", alpha=0.35)
        slam_ax.set_title("SLAM: the tube and the marker boxes (unknown markers)", fontsize=10)
    for a in axes[0]:
        if a is not slam_ax and inner is not None and len(inner):
            _rects(a, inner, facecolor="tab:green", edgecolor="darkgreen", linewidth=0.2)
        if a is not slam_ax and boundary is not None and len(boundary):
            _rects(a, boundary, facecolor="gold", edgecolor="goldenrod", linewidth=0.2)
        if truth is not None and len(truth):
            a.plot(truth[:, 0], truth[:, 1], "k-", lw=1)
            a.plot(*truth[-1], "k+", ms=12, mew=2)
        if markers is not None and len(markers):
            a.plot(markers[:, 0], markers[:, 1], "r*", ms=10)
        a.set_aspect("equal")
        a.grid(alpha=0.3)
        a.set_xlabel("x (m)")
        a.set_ylabel("y (m)")
        a.autoscale_view()
    ax.set_title(title, fontsize=10)
    if zoom is not None:
        both = np.concatenate([inner, boundary])
        lo, hi = both[:, 0].min(axis=0), both[:, 1].max(axis=0)
        pad = 0.15 * max(hi - lo) + 1e-3
        zoom.set_xlim(lo[0] - pad, hi[0] + pad)
        zoom.set_ylim(lo[1] - pad, hi[1] + pad)
        zoom.set_title(f"last paving: {len(inner)} inner (green), {len(boundary)} boundary (yellow), truth +",
                       fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
