"""RGB-D rendering of a crowd scene: vertical extrusions (walls, boxes, pillars, pedestrians) on a floor.

Everything in the scene stands on the floor (z = 0) and is vertical, and the camera looks
horizontally (no pitch, no roll), so every image column is one horizontal ray: the
renderer intersects each column's ray with all wall segments and cylinders at once
(numpy, objects x columns), keeps the ``layers`` nearest hits per column, and paints
each hit over the rows its height covers (far to near). Depth along the optical axis
equals the forward distance of the hit, the same for every row of that hit. Colours
come from one texture atlas sampled with ``cv2.remap`` (bilinear): band-limited noise on
walls, floor and each pedestrian (a stable texture per id: trousers / shirt / head
colours times noise), so optical flow has texture to track.

Camera frame: x right, y down, z forward (optical). Depth is 0 where there is no return
(sky, or outside ``[min_range_m, max_range_m]``), as an RGB-D camera reports it.
Objects have no lids: over a box lower than the camera you see its inner back face.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TEXELS_PER_M = 64.0
_PED_SLOTS = 32
_PED_TILE = (128, 128)         # rows (2 m of height), cols (once around the body)
_WALL_TILE = (192, 256)        # 3 m x 4 m
_FLOOR_TILE = (256, 256)       # 4 m x 4 m
_FLOOR_FADE_M = 12.0           # beyond this the floor is drawn flat (no texture aliasing near the horizon)
_SKY = (200, 215, 230)


@dataclass(frozen=True)
class CameraModel:
    """Pinhole RGB-D camera mounted level on the robot (pixels; metres in the robot frame)."""

    width_px: int = 640
    height_px: int = 480
    fx_px: float = 525.0
    fy_px: float = 525.0
    cx_px: float = 319.5
    cy_px: float = 239.5
    x_m: float = 0.3            # ahead of the robot centre
    y_m: float = 0.0            # to the left
    z_m: float = 1.0            # above the floor
    min_range_m: float = 0.4
    max_range_m: float = 8.0

    def __post_init__(self) -> None:
        if self.width_px < 2 or self.height_px < 2 or self.fx_px <= 0 or self.fy_px <= 0:
            raise ValueError("camera needs width/height >= 2 px and positive focal lengths")
        if not 0 < self.z_m < 3.0:
            raise ValueError(f"camera height z_m must be in (0, 3) m (the floor is at 0), got {self.z_m}")
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ValueError("need 0 <= min_range_m < max_range_m")


def _tileable_noise(rng: np.random.Generator, shape: tuple[int, int], wavelength_px: float) -> np.ndarray:
    """Periodic band-limited noise in [-1, 1] (Gaussian low-pass in the Fourier domain)."""
    spec = np.fft.fft2(rng.standard_normal(shape))
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    sigma = 1.0 / wavelength_px
    out = np.real(np.fft.ifft2(spec * np.exp(-0.5 * (fx * fx + fy * fy) / sigma**2)))
    return out / (np.abs(out).max() + 1e-12)


def _pad_wrap(tile: np.ndarray) -> np.ndarray:
    """One texel of wrap-around padding on every side, so bilinear sampling is seamless."""
    return np.pad(tile, ((1, 1), (1, 1), (0, 0)), mode="wrap")


def _pedestrian_tile(rng: np.random.Generator) -> np.ndarray:
    h, w = _PED_TILE
    height_m = (np.arange(h) + 0.5) / TEXELS_PER_M
    trousers, shirt = rng.uniform(20, 200, 3), rng.uniform(40, 240, 3)
    skin, hair = np.array([200.0, 160.0, 130.0]) * rng.uniform(0.6, 1.1), rng.uniform(10, 90, 3)
    colour = np.where((height_m < 0.85)[:, None], trousers, shirt)
    colour = np.where((height_m >= 1.45)[:, None], skin, colour)
    colour = np.where((height_m >= 1.68)[:, None], hair, colour)
    noise = _tileable_noise(rng, (h, w), 6.0)[..., None] + 0.5 * _tileable_noise(rng, (h, w), 2.5)[..., None]
    return np.clip(colour[:, None, :] * (1.0 + 0.35 * noise), 0, 255)


def _surface_tile(rng: np.random.Generator, shape: tuple[int, int], base: tuple[float, float, float],
                  contrast: float) -> np.ndarray:
    noise = (_tileable_noise(rng, shape, 12.0) + 0.6 * _tileable_noise(rng, shape, 4.0)
             + 0.3 * _tileable_noise(rng, shape, 2.0))
    tint = 1.0 + 0.15 * _tileable_noise(rng, shape, 40.0)[..., None] * rng.uniform(-1, 1, 3)
    return np.clip(np.asarray(base) * tint * (1.0 + contrast * noise[..., None]), 0, 255)


@dataclass(frozen=True)
class _Tile:
    x0: float      # atlas column of texel (0, 0) (after padding)
    y0: float
    period: float  # horizontal period in texels


class TextureAtlas:
    """All textures stacked in one uint8 image; tiles are wrap-padded for seamless bilinear lookups."""

    def __init__(self, seed: int = 7) -> None:
        rng = np.random.default_rng(seed)
        width = max(_WALL_TILE[1], _FLOOR_TILE[1], _PED_TILE[1]) + 2
        blocks, tiles, y = [], {}, 0

        def add(name: str, tile: np.ndarray) -> None:
            nonlocal y
            padded = _pad_wrap(tile)
            block = np.zeros((padded.shape[0], width, 3))
            block[:, :padded.shape[1]] = padded
            blocks.append(block)
            tiles[name] = _Tile(1.0, float(y + 1), float(tile.shape[1]))
            y += padded.shape[0]

        add("wall", _surface_tile(rng, _WALL_TILE, (190, 180, 160), 0.45))
        add("obstacle", _surface_tile(rng, _WALL_TILE, (120, 90, 60), 0.5))
        add("floor", _surface_tile(rng, _FLOOR_TILE, (150, 150, 140), 0.4))
        add("flat_floor", np.full((4, 4, 3), 150.0))
        add("sky", np.full((4, 4, 3), _SKY, float))
        for k in range(_PED_SLOTS):
            add(f"ped{k}", _pedestrian_tile(rng))
        self.image = np.ascontiguousarray(np.concatenate(blocks).astype(np.uint8))
        self.tiles = tiles


def _hits_segments(cam: np.ndarray, dirs: np.ndarray, segs: np.ndarray, near_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Forward distance (S, W) to each segment along each column ray (inf = miss) and arc length (m)."""
    a, e = segs[:, 0, :], segs[:, 1, :] - segs[:, 0, :]
    ac = a - cam
    denom = dirs[None, :, 0] * e[:, 1, None] - dirs[None, :, 1] * e[:, 0, None]
    safe = np.where(np.abs(denom) > 1e-12, denom, np.nan)
    s = (ac[:, 0, None] * e[:, 1, None] - ac[:, 1, None] * e[:, 0, None]) / safe
    lam = (ac[:, 0, None] * dirs[None, :, 1] - ac[:, 1, None] * dirs[None, :, 0]) / safe
    ok = (s > near_m) & (lam >= 0) & (lam <= 1)
    length = np.linalg.norm(e, axis=1)
    return np.where(ok, s, np.inf), np.where(ok, lam * length[:, None], 0.0)


