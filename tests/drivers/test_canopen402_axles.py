"""nodes.control.can_axles: per-axle commands <-> per-drive counts, steer folding."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.canopen402 import DEFAULT_DRIVES
from nodes.control.can_axles import AxleDrive, command_from_actuals, fold_steer, setpoints_from_command

AXLES = [d.axle_drive() for d in DEFAULT_DRIVES]


def test_set_points_scale_per_role_and_axle():
    sp = setpoints_from_command(1.0, 0.5, -0.5, -0.25, AXLES)
    k_wheel, k_steer = DEFAULT_DRIVES[0].counts_per_unit, DEFAULT_DRIVES[1].counts_per_unit
    assert sp == {"front_wheel": round(k_wheel), "front_steer": round(0.5 * k_steer),
                  "rear_wheel": round(-0.5 * k_wheel), "rear_steer": round(-0.25 * k_steer)}


@settings(max_examples=200, deadline=None)
@given(v=st.floats(-3, 3), delta=st.floats(-10, 10), limit=st.floats(math.pi / 2, 3.0))
def test_fold_keeps_the_axle_velocity_vector(v, delta, limit):
    v2, d2 = fold_steer(v, delta, limit)
    assert abs(d2) <= limit + 1e-12
    assert v2 * math.cos(d2) == pytest.approx(v * math.cos(delta), abs=1e-9)
    assert v2 * math.sin(d2) == pytest.approx(v * math.sin(delta), abs=1e-9)


def test_pi_over_two_crab_and_reversing():
    assert fold_steer(1.0, math.pi / 2, math.pi / 2) == pytest.approx((1.0, math.pi / 2))
    assert fold_steer(1.0, math.pi, 2.5) == pytest.approx((-1.0, 0.0))      # reversing, wheel straight
    v, d = fold_steer(0.7, -3.0, 2.5)
    assert v == pytest.approx(-0.7) and d == pytest.approx(math.pi - 3.0)


def test_round_trip_and_bad_input():
    sp = setpoints_from_command(0.8, 0.3, 0.8, -0.3, AXLES)
    assert command_from_actuals({k: float(v) for k, v in sp.items()}, AXLES) == pytest.approx((0.8, 0.3, 0.8, -0.3), abs=1e-4)
    assert command_from_actuals({}, AXLES) == (0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        setpoints_from_command(math.nan, 0.0, 0.0, 0.0, AXLES)
    with pytest.raises(ValueError, match="role"):
        AxleDrive("x", "brake", "front", 1.0)
    with pytest.raises(ValueError, match="counts_per_unit"):
        AxleDrive("x", "wheel", "front", 0.0)
