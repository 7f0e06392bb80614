"""The deployed car: the rl_car launch in lockstep, the dead man's rule, refused observations."""
from __future__ import annotations

import numpy as np
import pytest

from msgs.learn import Observation, PolicyAction
from nodes.learn.policy_node import PolicyNode
from sim.car_node import CarSim
from sim.lockstep import run_lockstep
from tether.testing import Harness

LAUNCH = "launch/rl_car.yaml"


def test_policy_drives_the_car_to_its_targets_in_the_launch(tmp_path):
    png = tmp_path / "rl_car.png"
    run = run_lockstep(LAUNCH, duration_s=10.5, step_s=0.01,
                       overrides={"view": {"png": str(png)}, "car": {"episodes": 1}})
    ends = run.of("car/episode")
    assert len(ends) == 1 and ends[0].truncated
    final_mm = dict(zip(ends[0].metric_names, ends[0].metrics))["distance_m"] * 1000
    start_mm = float(run.of("car/obs")[0].obs[8]) * 1000
    assert final_mm < 50.0 < start_mm                     # 0.3-1.5 m away at the start
    assert png.stat().st_size > 10_000
    assert run.node("car").stale <= 1                      # only the first tick, before any action


def _car(hold_s: float = 0.3) -> Harness:
    return Harness(CarSim, params={"episodes": 1, "hold_s": hold_s, "rate_hz": 10.0})


def test_car_stops_when_actions_stop_coming():
    h = _car()
    h.advance_to(0.0)                                     # first observation
    h.feed([(0.05, "action", PolicyAction(action=np.array([1.0, 0.0], np.float32)))], until_s=0.45)
    poses = [o.pose for o in h.of("odom")]
    moving = [np.hypot(b.x_m - a.x_m, b.y_m - a.y_m) for a, b in zip(poses, poses[1:])]
    assert moving[0] == pytest.approx(0.1, abs=1e-6)       # 1 m/s for 0.1 s while the action is fresh
    h.advance_to(1.0)
    poses = [o.pose for o in h.of("odom")]
    assert poses[-1].x_m == poses[-3].x_m and poses[-1].y_m == poses[-3].y_m   # stopped, not coasting
    assert h.node.stale >= 5


def test_nan_action_is_refused_and_the_car_holds_still():
    h = _car()
    h.advance_to(0.0)
    h.feed([(0.05, "action", PolicyAction(action=np.array([np.nan, 0.0], np.float32)))], until_s=0.15)
    poses = [o.pose for o in h.of("odom")]
    assert (poses[-1].x_m, poses[-1].y_m) == (poses[0].x_m, poses[0].y_m)


def test_policy_node_refuses_an_observation_of_another_size():
    h = Harness(PolicyNode, params={})
    h.feed([(0.0, "obs", Observation(obs=np.zeros(27, np.float32))),
            (0.1, "obs", Observation(obs=np.full(11, np.nan, np.float32))),
            (0.2, "obs", Observation(obs=np.zeros(11, np.float32)))])
    assert len(h.of("action")) == 1 and h.node.refused == 2
