"""Pictures of a reconstructed cable: both images with the tracked curves, and the 3-D curve
against the truth (seen from above and from the side, with one-sigma depth bars)."""
from __future__ import annotations

import math
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


def draw_homing(path: str | Path, gm, *, truth: np.ndarray, ins: np.ndarray, fixes: np.ndarray,
                target: tuple[float, float]) -> None:
    """Write a PNG of a UAV homing run: the path over the map (truth, INS, accepted fixes,
    start, target) and the distance to the target and the fix error over time. ``truth`` and
    ``ins`` (K, 3) rows of (stamp_ns, e, n); ``fixes`` (M, 4) rows of (stamp_ns, ok, e, n)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = truth
    t0 = T[0, 0]
    F = fixes[fixes[:, 1] > 0]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 6))
    h, w = gm.image.shape[:2]
    corners = gm.to_world(np.array([[0, 0], [w, h]], float))
    ax.imshow(gm.image[..., ::-1], extent=(corners[0, 0], corners[1, 0], corners[1, 1], corners[0, 1]))
    ax.plot(T[:, 1], T[:, 2], "w-", lw=2, label="truth")
    if len(ins):
        ax.plot(ins[:, 1], ins[:, 2], "y--", lw=1, label="INS (drifts)")
    if len(F):
        ax.plot(F[:, 2], F[:, 3], "g.", ms=4, label="geo fixes")
    ax.plot([T[0, 1]], [T[0, 2]], "bo", label="start")
    ax.plot([target[0]], [target[1]], "r*", ms=15, label="target")
    ax.set_xlim(min(corners[:, 0].min(), T[:, 1].min()) - 10, max(corners[:, 0].max(), T[:, 1].max()) + 10)
    ax.set_ylim(min(corners[:, 1].min(), T[:, 2].min()) - 10, max(corners[:, 1].max(), T[:, 2].max()) + 10)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.legend(loc="best", fontsize=8)
    dist = np.hypot(T[:, 1] - target[0], T[:, 2] - target[1])
    bx.semilogy((T[:, 0] - t0) / 1e9, np.maximum(dist, 1e-3), label="distance to target (truth)")
    tr = {s: (e, n) for s, e, n in zip(T[:, 0], T[:, 1], T[:, 2])}
    err = [(s, math.hypot(e - tr[s][0], n - tr[s][1])) for s, _, e, n in F if s in tr]
    if err:
        E = np.array(err)
        bx.semilogy((E[:, 0] - t0) / 1e9, np.maximum(E[:, 1], 1e-3), "g.", label="fix error")
    bx.set_xlabel("time (s)")
    bx.set_ylabel("m")
    bx.grid(alpha=0.3, which="both")
    bx.legend()
    fig.suptitle(f"UAV homing: {len(F)} of {len(fixes)} frames fixed; final distance {dist[-1]:.2f} m")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=70)
    plt.close(fig)
