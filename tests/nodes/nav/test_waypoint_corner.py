"""The local planner's waypoint lies no farther along its path than the path's first corner when the
straight line past the corner would pass a person: steering at such a point cuts through what the cost
priced (hallway: a waypoint 2 m along a path that swerved around an oncoming walker lay on the walker).
A corner that only bends with the floor's cost leaves the waypoint its full distance."""
from __future__ import annotations

import numpy as np

from nodes.nav.grid_frame import GridFrame
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)          # robot frame: x -0.5..5.5 m, y -3..3 m


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    t = float(np.clip(np.dot(p - a, b - a) / max(np.dot(b - a, b - a), 1e-12), 0.0, 1.0))
    return float(np.hypot(*(p - (a + t * (b - a)))))


def _around_a_person(waypoint_min_m: float, person: np.ndarray, cost: np.ndarray):
    planner = SocialPlanner(PlannerParams(memory_s=0.0, waypoint_min_m=waypoint_min_m))
    planner.set_goal((10.0, 0.0))
    return planner.update((0.0, 0.0, 0.0), cost, FRAME, person, 0.0)


def test_the_waypoint_does_not_cut_the_corner_around_a_person():
    x, y = FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T
    x, y = x.reshape(FRAME.shape), y.reshape(FRAME.shape)
    person_xy = np.array([1.5, 0.2])
    person = np.hypot(x - person_xy[0], y - person_xy[1]) <= 0.3
    d = _around_a_person(0.0, person, np.where(person, 60.0, 2.0))
    assert d.mode == "local", d
    assert len(d.path_xy) >= 3                                   # the path bends around the person
    corner = float(np.hypot(*d.path_xy[1]))
    assert corner < PlannerParams().waypoint_m                   # ... before the waypoint distance
    # the robot steers straight at it: that line keeps its body (0.35 m) off the person (0.3 m)
    assert _segment_distance(person_xy, np.zeros(2), d.waypoint) > 0.65


def test_the_waypoint_stays_on_the_first_leg_when_the_people_are_nearer():
    x, y = FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T
    x, y = x.reshape(FRAME.shape), y.reshape(FRAME.shape)
    person_xy = np.array([1.5, 0.2])
    person = np.hypot(x - person_xy[0], y - person_xy[1]) <= 0.3
    other_xy = np.array([1.75, -0.35])                          # a second person just past the path's bend
    crowd = person | (np.hypot(x - other_xy[0], y - other_xy[1]) <= 0.3)
    d = _around_a_person(0.0, crowd, np.where(person, 60.0, 2.0))
    assert len(d.path_xy) >= 3
    corner = float(np.hypot(*d.path_xy[1]))
    assert abs(_along(d.path_xy, d.waypoint) - corner) < 1e-6                       # at the corner


def _along(path_xy: np.ndarray, point: np.ndarray) -> float:
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path_xy, axis=0).T))])
    k = int(np.argmin([_segment_distance(point, a, b) for a, b in zip(path_xy[:-1], path_xy[1:])]))
    return float(along[k] + np.hypot(*(point - path_xy[k])))


def test_a_corner_around_dear_floor_without_people_keeps_the_full_waypoint_distance():
    x, y = FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T
    x, y = x.reshape(FRAME.shape), y.reshape(FRAME.shape)
    dear = np.hypot(x - 1.5, y - 0.2) <= 0.3                    # dear floor, nobody on it
    far = np.zeros(FRAME.shape, bool)
    far[0, 0] = True                                             # a crowd cell in range, far from the path
    d = _around_a_person(0.0, far, np.where(dear, 60.0, 2.0))
    assert len(d.path_xy) >= 3 and np.hypot(*d.path_xy[1]) < PlannerParams().waypoint_m     # a corner first
    assert abs(_along(d.path_xy, d.waypoint) - PlannerParams().waypoint_m) < 1e-6
    planner = SocialPlanner(PlannerParams(memory_s=0.0, corner_people_only=False))         # every corner limits
    planner.set_goal((10.0, 0.0))
    d = planner.update((0.0, 0.0, 0.0), np.where(dear, 60.0, 2.0), FRAME, far, 0.0)
    assert _segment_distance(d.waypoint, d.path_xy[0], d.path_xy[1]) < 1e-9


def test_a_straight_path_keeps_the_full_waypoint_distance():
    planner = SocialPlanner(PlannerParams(memory_s=0.0))
    planner.set_goal((10.0, 0.0))
    far = np.zeros(FRAME.shape, bool)
    far[0, 0] = True                                             # a crowd cell in range: plan locally
    d = planner.update((0.0, 0.0, 0.0), np.full(FRAME.shape, 2.0), FRAME, far, 0.0)
    assert d.mode == "local", d
    assert np.hypot(*d.waypoint) == np.float64(PlannerParams().waypoint_m) or \
        abs(np.hypot(*d.waypoint) - PlannerParams().waypoint_m) < 0.05


def test_waypoint_min_m_at_the_waypoint_distance_is_the_plain_carrot():
    x, y = FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T
    person = (np.hypot(x - 1.5, y - 0.2) <= 0.3).reshape(FRAME.shape)
    d = _around_a_person(PlannerParams().waypoint_m, person, np.where(person, 60.0, 2.0))
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(d.path_xy, axis=0).T))])
    assert along[1] < PlannerParams().waypoint_m < along[-1]
    assert _segment_distance(d.waypoint, d.path_xy[1], d.path_xy[2]) < 1e-9          # past the corner
