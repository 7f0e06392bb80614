"""bench/social_nav's start-spread summary: over the first K starts of each scenario (6 by default, 3 the old
rule kept beside as ``starts3``), the guard share's spread and the contacts summed per scenario."""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))


def _rows(closest, dwa, guard, strict, time_s, human_s=10.0):
    n = len(closest)
    irl = {"closest_m": closest, "time_s": time_s, "guard_frac": guard, "robot_contacts_strict": strict,
           "contacts_strict_moving": [0] * n, "collisions_robot": strict, "stopped_at_closest": [False] * n}
    other = {"closest_m": dwa, "time_s": [12.0] * n, "guard_frac": [0.0] * n, "robot_contacts_strict": [0] * n,
             "contacts_strict_moving": [0] * n, "collisions_robot": [0] * n, "stopped_at_closest": [False] * n}
    return {"human": {"time_s": [human_s] * n}, "irl": irl, "dwa": other}


def test_summary_over_six_starts_and_the_first_three():
    from social_nav import spread_summary
    scenarios = {"hallway": _rows([0.7, 0.6, 0.6, 0.2, 0.7, 0.3], [0.5] * 6, [0.3, 0.16, 0.26, 0.37, 0.34, 0.35],
                                  [0, 0, 0, 1, 0, 1], [11.0, 11.0, 11.0, 13.0, 13.0, None]),
                 "toward": _rows([1.1] * 6, [0.9] * 6, [0.0] * 6, [0] * 6, [11.0] * 6)}
    six, three = spread_summary(scenarios, 6), spread_summary(scenarios, 3)
    hall = six["per_scenario"]["hallway"]["irl"]
    assert hall["guard_frac"] == {"min": 0.16, "median": 0.32, "max": 0.37}
    assert hall["closest_min_m"] == 0.2 and hall["robot_contacts_strict"] == 2 and hall["closest_ge_dwa"] == "4/6"
    assert six["irl"]["robot_contacts_strict"] == 2 and three["irl"]["robot_contacts_strict"] == 0
    assert six["closest_ge_dwa"] == "10/12" and three["closest_ge_dwa"] == "6/6"
    assert six["guard_frac_median"]["hallway"] == 0.32 and three["guard_frac_median"]["hallway"] == 0.26
    assert six["time_ratio_median"]["hallway"] == 1.2 and three["time_ratio_median"]["hallway"] == 1.1
    assert (six["time_ok_count"], three["time_ok_count"]) == (1, 2)
    assert six["time_ok_episodes"] == "9/12"                # the episode that never arrived counts as late
