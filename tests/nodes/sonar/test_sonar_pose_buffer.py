"""PoseBuffer: interpolation at a stamp (lerp + slerp), waiting, gaps, order, wrap-around."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nodes.sonar.pose_buffer import PoseBuffer, slerp_pose

GAP = 500_000_000


def _pose(x: float, yaw_rad: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("z", yaw_rad).as_matrix()
    t[:3, 3] = (x, 2 * x, -1.0)
    return t


def _yaw(t: np.ndarray) -> float:
    return math.atan2(t[1, 0], t[0, 0])


def test_interpolates_position_linearly_and_rotation_at_constant_rate() -> None:
    buf = PoseBuffer()
    buf.add(0, _pose(0.0, 0.0))
    buf.add(100_000_000, _pose(1.0, math.radians(30)))
    pose, status, bracket = buf.at(25_000_000, GAP)
    assert status == "interpolated" and bracket == 100_000_000
    np.testing.assert_allclose(pose[:3, 3], [0.25, 0.5, -1.0], atol=1e-12)
    assert math.degrees(_yaw(pose)) == pytest.approx(7.5, abs=1e-9)
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3))


def test_slerp_takes_the_short_way_across_plus_minus_180() -> None:
    mid = slerp_pose(_pose(0, math.radians(170)), _pose(0, math.radians(-170)), 0.5)
    assert abs(abs(math.degrees(_yaw(mid))) - 180.0) < 1e-6


def test_exact_wait_before_first_and_gap() -> None:
    buf = PoseBuffer()
    assert buf.at(5, GAP)[1] == "wait"                   # nothing yet: its pose may still come
    buf.add(10**9, _pose(1.0, 0.0))
    buf.add(2 * 10**9, _pose(2.0, 0.0))                   # 1 s gap
    buf.add(2 * 10**9 + 10**8, _pose(3.0, 0.0))
    assert buf.at(10**9, GAP)[1] == "exact"
    assert buf.at(10**9 - 1, GAP)[1] == "before_first"
    assert buf.at(15 * 10**8, GAP)[1] == "gap"
    assert buf.at(2 * 10**9 + 5 * 10**7, GAP)[1] == "interpolated"
    assert buf.at(3 * 10**9, GAP) == (None, "wait", 0)     # newer than the newest: never an old pose


def test_out_of_order_poses_are_sorted_duplicates_replace_and_old_ones_go() -> None:
    buf = PoseBuffer(span_ns=10**9)
    for stamp, x in ((2, 2.0), (0, 0.0), (1, 1.0), (1, 5.0)):
        buf.add(stamp * 10**8, _pose(x, 0.0))
    assert len(buf) == 3 and buf.at(10**8, GAP)[0][0, 3] == 5.0
    buf.add(3 * 10**9, _pose(30.0, 0.0))
    assert len(buf) == 1 and buf.newest_ns == 3 * 10**9
