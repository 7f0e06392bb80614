"""A camera moving through a textured room, rendered for feature matching: planar textured
quads (floor, walls, a few boxes) at several depths -- a planar scene would make every pair
of views a homography, which is exactly what self-calibration must not be given -- drawn far
to near with perspective warps. Only what the scene needs: no lighting, no lens distortion.

    room = make_room(rng=np.random.default_rng(0))
    img = render_view(room, K, R, C, (640, 480))     # uint8 grey; R world->camera, C centre
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Quad:
    corners_m: np.ndarray     # (4, 3) world, in texture order (0,0) (w,0) (w,h) (0,h)
    texture: np.ndarray       # (h, w) uint8


def texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Multi-scale noise with sharp blobs and edges: corners for ORB and SIFT at every scale."""
    img = np.zeros((size, size), np.float32)
    for cells, amp in ((4, 60), (16, 40), (64, 25)):
        g = rng.normal(0, amp, (cells, cells)).astype(np.float32)
        img += cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
    for _ in range(120):
        c = tuple(int(v) for v in rng.integers(0, size, 2))
        if rng.random() < 0.5:
            cv2.circle(img, c, int(rng.integers(3, 18)), float(rng.uniform(-90, 90)), -1)
        else:
            d = rng.integers(4, 30, 2)
            cv2.rectangle(img, c, (c[0] + int(d[0]), c[1] + int(d[1])), float(rng.uniform(-90, 90)), -1)
    return np.clip(img + 128, 0, 255).astype(np.uint8)


def _tiles(corners: np.ndarray, tex: np.ndarray, n: int) -> list[Quad]:
    """Split a quad (and its texture) into n x n tiles, so a tile behind the camera can be skipped."""
    out = []
    h, w = tex.shape
    for i in range(n):
        for j in range(n):
            u0, u1, v0, v1 = j / n, (j + 1) / n, i / n, (i + 1) / n
            bil = lambda u, v: ((1 - u) * (1 - v) * corners[0] + u * (1 - v) * corners[1]      # noqa: E731
                                + u * v * corners[2] + (1 - u) * v * corners[3])
            c = np.array([bil(u0, v0), bil(u1, v0), bil(u1, v1), bil(u0, v1)])
            out.append(Quad(c, tex[int(v0 * h):int(v1 * h), int(u0 * w):int(u1 * w)]))
    return out


def make_room(*, rng: np.random.Generator, depth_m: float = 8.0) -> list[Quad]:
    """Floor, back and side walls, ceiling-less, and three boxes' faces, each textured."""
    d = depth_m
    quads = []
    walls = [np.array([[-3, -2, d], [3, -2, d], [3, 1.5, d], [-3, 1.5, d]]),                 # back
             np.array([[-3, 1.5, d], [3, 1.5, d], [3, 1.5, 0.3], [-3, 1.5, 0.3]]),           # floor (y down)
             np.array([[-3, -2, 0.3], [-3, -2, d], [-3, 1.5, d], [-3, 1.5, 0.3]]),           # left
             np.array([[3, -2, d], [3, -2, 0.3], [3, 1.5, 0.3], [3, 1.5, d]])]               # right
    for w in walls:
        quads += _tiles(w.astype(float), texture(rng), 4)
    for cx, cz, s in ((-1.4, 4.0, 0.8), (1.2, 5.0, 1.0), (0.2, 6.2, 0.9)):
        front = np.array([[cx - s / 2, 1.5 - s, cz], [cx + s / 2, 1.5 - s, cz], [cx + s / 2, 1.5, cz],
                          [cx - s / 2, 1.5, cz]])
        side = np.array([[cx + s / 2, 1.5 - s, cz], [cx + s / 2, 1.5 - s, cz + s], [cx + s / 2, 1.5, cz + s],
                         [cx + s / 2, 1.5, cz]])
        top = np.array([[cx - s / 2, 1.5 - s, cz + s], [cx + s / 2, 1.5 - s, cz + s], [cx + s / 2, 1.5 - s, cz],
                        [cx - s / 2, 1.5 - s, cz]])
        quads += [Quad(front, texture(rng, 256)), Quad(side, texture(rng, 256)), Quad(top, texture(rng, 256))]
    return quads


def render_view(quads: list[Quad], K: np.ndarray, R: np.ndarray, C: np.ndarray, size: tuple[int, int], *,
                rng: np.random.Generator | None = None, noise_grey: float = 2.0) -> np.ndarray:
    """The grey image of the room from a camera (R: world -> camera, C: centre), far to near."""
    w, h = size
    img = np.full((h, w), 40, np.uint8)
    order = []
    for q in quads:
        Xc = (q.corners_m - C) @ R.T
        if np.any(Xc[:, 2] < 0.15):
            continue                                   # a tile crossing the image plane: skipped
        x = Xc @ K.T
        px = (x[:, :2] / x[:, 2:]).astype(np.float32)
        if px[:, 0].max() < 0 or px[:, 0].min() > w or px[:, 1].max() < 0 or px[:, 1].min() > h:
            continue
        order.append((float(Xc[:, 2].mean()), px, q.texture))
    for _, px, tex in sorted(order, key=lambda o: -o[0]):
        th, tw = tex.shape
        src = np.float32([[0, 0], [tw, 0], [tw, th], [0, th]])
        H = cv2.getPerspectiveTransform(src, px)
        warped = cv2.warpPerspective(tex, H, (w, h), flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.full_like(tex, 255), H, (w, h), flags=cv2.INTER_NEAREST)
        img[mask > 0] = warped[mask > 0]
    if rng is not None and noise_grey > 0:
        img = np.clip(img + rng.normal(0, noise_grey, img.shape), 0, 255).astype(np.uint8)
    return img
