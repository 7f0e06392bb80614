"""Seed-15 controllers: the final two-stage law, the singular first law, the kinematic baseline; hard cases."""
import math

import numpy as np
import pytest

from nodes.control.double_ackermann import (FblinController, FinalController, KinematicController, RefPoint,
                                            fblin_law, final_law, paper_inputs)
from nodes.control.kinematics import Limits, Wheels, initial_wheels, s_from_world, wrap_angle
from nodes.control.trajectory import make_trajectory
from sim.vehicle4ws import VehicleParams, simulate_tracking

L = 1.0


def ref_at(traj, t):
    r = traj(t)
    return RefPoint(tuple(r.p[0]), tuple(r.dp[0]), tuple(r.ddp[0]))


def residual(cmd) -> np.ndarray:
    return cmd[:, 0] * np.cos(cmd[:, 1]) - cmd[:, 2] * np.cos(cmd[:, 3])


@pytest.mark.parametrize("kind", ["figure8", "crab", "spin", "focus"])
def test_final_law_on_the_reference_is_pure_feedforward(kind):
    traj = make_trajectory(kind)
    t, h = 3.7, 1e-5
    ref = ref_at(traj, t)
    s_ref = s_from_world(ref.p[2], *ref.dp, L)
    law = final_law(ref.p, s_ref, ref, wheelbase_m=L, k_p=3.0, k_s=50.0)
    assert law.s_d == pytest.approx(s_ref, abs=1e-12)
    # s_dot_d is the analytic time derivative of s_d along the reference (checks the seed fix on dA^-1/dX)
    nxt = ref_at(traj, t + h)
    s_next = s_from_world(nxt.p[2], *nxt.dp, L)
    fd = [(a - b) / h for a, b in zip(s_next, s_ref)]
    assert law.sdot_d == pytest.approx(fd, abs=1e-4)
    assert law.sdot_cmd == pytest.approx(law.sdot_d, abs=1e-12)


def test_final_law_finite_at_rear_pi_over_2_crab_and_rest():
    # crab: both wheels at +-pi/2, the first law's singular point; and exactly at rest.
    crab = Wheels(0.4, math.pi / 2, 0.4, math.pi / 2)
    rest = Wheels(0.0, 0.0, 0.0, math.pi / 2)
    ref = RefPoint((0.1, 0.2, 0.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.3))
    for w in (crab, rest):
        s = (0.0, w.v_front * math.sin(w.delta_front), w.v_rear * math.sin(w.delta_rear))
        law = final_law((0.0, 0.0, 0.0), s, ref, wheelbase_m=L, k_p=3.0, k_s=50.0)
        u = paper_inputs(w, law.sdot_cmd)
        assert all(math.isfinite(v) for v in (*law.s_d, *law.sdot_cmd, *u))
    assert paper_inputs(rest, (1.0, 1.0, 1.0))[1::2] == (0.0, 0.0)      # steering gated at rest


def test_first_law_blows_up_as_rear_steer_nears_pi_over_2():
    ref = RefPoint((0.0, 0.0, 0.0), (0.5, 0.1, 0.1), (0.0, 0.0, 0.0))
    mags = []
    for gap in (1e-1, 1e-2, 1e-3):
        u = fblin_law((0.0, 0.0, 0.0), Wheels(0.5, 0.2, 0.0, math.pi / 2 - gap), ref, wheelbase_m=L, k_p=2.0)
        mags.append(max(abs(v) for v in u))
    assert mags[1] > 10 * mags[0] and mags[2] > 10 * mags[1] or not math.isfinite(mags[2])
    ctrl = FblinController()                                      # the shell turns it into a finite stop
    cmd = ctrl.step(ref, (0.0, 0.0, 0.0), Wheels(0.5, 0.2, 0.0, math.pi / 2), 0.02)
    assert ctrl.status == "singular" and cmd.v_front == 0.0 and cmd.v_rear == 0.0
    assert all(math.isfinite(v) for v in cmd)


def test_first_law_matches_final_law_where_both_are_valid():
    # Same reference, moderate steer: the fblin solution rates reproduce p_ddot like the final law does.
    w = Wheels(0.4, 0.3, 0.4 * math.cos(0.3) / math.cos(-0.2), -0.2)
    ref = RefPoint((0.0, 0.0, 0.0), (0.3, 0.1, 0.05), (0.02, -0.01, 0.0))
    u = fblin_law((0.0, 0.0, 0.0), w, ref, wheelbase_m=L, k_p=2.0)
    assert all(math.isfinite(v) and abs(v) < 10 for v in u)


