"""4WS vehicle simulator: kinematics, actuator limits and lag, scrub, seeded slip, node inputs."""
import math

import numpy as np
import pytest

from msgs.control import VehicleState, WheelCommand
from nodes.control.kinematics import Wheels
from sim.vehicle4ws import Vehicle4WS, Vehicle4WSModel, VehicleParams
from tether.testing import Harness

FAST = VehicleParams(steer_rate_radps=1e6, wheel_accel_mps2=1e6, wheel_speed_mps=10.0)


def test_straight_crab_and_spin():
    m = Vehicle4WSModel(FAST, pose=(0.0, 0.0, math.pi / 2), wheels=Wheels(0.5, 0.0, 0.5, 0.0))
    m.step(Wheels(0.5, 0.0, 0.5, 0.0), 2.0)
    assert m.pose == pytest.approx((0.0, 1.0, math.pi / 2), abs=1e-9)
    m = Vehicle4WSModel(FAST, wheels=Wheels(0.5, math.pi / 2, 0.5, math.pi / 2))
    m.step(Wheels(0.5, math.pi / 2, 0.5, math.pi / 2), 2.0)        # crab: |delta_b| = pi/2
    assert m.pose == pytest.approx((0.0, 1.0, 0.0), abs=1e-9)
    m = Vehicle4WSModel(FAST, pose=(1.0, 1.0, 3.0), wheels=Wheels(0.5, math.pi / 2, 0.5, -math.pi / 2))
    m.step(Wheels(0.5, math.pi / 2, 0.5, -math.pi / 2), 1.0)      # spin at 1 rad/s through +pi
    assert m.pose == pytest.approx((1.0, 1.0, 4.0 - 2 * math.pi), abs=1e-9)


def test_circle_closes_exactly():
    # double Ackermann turning about a point: front +d, rear -d; radius of O = (L/2) / tan(d)
    d, v = 0.3, 0.4
    omega = 2 * v * math.sin(d) / 1.0
    m = Vehicle4WSModel(FAST, wheels=Wheels(v, d, v, -d))
    m.step(Wheels(v, d, v, -d), 2 * math.pi / omega)
    assert m.pose[:2] == pytest.approx((0.0, 0.0), abs=1e-9)


def test_actuator_rate_and_accel_limits():
    p = VehicleParams(steer_rate_radps=2.0, wheel_accel_mps2=1.0)
    m = Vehicle4WSModel(p)
    m.step(Wheels(1.0, 1.0, -1.0, -3.0), 0.1)
    assert m.wheels == pytest.approx((0.1, 0.2, -0.1, -0.2))
    m.step(Wheels(1.0, 1.0, -1.0, -3.0), 5.0)
    assert m.wheels == pytest.approx((1.0, 1.0, -1.0, -p.steer_limit_rad))    # clamped at the steer stop


def test_first_order_drive_lag():
    p = VehicleParams(wheel_tau_s=0.05, steer_tau_s=0.1, wheel_accel_mps2=100.0, steer_rate_radps=100.0)
    m = Vehicle4WSModel(p)
    m.step(Wheels(1.0, 0.5, 1.0, 0.5), 0.05)
    assert m.wheels.v_front == pytest.approx(1 - math.exp(-1), abs=1e-9)
    assert m.wheels.delta_front == pytest.approx(0.5 * (1 - math.exp(-0.5)), abs=1e-9)


def test_fighting_wheels_scrub_not_teleport():
    m = Vehicle4WSModel(FAST, wheels=Wheels(1.0, 0.0, 0.0, 0.0))
    m.step(Wheels(1.0, 0.0, 0.0, 0.0), 1.0)                  # front pushes, rear stands still
    assert m.scrub_mps == pytest.approx(1.0)
    assert m.pose == pytest.approx((0.5, 0.0, 0.0))         # least-squares twist: half speed


def test_slip_noise_is_seeded_and_bounded():
    def run(seed):
        m = Vehicle4WSModel(VehicleParams(slip_std=0.05, seed=seed), wheels=Wheels(0.5, 0.0, 0.5, 0.0))
        m.step(Wheels(0.5, 0.0, 0.5, 0.0), 4.0)
        return m.pose
    a, b, c = run(1), run(1), run(2)
    assert a == b and a != c
    assert abs(a[0] - 2.0) < 0.5 and abs(a[1]) < 0.5


def test_non_finite_command_is_held():
    m = Vehicle4WSModel(FAST, wheels=Wheels(0.2, 0.0, 0.2, 0.0))
    m.step(Wheels(math.nan, 0.0, math.inf, 0.0), 1.0)
    assert m.pose == pytest.approx((0.2, 0.0, 0.0))


def test_node_cmd_then_actuation_override():
    with Harness(Vehicle4WS, params={"rate_hz": 10, "steer_rate_radps": 1000, "wheel_accel_mps2": 1000}) as h:
        h.feed([(0.0, "cmd", WheelCommand(v_front_mps=1.0, v_rear_mps=1.0))], until_s=1.0)
        st = h.of("state")[-1]
        assert isinstance(st, VehicleState) and st.x_m == pytest.approx(1.0, abs=1e-3) and st.v_front_mps == 1.0
        # measured actuation from the drives takes over: sideways at 0.5 m/s, cmd ignored from now on
        h.feed([(1.0, "actuation", WheelCommand(v_front_mps=0.5, delta_front_rad=math.pi / 2,
                                               v_rear_mps=0.5, delta_rear_rad=math.pi / 2)),
                (1.0, "cmd", WheelCommand(v_front_mps=2.0, v_rear_mps=2.0))], until_s=2.0)
        st = h.of("state")[-1]
        assert st.x_m == pytest.approx(1.0, abs=1e-3) and st.y_m == pytest.approx(0.5, abs=1e-9)
        assert st.delta_rear_rad == pytest.approx(math.pi / 2)


def test_node_drops_non_finite_input_and_counts_it():
    with Harness(Vehicle4WS, params={"rate_hz": 10}) as h:
        h.feed([(0.0, "cmd", WheelCommand(v_front_mps=math.nan))], until_s=0.5)
        assert h.node.bad_inputs == 1
        assert all(np.isfinite([s.x_m, s.v_front_mps]).all() for s in h.of("state"))
        assert h.of("state")[-1].x_m == 0.0


def test_a_state_is_stamped_with_the_time_its_pose_is_for():
    """The state's stamp is the time the model was integrated to, not a second clock reading: a
    node preempted between the two (a higher real-time priority waking) stamped its pose
    milliseconds late, and the tracking evaluation saw single-sample error spikes (4.7 mm at
    0.5 m/s in launch/ackermann_can.yaml at SCHED_FIFO)."""
    h = Harness(Vehicle4WS, params={"theta_rad": 0.0})
    clock = iter(range(0, 10**9, 3_000_000))            # every reading 3 ms after the last
    h.node.now_ns = lambda: next(clock)
    h.node.on_actuation(WheelCommand(v_front_mps=1.0, v_rear_mps=1.0))
    for _ in range(5):
        state = h.node.on_tick(None)["state"]
        assert state.x_m == pytest.approx(state.stamp_ns * 1e-9, abs=1e-12)   # 1 m/s straight from x = 0 at t = 0
