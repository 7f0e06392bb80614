"""bench/social_nav's weaving measures: heading reversals (a turn the other way than the turn before) and the
planner's adopted re-plans read from its status reasons ('path kept' is not one)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))

from social_nav_episode import TURN_RADPS, heading_reversals  # noqa: E402


def test_a_weave_counts_every_swing_and_a_long_turn_none():
    t = np.arange(0.0, 6.0, 1 / 15)
    weave = 1.0 * np.sin(2 * np.pi * t / 2.0)           # three full swings left-right
    assert heading_reversals(weave) == 5
    assert heading_reversals(np.full_like(t, 0.8)) == 0     # one long turn
    assert heading_reversals(0.9 * TURN_RADPS * np.sign(np.sin(5 * t))) == 0   # wobbles below the turn rate


def test_replanned_reads_the_planner_status():
    import social_nav
    assert social_nav.replanned("local/path_blocked")
    assert social_nav.replanned("local/safe_zone")
    assert not social_nav.replanned("local/path kept")
    assert not social_nav.replanned("local")
    assert not social_nav.replanned("global/global_path")
    assert not social_nav.replanned("hold/hold_retry/local plan: no reachable cell around the robot")