def test_heading_error_wraps_at_pi():
    ref = RefPoint((0.0, 0.0, math.pi - 0.01), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    law = final_law((0.0, 0.0, -math.pi + 0.01), (0.0, 0.0, 0.0), ref, wheelbase_m=L, k_p=2.0, k_s=50.0)
    omega = (law.s_d[1] - law.s_d[2]) / L
    assert omega == pytest.approx(2.0 * wrap_angle(-0.02), abs=1e-9)       # turn 0.02 rad back, not 2 pi


@pytest.mark.parametrize("kind,params,bound_mm", [
    ("figure8", {}, 0.2), ("crab", {}, 0.5), ("spin", {}, 0.01), ("focus", {}, 0.2),
    ("circle", {"heading": "reverse"}, 0.05)])
def test_final_controller_tracks_hard_trajectories(kind, params, bound_mm):
    res = simulate_tracking(FinalController(), make_trajectory(kind, **params), rate_hz=50, duration_s=8.0)
    s = res.summary()
    assert s["rms_mm"] < bound_mm and s["max_deg"] < 0.05 and s["bad_ticks"] == 0.0
    assert np.abs(residual(res.cmd)).max() < 1e-9          # rigid-body constraint on every command


def test_final_beats_kinematic_baseline_and_first_law_fails_on_crab():
    traj = make_trajectory("figure8")
    final = simulate_tracking(FinalController(), traj, rate_hz=20, duration_s=8.0).summary()
    kin = simulate_tracking(KinematicController(), traj, rate_hz=20, duration_s=8.0).summary()
    assert final["rms_mm"] * 3 < kin["rms_mm"]
    crab = simulate_tracking(FblinController(), make_trajectory("crab"), rate_hz=50, duration_s=3.0)
    assert crab.summary()["bad_ticks"] > 0.9 and crab.summary()["max_mm"] > 100
    assert np.all(np.isfinite(crab.cmd))


def test_modelled_bus_with_lead_compensation():
    params = VehicleParams(wheel_tau_s=0.02, steer_tau_s=0.02)
    traj = make_trajectory("figure8")
    kw = dict(rate_hz=50, duration_s=6.0, params=params, latency_s=0.005, state_delay_s=0.005)
    led = simulate_tracking(FinalController(lead_s=0.025), traj, **kw).summary()
    raw = simulate_tracking(FinalController(), traj, **kw).summary()
    assert led["rms_mm"] < 1.0 and led["rms_mm"] * 5 < raw["rms_mm"]


def test_start_from_rest_with_offset_saturates_then_converges():
    lim = Limits(steer_rate_radps=2.0, wheel_accel_mps2=1.0, wheel_speed_mps=0.8)
    ctrl = FinalController(limits=lim)
    ref = RefPoint((1.0, 0.5, 0.8), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    from sim.vehicle4ws import Vehicle4WSModel
    model = Vehicle4WSModel(VehicleParams(steer_rate_radps=2.0, wheel_accel_mps2=1.0, wheel_speed_mps=0.8))
    prev = None
    for _ in range(400):                                   # 8 s at 50 Hz
        cmd = ctrl.step(ref, model.pose, model.wheels, 0.02)
        assert abs(cmd.v_front) <= 0.8 + 1e-12 and abs(cmd.v_rear) <= 0.8 + 1e-12
        if prev is not None:
            assert abs(cmd.delta_front - prev.delta_front) <= 2.0 * 0.02 + 1e-12
            assert abs(cmd.v_front - prev.v_front) <= 1.0 * 0.02 + 1e-9
        assert abs(residual(np.array([cmd]))[0]) < 1e-9
        prev = cmd
        model.step(cmd, 0.02)
    x, y, th = model.pose
    # At rest the steering is held once the wanted speed drops below v_gate, so an error of at most
    # about v_gate / k_p (3 mm here) may remain across the wheels; along them it keeps converging.
    assert math.hypot(x - 1.0, y - 0.5) < lim.v_gate_mps / ctrl.k_p and abs(wrap_angle(th - 0.8)) < 3e-3


def test_non_finite_input_commands_a_finite_stop():
    ctrl = FinalController()
    ctrl.prev = Wheels(0.3, 0.2, 0.3, -0.1)
    bad = RefPoint((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cmd = ctrl.step(bad, (0.0, 0.0, 0.0), Wheels(0.3, 0.2, 0.3, -0.1), 0.02)
    assert cmd == Wheels(0.0, 0.2, 0.0, -0.1) and ctrl.status == "non-finite input"
    cmd = ctrl.step(RefPoint((0, 0, 0), (0, 0, 0), (0, 0, 0)), (0.0, 0.0, 0.0), Wheels(math.inf, 0, 0, 0), 0.02)
    assert all(math.isfinite(v) for v in cmd)


def test_reversing_keeps_wheels_straight():
    traj = make_trajectory("circle", heading="reverse", radius_m=3.0)
    res = simulate_tracking(FinalController(), traj, rate_hz=50, duration_s=4.0)
    assert np.all(res.cmd[:, 0] < 0) and np.all(res.cmd[:, 2] < 0)           # wheels spin backwards...
    assert np.abs(res.cmd[:, [1, 3]]).max() < 0.3                             # ...rather than steering by pi


def test_config_errors():
    with pytest.raises(ValueError, match="steer_limit_rad"):
        FinalController(limits=Limits(steer_limit_rad=1.0))
    with pytest.raises(ValueError, match="wheelbase_m"):
        FinalController(wheelbase_m=0.0)
    assert initial_wheels((0.0, 0.0, 0.0)) == Wheels(0.0, 0.0, 0.0, 0.0)


def test_start_from_rest_on_a_ramped_figure_eight_aligns_wheels_without_flips():
    from sim.vehicle4ws import Vehicle4WSModel
    traj = make_trajectory("figure8", ramp_s=2.0)
    ctrl = FinalController(lead_s=0.02)
    model = Vehicle4WSModel(VehicleParams(wheel_tau_s=0.02, steer_tau_s=0.02), pose=(0.0, 0.0, -math.pi / 2))
    errs, rear = [], []
    for k in range(300):                                   # 6 s at 50 Hz, wheels straight at rest at t = 0
        cmd = ctrl.step(ref_at(traj, k * 0.02), model.pose, model.wheels, 0.02)
        model.step(cmd, 0.02)
        r = traj(k * 0.02 + 0.02).p[0]
        errs.append(math.hypot(model.x - r[0], model.y - r[1]))
        rear.append(cmd.delta_rear)
    assert max(errs) < 0.02 and max(errs[200:]) < 5e-5       # ~1 cm while the wheels swing ~2 rad
    assert min(rear[1:]) > 0.0      # the rear wheel turned the forward way (to ~2.2 rad), no half-turn flip


def test_restart_is_seeded_from_the_measured_wheels_not_the_last_command():
    """Commands went out while the drives were not enabled (measured steering stayed at -0.8 rad):
    after a stop, the next command slews from where the wheels are, not from the stale command."""
    ctrl = FinalController()
    ref = RefPoint((0.0, 0.0, 0.0), (0.3, 0.3, 0.0), (0.0, 0.0, 0.0))
    stuck = Wheels(0.0, -0.8, 0.0, -0.8)
    for _ in range(30):
        cmd = ctrl.step(ref, (0.0, 0.0, 0.0), stuck, 0.02)
    assert cmd.delta_front == pytest.approx(math.pi / 4, abs=1e-3)        # believes it steered to 45 deg
    ctrl.stop(stuck, "stale")
    cmd = ctrl.step(ref, (0.0, 0.0, 0.0), stuck, 0.02)
    step = ctrl.limits.steer_rate_radps * 0.02
    assert cmd.delta_front == pytest.approx(-0.8 + step) and cmd.delta_rear == pytest.approx(-0.8 + step)
    assert abs(cmd.v_front) <= ctrl.limits.wheel_accel_mps2 * 0.02 + 1e-12


@pytest.mark.parametrize("offset", [(0.002, -0.001), (0.001, 0.001), (-0.001, -0.002), (0.0, 0.002)])
def test_start_from_rest_with_a_millimetre_offset_keeps_both_wheels_on_the_forward_branch(offset):
    """At walking pace a millimetre error dominates the command; the wheels must still pick the
    branch of the path (rear at ~2.2 rad, 0.3 rad from its stop) and never reverse through a flip."""
    from sim.vehicle4ws import Vehicle4WSModel
    traj = make_trajectory("figure8", ramp_s=4.0)
    ctrl = FinalController(lead_s=0.02)
    model = Vehicle4WSModel(VehicleParams(wheel_tau_s=0.02, steer_tau_s=0.02),
                            pose=(offset[0], offset[1], -math.pi / 2))
    cmds, errs = [], []
    for k in range(400):                                   # 8 s at 50 Hz from straight wheels at rest
        cmd = ctrl.step(ref_at(traj, k * 0.02), model.pose, model.wheels, 0.02)
        model.step(cmd, 0.02)
        cmds.append(cmd)
        r = traj(k * 0.02 + 0.02).p[0]
        errs.append(math.hypot(model.x - r[0], model.y - r[1]))
    c = np.array(cmds)
    assert c[:, [0, 2]].min() > -0.01                     # no wheel drives backwards (a flip runs at -0.3 m/s)
    assert c[:, 3].min() > -0.1 and c[:, 3].max() <= 2.5 # rear stays on the forward side, clamped at its stop
    assert max(errs) < 5e-3 and max(errs[300:]) < 5e-4
