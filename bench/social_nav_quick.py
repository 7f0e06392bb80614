"""Social navigation, IRL planner only: the quick loop for tuning the planner (no DWA episodes, no human reference runs).

    python bench/social_nav_quick.py [--scenes hallway ...] [--starts 6] [--param planner.KEY=VALUE ...]
                                     [--against out/bench/social_nav.json] [--guard on|shadow] [--conflict 0.09] [--json]

Runs the IRL stack of bench/social_nav.py (same scenes, same clear-start shifts, the same start times 0.4 s apart)
and prints, per episode and per scenario, what ``start_spread`` reports for IRL: closest approach (m), time (s),
the guard's share of control ticks, the share braked while the planner kept a path it had flagged as blocked
(``guard_why.planner_kept_blocked_path``), strict robot contacts and the planner's own waiting share. DWA and the
human reference do not depend on the planner's settings: ``--against`` takes them from a full run's JSON
(``start_spread.scenarios``; same starts), so closest >= DWA and time / human come out as in the full bench. A full
``bench/social_nav.py --starts 6`` run is still what a change is judged on; hallway's DWA episodes (60 s each, it
never arrives) are most of that run's time, and this skips them.

``--guard shadow``: the planner's command drives the robot, the guard only counts the ticks it would have braked
(bench/social_nav.py's shadow; ``guard_frac`` is then that share); each episode also gives the robot's contacts at
0.65 m (``robot_contacts``) and the pedestrians' walk-ins (``walk_ins_strict`` at touching distance, ``walk_ins`` at
0.65 m). ``--conflict PRICE`` runs a copy of the weights file with its conflict weight replaced (the grid cost's
price of a predicted-conflict cell and the speed profile's, :func:`sim.irl_match.weights_with_price`): 0.09 is the price
BIRL learns from walkers (default.json ``conflict_weight.learnt``), the shipped 4.0 is set by hand.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from sim.crowd import CrowdWorld  # noqa: E402
from sim.crowd_scenes import load_scene  # noqa: E402
from sim.irl_demos import sim_camera  # noqa: E402
from sim.irl_match import weights_with_price  # noqa: E402
from social_nav import GUARD_MODES, IrlStack, node_params, run_robot  # noqa: E402
from social_nav_episode import metrics  # noqa: E402
from social_nav_humans import SCENES, clear_start_s  # noqa: E402


def episode_row(m: dict) -> dict:
    """The IRL metrics this loop reports of one episode (``metrics`` of bench/social_nav_episode.py)."""
    return {"closest_m": m["closest_m"], "time_s": m["time_s"], "guard_frac": m["guard_frac"],
            "kept_blocked": m["guard_why"].get("planner_kept_blocked_path", 0.0),
            "robot_contacts_strict": m["robot_contacts_strict"], "planner_wait_frac": m.get("planner_wait_frac"),
            "robot_contacts": m["collisions_robot"], "walk_ins_strict": m["contacts_strict"] - m["robot_contacts_strict"],
            "walk_ins": m["collisions_pedestrian"]}


def summary(rows: list[dict], against: dict | None) -> dict:
    """Per scenario over its starts: guard share median, kept-blocked median, strict contacts, closest min / median;
    with ``against`` (that scenario's ``start_spread.scenarios`` entry of a full run) closest >= DWA's and the median
    time / human time (an episode that does not arrive counts as infinitely late, as bench/social_nav.py does)."""
    out = {"guard_frac_median": float(np.median([r["guard_frac"] for r in rows])),
           "kept_blocked_median": float(np.median([r["kept_blocked"] for r in rows])),
           "robot_contacts_strict": int(sum(r["robot_contacts_strict"] for r in rows)),
           "closest_min_m": min(r["closest_m"] for r in rows),
           "closest_median_m": float(np.median([r["closest_m"] for r in rows]))}
    if "walk_ins_strict" in rows[0]:
        out.update({k: int(sum(r[k] or 0 for r in rows)) for k in ("robot_contacts", "walk_ins_strict", "walk_ins")})
    if against is not None:
        dwa, human = against["dwa"]["closest_m"], against["human"]["time_s"]
        ok = [r["closest_m"] >= d for r, d in zip(rows, dwa) if d is not None]
        out["closest_ge_dwa"] = f"{sum(ok)}/{len(ok)}"
        ratios = [r["time_s"] / h if r["time_s"] and h else float("inf") for r, h in zip(rows, human)]
        out["time_ratio_median"] = float(np.median(ratios))
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", default=[], help=f"scenes (default: {' '.join(SCENES)})")
    ap.add_argument("--starts", type=int, default=6, help="start times per scene, 0.4 s apart (as social_nav.py)")
    ap.add_argument("--weights", default="", help="weights file for the IRL cost ('' = shipped default)")
    ap.add_argument("--param", action="append", default=[], help="node parameter override NODE.KEY=VALUE")
    ap.add_argument("--against", default="", help="a full social_nav.py --json run: DWA and human from its start_spread")
    ap.add_argument("--guard", choices=GUARD_MODES, default="on",
                    help="shadow: the planner's command drives the robot, the guard only counts what it would brake")
    ap.add_argument("--conflict", type=float, default=None,
                    help="the weights file's conflict price replaced by this (grid cost and speed profile; "
                         "learnt from walkers: 0.09)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.starts < 1:
        raise SystemExit("social_nav_quick: --starts must be >= 1")
    logging.basicConfig(level=logging.ERROR)
    spread = json.loads(Path(args.against).read_text())["start_spread"]["scenarios"] if args.against else {}
    weights = args.weights or str(ROOT / "nodes" / "nav" / "weights" / "default.json")
    tmp = tempfile.TemporaryDirectory()
    if args.conflict is not None:
        weights = str(weights_with_price(weights, args.conflict, Path(tmp.name) / "weights_conflict.json"))
    params = node_params(args.param)
    out = {"params": args.param, "guard": args.guard, "conflict": args.conflict, "scenarios": {}}
    for name in args.scenes or SCENES:
        scene = load_scene(name)
        shift = clear_start_s(scene)
        rows = []
        for k in range(args.starts):
            ep = run_robot(lambda s=scene: CrowdWorld(s, camera=sim_camera()), IrlStack, weights, scene.duration_s,
                           params, shift + 0.4 * k, guard=args.guard)
            rows.append(episode_row(metrics(ep)))
            print(f"{name} start +{0.4 * k:.1f} s: {rows[-1]}", file=sys.stderr, flush=True)
        out["scenarios"][name] = {"episodes": rows, **summary(rows, spread.get(name))}
        if not args.json:
            print(name, {k: v for k, v in out["scenarios"][name].items() if k != "episodes"}, flush=True)
    tmp.cleanup()
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
