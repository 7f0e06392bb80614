"""CasADi MPC: tracks hard trajectories, warm start, finite output, constraint on commands."""
import math

import numpy as np
import pytest

from nodes.control.double_ackermann import RefPoint
from nodes.control.kinematics import Wheels
from nodes.control.mpc import MpcController, taylor_preview
from nodes.control.trajectory import make_trajectory
from sim.vehicle4ws import simulate_tracking


@pytest.fixture(scope="module")
def mpc():
    return MpcController(horizon=10)


@pytest.mark.parametrize("kind,bound_mm", [("figure8", 0.5), ("crab", 2.0), ("spin", 0.01), ("focus", 0.5)])
def test_mpc_tracks(mpc, kind, bound_mm):
    # focus: the heading crosses +-pi after 0.6 s (the warm start must follow the wrap)
    res = simulate_tracking(mpc, make_trajectory(kind), rate_hz=20, duration_s=4.0)
    s = res.summary()
    assert s["rms_mm"] < bound_mm and s["bad_ticks"] == 0.0
    assert np.abs(res.cmd[:, 0] * np.cos(res.cmd[:, 1]) - res.cmd[:, 2] * np.cos(res.cmd[:, 3])).max() < 1e-9
    assert mpc.solve_fail == 0


def test_mpc_heading_wrap_and_offset(mpc):
    mpc.reset()
    ref = RefPoint((0.2, 0.0, math.pi - 0.05), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cmd = mpc.step(ref, (0.0, 0.0, -math.pi + 0.05), Wheels(0.0, 0.0, 0.0, 0.0), 0.05)
    assert all(math.isfinite(v) for v in cmd)
    # turning -0.1 rad the short way: the front wheel moves right of the rear (omega < 0) or the robot waits
    omega = (cmd.v_front * math.sin(cmd.delta_front) - cmd.v_rear * math.sin(cmd.delta_rear))
    assert omega <= 1e-9


def test_taylor_preview_extrapolates_constant_acceleration():
    fn = taylor_preview(RefPoint((1.0, 0.0, 0.0), (0.5, 0.0, 0.1), (0.2, 0.0, 0.0)))
    p, dp = fn(np.array([0.0, 1.0]))
    assert p[1] == pytest.approx([1.6, 0.0, 0.1]) and dp[1] == pytest.approx([0.7, 0.0, 0.1])
