"""Sonar messages: raw polar pings, Cartesian fan images, ICP localisation results."""
from __future__ import annotations

import numpy as np

from tether.message import Message, const
from msgs.geometry import Pose3D


class SonarPing(Message, tag="sonar.SonarPing"):
    """One raw multibeam ping in polar form, as the sonar produced it.

    ``intensities`` is ranges x beams (uint8 or uint16, row 0 nearest the sonar);
    ``bearings_rad`` gives each beam's bearing (positive to starboard/right, 0 ahead),
    possibly non-uniform and in either order. Range of row i is
    ``(i + 0.5) * range_resolution_m`` unless the driver states otherwise.
    """

    intensities: np.ndarray = const(np.zeros((0, 0), np.uint8))
    bearings_rad: np.ndarray = const(np.zeros(0, np.float32))
    range_resolution_m: float = 0.0
    range_m: float = 0.0
    frequency_hz: float = 0.0
    sound_speed_mps: float = 1500.0
    ping_id: int = 0
    gain_percent: float = 0.0
    gamma: float = 1.0
    vertical_aperture_rad: float = 0.0
    horizontal_aperture_rad: float = 0.0
    device_stamp_ns: int = 0      # the sonar's own ping time, if it reports one
    # appended (issue 3): per-row gain as sent by the device (empty when absent), device facts
    row_gains: np.ndarray = const(np.zeros(0, np.float32))
    master_mode: int = 0          # Oculus: 1 low frequency (wide), 2 high frequency (narrow)
    device_id: int = 0            # the sonar's serial number (srcDeviceId)


class FanImage(Message, tag="sonar.FanImage"):
    """A Cartesian fan image in the sonar frame.

    ``image`` is H x W; pixel (row, col) is at x = (col - origin_col_px) * m_per_px
    (starboard), y = (origin_row_px - row) * m_per_px (ahead). Pixels outside the fan
    are 0 and ``mask`` (uint8) is 1 inside it.
    """

    image: np.ndarray = const(np.zeros((0, 0), np.uint8))
    mask: np.ndarray = const(np.zeros((0, 0), np.uint8))
    m_per_px: float = 0.0
    origin_row_px: float = 0.0
    origin_col_px: float = 0.0
    ping_id: int = 0


class IcpResult(Message, tag="sonar.IcpResult"):
    """Pose correction from aligning a cloud to a model.

    ``correction`` maps the cloud's frame onto the model's; ``covariance`` is 6x6 over
    (x, y, z, roll, pitch, yaw). ``degenerate`` is True when some direction is not
    observable (smallest normal-matrix eigenvalue below threshold); ``ambiguous`` when
    distinct poses fit equally well (symmetric structure). Then the correction is not
    to be trusted in those directions.
    """

    correction: Pose3D = Pose3D()
    covariance: np.ndarray = const(np.full((6, 6), np.nan))
    converged: bool = False
    degenerate: bool = False
    ambiguous: bool = False
    min_eigenvalue: float = 0.0
    rmse_m: float = float("nan")
    inlier_ratio: float = 0.0
    iterations: int = 0
    cloud_size: int = 0
    # appended (issue 22): the near-equal corrections of the yaw search, one row each
    # (x_m, y_m, yaw_rad of the correction, cost), best first (> 1 row: ambiguous), and the
    # navigation-prior gate: squared Mahalanobis distance, and whether it rejected the correction
    # (then ``ambiguous`` is set too, so that no reader trusts it)
    hypotheses: np.ndarray = const(np.zeros((0, 4), np.float64))
    prior_mahalanobis2: float = float("nan")
    gated: bool = False
    poor_fit: bool = False        # residual RMS above the localizer's max_rmse_m: not trusted (ambiguous set)
