"""A re-plan because the path became blocked keeps passing a person beside the path on the side the path passes
them (``PlannerParams.side_hold_m``, :func:`nodes.nav.plan_geometry.side_barriers`): with the learnt cost a walker
costs little more than free floor, and the fresh plan flipped sides of the same walker grid after grid (hallway:
+1.1 m then -1.1 m within 0.5 s), each flip a full-rate turn whose arc swept into the people beside the robot."""
from __future__ import annotations

import numpy as np

from nodes.nav.grid_frame import GridFrame
from nodes.nav.plan_geometry import side_barriers
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)          # robot frame: x -0.5..5.5 m, y -3..3 m
X, Y = (a.reshape(FRAME.shape) for a in FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T)
PATH = np.array([[0.0, 0.0], [5.0, 0.0]])


def _replan(side_hold_m: float, dearer_right: float, *, vy_mps: float = 0.0, seen: bool = True,
            side_motion: bool = True) -> tuple[str, np.ndarray]:
    """A planner following a straight local path toward (10, 0); a person then stands 3 m ahead, 0.25 m to the
    left of that path (the path passes them on their right: blocked), priced a little by the learnt cost, and
    seen by the flow (``seen``) walking sideways at ``vy_mps``; the floor to the right of the path costs
    ``dearer_right`` more per cell than to the left. Returns the re-plan's event and waypoint."""
    planner = SocialPlanner(PlannerParams(memory_s=0.0, side_hold_m=side_hold_m, side_motion=side_motion))
    planner.set_goal((10.0, 0.0))
    far = np.zeros(FRAME.shape, bool)
    far[0, 0] = True                                    # a crowd cell in range: Algorithm 2 plans locally
    d = planner.update((0.0, 0.0, 0.0), np.full(FRAME.shape, 2.0), FRAME, far, 0.0)
    assert d.mode == "local" and abs(d.waypoint[1]) < 0.05, d
    person = np.hypot(X - 3.0, Y - 0.25) <= 0.3
    if seen:
        body = np.column_stack([np.full(40, 3.0) + np.tile([-0.1, 0.0, 0.1, 0.05], 10), np.linspace(0.05, 0.45, 40),
                                np.linspace(0.3, 1.7, 40)])
        planner.set_people((0.0, 0.0, 0.0), body, np.tile([0.0, vy_mps, 0.0], (40, 1)), 0.1)
    cost = np.where(person, 12.0, 2.0) + np.where((Y < 0) & (X > 1) & (X < 5), dearer_right, 0.0)
    d = planner.update((0.0, 0.0, 0.0), cost, FRAME, person, 0.1)
    assert d.event == "path_blocked" and d.mode == "local", d
    return d.event, d.waypoint


def test_a_blocked_path_is_replanned_on_the_same_side_of_the_person():
    _, waypoint = _replan(side_hold_m=2.0, dearer_right=0.3)
    assert waypoint[1] < 0                              # still passing the person on their right


def test_the_hold_is_on_by_default():
    _, waypoint = _replan(side_hold_m=PlannerParams().side_hold_m, dearer_right=0.3)
    assert waypoint[1] < 0


def test_without_the_hold_the_replan_flips_to_the_other_side():
    _, waypoint = _replan(side_hold_m=0.0, dearer_right=0.3)
    assert waypoint[1] > 0.5                            # the slightly cheaper left side: the flip the hold prevents


def test_a_walker_crossing_the_path_is_not_held_to_a_side():
    _, waypoint = _replan(side_hold_m=2.0, dearer_right=0.3, vy_mps=-0.8)    # walking to the right, across the path
    assert waypoint[1] > 0.5                            # passes behind them: the side changes as they cross


def test_only_people_the_flow_sees_there_hold_a_side():
    _, waypoint = _replan(side_hold_m=2.0, dearer_right=0.3, seen=False)
    assert waypoint[1] > 0.5
    _, waypoint = _replan(side_hold_m=2.0, dearer_right=0.3, seen=False, side_motion=False)
    assert waypoint[1] < 0                              # without the motion test every people cell holds


def test_a_much_dearer_side_still_gives_way():
    _, waypoint = _replan(side_hold_m=2.0, dearer_right=3.0)
    assert waypoint[1] > 0.5                            # a price, not a lock


def test_the_barrier_runs_from_the_person_away_from_the_path():
    person = np.hypot(X - 3.0, Y - 0.6) <= 0.3
    barrier = side_barriers(PATH, person, FRAME, near_m=1.5, length_m=2.0)
    cells = FRAME.xy_of(np.argwhere(barrier))
    assert len(cells) and np.allclose(cells[:, 0], 3.0) and cells[:, 1].min() >= 0.5 and cells[:, 1].max() <= 2.75
    right = side_barriers(PATH, np.hypot(X - 3.0, Y + 0.6) <= 0.3, FRAME, near_m=1.5, length_m=2.0)
    assert FRAME.xy_of(np.argwhere(right))[:, 1].max() <= -0.5      # mirrored for a person on the right


def test_no_barrier_for_people_on_the_path_far_from_it_behind_or_beyond_its_end():
    for x, y in ((3.0, 0.0), (3.0, 2.0), (-0.4, 0.6), (5.4, 0.6)):
        person = np.hypot(X - x, Y - y) <= 0.15
        assert not side_barriers(PATH, person, FRAME, near_m=1.5, length_m=2.0, min_side_m=0.125).any(), (x, y)


def test_a_diagonal_barrier_has_no_diagonal_gap():
    from scipy.ndimage import label
    path = np.array([[0.0, 0.0], [4.0, 4.0]])
    person = np.hypot(X - 2.5, Y - 1.5) <= 0.2          # right of the diagonal path: the ray runs down-right
    barrier = side_barriers(path, person, FRAME, near_m=1.5, length_m=2.0)
    assert barrier.sum() >= 8
    assert label(barrier)[1] == 1                       # one 4-connected piece: an 8-connected path cannot slip through
