"""Draw a foraging swarm and its delivery curve as an image (OpenCV; no matplotlib in a node)."""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

SOURCE = (120, 200, 255)     # BGR
NEST = (140, 220, 140)
ZONE = (240, 200, 150)
CARRYING = (40, 160, 40)     # green, as in the seed's figures
EMPTY = (200, 90, 30)        # blue
WAITING = (0, 0, 0)


def render_swarm(xy_m: np.ndarray, heading_rad: np.ndarray, carrying: np.ndarray, waiting: np.ndarray, *,
                 length_m: float, width_m: float, radius_m: float, source_m: float, nest_m: float,
                 zones_m: Sequence[float] = (), zone_width_m: float = 0.3, gate_width_m: float = -1.0,
                 gate_y_m: float = 0.5, px_per_m: float = 200.0, title: str = "",
                 food_curve: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of the arena (y up) with the robots, and below it food delivered against time.

    ``xy_m`` (N, 2); ``heading_rad``, ``carrying``, ``waiting`` (N,); ``food_curve`` (T, 2) of
    (t_s, food) if given. Robots with food are green, without blue; waiting robots get a black ring.
    """
    w, h = int(round(length_m * px_per_m)), int(round(width_m * px_per_m))
    img = np.full((h, w, 3), 255, np.uint8)

    def px(x: float, y: float) -> tuple[int, int]:
        return int(round(x * px_per_m)), int(round((width_m - y) * px_per_m))

    cv2.rectangle(img, px(0, width_m), px(source_m, 0), SOURCE, -1)
    cv2.rectangle(img, px(length_m - nest_m, width_m), px(length_m, 0), NEST, -1)
    for zc in zones_m:
        cv2.rectangle(img, px(zc - zone_width_m / 2, width_m), px(zc + zone_width_m / 2, 0), ZONE, -1)
        if gate_width_m > 0:
            cv2.line(img, px(zc, 0), px(zc, gate_y_m - gate_width_m / 2), (60, 60, 60), 3)
            cv2.line(img, px(zc, gate_y_m + gate_width_m / 2), px(zc, width_m), (60, 60, 60), 3)
    r_px = max(2, int(round(radius_m * px_per_m)))
    for (x, y), th, c, wt in zip(np.asarray(xy_m, float), np.asarray(heading_rad, float), carrying, waiting):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        centre = px(x, y)
        cv2.circle(img, centre, r_px, CARRYING if c else EMPTY, -1, cv2.LINE_AA)
        tip = px(x + radius_m * np.cos(th), y + radius_m * np.sin(th))
        cv2.line(img, centre, tip, (255, 255, 255), 2, cv2.LINE_AA)
        if wt:
            cv2.circle(img, centre, r_px, WAITING, 2, cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (0, 0, 0), 2)
    panels = [np.full((36, w, 3), 255, np.uint8), img]
    cv2.putText(panels[0], title, (8, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 1, cv2.LINE_AA)
    if food_curve is not None and len(food_curve) > 1:
        panels.append(_curve(np.asarray(food_curve, float), w))
    return np.vstack(panels)


def _curve(tf: np.ndarray, w: int, h: int = 160) -> np.ndarray:
    """Food delivered against time, axes labelled."""
    out = np.full((h, w, 3), 255, np.uint8)
    left, bottom, top = 60, h - 30, 15
    t_max, f_max = max(tf[-1, 0], 1e-9), max(tf[:, 1].max(), 1.0)
    pts = np.stack([left + tf[:, 0] / t_max * (w - left - 20), bottom - tf[:, 1] / f_max * (bottom - top)], 1)
    cv2.line(out, (left, bottom), (w - 20, bottom), (0, 0, 0), 1)
    cv2.line(out, (left, bottom), (left, top), (0, 0, 0), 1)
    cv2.polylines(out, [np.round(pts).astype(np.int32)], False, CARRYING, 2, cv2.LINE_AA)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(out, f"{f_max:.0f}", (8, top + 10), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(out, "food", (8, (top + bottom) // 2), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(out, f"t = {t_max:.0f} s", (w - 110, h - 8), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return out
