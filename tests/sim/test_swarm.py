"""Swarm simulator: the seed's dynamics, the task's bookkeeping and the hard cases."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.swarm import SwarmWorld, seed_scene, wrap


def items(w: SwarmWorld) -> np.ndarray:
    """Food in the system that did not come from the source: must stay what it was at t = 0."""
    return w.carrying.sum(axis=1) + w.cache.sum(axis=1) + w.food - w.picked


def test_no_robots_and_one_robot():
    empty = SwarmWorld(seed_scene(1), 0, seeds=range(3))
    empty.run(20.0)
    assert empty.food.tolist() == [0, 0, 0] and empty.efficiency().tolist() == [0.0, 0.0, 0.0]
    alone = SwarmWorld(seed_scene(0), 1, seeds=range(8))
    alone.run(200.0)
    # 3 m each way at <= 0.1 m/s: at most about three round trips in 200 s, and no contacts
    assert np.all(alone.food >= 2) and np.all(alone.food <= 4)
    assert alone.contact_s.sum() == 0


@pytest.mark.parametrize("scene", [seed_scene(0), seed_scene(1), seed_scene(2), seed_scene(1, transfer="cache"),
                                   seed_scene(0, transfer="p2p"), seed_scene(1, policy="adaptive"),
                                   seed_scene(1, gate_width_m=0.3)], ids=lambda s: f"{len(s.zones_m)}-{s.transfer}-"
                                                                              f"{s.policy}-{s.gate_width_m}")
def test_food_is_conserved_and_robots_stay_in_the_arena(scene):
    w = SwarmWorld(scene, 25, seeds=range(4))
    start = items(w).copy()
    for _ in range(600):
        w.step(0.1)
        assert np.array_equal(items(w), start)
    r = scene.radius_m
    assert np.all((w.x >= r - 1e-12) & (w.x <= scene.length_m - r + 1e-12))
    assert np.all((w.y >= r - 1e-12) & (w.y <= scene.width_m - r + 1e-12))
    assert np.all(np.isfinite(w.th)) and np.all(np.abs(w.th) <= math.pi + 1e-12)
    assert w.food.sum() > 0


def test_partitioning_hands_over():
    direct = SwarmWorld(seed_scene(1), 20, seeds=range(4))
    direct.run(100.0)
    assert np.all(direct.handovers > 0) and direct.wait_s.sum() > 0
    p2p = SwarmWorld(seed_scene(0, transfer="p2p"), 20, seeds=range(4))
    p2p.run(100.0)
    assert p2p.handovers.sum() > 0


def test_batched_worlds_are_independent():
    scene = seed_scene(1, policy="adaptive")
    both = SwarmWorld(scene, 12, seeds=[3, 4])
    both.run(60.0)
    for k, seed in enumerate((3, 4)):
        solo = SwarmWorld(scene, 12, seeds=[seed])
        solo.run(60.0)
        np.testing.assert_array_equal(solo.x[0], both.x[k])
        assert solo.food[0] == both.food[k]


def test_robots_spawned_on_one_point_separate():
    w = SwarmWorld(seed_scene(0), 10, seeds=[0])
    w.x[:], w.y[:] = 2.0, 0.5
    for _ in range(100):
        w.step(0.1)
    d = np.hypot(w.x[0][:, None] - w.x[0][None], w.y[0][:, None] - w.y[0][None]) + np.eye(10)
    assert np.all(np.isfinite(w.x)) and d.min() > 1.5 * w.scene.radius_m


def test_head_on_robots_bounce_apart():
    w = SwarmWorld(seed_scene(0), 2, seeds=[0])
    w.x[0], w.y[0], w.th[0], w.v[0] = [1.92, 2.08], [0.5, 0.5], [0.0, math.pi], [0.1, 0.1]
    w.carrying[0] = [True, False]
    for _ in range(3):
        w.step(0.1)
    assert w.contact_s[0].min() > 0                           # both touched
    assert math.cos(w.th[0, 0]) < 0 < math.cos(w.th[0, 1])    # and turned away from each other
    assert w.x[0, 1] - w.x[0, 0] >= 2 * w.scene.radius_m - 1e-9


def test_heading_takes_the_short_way_across_the_wrap():
    w = SwarmWorld(seed_scene(0), 1, seeds=[0])
    w.x[0], w.y[0], w.th[0], w.carrying[0] = [2.0], [0.5], [-math.pi + 0.05], [False]   # target pi: 0.05 rad away
    turned = []
    for _ in range(20):
        w.step(0.1)
        turned.append(abs(wrap(w.th[0, 0] - math.pi)))
    assert max(turned) < 0.06
    np.testing.assert_allclose(wrap(np.array([3 * math.pi, -3 * math.pi])), [math.pi, math.pi])


def test_a_gate_narrower_than_a_robot_lets_nobody_through():
    scene = seed_scene(1, gate_width_m=0.1, theta_s=0.0)     # 0.1 m < 2 x 0.07 m; never waits
    w = SwarmWorld(scene, 20, seeds=range(3))
    left = w.x < scene.zones_m[0]
    for _ in range(1500):
        w.step(0.1)
        assert np.array_equal(w.x < scene.zones_m[0], left)
    assert w.handovers.sum() == 0
    wide = SwarmWorld(seed_scene(1, gate_width_m=0.4, theta_s=0.0), 20, seeds=range(3))
    side = wide.x < 1.8
    wide.run(150.0)
    assert np.any((wide.x < 1.8) != side)                     # a robot-sized gate lets them pass


def test_theta_zero_never_waits_and_infinite_theta_never_gives_up():
    never = SwarmWorld(seed_scene(1, theta_s=0.0), 10, seeds=range(3))
    never.run(100.0)
    assert never.wait_s.max() < 1.0                           # one tick per arrival at most
    forever = SwarmWorld(seed_scene(1, theta_s=math.inf), 1, seeds=range(3))
    forever.run(200.0)
    assert np.all(forever.food <= 1)                          # alone, it waits at the zone for good
    assert np.all(forever.waiting[:, 0] | (forever.food == 0))


def test_time_step_does_not_change_the_average():
    # at N = 30, where robots jam: turning away at every tick of a contact made F/N fall 18 %
    # from dt 0.1 to 0.05 s; a bounce of fixed duration does not depend on the tick
    a = SwarmWorld(seed_scene(1), 30, seeds=range(16))
    a.run(200.0, 0.1)
    b = SwarmWorld(seed_scene(1), 30, seeds=range(100, 116))
    b.run(200.0, 0.05)
    ea, eb = a.efficiency(), b.efficiency()
    noise = math.hypot(ea.std(ddof=1), eb.std(ddof=1)) / 4
    assert abs(ea.mean() - eb.mean()) < 3 * noise


def test_scene_errors_say_what_is_wrong():
    with pytest.raises(ValueError, match="0, 1 or 2"):
        seed_scene(3)
    with pytest.raises(ValueError, match="no exchange zones"):
        seed_scene(1, transfer="p2p")
    with pytest.raises(ValueError, match="theta_s"):
        seed_scene(1, theta_s=-1.0)
    with pytest.raises(ValueError, match="dt_s"):
        SwarmWorld(seed_scene(0), 3).step(0.0)
