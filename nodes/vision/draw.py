"""Pictures of a reconstructed cable: both images with the tracked curves, and the 3-D curve
against the truth (seen from above and from the side, with one-sigma depth bars)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def overlay_tracks(image: np.ndarray, tracks: list[np.ndarray], points_px: np.ndarray | None = None) -> np.ndarray:
    """A copy of ``image`` with tracked polylines (red) and matched points (green)."""
    out = image.copy()
    for t in tracks:
        if len(t) > 1:
            cv2.polylines(out, [np.round(t).astype(np.int32)], False, (0, 0, 255), 1, cv2.LINE_AA)
    if points_px is not None:
        for x, y in np.round(points_px).astype(int):
            cv2.circle(out, (int(x), int(y)), 1, (0, 255, 0), -1)
    return out


def draw_cable(path: str | Path, *, left: np.ndarray, right: np.ndarray, points_m: np.ndarray,
               sigma_m: np.ndarray, left_px: np.ndarray, truth_m: np.ndarray | None = None,
               tracks_left: list[np.ndarray] = (), tracks_right: list[np.ndarray] = (), title: str = "") -> None:
    """Write a PNG: top row the two images with the tracked curve, bottom row the cable from
    above (x-z) and from the side (z-y), reconstruction against the truth."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 10))
    ax_l, ax_r = fig.add_subplot(2, 2, 1), fig.add_subplot(2, 2, 2)
    ax_l.imshow(cv2.cvtColor(overlay_tracks(left, list(tracks_left), left_px), cv2.COLOR_BGR2RGB))
    ax_r.imshow(cv2.cvtColor(overlay_tracks(right, list(tracks_right)), cv2.COLOR_BGR2RGB))
    ax_l.set_title("left: tracked (red), matched (green)")
    ax_r.set_title("right: tracked")
    for a in (ax_l, ax_r):
        a.axis("off")
    top, side = fig.add_subplot(2, 2, 3), fig.add_subplot(2, 2, 4)
    for ax, (i, j), names in ((top, (0, 2), ("x (m)", "z (m)")), (side, (2, 1), ("z (m)", "y (m, down)"))):
        if truth_m is not None and len(truth_m):
            ax.plot(truth_m[:, i], truth_m[:, j], "-", color="0.4", lw=1.5, label="truth")
        if len(points_m):
            err_i = sigma_m[:, i] if i == 2 else None
            err_j = sigma_m[:, j] if j == 2 else None
            ax.errorbar(points_m[:, i], points_m[:, j], xerr=err_i, yerr=err_j, fmt=".", ms=2, color="tab:red",
                        ecolor="tab:orange", elinewidth=0.5, label="stereo (1-sigma depth)")
        ax.set_xlabel(names[0])
        ax.set_ylabel(names[1])
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    side.invert_yaxis()
    top.set_title("from above")
    side.set_title("from the side")
    fig.suptitle(title)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
