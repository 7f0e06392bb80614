"""The UAV servo and simulator: homing on fixes, holding on a rejected fix, INS search, limits."""
from __future__ import annotations

import math

import pytest

from msgs.uav import GeoFix, UavCommand, UavState
from nodes.control.uav_homing import Gains, servo
from nodes.control.uav_servo import UavServo
from sim.aerial import Command, Limits, Uav, UavState as S
from sim.uav_node import UavSim
from tether.errors import ConfigError
from tether.testing import Harness


def test_servo_points_at_the_target_in_the_body_frame_and_saturates():
    g = Gains()
    cmd = servo((0.0, 0.0, math.pi / 2, 40.0), (0.0, 100.0, math.pi / 2, 40.0), g)   # facing north, target north
    assert cmd[0] == pytest.approx(g.speed_mps) and abs(cmd[1]) < 1e-9 and cmd[2] == 0 and cmd[3] == 0
    cmd = servo((0.0, 0.0, 0.0, 40.0), (0.0, -1.0, 0.0, 50.0), g)                     # facing east, target south
    assert cmd[1] == pytest.approx(0.4) and cmd[3] == pytest.approx(g.climb_mps)     # right, and up (clipped)
    cmd = servo((0.0, 0.0, 3.0, 40.0), (0.0, 0.0, -3.0, 40.0), g)                     # across the wrap: short way
    assert cmd[2] > 0


def test_uav_respects_its_limits_and_altitude_band():
    uav = Uav(S(0, 0, 0, 119.0), Limits())
    for _ in range(100):
        s = uav.step(Command(forward=50.0, climb=10.0, yaw_rate=10.0), 0.1)
    assert s.alt == pytest.approx(120.0)                         # altitude at its limit stays there
    assert s.e == pytest.approx(100 * 0.1 * 6.0, rel=1e-6) or math.hypot(s.e, s.n) <= 60.0 + 1e-6


def _servo(**params):
    return Harness(UavServo, params=dict(target_e_m=10.0, target_n_m=0.0, rate_hz=10.0, **params))


def test_servo_holds_on_a_rejected_fix_then_searches_on_the_ins():
    h = _servo(hold_s=2.0)
    ins = UavState(e_m=0.0, n_m=0.0, alt_m=40.0, yaw_rad=0.0, source="ins")
    t0 = h.start_ns                                                 # fixes carry their image's stamp
    h.feed([(0.0, "ins", ins), (0.05, "fix", GeoFix(stamp_ns=t0 + 50_000_000, ok=True, e_m=0.0, n_m=0.0,
                                                    alt_m=40.0))], until_s=1.0)
    moving = h.of("command")[-1]
    assert moving.forward_mps > 0.5
    start = len(h.outputs)
    h.feed([(1.0, "fix", GeoFix(stamp_ns=t0 + 1_000_000_000, ok=False, reason="no match"))], until_s=2.8)
    held = [o.msg for o in h.outputs[start:]]
    f = [m.forward_mps for m in held]
    assert f and all(b <= a + 1e-12 for a, b in zip([moving.forward_mps] + f, f))   # braking, never speeding up
    assert f[-1] == pytest.approx(0.0, abs=1e-9)                    # rate-limited down to a hold
    h.advance_to(6.0)                                               # the fix has timed out: search on the INS
    assert h.node.mode == "search" and h.of("command")[-1].forward_mps > 0


def test_sim_hovers_on_a_stale_command_and_publishes_its_camera():
    sim = Harness(UavSim, params=dict(rate_hz=10.0, image_every=5, command_timeout_s=0.3))
    sim.feed([(0.0, "command", UavCommand(forward_mps=3.0))], until_s=1.0)
    truth = sim.of("truth")
    assert len(sim.of("image")) == len(truth[::5]) and sim.of("image")[0].data.shape == (480, 640, 3)
    e = [m.e_m for m in truth]
    assert e[2] > e[1]                                              # moving while the command is fresh
    assert e[-1] == pytest.approx(e[-2])                            # then hovering
    with pytest.raises(ConfigError):
        Harness(UavSim, params=dict(map="google"))
