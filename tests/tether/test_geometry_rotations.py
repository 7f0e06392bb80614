"""Pose3D's quaternion <-> matrix, now scipy's Rotation: the poles, non-unit and zero input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msgs.geometry import Pose3D


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, -1, 1)])
@pytest.mark.parametrize("angle", [0.0, 1e-9, math.pi / 2, math.pi - 1e-9, math.pi])
def test_round_trip_including_half_turns(axis, angle):
    r = Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * angle).as_matrix()
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, (1.0, -2.0, 3.0)
    pose = Pose3D.from_matrix(m)
    assert pose.qw >= 0 and abs(pose.qw ** 2 + pose.qx ** 2 + pose.qy ** 2 + pose.qz ** 2 - 1) < 1e-12
    assert np.allclose(pose.matrix(), m, atol=1e-9)


def test_non_unit_zero_and_nearly_orthonormal_input():
    half = Pose3D(qw=2.0, qz=2.0)                                            # 90 deg about z, scaled by 2.83
    assert np.allclose(half.matrix()[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert np.allclose(Pose3D(qw=0.0).matrix(), np.eye(4))                  # zero: no rotation
    assert np.allclose(Pose3D(qw=math.nan).matrix(), np.eye(4))
    noisy = np.eye(4)
    noisy[:3, :3] += 1e-6 * np.random.default_rng(0).normal(size=(3, 3))
    q = Pose3D.from_matrix(noisy)
    assert abs(q.qw ** 2 + q.qx ** 2 + q.qy ** 2 + q.qz ** 2 - 1) < 1e-12 and q.qw > 0.999999
