"""Picture of a multi-robot SLAM run: every robot's trajectory in its colour, inter-robot closures drawn."""
from __future__ import annotations

from pathlib import Path

import numpy as np

COLOURS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]


def draw_team(path: Path, trajectories: dict[int, tuple[np.ndarray, np.ndarray]], *, accepted: np.ndarray,
              rejected: np.ndarray, reference: dict[int, np.ndarray] | None = None, title: str = "") -> Path:
    """Write a PNG: ``trajectories`` robot -> (ids (N,), poses (N, 3)); closures (C, 2) vertex-id pairs,
    accepted in grey, rejected in red dashes; ``reference`` id -> (x, y) dotted black (the centralised optimum)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    where = {int(v): p[:2] for _, (ids, poses) in trajectories.items() for v, p in zip(ids.tolist(), poses)}
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    if reference:
        ref = np.array([reference[v] for v in sorted(reference)])
        ax.plot(ref[:, 0], ref[:, 1], ":", color="k", lw=0.8, label="centralised optimum")
    for kind, pairs, style in (("accepted", accepted, dict(color="0.6", lw=0.4)),
                               ("rejected", rejected, dict(color="red", lw=0.8, ls="--"))):
        drawn = False
        for a, b in np.asarray(pairs, np.int64).reshape(-1, 2).tolist():
            if a in where and b in where:
                ax.plot(*np.array([where[a], where[b]]).T, **style, label=None if drawn else f"{kind} closures")
                drawn = True
    for r, (ids, poses) in sorted(trajectories.items()):
        if len(poses):
            ax.plot(poses[:, 0], poses[:, 1], "-", color=COLOURS[r % len(COLOURS)], lw=1.2, label=f"robot {r}")
            ax.plot(*poses[0, :2], "o", color=COLOURS[r % len(COLOURS)], ms=5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
