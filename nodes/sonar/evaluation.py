"""Localisation metrics and pictures for the sonar pipeline (pure: arrays in, numbers and PNGs out)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation error (m) and heading error (rad, wrapped to [0, pi]) between two 4x4 poses."""
    dt = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    # Heading of the boresight (x axis) projected on the horizontal plane; arctan2, not arctan.
    he = math.atan2(estimate[1, 0], estimate[0, 0])
    ht = math.atan2(truth[1, 0], truth[0, 0])
    return dt, abs(math.remainder(he - ht, 2 * math.pi))


def nearest(stamps: np.ndarray, stamp: int) -> int:
    """Index of the stamp closest to ``stamp`` (``stamps`` sorted ascending, non-empty)."""
    i = int(np.searchsorted(stamps, stamp))
    if i == 0:
        return 0
    if i == len(stamps):
        return len(stamps) - 1
    return i if stamps[i] - stamp < stamp - stamps[i - 1] else i - 1


def save_fan_png(path: str | Path, image: np.ndarray, m_per_px: float, origin_row: float, origin_col: float,
                 title: str = "") -> None:
    """The Cartesian fan with metric axes (x starboard, y ahead)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h, w = image.shape
    extent = (-origin_col * m_per_px, (w - origin_col) * m_per_px, (origin_row - h) * m_per_px, origin_row * m_per_px)
    fig, ax = plt.subplots(figsize=(7, 5.5))
    ax.imshow(image, cmap="copper", extent=extent, origin="upper", interpolation="nearest")
    ax.set_xlabel("starboard (m)")
    ax.set_ylabel("ahead (m)")
    ax.set_title(title or "sonar fan")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def save_cloud_png(path: str | Path, cloud: np.ndarray, model: np.ndarray, corrected: np.ndarray | None = None,
                   title: str = "", *, carved: np.ndarray | None = None, carved_sigma: np.ndarray | None = None,
                   carved_label: str = "carved cloud") -> None:
    """Top and side views of the accumulated cloud (raw and ICP-corrected) over the structure model.

    With ``carved`` (K, 3) a third row of views shows the elevation-resolved cloud alone over the
    model, coloured by ``carved_sigma`` (K,) elevation 1-sigma in m when given.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    def thin(p: np.ndarray, n: int = 20000) -> np.ndarray:
        return p if len(p) <= n else p[rng.choice(len(p), n, replace=False)]

    cloud, model = thin(cloud), thin(model)
    views = [(0, 1, "x east (m)", "y north (m)"), (0, 2, "x east (m)", "z up (m)")]
    fig, grid = plt.subplots(2 if carved is not None else 1, 2, figsize=(13, 11 if carved is not None else 5.5),
                             squeeze=False)
    axes = grid[0]
    if carved is not None:
        for ax, (i, j, xl, yl) in zip(grid[1], views):
            ax.scatter(model[:, i], model[:, j], s=1, c="0.75", label="structure model")
            if len(carved):
                colour = carved_sigma if carved_sigma is not None and len(carved_sigma) == len(carved) else "tab:green"
                sc = ax.scatter(carved[:, i], carved[:, j], s=2, c=colour, cmap="viridis", vmin=0.0, vmax=0.3,
                                label=carved_label)
                if carved_sigma is not None and len(carved_sigma) == len(carved):
                    fig.colorbar(sc, ax=ax, shrink=0.7, label="elevation 1-sigma (m)")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_aspect("equal")
            ax.set_title(f"{carved_label}: {len(carved)} points")
        grid[1][0].legend(loc="upper right", markerscale=8, fontsize=8)
    for ax, (i, j, xl, yl) in zip(axes, views):
        ax.scatter(model[:, i], model[:, j], s=1, c="0.6", label="structure model")
        ax.scatter(cloud[:, i], cloud[:, j], s=1, c="tab:red", alpha=0.4, label="cloud (navigation pose)")
        if corrected is not None and len(corrected):
            c = thin(corrected)
            ax.scatter(c[:, i], c[:, j], s=1, c="tab:blue", alpha=0.4, label="cloud after ICP")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_aspect("equal")
    axes[0].legend(loc="upper right", markerscale=8, fontsize=8)
    fig.suptitle(title or "highlight cloud over the structure model")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def surface_distances(points: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """Distance (m) from each of ``points`` (N, 3) to the nearest of the dense ``surface`` samples (M, 3).

    Sample the surface finely (a few cm): the nearest-sample distance overstates the distance to the
    surface by at most about half the sample spacing.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, float).reshape(-1, 3)
    if len(pts) == 0 or len(surface) == 0:
        return np.full(len(pts), np.inf)
    return cKDTree(np.asarray(surface, float)).query(pts, workers=1)[0]


def visible_surface(surface: np.ndarray, hits: np.ndarray, within_m: float = 0.1) -> np.ndarray:
    """The samples of ``surface`` (M, 3) that some true first hit (K, 3) of the run lands within ``within_m`` of."""
    from scipy.spatial import cKDTree

    surface = np.asarray(surface, float).reshape(-1, 3)
    hits = np.asarray(hits, float).reshape(-1, 3)
    if len(surface) == 0 or len(hits) == 0:
        return surface[:0]
    d, _ = cKDTree(hits).query(surface, distance_upper_bound=within_m, workers=1)
    return surface[np.isfinite(d)]


def cloud_metrics(cloud: np.ndarray, surface: np.ndarray, visible: np.ndarray | None = None) -> dict:
    """Accuracy and completeness of a reconstructed cloud against a structure's surface.

    Parameters
    ----------
    cloud : (N, 3) reconstructed points, world m.
    surface : (M, 3) dense samples of the structures' surfaces (the truth for accuracy).
    visible : (V, 3) samples of the surface the run saw (for completeness); None skips completeness.

    Returns
    -------
    dict with ``points``, ``acc_median_m``, ``acc_p90_m``, ``acc_frac_0p1``, ``acc_frac_0p2`` (cloud
    -> surface) and ``completeness_0p2`` (fraction of ``visible`` within 0.2 m of a cloud point).
    """
    from scipy.spatial import cKDTree

    d = surface_distances(cloud, surface)
    out = {"points": int(len(d)),
           "acc_median_m": float(np.median(d)) if len(d) else float("nan"),
           "acc_p90_m": float(np.percentile(d, 90)) if len(d) else float("nan"),
           "acc_frac_0p1": float(np.mean(d <= 0.1)) if len(d) else 0.0,
           "acc_frac_0p2": float(np.mean(d <= 0.2)) if len(d) else 0.0}
    if visible is not None:
        if len(visible) == 0:
            out["completeness_0p2"] = float("nan")
        elif len(cloud) == 0:
            out["completeness_0p2"] = 0.0
        else:
            near, _ = cKDTree(np.asarray(cloud, float)).query(np.asarray(visible, float), distance_upper_bound=0.2,
                                                              workers=1)
            out["completeness_0p2"] = float(np.mean(np.isfinite(near)))
    return out
