"""bench/social_nav_quick's per-scenario summary (IRL only): guard share and kept-blocked medians, contacts summed,
and with a full run's DWA / human episodes beside, closest >= DWA and the median time / human time (an episode that
never arrives counts as infinitely late, as bench/social_nav.py's start spread counts it)."""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))


def _row(closest, time_s, guard, kept=0.0, strict=0):
    return {"closest_m": closest, "time_s": time_s, "guard_frac": guard, "kept_blocked": kept,
            "robot_contacts_strict": strict, "planner_wait_frac": 0.0}


def test_summary_against_a_full_run():
    from social_nav_quick import summary
    rows = [_row(0.6, 11.0, 0.3, 0.2), _row(0.4, None, 0.1, 0.0, 1), _row(0.9, 13.0, 0.2, 0.1)]
    full = {"dwa": {"closest_m": [0.5, 0.5, 1.0]}, "human": {"time_s": [10.0, 10.0, 10.0]}}
    s = summary(rows, full)
    assert s["guard_frac_median"] == 0.2 and s["kept_blocked_median"] == 0.1
    assert s["robot_contacts_strict"] == 1 and s["closest_min_m"] == 0.4 and s["closest_median_m"] == 0.6
    assert s["closest_ge_dwa"] == "1/3"
    assert s["time_ratio_median"] == 1.3                    # 1.1, inf (never arrived), 1.3


def test_summary_alone_has_no_dwa_keys():
    from social_nav_quick import summary
    s = summary([_row(0.6, 11.0, 0.3)], None)
    assert "closest_ge_dwa" not in s and s["guard_frac_median"] == 0.3
