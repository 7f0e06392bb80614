"""A path flagged as passing people is replaced only by a plan the cost says is clearly cheaper: with the
learnt cost alone (person_cost 0) the fresh plan may pass the same people, and re-planning on every grid
made the robot weave (hallway: half of all cost grids re-planned, each to a slightly different waypoint)."""
from __future__ import annotations

import numpy as np

from nodes.nav.grid_frame import GridFrame
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)          # robot frame: x -0.5..5.5 m, y -3..3 m
X, Y = (a.reshape(FRAME.shape) for a in FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T)


def _following(**params) -> tuple[SocialPlanner, np.ndarray]:
    """A planner following a straight local path toward (10, 0); returns it and its waypoint."""
    planner = SocialPlanner(PlannerParams(memory_s=0.0, **params))
    planner.set_goal((10.0, 0.0))
    far = np.zeros(FRAME.shape, bool)
    far[0, 0] = True                                    # a crowd cell in range: Algorithm 2 plans locally
    d = planner.update((0.0, 0.0, 0.0), np.full(FRAME.shape, 2.0), FRAME, far, 0.0)
    assert d.mode == "local" and abs(d.waypoint[1]) < 0.05, d
    return planner, d.waypoint.copy()


def _person_ahead(bump: float) -> tuple[np.ndarray, np.ndarray]:
    """A person 3 m ahead on the path (high density; the learnt cost does not price them) and, 1.5 m ahead,
    a spot of the floor ``bump`` dearer than the rest (2): the path through it costs a little more than one
    around it."""
    person = np.hypot(X - 3.0, Y) <= 0.3
    return np.where(np.hypot(X - 1.5, Y - 0.1) <= 0.1, 2.0 + bump, 2.0), person


def test_a_blocked_path_little_dearer_than_a_fresh_plan_is_kept():
    planner, waypoint = _following()
    cost, person = _person_ahead(1.5)
    d = planner.update((0.0, 0.0, 0.0), cost, FRAME, person, 0.1)
    assert d.event == "" and d.reason == "path kept", d
    np.testing.assert_allclose(d.waypoint, waypoint)
    np.testing.assert_allclose(planner.waypoint, waypoint)


def test_without_the_margin_the_same_grid_moves_the_waypoint():
    planner, waypoint = _following(replan_margin_m=-1.0)
    cost, person = _person_ahead(1.5)
    d = planner.update((0.0, 0.0, 0.0), cost, FRAME, person, 0.1)
    assert d.event == "path_blocked", d
    assert np.hypot(*(d.waypoint - waypoint)) > 0.5


def test_a_clearly_cheaper_plan_replaces_the_blocked_path():
    planner, waypoint = _following()
    cost, person = _person_ahead(10.0)
    d = planner.update((0.0, 0.0, 0.0), cost, FRAME, person, 0.1)
    assert d.event == "path_blocked" and d.mode == "local", d
    assert np.hypot(*(d.waypoint - waypoint)) > 0.5
