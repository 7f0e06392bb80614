"""SonarEvaluation: errors of corrected poses vs truth, and a confident wrong pose is counted, never hidden."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from msgs.geometry import Pose3D
from msgs.sonar import IcpResult
from nodes.sonar.evaluate import SonarEvaluation
from nodes.sonar.evaluation import nearest, pose_error
from sim.nav_drift import drift_matrix
from tether.testing import Harness


def test_pose_error_wraps_heading_and_nearest_picks_the_closest_stamp() -> None:
    a = np.eye(4)
    b = np.eye(4)
    b[:2, :2] = [[math.cos(3.1), -math.sin(3.1)], [math.sin(3.1), math.cos(3.1)]]
    c = np.eye(4)
    c[:2, :2] = [[math.cos(-3.1), -math.sin(-3.1)], [math.sin(-3.1), math.cos(-3.1)]]
    assert abs(pose_error(b, c)[1] - (2 * math.pi - 6.2)) < 1e-9          # across +-pi, not 6.2 rad
    b[:3, 3] = (3.0, 4.0, 0.0)
    assert abs(pose_error(b, a)[0] - 5.0) < 1e-12
    stamps = np.array([10, 20, 30])
    assert [nearest(stamps, s) for s in (0, 14, 16, 26, 99)] == [0, 0, 1, 2, 2]


def test_summary_measures_corrected_error_and_counts_confident_wrong_poses(tmp_path: Path) -> None:
    h = Harness(SonarEvaluation, params={"png": False, "out_dir": str(tmp_path)})
    drift = drift_matrix(0.4, -0.3, math.radians(3.0))
    events = []
    for i in range(10):
        t = i * 0.1
        truth = Pose3D(x_m=float(i), y_m=-5.0, z_m=-1.0, stamp_ns=int(t * 1e9))
        nav = Pose3D.from_matrix(drift @ truth.matrix(), stamp_ns=truth.stamp_ns)
        fix = np.linalg.inv(drift)
        if i == 3:                                   # a confident wrong pose (the symmetric tripod, 120 deg)
            fix = drift_matrix(0.0, 0.0, math.radians(120.0)) @ fix
        result = IcpResult(correction=Pose3D.from_matrix(fix), converged=True, iterations=5, stamp_ns=truth.stamp_ns)
        events += [(t, "truth", truth), (t, "nav", nav), (t + 0.01, "correction", result)]
    h.feed(events)
    s = h.node.summary()
    assert s["corrections"] == 10 and s["trusted_corrections"] == 10
    assert s["loc_err_m"] < 1e-6 and s["loc_err_deg"] < 1e-6          # steady state: exact corrections
    assert s["nav_err_m"] > 0.3 and abs(s["nav_err_deg"] - 3.0) < 1e-6
    assert s["wrong_trusted"] == 1 and abs(s["max_trusted_err_deg"] - 120.0) < 1e-6
