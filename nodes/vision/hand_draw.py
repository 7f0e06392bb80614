"""Pictures of hands: keypoints over an image, and a gesture-teleoperation run (gestures over
time against the truth, the commands with the dead man's stops, the robot's path)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["draw_keypoints", "draw_teleop"]

_BONES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (5, 9), (9, 10), (10, 11), (11, 12),
          (9, 13), (13, 14), (14, 15), (15, 16), (13, 17), (0, 17), (17, 18), (18, 19), (19, 20)]
_COLOURS = [(0, 0, 255), (0, 160, 255), (0, 220, 0), (255, 160, 0), (255, 0, 200)]


def draw_keypoints(image: np.ndarray, keypoints_px: np.ndarray, *, text: str = "") -> np.ndarray:
    """A BGR copy of ``image`` with the 21-keypoint skeleton (a colour per finger) and ``text``."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    kp = np.asarray(keypoints_px, float)
    if kp.shape == (21, 2) and np.all(np.isfinite(kp)):
        for a, b in _BONES:
            f = max(0, (b - 1) // 4) if b > 0 else 0
            cv2.line(out, tuple(np.round(kp[a]).astype(int)), tuple(np.round(kp[b]).astype(int)), _COLOURS[f], 1,
                     cv2.LINE_AA)
        for p in np.round(kp).astype(int):
            cv2.circle(out, (int(p[0]), int(p[1])), 1, (255, 255, 255), -1)
    if text:
        cv2.putText(out, text, (2, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 255), 1, cv2.LINE_AA)
    return out


def draw_teleop(path: str | Path, *, truth: list[tuple[float, str]], seen: list[tuple[float, str, float]],
                cmds: np.ndarray, path_xy: np.ndarray, frames: list[np.ndarray] = (), deadman_s: float = 0.3,
                title: str = "") -> None:
    """Write a PNG of a teleoperation run.

    Parameters
    ----------
    truth : [(t_s, gesture)] shown to the camera ("none": no hand; missing times: no image)
    seen : [(t_s, gesture, confidence)] recognised
    cmds : (N, 3) t_s, v_mps, w_radps commanded
    path_xy : (M, 2) the robot's path, m
    frames : a few BGR frames with keypoints drawn, shown along the top
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = sorted({g for _, g in truth} | {g for _, g, _ in seen})
    y = {g: i for i, g in enumerate(names)}
    fig = plt.figure(figsize=(11, 7.5))
    n_f = len(frames)
    gs = fig.add_gridspec(3, max(n_f, 3), height_ratios=[1.0, 1.3, 1.3])
    for i, f in enumerate(frames):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(f[..., ::-1])
        ax.axis("off")
    ax = fig.add_subplot(gs[1, :])
    if truth:
        t, g = zip(*truth)
        ax.plot(t, [y[x] for x in g], "k.", ms=6, label="shown to the camera")
    if seen:
        t, g, c = zip(*seen)
        sc = ax.scatter(t, [y[x] + 0.15 for x in g], c=c, cmap="viridis", vmin=0, vmax=1, s=8, label="recognised")
        fig.colorbar(sc, ax=ax, label="confidence", pad=0.01)
    ax.set_yticks(range(len(names)), names)
    ax.set_xlabel("t, s")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title or "gesture teleoperation")
    ax2 = fig.add_subplot(gs[2, :-1])
    if len(cmds):
        ax2.plot(cmds[:, 0], cmds[:, 1], label="v, m/s")
        ax2.plot(cmds[:, 0], cmds[:, 2], label="w, rad/s")
        stopped = (cmds[:, 1] == 0) & (cmds[:, 2] == 0)
        ax2.fill_between(cmds[:, 0], -0.7, 0.7, where=stopped, color="red", alpha=0.12, step="mid",
                         label=f"zero command (stop / dead man {deadman_s:.1f} s)")
    ax2.set_xlabel("t, s")
    ax2.legend(fontsize=8, loc="upper right")
    ax3 = fig.add_subplot(gs[2, -1])
    if len(path_xy):
        ax3.plot(path_xy[:, 0], path_xy[:, 1], "b-")
        ax3.plot(path_xy[0, 0], path_xy[0, 1], "go")
        ax3.plot(path_xy[-1, 0], path_xy[-1, 1], "rs")
    ax3.set_aspect("equal", "datalim")
    ax3.set_title("wheelchair path (m)", fontsize=9)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
