"""A sonar ping projected onto a flat seabed, in a frame fixed to the vehicle (pure numpy/OpenCV).

The mosaic (:mod:`nodes.sonar.mosaic`) registers such images: drawn in the vehicle's level
frame -- columns ahead, rows to port, centred ``center_ahead_m`` ahead -- a navigation
error shows as a rigid motion between two of them. Each pixel's seabed point is taken to
the head frame (FRD, with the head's pitch and roll), to (range, bearing, elevation), and
sampled from the ping's (range x beam) intensities. The lookup maps depend only on the
geometry and are cached.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from nodes.sonar.icp import yaw_of


@dataclass(frozen=True)
class SeabedGrid:
    """The image: ``image_px`` square cells of ``cell_m``, centred ``center_ahead_m`` ahead of the head."""

    seafloor_z_m: float = -8.0
    cell_m: float = 0.1
    image_px: int = 256
    center_ahead_m: float = 13.5
    flat_field_m: float = 4.0          # the illumination's scale, divided out of every image
    mask_erode_m: float = 1.0          # keep this far inside the fan's edges


class SeabedProjector:
    """Ping intensities -> (flat-fielded seabed image, validity mask), maps cached per geometry."""

    def __init__(self, grid: SeabedGrid) -> None:
        self.grid = grid
        self._key: tuple | None = None

    def _maps(self, shape: tuple[int, int], bearings_rad: np.ndarray, range_resolution_m: float,
              vertical_aperture_rad: float, head: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g = self.grid
        altitude = head[2, 3] - g.seafloor_z_m
        yaw = yaw_of(head)
        level = np.eye(3)
        level[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        attitude = level.T @ head[:3, :3]               # head in the level frame: pitch and roll only
        key = (round(altitude, 2), tuple(np.round(attitude, 3).ravel()), shape, round(range_resolution_m, 6),
               float(bearings_rad[0]), float(bearings_rad[-1]), vertical_aperture_rad)
        if key == self._key:
            return self._map_x, self._map_y, self._mask
        n, c = g.image_px, (g.image_px - 1) / 2
        cols, rows = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
        fwd = g.center_ahead_m + (cols - c) * g.cell_m
        left = (rows - c) * g.cell_m
        d = np.stack([fwd, left, np.full_like(fwd, -altitude)], axis=-1) @ attitude     # level -> head (FRD)
        r = np.linalg.norm(d, axis=-1)
        theta = np.arctan2(d[..., 1], d[..., 0])
        phi = np.arcsin(np.clip(d[..., 2] / np.maximum(r, 1e-9), -1, 1))
        bearings = np.asarray(bearings_rad, float)
        order = np.argsort(bearings)
        beam = np.interp(theta, bearings[order], order.astype(float))
        rng = r / range_resolution_m - 0.5
        half = 0.5 * (vertical_aperture_rad or math.radians(20.0))
        mask = ((theta >= bearings.min()) & (theta <= bearings.max()) & (rng >= 0)
                & (rng <= shape[0] - 1) & (np.abs(phi) <= half))
        if g.mask_erode_m > 0:                          # the fan's edges: where the beam pattern changes fastest
            k = 2 * int(round(g.mask_erode_m / g.cell_m)) + 1
            mask = cv2.erode(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
        self._key = key
        self._map_x, self._map_y, self._mask = beam.astype(np.float32), rng.astype(np.float32), mask
        return self._map_x, self._map_y, self._mask

    def project(self, intensities: np.ndarray, bearings_rad: np.ndarray, range_resolution_m: float,
                vertical_aperture_rad: float, head: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The seabed image (flat-fielded: mean 1 over its mask) and its mask.

        ``intensities`` (R, B) with row i at range (i + 0.5) x ``range_resolution_m``;
        ``head`` the 4x4 sonar-head (FRD) -> world pose. The echo level falls with range and
        the beam pattern in the same way in every ping: a pattern fixed to the vehicle, which
        would pull every registration towards zero shift. Dividing by the image's own heavy
        blur (normalised by the mask's) removes it.
        """
        map_x, map_y, mask = self._maps(np.shape(intensities), bearings_rad, range_resolution_m,
                                        vertical_aperture_rad, head)
        image = cv2.remap(np.asarray(intensities, np.float32), map_x, map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        valid = mask.astype(np.float32)
        sigma = self.grid.flat_field_m / self.grid.cell_m
        shade = cv2.GaussianBlur(image * valid, (0, 0), sigma) / np.maximum(cv2.GaussianBlur(valid, (0, 0), sigma), 1e-3)
        flat = np.where(mask & (shade > 1e-3), image / np.maximum(shade, 1e-3), 0.0)
        return flat.astype(np.float32), mask
