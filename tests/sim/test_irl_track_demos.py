"""Demos from recorded walkers: the conflict feature from the others' real futures (hindsight) against their
constant-velocity prediction."""
from __future__ import annotations

import numpy as np

from sim.irl_demos import track_demos
from sim.pedestrian_data import Tracks


def _crowd() -> Tracks:
    """An expert walking +x at 1 m/s for 10 m; another walker heading for its line (+y, 1 m/s) who stops 1 m short
    of it after 2 s and stands there."""
    t = np.arange(0.0, 10.01, 0.4)
    expert = np.column_stack([t, np.zeros_like(t)])
    other = np.column_stack([np.full_like(t, 3.0), np.minimum(-3.0 + t, -1.0)])
    return Tracks("synthetic", np.array([1, 2]), (t, t), (expert, other), 0.4)


def _conflict_on_path(hindsight: bool) -> int:
    demos = [d for d in track_demos(_crowd(), 5, hindsight=hindsight) if len(d.path) > 1]
    return sum(int(d.features[d.path[:, 0], d.path[:, 1], 12].sum()) for d in demos[:3])


def test_hindsight_sees_that_the_walker_stopped_short_of_the_expert_path():
    assert _conflict_on_path(hindsight=False) > 0        # the prediction puts them on the expert's line
    assert _conflict_on_path(hindsight=True) == 0         # they never got there, and the expert walked on
