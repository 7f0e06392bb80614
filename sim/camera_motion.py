"""Camera motions through a rigid scene, for self-calibration: views of random 3-D points by one
camera moving in one of the ways the issue names, and the pixel correspondences between them.

Frames: world x right, y down, z forward (OpenCV camera convention at the first view).
Motions (``MOTIONS``):

* ``general``: centres anywhere within a metre, each view looking at a different point of the
  scene with some roll -- rotations of 10-30 degrees about varied axes;
* ``small_rotation``: the same centres, rotations below 5 degrees;
* ``translation``: no rotation at all (a critical motion: the Kruppa equations hold for any K);
* ``fixating``: a turntable orbit, every optical axis through the same point (critical);
* ``single_axis``: rotations about one axis only, centres moving (critical for constant
  intrinsics with a free principal point: Sturm's classes);
* ``rotation``: the centre fixed, rotations about varied axes (the infinite homography case).

    views = camera_views("general", n_views=8, rng=np.random.default_rng(0))
    pairs = correspondences(views, K, image_size=(640, 480), noise_px=0.5, rng=rng)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

MOTIONS = ("general", "small_rotation", "translation", "fixating", "single_axis", "rotation")
CRITICAL = ("translation", "fixating", "single_axis")

#: the left camera of ../shared/data/camera's chessboard set, by cv2.calibrateCamera (SOURCES.md)
K_CHESSBOARD = np.array([[536.07, 0, 342.37], [0, 536.02, 235.54], [0, 0, 1.0]])


@dataclass(frozen=True)
class View:
    R: np.ndarray          # world -> camera rotation
    C: np.ndarray          # camera centre in the world


def look_at(C: np.ndarray, target: np.ndarray, roll_rad: float = 0.0) -> np.ndarray:
    """World -> camera rotation of a camera at C looking at target (y down), rolled about its axis."""
    z = target - C
    z = z / np.linalg.norm(z)
    up = np.array([0.0, -1.0, 0.0])
    x = np.cross(-up, z) if abs(z @ up) < 0.99 else np.array([1.0, 0, 0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    c, s = math.cos(roll_rad), math.sin(roll_rad)
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) @ R


def scene_points(n: int, rng: np.random.Generator, *, depth_m: float = 6.0, size_m: float = 4.0) -> np.ndarray:
    """(n, 3) points filling a box in front of the first view (depth 0.6-1.4 x depth_m)."""
    return np.stack([rng.uniform(-size_m / 2, size_m / 2, n), rng.uniform(-size_m / 2.6, size_m / 2.6, n),
                     rng.uniform(0.6 * depth_m, 1.4 * depth_m, n)], axis=1)


def camera_views(motion: str, *, n_views: int = 8, rng: np.random.Generator, depth_m: float = 6.0,
                 min_angle_deg: float | None = None) -> list[View]:
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {MOTIONS}, got {motion!r}")
    centre = np.array([0.0, 0.0, depth_m])
    views = []
    for k in range(n_views):
        if motion == "general":
            C = rng.uniform(-1.0, 1.0, 3)
            R = look_at(C, centre + rng.uniform(-1.8, 1.8, 3) * [1, 0.8, 0.5], rng.uniform(-0.35, 0.35))
        elif motion == "small_rotation":
            C = rng.uniform(-1.0, 1.0, 3)
            axis = rng.normal(size=3)
            R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(rng.uniform(0, 2.5))).as_matrix()
        elif motion == "translation":
            C = rng.uniform(-1.0, 1.0, 3)
            R = np.eye(3)
        elif motion == "fixating":
            a = math.radians(-30 + 60 * k / max(n_views - 1, 1)) + rng.uniform(-0.05, 0.05)
            C = centre + depth_m * np.array([math.sin(a), 0.0, -math.cos(a)])
            R = look_at(C, centre)
        elif motion == "single_axis":
            a = math.radians(rng.uniform(-25, 25))
            C = np.array([rng.uniform(-1, 1), 0.0, rng.uniform(-1, 1)])
            R = Rotation.from_rotvec([0.0, a, 0.0]).as_matrix()
        else:                                   # rotation
            C = np.zeros(3)
            R = look_at(C, centre + rng.uniform(-1.8, 1.8, 3) * [1, 0.8, 0.3], rng.uniform(-0.35, 0.35))
        views.append(View(R, C))
    return views


def project(K: np.ndarray, view: View, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixels and (N,) depth of world points in a view."""
    Xc = (X - view.C) @ view.R.T
    z = Xc[:, 2]
    x = Xc @ K.T
    return x[:, :2] / np.where(np.abs(x[:, 2:]) > 1e-12, x[:, 2:], 1e-12), z


def correspondences(views: list[View], K: np.ndarray, *, image_size: tuple[int, int] = (640, 480),
                    noise_px: float = 0.5, n_points: int = 300, rng: np.random.Generator,
                    pairs: list[tuple[int, int]] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Noisy pixel correspondences (pts_i, pts_j) for each pair of views (default: neighbours and
    second neighbours), points seen in front of both cameras and inside both images."""
    X = scene_points(n_points, rng)
    w, h = image_size
    seen = []
    for v in views:
        x, z = project(K, v, X)
        x = x + rng.normal(0, noise_px, x.shape)
        ok = (z > 0.1) & (x[:, 0] >= 0) & (x[:, 0] < w) & (x[:, 1] >= 0) & (x[:, 1] < h)
        seen.append((x, ok))
    n = len(views)
    pairs = pairs or [(i, i + 1) for i in range(n - 1)] + [(i, i + 2) for i in range(n - 2)]
    out = []
    for i, j in pairs:
        both = seen[i][1] & seen[j][1]
        out.append((seen[i][0][both], seen[j][0][both]))
    return out
