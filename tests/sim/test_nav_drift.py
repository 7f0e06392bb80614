"""DriftingNav: the drift it reports is exactly what separates its pose from the truth."""
from __future__ import annotations

import math

import numpy as np

from msgs.geometry import Pose3D
from sim.nav_drift import DriftingNav, drift_matrix
from tether.testing import Harness


def test_drifted_pose_is_drift_times_truth_and_walk_is_seeded() -> None:
    truths = [Pose3D(x_m=float(i), y_m=2.0, z_m=-3.0, qw=math.cos(0.1 * i), qz=math.sin(0.1 * i),
                     stamp_ns=i * 100_000_000) for i in range(30)]
    runs = []
    for _ in range(2):
        h = Harness(DriftingNav, params={"seed": 7})
        h.feed([(t.stamp_ns / 1e9, "truth", t) for t in truths])
        runs.append((h.of("pose"), h.of("drift")))
    poses, drifts = runs[0]
    assert [p.x_m for p in poses] == [p.x_m for p in runs[1][0]]           # seeded: identical runs
    for truth, pose, drift in zip(truths, poses, drifts):
        np.testing.assert_allclose(drift.matrix() @ truth.matrix(), pose.matrix(), atol=1e-9)
        assert pose.z_m == truth.z_m and pose.stamp_ns == truth.stamp_ns  # depth is measured, not drifted
    first = drifts[0].matrix()
    np.testing.assert_allclose(first, drift_matrix(0.4, -0.3, math.radians(3.0)), atol=1e-12)
    assert not np.allclose(drifts[-1].matrix(), first)                    # the walk moves it


def test_zero_drift_returns_the_truth() -> None:
    h = Harness(DriftingNav, params={"bias_x_m": 0, "bias_y_m": 0, "bias_yaw_deg": 0,
                                     "walk_m_per_sqrt_s": 0, "walk_deg_per_sqrt_s": 0})
    truth = Pose3D(x_m=1.0, y_m=-2.0, z_m=-1.0, qw=0.8, qx=0.6, stamp_ns=5)
    (pose,) = [o.msg for o in h.feed([(0.0, "truth", truth)]) if o.output == "pose"]
    np.testing.assert_allclose(pose.matrix(), truth.matrix(), atol=1e-12)
