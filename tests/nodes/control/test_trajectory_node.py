"""TrajectoryGenerator start-up: waits for enable, starts at the vehicle's pose from rest, pauses and resumes."""
import math

import numpy as np
import pytest

from msgs.control import VehicleState
from msgs.std import Bool
from nodes.control.trajectory import make_trajectory
from nodes.control.trajectory_node import TrajectoryGenerator
from tether.testing import Harness

GATED = {"kind": "figure8", "rate_hz": 50, "ramp_s": 2.0, "wait_for_enable": True, "start_from_state": True}
POSE = VehicleState(x_m=1.0, y_m=-2.0, theta_rad=0.4)


def speeds(refs) -> np.ndarray:
    return np.array([math.hypot(r.dx_mps, r.dy_mps) for r in refs])


def test_nothing_until_enabled_and_a_state_then_starts_from_rest_where_the_vehicle_stands():
    with Harness(TrajectoryGenerator, params=GATED) as h:
        h.feed([(0.1, "state", POSE)], until_s=1.0)
        assert h.of("reference") == []                       # a state but no enable
        h.feed([(1.0, "enable", Bool(data=False))], until_s=1.5)
        assert h.of("reference") == []
        h.feed([(1.51, "enable", Bool(data=True))], until_s=4.0)
        refs = h.of("reference")
        first = refs[0]
        assert first.stamp_ns == int(1.52e9) and first.t_s == 0.0
        assert (first.x_m, first.y_m, first.theta_rad) == pytest.approx((1.0, -2.0, 0.4))
        assert first.dx_mps == first.dy_mps == first.dtheta_radps == 0.0
        v = speeds(refs)
        assert np.all(np.diff(v[:50]) >= 0) and v[-1] == pytest.approx(math.hypot(*make_trajectory("figure8")(
            refs[-1].t_s).dp[0, :2]), rel=1e-9)               # ramped up to the trajectory's own speed
        # the path is the figure-eight moved rigidly: same distances from the start
        base = make_trajectory("figure8")(np.array([r.t_s for r in refs]))
        d_ref = np.hypot(np.array([r.x_m for r in refs]) - 1.0, np.array([r.y_m for r in refs]) + 2.0)
        assert np.allclose(d_ref, np.hypot(base.p[:, 0] - base.p[0, 0], base.p[:, 1] - base.p[0, 1]), atol=1e-12)


def test_waits_for_a_state_when_asked_to_start_from_it():
    with Harness(TrajectoryGenerator, params=GATED) as h:
        h.feed([(0.0, "enable", Bool(data=True))], until_s=0.5)
        assert h.of("reference") == []
        h.feed([(0.5, "state", VehicleState(x_m=math.nan)), (0.6, "state", POSE)], until_s=0.7)
        refs = h.of("reference")
        assert len(refs) == 5 and refs[0].x_m == 1.0              # the non-finite state was not taken


def test_enable_lost_holds_the_reference_then_resumes_from_rest_where_it_stopped():
    with Harness(TrajectoryGenerator, params=GATED) as h:
        h.feed([(0.0, "state", POSE), (0.0, "enable", Bool(data=True))], until_s=5.0)
        moving = h.of("reference")[-1]
        h.feed([(5.005, "enable", Bool(data=False)), (5.5, "state", VehicleState(x_m=9.0))], until_s=7.0)
        held = [r for r in h.of("reference") if r.stamp_ns > 5.005e9]
        assert len(held) == 100 and h.node.pauses == 1
        assert all(r.dx_mps == r.dy_mps == r.dtheta_radps == r.ddx_mps2 == 0.0 for r in held)
        assert len({(r.x_m, r.y_m, r.theta_rad, r.t_s) for r in held}) == 1          # standing still
        assert held[0].t_s == pytest.approx(moving.t_s + 0.02)          # where it was at the first tick after the drop
        h.feed([(7.01, "enable", Bool(data=True))], until_s=9.0)
        resumed = [r for r in h.of("reference") if r.stamp_ns > 7.01e9]
        assert (resumed[0].x_m, resumed[0].y_m) == (held[-1].x_m, held[-1].y_m)       # same place, not re-anchored
        assert speeds(resumed)[0] == 0.0 and speeds(resumed)[-1] > 0.1                 # ramped up again
        steps = np.hypot(np.diff([r.x_m for r in resumed]), np.diff([r.y_m for r in resumed]))
        assert steps.max() < 0.4 * 0.02 + 1e-9                                        # no jump anywhere


def test_default_config_starts_at_the_first_tick_at_the_trajectory_origin():
    with Harness(TrajectoryGenerator, params={"kind": "circle", "rate_hz": 10}) as h:
        h.advance_to(0.35)
        refs = h.of("reference")
        assert [r.t_s for r in refs] == pytest.approx([0.0, 0.1, 0.2, 0.3])
        assert (refs[0].x_m, refs[0].y_m) == pytest.approx((1.5, 0.0)) and refs[0].dy_mps == pytest.approx(0.5)


def test_align_stands_still_announcing_the_way_out_then_ramps():
    params = dict(GATED, align_s=0.5)
    with Harness(TrajectoryGenerator, params=params) as h:
        h.feed([(0.0, "state", POSE), (0.0, "enable", Bool(data=True))], until_s=1.0)
        refs = h.of("reference")
        aligning = [r for r in refs if r.stamp_ns < 0.52e9]
        assert len(aligning) == 25 and all(r.t_s == 0.0 and r.dx_mps == r.dy_mps == 0.0 for r in aligning)
        assert len({(r.x_m, r.y_m) for r in aligning}) == 1
        # a vanishing acceleration along the departure direction (the path's, rotated by the anchor)
        start = make_trajectory("figure8")(0.0)
        dth = POSE.theta_rad - start.p[0, 2]
        way = np.array([math.cos(dth) * start.dp[0, 0] - math.sin(dth) * start.dp[0, 1],
                        math.sin(dth) * start.dp[0, 0] + math.cos(dth) * start.dp[0, 1]])
        acc = np.array([aligning[0].ddx_mps2, aligning[0].ddy_mps2])
        assert 0 < np.linalg.norm(acc) < 1e-5 and np.dot(acc, way) / np.linalg.norm(acc) / np.linalg.norm(way) == \
            pytest.approx(1.0)
        assert refs[-1].t_s > 0.0 and speeds(refs)[-1] > 0.0          # then it moves
