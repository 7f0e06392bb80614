"""Seed 08's test scene: one large seafloor image cut into eight overlapping sub-images,
visited 1-2-3-4 then 8-7-6-5, each seen through its own speckle, with a noisy navigation
prior. Only what the experiment needs: no sonar geometry, no fan.

>>> scene = subimage_scene(0, rotate=False)
>>> len(scene.images), scene.images[0].shape
(8, (320, 320))
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from nodes.slam.mosaic import cut

ORDER = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 3), (1, 2), (1, 1), (1, 0))     # (row, column): 1-2-3-4 / 8-7-6-5
SIZE = 320
STEP = 160                                                                  # half an image: 50 % overlap


def seafloor(rng: np.random.Generator, h: int = 600, w: int = 1000) -> np.ndarray:
    """Reflectivity in (0, 1): smooth noise at three scales (sediment ripples to patches)."""
    img = np.zeros((h, w), np.float32)
    for sigma, amp in ((2, 0.5), (6, 1.0), (20, 1.5)):
        layer = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), sigma)
        img += amp * (layer - layer.mean()) / layer.std()
    return (1 / (1 + np.exp(-img))).astype(np.float32)


@dataclass
class SubimageScene:
    big: np.ndarray
    truth: np.ndarray               # (8, 3) poses in pixels of the large image
    nav: np.ndarray                 # the navigation prior: truth + noise
    images: list[np.ndarray]


def subimage_scene(seed: int, *, rotate: bool, looks: int = 4, nav_sigma: tuple[float, float, float] = (8.0, 8.0, 0.03),
                   max_angle: float = 0.3, big: np.ndarray | None = None) -> SubimageScene:
    """The scene of one seed; ``rotate``: each sub-image turned by up to ``max_angle`` rad
    (then the prior's angle carries ``nav_sigma[2]`` noise; without rotation it is exact)."""
    rng = np.random.default_rng(seed)
    big = seafloor(rng) if big is None else big
    truth = np.array([[220 + STEP * c, 220 + STEP * r, rng.uniform(-max_angle, max_angle) if rotate else 0.0]
                      for r, c in ORDER])
    sigma = (nav_sigma[0], nav_sigma[1], nav_sigma[2] if rotate else 0.0)
    nav = truth + rng.normal(scale=sigma, size=truth.shape)
    images = [cut(big, p, SIZE) * rng.gamma(looks, 1.0 / looks, (SIZE, SIZE)).astype(np.float32) for p in truth]
    return SubimageScene(big=big, truth=truth, nav=nav, images=images)
