"""The local planner keeps the side it chose around a person while the other side is only a little
cheaper (``PlannerParams.commitment``, a sub-goal hysteresis); without it, it flips."""
from __future__ import annotations

import numpy as np

from nodes.nav.grid_frame import GridFrame
from nodes.nav.social_planner import PlannerParams, SocialPlanner

FRAME = GridFrame((25, 25), 0.25, -0.5, -3.0)          # robot frame: x -0.5..5.5 m, y -3..3 m


def _grid(dearer_side: str, extra: float) -> tuple[np.ndarray, np.ndarray]:
    """A person 2.5 m ahead on the robot's line; one side a little dearer per cell than the other."""
    x, y = FRAME.xy_of(np.argwhere(np.ones(FRAME.shape, bool))).T
    x, y = x.reshape(FRAME.shape), y.reshape(FRAME.shape)
    person = (np.abs(x - 2.5) <= 0.3) & (np.abs(y) <= 0.3)
    cost = np.full(FRAME.shape, 2.0)
    cost[(y < -0.2) if dearer_side == "right" else (y > 0.2)] += extra
    cost[person] = 60.0
    return cost, person


def _sides(commitment: float, extra: float = 0.15) -> list[float]:
    planner = SocialPlanner(PlannerParams(commitment=commitment, memory_s=0.0))
    planner.set_goal((10.0, 0.0))
    pose = (0.0, 0.0, 0.0)
    out = []
    for t_s, dearer in ((0.0, "right"), (3.5, "left")):       # 3.5 s: the waypoint timed out, a re-plan
        cost, person = _grid(dearer, extra)
        d = planner.update(pose, cost, FRAME, person, t_s)
        assert d.mode == "local", d
        out.append(float(np.sign(d.waypoint[1])))
    return out


def test_a_slightly_cheaper_other_side_does_not_flip_the_plan():
    assert _sides(commitment=PlannerParams().commitment) == [1.0, 1.0]     # left, and left again


def test_without_commitment_the_plan_flips():
    assert _sides(commitment=0.0) == [1.0, -1.0]                            # the hysteresis is what holds it


def test_a_much_cheaper_other_side_still_wins():
    assert _sides(commitment=PlannerParams().commitment, extra=2.0) == [1.0, -1.0]   # a margin, not a lock
