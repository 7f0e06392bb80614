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

import csv
import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "uav" / "brighton_beach"


@dataclass(frozen=True)
class GeoMap:
    """A map image and its affine G: [e, n] = G @ [u, v, 1]."""

    image: np.ndarray
    G: np.ndarray

    @property
    def m_per_px(self) -> float:
        return float(math.sqrt(abs(np.linalg.det(self.G[:, :2]))))

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        uv = np.atleast_2d(uv)
        return uv @ self.G[:, :2].T + self.G[:, 2]

    def to_px(self, en: np.ndarray) -> np.ndarray:
        en = np.atleast_2d(en)
        return (en - self.G[:, 2]) @ np.linalg.inv(self.G[:, :2]).T

    def world_bounds(self) -> np.ndarray:
        """(2, 2) [[e_min, n_min], [e_max, n_max]] of the image's corners."""
        h, w = self.image.shape[:2]
        c = self.to_world(np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
        return np.array([c.min(axis=0), c.max(axis=0)])


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


def procedural_map(*, rng: np.random.Generator, size_px: int = 1600, m_per_px: float = 0.12) -> GeoMap:
    """A textured field for tests that must not depend on real data: patches, roads, blobs,
    north up, centred on (0, 0)."""
    img = np.zeros((size_px, size_px, 3), np.float32)
    for cells, amp in ((6, 50), (24, 30), (96, 18)):
        g = rng.normal(0, amp, (cells, cells, 3)).astype(np.float32)
        img += cv2.resize(g, (size_px, size_px), interpolation=cv2.INTER_CUBIC)
    img += np.array([70, 120, 90], np.float32)
    for _ in range(40):                                        # roads
        p = rng.integers(0, size_px, 4)
        cv2.line(img, (int(p[0]), int(p[1])), (int(p[2]), int(p[3])), (150, 150, 150), int(rng.integers(6, 20)))
    for _ in range(600):                                       # trees, cars, roofs
        c = tuple(int(v) for v in rng.integers(0, size_px, 2))
        col = tuple(float(v) for v in rng.uniform(20, 230, 3))
        if rng.random() < 0.6:
            cv2.circle(img, c, int(rng.integers(4, 20)), col, -1)
        else:
            d = rng.integers(6, 30, 2)
            cv2.rectangle(img, c, (c[0] + int(d[0]), c[1] + int(d[1])), col, -1)
    img = np.clip(img, 0, 255).astype(np.uint8)
    h = size_px / 2 * m_per_px
    G = np.array([[m_per_px, 0, -h], [0, -m_per_px, h]])
    return GeoMap(img, G)


def frames_gps(path: Path = DATA / "frames_gps.csv") -> list[dict]:
    with open(path, newline="") as f:
        return [dict(r) for r in csv.DictReader(f)]


def enu_of(lat: np.ndarray, lon: np.ndarray, lat0: float, lon0: float) -> np.ndarray:
    """Local east-north metres (equirectangular; exact to mm over a few hundred metres)."""
    R = 6378137.0
    return np.stack([np.radians(lon - lon0) * R * math.cos(math.radians(lat0)), np.radians(lat - lat0) * R], axis=1)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity (Umeyama, no reflection) src (N, 2) -> dst (N, 2), as 2x3."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a ** 2).sum())
    return np.hstack([s * R, (md - s * R @ ms)[:, None]])


#: DJI FC300S (Phantom 3): 94 degrees diagonal on 16:9 -> about 86 degrees across
BRIGHTON_HFOV_DEG = 2 * math.degrees(math.atan(math.tan(math.radians(47)) * 16 / math.hypot(16, 9)))


def georeference(centres_px: np.ndarray, enu: np.ndarray) -> np.ndarray:
    """G (2x3, map px -> east-north) from frame centres in the map and their GPS positions: a
    similarity once the image's v axis (down) is turned to point north."""
    flip = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    S = fit_similarity(centres_px * [1, -1], enu)
    return S @ flip


def brighton_frames() -> list[tuple[np.ndarray, dict]]:
    """The 18 real frames (1000x562 BGR) with their GPS row."""
    rows = frames_gps()
    return [(cv2.imread(str(DATA / "frames_1000px" / r["file"])), r) for r in rows]


def register_brighton(method: str = "sift") -> tuple[np.ndarray, list, list[dict], np.ndarray]:
    """The ortho image, each real frame's registration to it, the GPS rows and their east-north
    positions (metres from the first frame)."""
    from nodes.vision.georegister import MapFeatures, register

    ortho = cv2.imread(str(DATA / "ortho_render_brighton_beach.jpg"))
    mf = MapFeatures.of(ortho, method=method)
    frames = brighton_frames()
    rows = [r for _, r in frames]
    lat = np.array([float(r["lat"]) for r in rows])
    lon = np.array([float(r["lon"]) for r in rows])
    enu = enu_of(lat, lon, lat[0], lon[0])
    fixes = [register(f, mf, prescale=1.0, pyramid=(0.5, 0.7, 1.0), alpha_range=(0.5, 2.0)) for f, _ in frames]
    return ortho, fixes, rows, enu


def brighton_map() -> GeoMap:
    """The real ortho render, georeferenced by its own frames' GPS (registration of each frame
    gives its centre in the image; a similarity fits those to the GPS positions)."""
    ortho, fixes, _, enu = register_brighton()
    ok = [k for k, f in enumerate(fixes) if f.ok]
    if len(ok) < 3:
        raise ValueError(f"only {len(ok)} real frames registered to the ortho image: cannot georeference it")
    G = georeference(np.array([fixes[k].centre_px for k in ok]), enu[ok])
    return GeoMap(ortho, G)
