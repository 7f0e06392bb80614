"""The planner's own turn bound (``PlannerParams.turn_near_radps``, off by default): turning toward a person
within ``turn_near_m`` beside or ahead of the robot is no faster than the bound; a turn away from them, or with
nobody near, is steering's."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.nav.grid_frame import GridFrame
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)


def _turn(person_y: float, *, turn_near_radps: float, goal=(0.5, 3.0)) -> float:
    """A planner at the origin heading +x with a goal up and to its left (a full-rate left turn), a standing
    person 1 m ahead at ``person_y``; returns the commanded turn rate."""
    planner = SocialPlanner(PlannerParams(memory_s=0.0, turn_near_radps=turn_near_radps))
    planner.set_goal(goal)
    pose = (0.0, 0.0, 0.0)
    body = np.array([[1.0, person_y, 1.0], [1.0, person_y + 0.1, 1.2], [1.05, person_y - 0.1, 0.8]])
    planner.set_people(pose, body, np.zeros_like(body), 0.0)
    planner.update(pose, np.full(FRAME.shape, 2.0), FRAME, np.zeros(FRAME.shape, bool), 0.0)
    return planner.command(pose, 0.0, 0.0)[1]


def test_a_turn_toward_a_person_beside_is_bounded():
    assert _turn(0.8, turn_near_radps=0.0) == pytest.approx(1.2)           # steering's full rate
    assert _turn(0.8, turn_near_radps=0.6) == pytest.approx(0.6)


def test_a_turn_away_from_the_person_or_with_nobody_near_is_not():
    assert _turn(-0.8, turn_near_radps=0.6) == pytest.approx(1.2)          # the person is on the right
    assert _turn(4.0, turn_near_radps=0.6) == pytest.approx(1.2)           # too far
