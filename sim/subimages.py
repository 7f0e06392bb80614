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


def seafloor(rng: np.random.Generator, h: int = 600, w: int = 1000, *,
             scales_px: tuple[float, float, float] = (2.0, 6.0, 20.0)) -> np.ndarray:
    """Reflectivity in (0, 1): smooth noise at three scales (sediment ripples to patches)."""
    img = np.zeros((h, w), np.float32)
    for sigma, amp in zip(scales_px, (0.5, 1.0, 1.5)):
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


def survey_pings(scene, *, duration_s: float, rate_hz: float = 10.0, seed: int = 0, range_m: float = 20.0,
                 beams: int = 256, bias=(0.4, -0.3, 3.0), walk=(0.05, 0.3)):
    """Yield ``(t_s, SonarPing, nav Pose3D, truth Pose3D)`` of an FLS scene's platform run, in
    virtual time: the sonar rendered at ``rate_hz``, the navigation drifting like
    :class:`sim.nav_drift.DriftingNav` (bias (x m, y m, yaw deg) and a random walk per sqrt s)."""
    import math

    from msgs.geometry import Pose3D
    from msgs.sonar import SonarPing
    from sim.fls_render import PingSettings, render_ping
    from sim.nav_drift import drift_matrix

    rng = np.random.default_rng(seed)
    settings = PingSettings(n_beams=beams, range_m=range_m)
    drift = np.zeros(3)
    for k in range(int(duration_s * rate_hz)):
        t = k / rate_hz
        stamp = int(round(t * 1e9))
        pose = scene.sonar_pose(t)
        r = render_ping(scene, pose, settings, rng=rng)
        drift += rng.normal(0, 1, 3) * np.array([walk[0], walk[0], math.radians(walk[1])]) * math.sqrt(1 / rate_hz)
        nav = drift_matrix(bias[0] + drift[0], bias[1] + drift[1], math.radians(bias[2]) + drift[2]) @ pose
        ping = SonarPing(stamp_ns=stamp, frame_id="sonar", intensities=r.intensities,
                         bearings_rad=r.bearings_rad.astype(np.float32), range_resolution_m=r.range_resolution_m,
                         range_m=r.range_m, frequency_hz=r.frequency_hz,
                         vertical_aperture_rad=r.vertical_aperture_rad, horizontal_aperture_rad=r.horizontal_aperture_rad,
                         ping_id=k + 1)
        yield t, ping, Pose3D.from_matrix(nav, stamp_ns=stamp, frame_id="world"), \
            Pose3D.from_matrix(pose, stamp_ns=stamp, frame_id="world")
