"""The controller's wheels come from the drives (``measured``, e.g. can/measured at the control rate)
while they are fresh; else from the vehicle state. Bad measured wheels are dropped and counted."""
import math

from msgs.control import VehicleState, WheelCommand
from nodes.control.controller import DoubleAckermannController
from tether.testing import Harness


def test_measured_wheels_seed_the_law_and_fall_back_to_the_state_when_stale():
    state = VehicleState(delta_front_rad=0.0, delta_rear_rad=0.0)         # the vehicle model says straight
    drives = WheelCommand(delta_front_rad=0.7, delta_rear_rad=-0.3)       # the drives say otherwise
    with Harness(DoubleAckermannController, params={"rate_hz": 50, "stale_s": 0.1}) as h:
        h.feed([(0.01, "state", state), (0.01, "measured", drives)], until_s=0.05)
        held = h.of("cmd")
        assert held and all((c.delta_front_rad, c.delta_rear_rad) == (0.7, -0.3) for c in held)
        # drives silent past stale_s: the state's wheels again (after a stop, seeded anew)
        h.feed([(0.06 + 0.02 * k, "state", state) for k in range(10)], until_s=0.25)
        assert h.node._wheels() == (0.0, 0.0, 0.0, 0.0)


def test_non_finite_measured_wheels_are_dropped_and_counted():
    with Harness(DoubleAckermannController, params={"rate_hz": 50}) as h:
        good = WheelCommand(delta_front_rad=0.2, delta_rear_rad=0.1)
        bad = WheelCommand(v_front_mps=math.nan, delta_front_rad=0.9)
        h.feed([(0.01, "state", VehicleState()), (0.01, "measured", good), (0.03, "measured", bad)], until_s=0.06)
        assert h.node.bad_inputs == 1
        assert all(math.isfinite(c.v_front_mps) and c.delta_front_rad == 0.2 for c in h.of("cmd"))