def _hits_cylinders(cam: np.ndarray, dirs: np.ndarray, cyl: np.ndarray,
                    near_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Forward distance (C, W) to each cylinder's near side (inf = miss) and the hit's angle / 2 pi."""
    f = cam - cyl[:, :2]
    a2 = np.einsum("wi,wi->w", dirs, dirs)[None, :]
    b = f @ dirs.T
    cc = (np.einsum("ci,ci->c", f, f) - cyl[:, 2] ** 2)[:, None]
    disc = b * b - a2 * cc
    s = (-b - np.sqrt(np.maximum(disc, 0.0))) / a2
    ok = (disc > 0) & (cc > 0) & (s > near_m)      # cc <= 0: the camera is inside the cylinder
    hx = cam[0] + s * dirs[None, :, 0] - cyl[:, 0, None]
    hy = cam[1] + s * dirs[None, :, 1] - cyl[:, 1, None]
    return np.where(ok, s, np.inf), np.arctan2(hy, hx) / (2 * np.pi)


class Renderer:
    """Render colour and depth of static geometry plus pedestrians from the robot's camera.

    Parameters
    ----------
    segments : ndarray, shape (S, 2, 2)
        Wall / box faces (world m). ``obstacle`` (S,) bool marks box faces (obstacle texture).
    segment_heights_m : ndarray, shape (S,)
    cylinders : ndarray, shape (C, 3)
        Static pillars: x, y, radius (m). ``cylinder_heights_m`` (C,).
    camera : CameraModel
    layers : int
        Nearest hits kept per column (occlusion depth).
    """

    def __init__(self, segments: np.ndarray, segment_heights_m: np.ndarray, cylinders: np.ndarray,
                 cylinder_heights_m: np.ndarray, *, obstacle: np.ndarray | None = None,
                 camera: CameraModel = CameraModel(), layers: int = 4, texture_seed: int = 7) -> None:
        self.camera = cam = camera
        self.segments = np.asarray(segments, float).reshape(-1, 2, 2)
        self.seg_h = np.minimum(np.asarray(segment_heights_m, float), _WALL_TILE[0] / TEXELS_PER_M)
        obstacle = np.zeros(len(self.segments), bool) if obstacle is None else np.asarray(obstacle, bool)
        self.cylinders = np.asarray(cylinders, float).reshape(-1, 3)
        self.cyl_h = np.minimum(np.asarray(cylinder_heights_m, float), _WALL_TILE[0] / TEXELS_PER_M)
        self.layers = int(layers)
        self.atlas = TextureAtlas(texture_seed)
        u = np.arange(cam.width_px)
        self._dirs_robot = np.stack([np.ones(cam.width_px), -(u - cam.cx_px) / cam.fx_px], axis=1)
        self._vn = ((np.arange(cam.height_px) - cam.cy_px) / cam.fy_px).astype(np.float32)
        self._rows = np.arange(cam.height_px, dtype=np.float32)[:, None]
        self._cols = np.arange(cam.width_px)[None, :]
        self._below = int(np.searchsorted(self._vn, 1e-6))      # first row below the horizon
        self._s_floor = (cam.z_m / self._vn[self._below:])[:, None]    # forward distance of the floor per row
        self._far_rows = self._s_floor > _FLOOR_FADE_M
        seg_tiles = [self.atlas.tiles["obstacle" if o else "wall"] for o in obstacle]
        cyl_tile = self.atlas.tiles["obstacle"]
        self._static_tex = np.array([(t.x0, t.y0, t.period) for t in seg_tiles] +
                                    [(cyl_tile.x0, cyl_tile.y0, cyl_tile.period)] * len(self.cylinders)
                                    ).reshape(-1, 3)
        ped = [self.atlas.tiles[f"ped{k}"] for k in range(_PED_SLOTS)]
        self._ped_tex = np.array([(t.x0, t.y0, t.period) for t in ped])

    def render(self, pose: tuple[float, float, float], ped_xy: np.ndarray | None = None,
               ped_ids: np.ndarray | None = None, ped_radius_m: np.ndarray | float = 0.3,
               ped_height_m: np.ndarray | float = 1.75) -> tuple[np.ndarray, np.ndarray]:
        """Colour (H, W, 3) uint8 RGB and depth (H, W) float32 m (0 = no return) at robot ``pose``.

        ``pose`` is (x_m, y_m, yaw_rad) of the robot in the world; pedestrians are vertical
        cylinders at ``ped_xy`` (N, 2) m with per-id textures.
        """
        cam = self.camera
        ped_xy = np.zeros((0, 2)) if ped_xy is None else np.asarray(ped_xy, float).reshape(-1, 2)
        n_ped = len(ped_xy)
        ids = np.arange(n_ped) if ped_ids is None else np.asarray(ped_ids, np.int64)
        radius = np.broadcast_to(np.asarray(ped_radius_m, float), (n_ped,))
        ped_h = np.minimum(np.broadcast_to(np.asarray(ped_height_m, float), (n_ped,)), _PED_TILE[0] / TEXELS_PER_M)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        cam_xy = np.asarray(pose[:2], float) + rot @ (cam.x_m, cam.y_m)
        dirs = self._dirs_robot @ rot.T
        near = 0.05

        s_seg, u_seg = _hits_segments(cam_xy, dirs, self.segments, near)
        cyl = np.concatenate([self.cylinders, np.column_stack([ped_xy, radius])])
        s_cyl, frac = _hits_cylinders(cam_xy, dirs, cyl, near)
        tex = np.concatenate([self._static_tex, self._ped_tex[ids % _PED_SLOTS]])
        phase = np.concatenate([np.zeros(len(self.cylinders)), (ids * 0.6180339887) % 1.0])
        u_cyl = (frac + phase[:, None]) % 1.0 * tex[len(self.segments):, 2, None]
        u_seg = u_seg * TEXELS_PER_M
        hits = np.concatenate([s_seg, s_cyl])
        u_all = np.concatenate([u_seg, u_cyl])
        heights = np.concatenate([self.seg_h, self.cyl_h, ped_h])
        return self._compose(hits, u_all, heights, tex, cam_xy, dirs)

    def _compose(self, hits: np.ndarray, u_all: np.ndarray, heights: np.ndarray, tex: np.ndarray,
                 cam_xy: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cam, width = self.camera, self.camera.width_px
        k = min(self.layers, len(hits))
        if k:
            near_idx = np.argpartition(hits, k - 1, axis=0)[:k] if len(hits) > k else np.argsort(hits, axis=0)
            order = np.argsort(np.take_along_axis(hits, near_idx, 0), axis=0)
            obj = np.take_along_axis(near_idx, order, 0)                       # (k, W) nearest first
            s_k = np.take_along_axis(hits, obj, 0)
        else:
            obj, s_k = np.zeros((0, width), int), np.zeros((0, width))
        finite = np.isfinite(s_k)
        s_safe = np.where(finite, s_k, 1.0)
        top = np.where(finite, cam.cy_px - cam.fy_px * (heights[obj] - cam.z_m) / s_safe, np.inf)
        bottom = cam.cy_px + cam.fy_px * cam.z_m / s_safe
        layer = np.full((cam.height_px, width), k, np.int32)
        inside = np.empty((cam.height_px, width), bool)
        scratch = np.empty((cam.height_px, width), bool)
        for j in range(k - 1, -1, -1):                                         # painter: far to near
            np.greater_equal(self._rows, top[j].astype(np.float32), out=inside)
            np.less_equal(self._rows, bottom[j].astype(np.float32), out=scratch)
            inside &= scratch
            np.copyto(layer, j, where=inside)
        # per-(layer, column) tables; row k = background, filled below
        depth_tab = np.zeros((k + 1, width), np.float32)
        depth_tab[:k] = s_safe
        mapx_tab = np.zeros((k + 1, width), np.float32)
        mapx_tab[:k] = tex[obj, 0] + np.take_along_axis(u_all, obj, 0) % tex[obj, 2]
        mapy_tab = np.zeros((k + 1, width), np.float32)
        mapy_tab[:k] = tex[obj, 1]
        flat = layer * width + self._cols
        depth = np.take(depth_tab, flat)
        map_x = np.take(mapx_tab, flat)
        map_y = np.take(mapy_tab, flat)
        height_px = (cam.z_m - depth * self._vn[:, None]) * TEXELS_PER_M
        map_y += np.maximum(height_px, 0.0)
        background = layer == k
        self._background(background, depth, map_x, map_y, cam_xy, dirs)
        rgb = cv2.remap(self.atlas.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        depth[(depth < cam.min_range_m) | (depth > cam.max_range_m)] = 0.0
        return rgb, depth

    def _background(self, background: np.ndarray, depth: np.ndarray, map_x: np.ndarray, map_y: np.ndarray,
                    cam_xy: np.ndarray, dirs: np.ndarray) -> None:
        """Fill floor (below the horizon) and sky pixels in place."""
        tiles, lo = self.atlas.tiles, self._below
        sky = tiles["sky"]
        up = background[:lo]
        np.copyto(depth[:lo], 0.0, where=up)
        np.copyto(map_x[:lo], sky.x0 + 1.5, where=up)
        np.copyto(map_y[:lo], sky.y0 + 1.5, where=up)
        s_floor = self._s_floor
        floor, flat = tiles["floor"], tiles["flat_floor"]
        down = background[lo:]
        for out, origin, d, tile0, period in ((map_x, cam_xy[0], dirs[:, 0], floor.x0, _FLOOR_TILE[1]),
                                              (map_y, cam_xy[1], dirs[:, 1], floor.y0, _FLOOR_TILE[0])):
            tex = s_floor * (d * TEXELS_PER_M).astype(np.float32)[None, :]
            tex += np.float32((origin * TEXELS_PER_M) % period)
            tex -= np.floor(tex * np.float32(1.0 / period)) * np.float32(period)    # fast mod
            tex += np.float32(tile0)
            np.copyto(out[lo:], tex, where=down)
        far = down & self._far_rows
        np.copyto(map_x[lo:], flat.x0 + 1.5, where=far)
        np.copyto(map_y[lo:], flat.y0 + 1.5, where=far)
        np.copyto(depth[lo:], np.broadcast_to(s_floor, down.shape), where=down)
