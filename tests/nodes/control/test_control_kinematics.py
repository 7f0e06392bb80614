"""Double-Ackermann kinematics: conversions, steer branches, command shaping (constraint, limits, zero speed)."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nodes.control.kinematics import (Limits, Wheels, body_twist, choose_steer, initial_wheels, predict_pose,
                                      s_from_wheels, s_from_world, shape_command, wheel_rates, world_from_s,
                                      wrap_angle)

finite = st.floats(-3.0, 3.0, allow_nan=False)


def constraint_residual(w: Wheels) -> float:
    return w.v_front * math.cos(w.delta_front) - w.v_rear * math.cos(w.delta_rear)


def test_wrap_angle_edges():
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(3 * math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
    assert wrap_angle(-0.2) == pytest.approx(-0.2)


@given(st.floats(-math.pi, math.pi), finite, finite, finite)
def test_world_body_roundtrip(theta, dx, dy, dth):
    s = s_from_world(theta, dx, dy, dth, 1.3)
    assert world_from_s(theta, s, 1.3) == pytest.approx((dx, dy, dth), abs=1e-9)


def test_yaw_rate_uses_one_over_wheelbase():
    # Seed erratum: F and B are L apart, so opposite lateral speeds of 0.5 m/s spin at 1/L rad/s, not 2/L.
    vx, vy, om, scrub = body_twist(Wheels(0.5, math.pi / 2, 0.5, -math.pi / 2), 1.0)
    assert (vx, vy, scrub) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert om == pytest.approx(1.0)


def test_crab_twist_is_pure_sideways():
    vx, vy, om, _ = body_twist(Wheels(0.4, math.pi / 2, 0.4, math.pi / 2), 1.0)
    assert (vx, vy, om) == pytest.approx((0.0, 0.4, 0.0), abs=1e-12)


def test_choose_steer_prefers_reversing_to_half_turn():
    # Straight backwards with wheels straight: reverse the wheel, do not steer by pi.
    d, v = choose_steer(-0.5, 0.0, 0.0, 2.5)
    assert d == pytest.approx(0.0) and v == pytest.approx(-0.5)
    # Sideways from a wheel already at +pi/2 stays there (no jump to -pi/2).
    d, v = choose_steer(1e-9, 0.3, math.pi / 2, 2.5)
    assert d == pytest.approx(math.pi / 2) and v == pytest.approx(0.3)
    d, v = choose_steer(-1e-9, -0.3, math.pi / 2, 2.5)
    assert d == pytest.approx(math.pi / 2) and v == pytest.approx(-0.3)


def test_choose_steer_unwrapped_past_pi_over_2_and_respects_limit():
    d, v = choose_steer(math.cos(2.2), math.sin(2.2), 2.1, 2.5)
    assert d == pytest.approx(2.2) and v == pytest.approx(1.0)
    d, v = choose_steer(math.cos(2.7), math.sin(2.7), 2.4, 2.5)   # beyond the stop: flip
    assert d == pytest.approx(2.7 - math.pi) and v == pytest.approx(-1.0)


@settings(max_examples=300, deadline=None)
@given(finite, finite, finite, finite, finite, finite, st.floats(-2.5, 2.5), st.floats(-2.5, 2.5),
       st.floats(-2, 2), st.floats(-2, 2), st.sampled_from([0.0, 0.001, 0.02]))
def test_shape_command_always_satisfies_rigid_body_constraint(vt, lf, lb, ht, hf, hb, pdf, pdb, pvf, pvb, dt):
    prev = Wheels(pvf * math.cos(pdb), pdf, pvf * math.cos(pdf), pdb)   # consistent previous command
    lim = Limits()
    cmd = shape_command((vt, lf, lb), (ht, hf, hb), prev if dt > 0 else None, lim, dt)
    assert all(math.isfinite(v) for v in cmd)
    assert abs(constraint_residual(cmd)) < 1e-9
    assert abs(cmd.delta_front) <= lim.steer_limit_rad + 1e-9 and abs(cmd.delta_rear) <= lim.steer_limit_rad + 1e-9
    assert abs(cmd.v_front) <= lim.wheel_speed_mps + 1e-9 and abs(cmd.v_rear) <= lim.wheel_speed_mps + 1e-9
    if dt > 0:
        assert abs(cmd.delta_front - prev.delta_front) <= lim.steer_rate_radps * dt + 1e-9
        assert abs(cmd.delta_rear - prev.delta_rear) <= lim.steer_rate_radps * dt + 1e-9


def test_shape_command_reproduces_a_feasible_wish_exactly():
    s = (0.3, 0.1, -0.05)
    prev = initial_wheels(s)
    cmd = shape_command(s, (0, 0, 0), prev, Limits(), 0.02)
    assert s_from_wheels(cmd) == pytest.approx(s, abs=1e-12)


def test_saturation_slews_steering_and_slows_instead_of_scrubbing():
    prev = Wheels(0.5, 0.0, 0.5, 0.0)                          # driving straight
    lim = Limits(steer_rate_radps=1.0, wheel_accel_mps2=1.0)
    cmd = shape_command((0.0, 0.5, 0.5), (0, 0, 0), prev, lim, 0.02)   # sudden crab request
    assert cmd.delta_front == pytest.approx(0.02) and cmd.delta_rear == pytest.approx(0.02)
    assert abs(cmd.v_front - 0.5) <= 0.02 + 1e-12
    assert constraint_residual(cmd) == pytest.approx(0.0, abs=1e-12)


def test_zero_speed_holds_steering_or_presteers_along_the_acceleration():
    lim = Limits()
    prev = Wheels(0.0, 0.3, 0.0, -0.2)
    hold = shape_command((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), prev, lim, 0.02)
    assert (hold.delta_front, hold.delta_rear) == (0.3, -0.2) and hold.v_front == 0.0
    tiny = shape_command((1e-4, -3e-4, 2e-4), (0.0, 0.0, 0.0), prev, lim, 0.02)   # sub-gate noise: no steer jitter
    assert (tiny.delta_front, tiny.delta_rear) == (0.3, -0.2)
    pre = shape_command((0.0, 0.0, 0.0), (0.0, 1.0, 1.0), Wheels(0.0, 0.0, 0.0, 0.0), lim, 0.02)  # about to crab
    assert pre.delta_front == pytest.approx(lim.steer_rate_radps * 0.02) and pre.v_front == pytest.approx(0.0)


def test_wheel_rates_finite_at_rest_and_correct_when_moving():
    assert wheel_rates(0.0, 0.4, 1.0, 2.0, 0.01) == pytest.approx((math.cos(0.4) + 2 * math.sin(0.4), 0.0))
    v, d = 0.5, 0.3
    vdot, ddot = 0.2, -0.7          # w_dot for these rates, inverted back
    e, ep = np.array([math.cos(d), math.sin(d)]), np.array([-math.sin(d), math.cos(d)])
    wdot = vdot * e + v * ddot * ep
    assert wheel_rates(v, d, *wdot, 0.01) == pytest.approx((vdot, ddot))
    assert wheel_rates(-v, d, *(-vdot * e - v * ddot * ep), 0.01) == pytest.approx((-vdot, ddot))   # reversing


def test_initial_wheels_forward_branch():
    w = initial_wheels((-0.2, 0.3, 0.3))
    assert w.v_front > 0 and w.delta_front == pytest.approx(math.atan2(0.3, -0.2))
    w = initial_wheels((-0.3, 0.01, 0.01), steer_limit_rad=2.5)         # nearly straight back: reverse
    assert w.v_front < 0 and abs(w.delta_front) < 0.1


def test_predict_pose_follows_an_arc():
    w = Wheels(0.5, 0.0, 0.5, 0.0)
    assert predict_pose((1.0, 2.0, math.pi / 2), w, 0.1, 1.0) == pytest.approx((1.0, 2.05, math.pi / 2))
    spin = Wheels(0.5, math.pi / 2, 0.5, -math.pi / 2)
    x, y, th = predict_pose((0.0, 0.0, math.pi - 0.05), spin, 0.1, 1.0)   # wraps through +-pi
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-12) and th == pytest.approx(-math.pi + 0.05)


def test_choose_steer_clamps_at_the_stop_before_flipping():
    d, v = choose_steer(math.cos(2.7), math.sin(2.7), 2.45, 2.5, clamp_margin_rad=0.35)
    assert d == pytest.approx(2.5) and v == pytest.approx(math.cos(0.2))      # grazing the stop: clamp
    d, v = choose_steer(math.cos(2.95), math.sin(2.95), 2.45, 2.5, clamp_margin_rad=0.35)
    assert d == pytest.approx(2.95 - math.pi) and v == pytest.approx(-1.0)    # well past it: flip


def test_steer_targets_follow_the_path_branch_feedback_only_moves_the_angle():
    from nodes.control.kinematics import steer_targets
    lim = Limits()
    path = (-0.1, 0.2, 0.2)                                      # path wheels at ~2.03 rad, forward
    aim = (2.0, 2.0)
    # feedback opposing the path: the wheel stays on the path's branch and drives backwards along it
    df, db = steer_targets((0.1, -0.2, -0.2), (0, 0, 0), aim, lim, s_path=path)
    assert df == pytest.approx(math.atan2(0.2, -0.1)) and db == pytest.approx(df)
    cmd = shape_command((0.1, -0.2, -0.2), (0, 0, 0), Wheels(0.0, df, 0.0, db), lim, 0.02, targets=(df, db))
    assert cmd.v_front < 0 and cmd.delta_front == pytest.approx(df)
    # feedback turning the wanted direction past the stop: clamped, not swung half a turn
    df, db = steer_targets((-0.3, 0.05, 0.05), (0, 0, 0), (2.4, 2.4), lim, s_path=path)
    assert df == db == lim.steer_limit_rad
    assert steer_targets((-0.3, 0.05, 0.05), (0, 0, 0), (2.4, 2.4), lim)[0] == pytest.approx(
        math.atan2(0.05, -0.3) - math.pi)                        # without the path: the flip
