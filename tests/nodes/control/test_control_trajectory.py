"""Reference generators: analytic derivatives, crab / spin / focus semantics, wrap, bad parameters."""
import math

import numpy as np
import pytest

from nodes.control.kinematics import s_from_world
from nodes.control.trajectory import GENERATORS, circle, crab, figure_eight, focus, make_trajectory, spin

CASES = [("circle", {}), ("circle", {"heading": "reverse"}), ("circle", {"heading": 0.7}), ("figure8", {}),
         ("crab", {}), ("spin", {}), ("focus", {}), ("focus", {"path": "figure8", "focus_xy": (0.0, -0.4)}),
         ("figure8", {"ramp_s": 3.0}), ("spin", {"ramp_s": 1.0})]


@pytest.mark.parametrize("kind,params", CASES)
def test_derivatives_match_finite_differences(kind, params):
    t = np.linspace(0.0, 30.0, 30001)
    ref = make_trajectory(kind, **params)(t)
    dt = t[1] - t[0]
    p = np.unwrap(ref.p, axis=0)                  # heading is wrapped; its derivative is the continuous one
    # the ramp's jerk jumps at its two ends: central differences are O(dt) off at those samples only
    ok = np.abs(t - params.get("ramp_s", -1.0)) > 3 * dt
    ok[:3] = ok[-3:] = False
    assert np.abs(np.gradient(p, dt, axis=0) - ref.dp)[ok].max() < 1e-5
    assert np.abs(np.gradient(ref.dp, dt, axis=0) - ref.ddp)[ok].max() < 1e-5
    assert np.all(ref.p[:, 2] >= -math.pi) and np.all(ref.p[:, 2] < math.pi)


def test_crab_moves_purely_sideways_and_reverses():
    t = np.linspace(0, 12, 1201)
    ref = crab(t, heading_rad=0.4)
    s = np.array([s_from_world(th, dx, dy, dth, 1.0) for (_, _, th), (dx, dy, dth) in zip(ref.p, ref.dp)])
    assert np.abs(s[:, 0]).max() < 1e-12                       # v_tan = 0: body x never moves
    assert s[:, 1].max() > 0.4 and s[:, 1].min() < -0.4        # sideways both ways (reversing, through rest)


def test_spin_stays_put_and_wraps():
    ref = spin(np.linspace(0, 10, 101), rate_radps=1.0, heading_rad=3.0)
    assert np.all(ref.p[:, :2] == 0.0)
    assert ref.p[2, 2] == pytest.approx(3.2 - 2 * math.pi)   # 3.2 rad wraps to -3.08
    assert np.all(ref.dp[:, 2] == 1.0)


def test_focus_heading_aims_at_the_focus():
    f = (0.3, -0.2)
    ref = focus(np.linspace(0, 20, 50), focus_xy=f, path="circle", radius_m=2.0)
    aim = np.arctan2(f[1] - ref.p[:, 1], f[0] - ref.p[:, 0])
    assert np.allclose(np.cos(aim - ref.p[:, 2]), 1.0)


def test_circle_reverse_heading_points_backwards():
    ref = circle(np.array([1.0]), heading="reverse")
    vel = math.atan2(ref.dp[0, 1], ref.dp[0, 0])
    assert math.cos(ref.p[0, 2] - vel) == pytest.approx(-1.0)


def test_figure_eight_heading_is_independent_of_tangent():
    t = np.linspace(0, 40, 400)
    ref = figure_eight(t)
    tangent = np.arctan2(ref.dp[:, 1], ref.dp[:, 0])
    rel = np.angle(np.exp(1j * (tangent - ref.p[:, 2])))
    assert rel.max() - rel.min() > 3.0          # the body sees its velocity swing over > 3 rad


@pytest.mark.parametrize("kind,params,match", [
    ("circle", {"radius_m": 0.0}, "radius"), ("focus", {"focus_xy": (1.5, 0.0)}, "focus"),
    ("figure8", {"period_s": 0.0}, "period"), ("nope", {}, "unknown trajectory")])
def test_bad_parameters_say_what_to_do(kind, params, match):
    with pytest.raises(ValueError, match=match):
        make_trajectory(kind, **params)


def test_ramp_starts_at_rest_and_joins_the_unramped_path():
    plain, ramped = make_trajectory("figure8"), make_trajectory("figure8", ramp_s=2.0)
    r0 = ramped(0.0)
    assert np.all(r0.dp == 0.0) and np.all(r0.ddp == 0.0)
    later = ramped(np.array([5.0, 9.0]))
    assert np.allclose(later.p, plain(np.array([4.0, 8.0])).p)       # 1 s behind once at speed
    with pytest.raises(ValueError, match="ramp_s"):
        make_trajectory("circle", ramp_s=-1.0)


def test_generator_names():
    assert set(GENERATORS) == {"circle", "figure8", "crab", "spin", "focus"}
    with pytest.raises(ValueError, match="finite"):
        circle(np.array([np.nan]))


def test_resume_restarts_from_rest_at_the_held_point_and_anchor_moves_the_path_rigidly():
    from nodes.control.trajectory import anchor, resume
    base = make_trajectory("figure8")
    t = np.linspace(0.0, 6.0, 6001)
    ref, s = resume(base, 7.5, t, 2.0)
    assert s[0] == 7.5 and np.allclose(ref.p[0], base(7.5).p[0]) and np.allclose(ref.dp[0], 0.0)
    assert np.allclose(ref.dp[-1], base(s[-1]).dp[0]) and s[-1] == pytest.approx(7.5 + 6.0 - 1.0)   # full speed
    dt = t[1] - t[0]
    assert np.abs(np.gradient(np.unwrap(ref.p, axis=0), dt, axis=0) - ref.dp)[3:-3].max() < 1e-5
    # anchored at (1, 2, 0.5): the start lands on that pose, the path keeps its shape and speed
    start, at = tuple(base(0.0).p[0]), (1.0, 2.0, 0.5)
    moved = anchor(base(t), start, at)
    orig = base(t)
    assert np.allclose(moved.p[0], at)
    assert np.allclose(np.hypot(*(moved.p[:, :2] - moved.p[:1, :2]).T), np.hypot(*(orig.p[:, :2] - orig.p[:1, :2]).T))
    assert np.allclose(np.hypot(moved.dp[:, 0], moved.dp[:, 1]), np.hypot(orig.dp[:, 0], orig.dp[:, 1]))
    dth = at[2] - start[2]
    assert np.allclose((moved.p[:, 2] - orig.p[:, 2] - dth + np.pi) % (2 * np.pi) - np.pi, 0.0)
    assert np.abs(np.gradient(np.unwrap(moved.p, axis=0), dt, axis=0) - moved.dp)[3:-3].max() < 1e-5
    assert np.abs(np.gradient(moved.dp, dt, axis=0) - moved.ddp)[3:-3].max() < 1e-5
    # body-frame velocities (what the wheels see) are unchanged by the move
    for k in (0, 2500, 6000):
        assert np.allclose(s_from_world(moved.p[k, 2], *moved.dp[k], 1.0), s_from_world(orig.p[k, 2], *orig.dp[k], 1.0))
