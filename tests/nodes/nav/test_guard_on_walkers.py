"""bench/guard_on_walkers.py: the collision guard's rule, fed a walker's own command among other people's outlines,
brakes a head-on pass 0.6 m apart and not two people walking side by side 1.2 m apart."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))

import guard_on_walkers as gw  # noqa: E402
from sim.pedestrian_data import Tracks  # noqa: E402
from social_nav_episode import Episode  # noqa: E402

YAW = 2.0       # the scene is turned: a frame mistake (world velocity or position not turned) shows


def _turn(xy: np.ndarray) -> np.ndarray:
    c, s = np.cos(YAW), np.sin(YAW)
    return np.asarray(xy, float) @ np.array([[c, -s], [s, c]]).T


def _tracks(paths: list[tuple[np.ndarray, np.ndarray]]) -> Tracks:
    """Two walkers sampled every 0.4 s, as the recorded sets are, from (start, end) points walked in 8 s."""
    t = np.arange(0.0, 8.0 + 1e-9, 0.4)
    xy = [_turn(a + (b - a) * (t / 8.0)[:, None]) for a, b in paths]
    return Tracks("constructed", np.array([1, 2]), (t, t), tuple(xy), 0.4, 1.0)


HEAD_ON = [(np.array([0.0, 0.0]), np.array([8.0, 0.0])), (np.array([8.0, 0.6]), np.array([0.0, 0.6]))]
SIDE_BY_SIDE = [(np.array([0.0, 0.0]), np.array([8.0, 0.0])), (np.array([0.0, 1.2]), np.array([8.0, 1.2]))]


def test_two_walkers_passing_head_on_0p6_m_apart_are_braked():
    r = gw.dataset_guard("constructed", tracks=_tracks(HEAD_ON), params={})
    assert r["walkers"] == 2 and r["ticks"] > 200
    assert r["walkers_braked"] == 2
    assert r["guard_why"].get("stop", 0) > 0
    assert r["guard_why"].get("ahead_toward", 0) > 0
    assert r["gt_rule_frac"] > 0


def test_two_walkers_side_by_side_1p2_m_apart_are_not_braked():
    r = gw.dataset_guard("constructed", tracks=_tracks(SIDE_BY_SIDE), params={})
    assert r["walkers"] == 2 and r["ticks"] > 200
    assert r["guard_frac"] == 0.0 and r["gt_rule_frac"] == 0.0


def test_side_by_side_0p7_m_apart_is_braked_by_the_prediction():
    """A companion 0.7 m to the side: its outline comes within the walker's 0.45 m disc corridor, and its predicted
    places lie ahead on the path (the guard's extrapolation): braked, though the ground-truth centre rule does not
    (its centre never closes in)."""
    paths = [SIDE_BY_SIDE[0], (np.array([0.0, 0.7]), np.array([8.0, 0.7]))]
    r = gw.dataset_guard("constructed", tracks=_tracks(paths), params={})
    assert r["guard_frac"] > 0.5
    assert r["gt_rule_frac"] == 0.0
    assert r["without_companions"]["guard_frac"] == 0.0        # walking together: left out as a companion


def test_people_met_head_on_are_no_companions():
    r = gw.dataset_guard("constructed", tracks=_tracks(HEAD_ON), params={})
    assert r["without_companions"]["guard_frac"] == r["guard_frac"] > 0


def test_the_human_reference_episode_is_fed_as_the_recorded_walkers():
    """episode_guard: the reference's path and yaw rate, the episode's people with finite-difference velocities."""
    dt = 1.0 / 15.0
    t = np.arange(0.0, 8.0, dt)
    me = _turn(np.column_stack([t, np.zeros_like(t)]))
    for other_y, braked in ((0.6, True), (1.2, False)):
        toward = _turn(np.column_stack([8.0 - t, np.full_like(t, other_y)]))
        peds = [(np.array([7]), toward[k:k + 1]) for k in range(len(t))]
        ep = Episode(t, np.column_stack([me, np.full(len(t), YAW)]), np.zeros(len(t)), peds, None, 0)
        r = gw.episode_guard(ep, params={})
        assert r["ticks"] == len(t)
        assert (r["guard_frac"] > 0) == braked, (other_y, r)
        assert (r["gt_rule_frac"] > 0) == braked, (other_y, r)


def test_velocities_by_central_differences():
    t = np.array([0.0, 0.1, 0.2])
    peds = [(np.array([1]), np.array([[0.0, 0.0]])), (np.array([1, 2]), np.array([[0.1, 0.0], [5.0, 5.0]])),
            (np.array([1]), np.array([[0.2, 0.1]]))]
    v = gw.peds_velocity(t, peds)
    assert np.allclose(v[1][0], [1.0, 0.5]) and np.allclose(v[1][1], 0.0) and np.allclose(v[0][0], [1.0, 0.0])


def test_launch_params_are_the_benchs():
    assert gw.guard_params().get("stop_distance_m") == pytest.approx(1.0)


def test_a_person_about_to_cross_is_braked_for_where_they_will_be():
    """The others' velocities reach the guard, turned into the walker's frame: someone 1.3 m to the side stepping
    across at 1.5 m/s is braked for (predicted onto the path within the guard's 0.7 s); standing there, not."""
    pose = np.array([*_turn([[2.0, 3.0]])[0], YAW])
    across = _turn([[0.0, -1.5]])
    at = _turn([[2.9, 4.3]])
    for vel, braked in ((across, True), (np.zeros((1, 2)), False)):
        g = gw.WalkerGuard({})
        assert g.tick(0.0, pose, 1.0, 0.0, at, vel) == braked
        assert g.ticks == 1 and g.gt == 0


def test_social_nav_reports_the_human_references_share_beside_the_robots():
    """bench/social_nav.py's new keys: per scenario in the human metrics, worst and median in the headline."""
    import social_nav
    from types import SimpleNamespace

    dt = 1.0 / 15.0
    t = np.arange(0.0, 8.0, dt)
    me = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    runs, report = {}, {}
    for name, other_y in (("near", 0.6), ("far", 1.2)):
        toward = np.column_stack([8.0 - t, np.full_like(t, other_y)])
        ep = Episode(t, me, np.zeros(len(t)), [(np.array([7]), toward[k:k + 1]) for k in range(len(t))], None, 0)
        runs[name], report[name] = {"human": ep}, {"human": {"time_s": 8.0}}
    cases = {n: SimpleNamespace(replay=None) for n in runs}
    out = social_nav.guard_on_people(cases, runs, report, {})
    assert report["near"]["human"]["guard_frac_human"] > 0 and report["far"]["human"]["guard_frac_human"] == 0
    assert report["near"]["human"]["time_s"] == 8.0
    assert out["guard_frac_human"] == report["near"]["human"]["guard_frac_human"]
    assert out["guard_frac_human_median"] == pytest.approx(out["guard_frac_human"] / 2, abs=1e-4)
    assert out["guard_frac_walkers"] == {}


def test_readme_row_reads_the_json():
    w = gw.dataset_guard("constructed", tracks=_tracks(HEAD_ON), params={})
    d = {"walkers": {"constructed": w}, "human": {"toward": {**w, "robot_guard_frac": 0.02}}}
    bench, result, baseline, goal = gw.readme_row(d)
    assert f"constructed {100 * w['guard_frac']:.0f} %" in result and "toward 2 %" in baseline
    assert "below it" in goal
