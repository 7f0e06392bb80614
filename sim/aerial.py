"""A UAV over a geo-referenced map (seed 11): four commands with limits (planar translation,
yaw, climb, descend), its nadir camera rendered from the map at the altitude's scale and the
yaw's rotation, with blur, exposure change and noise; ground truth. Only what the scene needs:
a flat ground, a pinhole camera looking straight down.

Frames: the world is local east-north (metres); a map image has an affine ``G`` (2x3) from
its pixels (u right, v down) to east-north. The UAV's yaw is the heading of its camera's image
"up", counter-clockwise from east.

    gm = procedural_map(rng=np.random.default_rng(0))          # or brighton_map() (real, georeferenced)
    uav = Uav(UavState(e=10, n=-5, yaw=0.3, alt=40))
    uav.step(Command(forward=2.0), dt=0.1)
    img = render_nadir(gm, uav.state, CAMERA)                   # (480, 640, 3) uint8
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from nodes.vision.geomap import GeoMap, brighton_map, procedural_map

__all__ = ["CAMERA", "Camera", "Command", "GeoMap", "Limits", "Look", "Uav", "UavState", "brighton_map",
           "camera_to_map", "procedural_map", "render_nadir"]


@dataclass(frozen=True)
class Camera:
    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 80.0

    def ground_m_per_px(self, alt_m: float) -> float:
        return 2 * alt_m * math.tan(math.radians(self.hfov_deg) / 2) / self.width_px


CAMERA = Camera()


@dataclass(frozen=True)
class UavState:
    e: float = 0.0
    n: float = 0.0
    yaw: float = 0.0        # rad, heading of the image's "up", CCW from east
    alt: float = 40.0       # m above the (flat) ground


@dataclass(frozen=True)
class Command:
    """Body-frame velocity (forward = image up, right = image right), yaw rate, climb rate."""

    forward: float = 0.0
    right: float = 0.0
    yaw_rate: float = 0.0
    climb: float = 0.0


@dataclass(frozen=True)
class Limits:
    speed_m_s: float = 6.0
    yaw_rate_rad_s: float = math.radians(45)
    climb_m_s: float = 2.0
    alt_min_m: float = 10.0
    alt_max_m: float = 120.0


class Uav:
    """Kinematic multirotor: commands clipped to the limits, altitude kept within its band."""

    def __init__(self, state: UavState, limits: Limits = Limits()) -> None:
        self.state, self.limits = state, limits

    def step(self, cmd: Command, dt: float) -> UavState:
        L, s = self.limits, self.state
        v = np.array([cmd.forward, cmd.right], float)
        sp = float(np.hypot(*v))
        if sp > L.speed_m_s:
            v *= L.speed_m_s / sp
        fwd = np.array([math.cos(s.yaw), math.sin(s.yaw)])
        right = np.array([math.sin(s.yaw), -math.cos(s.yaw)])
        d = (v[0] * fwd + v[1] * right) * dt
        yaw = math.remainder(s.yaw + float(np.clip(cmd.yaw_rate, -L.yaw_rate_rad_s, L.yaw_rate_rad_s)) * dt, 2 * math.pi)
        alt = float(np.clip(s.alt + float(np.clip(cmd.climb, -L.climb_m_s, L.climb_m_s)) * dt, L.alt_min_m, L.alt_max_m))
        self.state = UavState(s.e + d[0], s.n + d[1], yaw, alt)
        return self.state


def camera_to_map(gm: GeoMap, state: UavState, cam: Camera = CAMERA) -> np.ndarray:
    """2x3 affine from camera pixels to map pixels for a nadir view."""
    g = cam.ground_m_per_px(state.alt)
    fwd = np.array([math.cos(state.yaw), math.sin(state.yaw)])
    right = np.array([math.sin(state.yaw), -math.cos(state.yaw)])
    cu, cv = (cam.width_px - 1) / 2, (cam.height_px - 1) / 2
    # world = C + g (u - cu) right - g (v - cv) fwd
    A = np.stack([g * right, -g * fwd], axis=1)                       # 2x2: (du, dv) -> (de, dn)
    t = np.array([state.e, state.n]) - A @ np.array([cu, cv])
    Gi = np.linalg.inv(gm.G[:, :2])
    return np.hstack([Gi @ A, (Gi @ (t - gm.G[:, 2]))[:, None]])


@dataclass(frozen=True)
class Look:
    blur_px: float = 0.6
    gain: float = 1.0            # exposure: multiplies the radiance
    gamma: float = 1.0
    noise_grey: float = 2.0


def render_nadir(gm: GeoMap, state: UavState, cam: Camera = CAMERA, *, look: Look = Look(),
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """The camera image: map pixels resampled (area-averaged when the map is finer than the
    view), then exposure, blur and noise. Outside the map: black."""
    M = camera_to_map(gm, state, cam)
    scale = math.sqrt(abs(np.linalg.det(M[:, :2])))              # map px per camera px
    src = gm.image
    if scale > 1.5:                                              # anti-alias: pre-shrink the map
        k = scale / 1.0
        src = cv2.resize(gm.image, None, fx=1 / k, fy=1 / k, interpolation=cv2.INTER_AREA)
        M = M / k
    img = cv2.warpAffine(src, M, (cam.width_px, cam.height_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0)).astype(np.float32)
    img = 255 * (np.clip(img * look.gain / 255, 0, 1) ** look.gamma)
    if look.blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.blur_px)
    if rng is not None and look.noise_grey > 0:
        img = img + rng.normal(0, look.noise_grey, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)
