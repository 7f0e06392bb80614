"""bench/social_nav's guard in shadow (issue 18 section 1: what keeps people at a distance without the guard acting?):
the real collision guard is fed what it always is and counts the ticks it would brake, but the planner's command
drives the simulated robot; with the guard on (the default) the guard's command does, as before. A kinematic stand-in
world and a stand-in planner that always asks for 0.5 m/s straight at a post 0.7 m ahead: no rendering."""
from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))

from msgs.geometry import Twist2D  # noqa: E402
from msgs.nav import FlowPoints  # noqa: E402
from nodes.nav.collision_guard import CollisionGuard  # noqa: E402
from tether.testing import Harness  # noqa: E402

ASK = Twist2D(vx_mps=0.5, wz_radps=0.0)
POST = FlowPoints(points_m=np.array([[0.7, 0.0, 1.0], [0.7, 0.05, 1.0]], np.float32),
                  velocity_mps=np.zeros((2, 3), np.float32))      # always 0.7 m ahead in the robot frame


class Walk:
    """A unicycle robot in an empty world (no pedestrians), the goal out of reach; CrowdWorld's interface as
    ``social_nav.run_robot`` uses it."""

    goal_reached = False
    collisions = 0
    collisions_by_robot = 0

    def __init__(self) -> None:
        self.t_s, self.pose, self.twist = 0.0, (0.0, 0.0, 0.0), (0.0, 0.0)

    def advance_crowd(self, dt_s: float) -> None:
        self.t_s += dt_s

    def pedestrians(self):
        return SimpleNamespace(ids=np.zeros(0, int), xy_m=np.zeros((0, 2)), vel_mps=np.zeros((0, 2)))

    def step(self, v: float, w: float, dt: float) -> None:
        x, y, yaw = self.pose
        self.pose, self.twist, self.t_s = (x + v * dt * np.cos(yaw), y + v * dt * np.sin(yaw), yaw + w * dt), (v, w), self.t_s + dt


class PostAhead:
    """A planner that always asks ASK, guarded by a real CollisionGuard that always sees the post (as the bench's
    stacks feed theirs: sensed points, then the command, through ``social_nav.guarded``)."""

    name = "stub"

    def __init__(self, world, weights: str, params: dict | None = None) -> None:
        self.guard = Harness(CollisionGuard, params={}, roundtrip=False, node_id="guard")

    def step(self, world, t: float, ms: dict) -> tuple[float, float]:
        from social_nav import guarded
        return guarded(self, self.guard.feed([(t, "points", POST), (t, "cmd", ASK)]), ASK)


def _episode(guard: str | None):
    from social_nav import run_robot
    kw = {} if guard is None else {"guard": guard}
    return run_robot(Walk, PostAhead, "", 3.0, {}, 0.0, **kw)


def test_shadow_guard_counts_the_stop_but_the_planner_drives():
    from social_nav_episode import metrics
    ep = _episode("shadow")
    travelled = ep.pose[-1, 0] - ep.pose[0, 0]
    assert travelled > 1.2                              # 0.5 m/s for ~3 s: the guard's stop did not reach the robot
    assert ep.guard_ticks >= ep.ticks - 1 > 30          # ... yet every tick (but maybe the first) counts as braked
    m = metrics(ep)
    assert m["guard"] == "shadow" and m["guard_frac"] > 0.9 and m["guard_why"]["stop"] > 0.9


def test_default_mode_is_the_guarded_robot():
    from social_nav_episode import metrics
    default, on = _episode(None), _episode("on")
    assert abs(default.pose[-1, 0] - default.pose[0, 0]) < 0.05      # the guard stopped it before it moved
    assert default.guard_ticks >= default.ticks - 1 > 30
    np.testing.assert_array_equal(default.pose, on.pose)
    assert "guard" not in metrics(default)                           # the guarded metrics keep their keys


def test_unknown_guard_mode_says_what_to_use():
    with pytest.raises(ValueError, match="on, shadow"):
        _episode("off")


def _planner(closest, strict, contacts, time_s, guard):
    n = len(closest)
    return {"closest_m": closest, "time_s": time_s, "guard_frac": guard, "robot_contacts_strict": strict,
            "contacts_strict": contacts, "contacts_strict_moving": strict, "collisions_robot": strict,
            "collisions_pedestrian": [0] * n, "stopped_at_closest": [False] * n}


def test_unguarded_summary_and_headline_count_walk_ins_apart():
    from social_nav import unguarded_headline, unguarded_summary
    scenarios = {
        "zara03": {"human": {"time_s": [20.0] * 3},
                   "irl": _planner([0.3, 0.9, 1.0], [1, 0, 0], [2, 0, 0], [18.0, 19.0, None], [0.2, 0.1, 0.0]),
                   "dwa": _planner([0.5, 0.5, 0.5], [0, 0, 0], [0, 0, 0], [19.0] * 3, [0.3, 0.3, 0.3])},
        "toward": {"human": {"time_s": [10.0] * 3},
                   "irl": _planner([1.0, 1.0, 1.0], [0] * 3, [0] * 3, [11.0] * 3, [0.0] * 3),
                   "dwa": _planner([0.7, 0.2, 0.7], [0, 1, 0], [0, 1, 0], [12.0] * 3, [0.1] * 3)}}
    s = unguarded_summary(scenarios, 3)
    zara = s["per_scenario"]["zara03"]
    assert zara["irl"]["walk_ins_strict"] == 1 and zara["irl"]["robot_contacts_strict"] == 1
    assert zara["irl"]["closest_median_m"] == 0.9 and zara["irl"]["guard_frac_would"]["median"] == 0.1
    assert zara["irl"]["time_ratio_median"] == 0.95 and s["closest_ge_dwa_scenarios"] == 2
    h = unguarded_headline(s)
    assert h["unguarded_robot_contacts_strict"] == 1 and h["unguarded_walk_ins_strict"] == 1
    assert (h["unguarded_closest_ge_dwa_count"], h["unguarded_episodes"]) == (5, 6)
    assert h["unguarded_guard_frac_would"] == 0.1 and h["unguarded_dwa"]["robot_contacts_strict"] == 1


def test_conflict_price_copy_of_the_weights(tmp_path):
    import json
    from sim.irl_match import weights_with_price     # what social_nav_quick --conflict runs on
    shipped = REPO / "nodes" / "nav" / "weights" / "default.json"
    doc = json.loads(shipped.read_text())
    got = json.loads(Path(weights_with_price(str(shipped), 0.09, tmp_path / "w.json")).read_text())
    k = doc["names"].index("conflict")
    assert got["weights"][k] == 0.09 and doc["weights"][k] != 0.09
    assert got["weights"][:k] == doc["weights"][:k] and got["step_cost"] == doc["step_cost"]
    with pytest.raises(ValueError, match=">= 0"):
        weights_with_price(str(shipped), -1.0, tmp_path / "w.json")
