"""Sensor messages: images, depth images, point clouds, occupancy/cost grids."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const


class CameraInfo(Message, tag="sensor.CameraInfo"):
    """Pinhole intrinsics in pixels. An estimate (self-calibration) adds one-sigma uncertainties
    (0: known exactly, inf: not determined), the method, and ``degenerate`` with a ``reason``
    when the data cannot determine the intrinsics (the numbers are then a placeholder)."""

    width_px: int = 0
    height_px: int = 0
    fx_px: float = 0.0
    fy_px: float = 0.0
    cx_px: float = 0.0
    cy_px: float = 0.0
    fx_sigma_px: float = 0.0
    fy_sigma_px: float = 0.0
    cx_sigma_px: float = 0.0
    cy_sigma_px: float = 0.0
    method: str = ""
    degenerate: bool = False
    reason: str = ""


class Image(Message, tag="sensor.Image"):
    """An image: ``data`` is H x W (mono) or H x W x C, with ``encoding`` like 'mono8', 'rgb8', 'bgr8', '32FC1'."""

    data: np.ndarray = const(np.zeros((0, 0), np.uint8))
    encoding: str = "mono8"


class DepthImage(Message, tag="sensor.DepthImage"):
    """Depth along the optical axis in metres (float32, H x W); NaN or 0 where unknown."""

    depth_m: np.ndarray = const(np.zeros((0, 0), np.float32))
    info: CameraInfo = CameraInfo()


class RgbdFrame(Message, tag="sensor.RgbdFrame"):
    """A registered colour + depth pair from one RGB-D camera."""

    rgb: np.ndarray = const(np.zeros((0, 0, 3), np.uint8))
    depth_m: np.ndarray = const(np.zeros((0, 0), np.float32))
    info: CameraInfo = CameraInfo()


class PointCloud(Message, tag="sensor.PointCloud"):
    """N x 3 float points in ``frame_id`` (metres), with optional per-point N-vectors: ``intensity``, and
    ``sigma_m`` the 1-sigma position uncertainty of each point (a sonar cloud's: along the elevation arc);
    empty when the producer gives none (older logs, appended field)."""

    points_m: np.ndarray = const(np.zeros((0, 3), np.float32))
    intensity: np.ndarray = const(np.zeros(0, np.float32))
    sigma_m: np.ndarray = const(np.zeros(0, np.float32))


class Grid(Message, tag="sensor.Grid"):
    """A 2D grid of float cells (rows = y, cols = x), origin = centre of cell (0, 0) in ``frame_id``."""

    data: np.ndarray = const(np.zeros((0, 0), np.float32))
    resolution_m: float = 0.1
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0
    origin_yaw_rad: float = 0.0
