"""Consistency of an ICP correction with the navigation prior: a Mahalanobis gate in (x, y, yaw).

The navigation pose says the correction is the identity, give or take ``sigma_m`` in position
and ``sigma_yaw_rad`` in heading; ICP says it is ``transform`` with ``covariance``. The squared
Mahalanobis distance of the correction's displacement at ``pivot`` (the structure, where the
correction is measured) and its yaw, under the sum of both covariances, is compared with the
chi-square quantile for three degrees of freedom at the chosen confidence.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2


def correction_error(transform: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(dx, dy, dyaw): how far ``transform`` moves ``pivot`` horizontally (m), and its yaw (rad)."""
    moved = transform[:3, :3] @ pivot + transform[:3, 3] - pivot
    return np.array([moved[0], moved[1], math.atan2(transform[1, 0], transform[0, 0])])


def mahalanobis_to_prior(transform: np.ndarray, covariance: np.ndarray, pivot: np.ndarray, *, sigma_m: float,
                         sigma_yaw_rad: float) -> float:
    """Squared Mahalanobis distance of the correction from the identity (see the module docstring).

    ``covariance`` is the 6x6 (x, y, z, roll, pitch, yaw) of :func:`nodes.sonar.icp.align`, about the
    model origin; non-finite entries are ignored (the prior alone is used).
    """
    if sigma_m <= 0 or sigma_yaw_rad <= 0:
        raise ValueError("need sigma_m > 0 and sigma_yaw_rad > 0")
    e = correction_error(np.asarray(transform, float), np.asarray(pivot, float))
    cov = np.diag([sigma_m ** 2, sigma_m ** 2, sigma_yaw_rad ** 2])
    c6 = np.asarray(covariance, float)
    if c6.shape == (6, 6) and np.all(np.isfinite(c6)):
        a = np.zeros((3, 6))               # (dt, dw) about the origin -> displacement at pivot, yaw
        a[:2, :3] = np.eye(3)[:2]
        a[:2, 3:] = -np.array([[0.0, -pivot[2], pivot[1]], [pivot[2], 0.0, -pivot[0]]])
        a[2, 5] = 1.0
        cov = cov + a @ c6 @ a.T
    return float(e @ np.linalg.solve(cov, e))


def gate_threshold(confidence: float) -> float:
    """Chi-square quantile (3 degrees of freedom) a squared distance must stay under."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    return float(chi2.ppf(confidence, 3))
