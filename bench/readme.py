"""The README's benchmark table, regenerated from the benches' own JSON output.

    python bench/readme.py --run [NAME ...]   # run benches with --json into out/bench/NAME.json
    python bench/readme.py --write            # rewrite the table's rows from out/bench/*.json
    python bench/readme.py --check            # list the rows still typed by hand (exit 1 if any)

``make bench-readme`` runs every bench that has a row formatter, then ``--write``. A row is
produced by its bench's formatter from that bench's JSON; a bench without a formatter (or
without a JSON yet) keeps its README row as it is, and ``--check`` names it.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "out" / "bench"
README = REPO / "README.md"
HEADER = "| benchmark | headline | reference, same run | goal |"

Row = tuple[str, str, str, str]


def _met(ok: bool) -> str:
    return "met" if ok else "**not met**"


def set_localize(d: dict) -> list[Row]:
    m, r = d["methods"], d["methods"]["ours"]
    sweep = [s for s in d["sweep"] if s["method"] in ("ours", "codac")]
    ratios = [a["ms_per_step"] / b["ms_per_step"] for a, b in zip(sweep[::2], sweep[1::2])]
    big = max(d["slam"], key=lambda s: s["steps"])
    o = d["outliers"]
    mo = d["mosaic"]
    width_ok = d["width_ratio"] <= 1.1 and d["time_ratio"] <= 1.0
    return [(f"`set_localize.py` {r['steps']:,} steps over 5 scenes (the seed's markers, random, collinear, a marker at "
             f"the start, one marker), eps {d['eps']} m",
             f"truth outside its box {d['truth_outside']} times; mean width {d['mean_width_m']:.3f} m, "
             f"{d['ms_per_step']:.2f} ms per step (median); 5 % outlier ranges: {o['flagged_empty']} of "
             f"{o['steps_with_outlier']} steps flagged as an empty set, {o['wrong_box_not_flagged']} wrong boxes "
             f"unflagged; SLAM tube over {big['steps']:,} steps {big['ours_s']:.2f} s",
             f"a plain codac script on the same measurements, run by run in turn: {d['mean_width_m_codac']:.3f} m, "
             f"{d['ms_per_step_codac']:.2f} ms (ratio {d['time_ratio']:.2f}; {min(ratios):.2f}-{max(ratios):.2f} over "
             f"the eps sweep); codac contractors alone {m['codac-ctc']['mean_width_m']:.3f} m, "
             f"{m['codac-ctc']['ms_per_step']:.2f} ms; an EKF's 3-sigma box {m['ekf']['mean_width_m']:.3f} m with the "
             f"truth outside {m['ekf']['truth_outside']} times; SLAM with codac contractors in a loop "
             f"{big['codac_s']:.2f} s ({big['speedup']:.1f}x), same widths",
             f"truth outside 0: {_met(d['truth_outside'] == 0)}; width within 1.1x at <= codac's time: "
             f"{_met(width_ok)} at equal eps"),
            (f"`set_localize.py` interval mosaic, seed 08 VII, {len(mo['rows'])} seeds",
             f"boxes hold {mo['boxes_hold_truth']} of {mo['centres']} true centres; mean box half-width "
             f"{mo['mean_box_half_px']:.1f} px (chain alone {mo['mean_chain_box_half_px']:.1f} px)",
             f"pose graph 3-sigma half-width {mo['mean_graph_3sigma_px']:.1f} px on the same links",
             f"boxes contain the centres: {_met(mo['boxes_hold_truth'] == mo['centres'])}")]


def winding(d: dict) -> list[Row]:
    g = next(x for x in d["gaps"] if x["removed"] == 0.10 and x["gaps"] == 4)
    tree_ok = [s for s in d["tree_sweep"] if s["max_err_away"] <= 1e-3]
    tree = min(tree_ok, key=lambda s: s["s"]) if tree_ok else None
    fast_ok = d["exact_s"] <= 2 and d["fast_s"] <= 0.2 and d["fast_max_err"] <= 1e-3
    return [(f"`winding.py` 2-D, 512x512 queries, {d['segments']:,} segments",
             f"exact (crossings in bands + chord angles) {d['exact_s']:.3f} s, error {d['exact_max_err_vs_direct']:.0e} "
             f"against the angle sum; four gaps removing 10 % of the arc: {g['mislabelled_px_winding']:,} px mislabelled "
             f"of {g['inside_px']:,}",
             f"the angle sum {d['direct_s']:.1f} s; libigl `winding_number` {d['libigl_s']:.1f} s; "
             f"`cv2.pointPolygonTest` {d['cv2_s']:.2f} s ({d['cv2_disagree_away']} disagreements off the curve); each "
             f"piece closed by its chord: {g['mislabelled_px_chord']:,} px mislabelled",
             f"exact <= 2 s, fast <= 0.2 s with error <= 1e-3: {_met(fast_ok)} (fast: {d['fast_method']}"
             + (f"; the dipole tree needs beta {tree['beta']:g}, {tree['s']:.1f} s, for {tree['max_err_away']:.0e})"
                if tree else ")")),
            (f"`winding.py` 3-D, {d['triangles']:,} triangles, {d['queries']:,} queries",
             f"dipole tree (beta 2, to the Hessian term) {d['mesh_s']:.1f} s + {d['mesh_build_s']:.1f} s build, max "
             f"error {d['mesh_max_err']:.1e}",
             f"libigl `fast_winding_number` {d['mesh_libigl_s']:.2f} s, {d['mesh_libigl_max_err']:.1e}",
             f"within 10x of libigl: {_met(d['mesh_ratio'] <= 10)} ({d['mesh_ratio']:.1f}x)")]


def ping360(d: dict) -> list[Row]:
    lo, hi = sorted(d["line"], key=lambda r: r["baud"])
    lat50 = max(r["latency_ms_p50"] for r in d["line"])
    lat99 = max(r["latency_ms_p99"] for r in d["line"])
    errors = sum(r["checksum_errors"] for r in d["line"])
    ref = (f"`bluerobotics-ping`'s parser {d['parse_beams_per_s_brping']:,.0f} beams/s on the same bytes "
           f"(same beams: {d['parse_agree']}; ratio {d['parse_ratio']:.0f})" if "parse_ratio" in d else "—")
    return [("`ping360.py` Ping protocol, 1,200-sample beams",
             f"parser {d['parse_beams_per_s']:,.0f} beams/s; {lo['baud']} baud {lo['beams_per_s']:.1f} beams/s (line "
             f"limit {lo['line_limit_beams_per_s']:.1f}), {hi['baud'] / 1e6:g} Mbaud {hi['beams_per_s']:.0f} beams/s "
             f"(limit {hi['line_limit_beams_per_s']:.0f}); write-to-publish {lat50:.2f} ms p50, {lat99:.2f} ms p99; "
             f"{errors} checksum errors", ref,
             "400 beams a turn, 0 checksum errors, resync after garbage: met (tests)")]


def _guard_on_humans(d: dict, scenarios: dict) -> str:
    """The same guard asked of the human reference (bench/guard_on_walkers.py's rule, in the social_nav run)."""
    human = {k: v["human"].get("guard_frac_human") for k, v in scenarios.items() if isinstance(v.get("human"), dict)}
    human = {k: v for k, v in human.items() if v is not None}
    if not human or d.get("guard_frac_human_median") is None:
        return ""
    robot = {k: v["irl"].get("guard_frac") for k, v in scenarios.items() if isinstance(v.get("irl"), dict)}
    below = [k for k in human if robot.get(k) is not None and robot[k] <= human[k]]
    worst = max(robot, key=lambda k: robot[k] if robot[k] is not None else -1)
    return (f" (the same guard brakes the human reference in {100 * d['guard_frac_human_median']:.0f} % of its moving "
            f"ticks by median, {100 * min(human.values()):.0f}-{100 * max(human.values()):.0f} %; the robot is braked "
            f"no more than the human on {len(below)} of {len(human)}; {worst}: robot {100 * robot[worst]:.0f} %, human "
            f"{100 * human.get(worst, float('nan')):.0f} %)")


def _guard_why(why: dict | None) -> str:
    """Which of the guard's rules braked, on the scenario where it braked most (shares of all ticks)."""
    if not why:
        return ""
    return (f"; on {why['scenario']}, stop {100 * why.get('stop', 0):.0f} % of ticks, hold after a stop "
            f"{100 * why.get('hold', 0):.0f} %, slowed {100 * why.get('slowed', 0):.0f} %, and {100 * why.get('planner_kept_blocked_path', 0):.0f} % "
            f"braked while the planner kept a path it had flagged as passing people"
            + ("; the nearest person ahead walked toward the robot in {:.0f} % of ticks, across {:.0f} %, stood {:.0f} %, "
               "went its way {:.0f} %, nobody within 1.8 m {:.0f} %".format(
                   *(100 * why.get(f"ahead_{k}", 0) for k in ("toward", "crossing", "standing", "same_way", "nobody")))
               if any(k.startswith("ahead_") for k in why) else ""))


def social_nav(d: dict) -> list[Row]:
    sc = d["scenarios"]
    n = len(sc)
    closer = [k for k in sc if d["goals"][k]["closest_ge_dwa"]]
    walk_in = d.get("closest_ge_dwa_or_walk_in_count")   # the issue's rule: a walker into the stopped robot is not counted
    timely = [k for k in sc if d["goals"][k]["time_within_15pct"]]
    ratio = {k: sc[k]["irl"]["time_s"] / sc[k]["human"]["time_s"] for k in sc
             if sc[k]["irl"]["time_s"] is not None and sc[k]["human"]["time_s"]}
    late = ", ".join(f"{k} {ratio[k]:.2f}x" if k in ratio else f"{k} no goal" for k in sc if k not in timely)
    dwa = d["dwa"]
    rows = [(f"`social_nav.py` {n} scenarios (4 synthetic, 2 real crowds), person_cost {d['person_cost']:g}, weights learnt "
             f"on {', '.join(d['weights_from'])} (none of them evaluated)",
             f"IRL planner: robot-caused contacts {d['robot_contacts']} (strict, at touching distance: "
             f"{d['robot_contacts_strict']}; any contact while moving {d['contacts_strict_moving']}); closest >= DWA's on "
             f"{len(closer)} of {n}" + (f" (not {', '.join(k for k in sc if k not in closer)}"
                                         + (f"; {walk_in} of {n} leaving out a walker into the stopped robot"
                                            if walk_in is not None else "") + ")" if len(closer) < n else "")
             + f", median {d['closest_median_m']:.2f} m; on time (<= 1.15x the human) {len(timely)} of {n}"
             + (f" (late: {late})" if late else "") + f"; the guard brakes in {100 * d['guard_frac']:.0f} % of ticks at "
             f"worst (median {100 * d['guard_frac_median']:.0f} %)" + _guard_why(d.get("guard_why_worst"))
             + (f"; the planner itself waits or slows (its speed along the path, against predicted people, at the "
                f"conflict price {d['weights']['conflict']:g}) in {100 * d['planner_wait_frac']:.0f} % of ticks at worst "
                f"(median {100 * d['planner_wait_frac_median']:.1f} %)" if d.get("planner_wait_frac") is not None else "")
             + (f"; a guard measuring its 1 m rule along the commanded arc ({d['guard_other_rule']}, off: it let DWA "
                f"touch a walker in group) would brake {100 * d['guard_frac_other_rule']:.0f} % at worst on the same runs"
                if d.get("guard_frac_other_rule") is not None else ""),
             f"DWA, predicting people too: robot contacts {dwa['robot_contacts']} (strict {dwa['robot_contacts_strict']}), "
             f"median closest {dwa['closest_median_m']:.2f} m, on time {dwa['time_ok_count']} of {n}, guard "
             f"{100 * dwa['guard_frac']:.0f} %",
             f"0 contacts: {_met(d['robot_contacts'] == 0 and d['robot_contacts_strict'] == 0)}; closest >= DWA on all"
             + (" but walk-ins" if walk_in is not None else "")
             + f": {_met((walk_in if walk_in is not None else len(closer)) == n)}; on time >= 5 of 6: {_met(len(timely) >= n - 1)}; guard < 5 %: "
             f"{_met(d['guard_frac'] < 0.05)}" + _guard_on_humans(d, sc))]
    spread = d.get("start_spread")
    if isinstance(spread, dict) and "closest_ge_dwa" in spread:
        irl, dw = spread.get("irl") or {}, spread.get("dwa") or {}
        guard = spread.get("guard_frac_median") or {}
        worst = max(guard, key=guard.get) if guard else None
        rows.append((f"`social_nav.py` every scenario from {spread.get('starts', '?')} start times "
                     f"{spread.get('step_s', 0.4):g} s apart",
                     f"IRL: robot contacts at touching distance {irl.get('robot_contacts_strict', '?')} "
                     f"(0.65 m: {irl.get('collisions_robot', '?')}); closest >= DWA's in {spread['closest_ge_dwa']} episodes "
                     f"({spread.get('closest_ge_dwa_or_walk_in', '?')} leaving out walk-ins), median "
                     f"{spread['closest_median_m']['irl']:.2f} m; on time by median {spread['time_ok_count']} of {n} "
                     f"({spread.get('time_ok_episodes', '?')} episodes); guard median share at worst "
                     + (f"{100 * guard[worst]:.0f} % ({worst})" if worst else "?")
                     + _first_starts(spread.get("starts3")),
                     f"DWA: robot contacts at touching distance {dw.get('robot_contacts_strict', '?')} "
                     f"(0.65 m: {dw.get('collisions_robot', '?')}), median closest {spread['closest_median_m']['dwa']:.2f} m",
                     "—"))
    rows += _unguarded(d)
    return rows


def _unguarded(d: dict) -> list[Row]:
    """``--guard shadow``: the same scenarios and starts with the guard fed and counted but not driving."""
    u = d.get("unguarded")
    if not isinstance(u, dict) or "per_scenario" not in u:
        return []
    ps, dw = u["per_scenario"], d["unguarded_dwa"]
    guarded = (d.get("start_spread") or {}).get("irl") or {}
    n = len(ps)
    contacts = ", ".join(f"{k} {v['irl']['robot_contacts_strict']}" for k, v in ps.items() if v["irl"]["robot_contacts_strict"])
    behind = ", ".join(f"{k} {v['irl']['closest_median_m']:.2f} vs {v['dwa']['closest_median_m']:.2f} m"
                       for k, v in ps.items() if v["irl"]["closest_median_m"] < v["dwa"]["closest_median_m"])
    would = {k: v["irl"]["guard_frac_would"]["median"] for k, v in ps.items()}
    worst = max(would, key=would.get)
    return [(f"`social_nav.py` --guard shadow: every scenario from {u['starts']} start times, the guard fed and counted "
             "but the planner's command driving (bench only)",
             f"IRL without the guard acting (person_cost {d['person_cost']:g}, conflict {d['weights']['conflict']:g}): "
             f"robot contacts at touching distance {d['unguarded_robot_contacts_strict']} (0.65 m: "
             f"{d['unguarded_robot_contacts']}; guarded, same run: {guarded.get('robot_contacts_strict', '?')}) "
             f"({contacts}), walk-ins {d['unguarded_walk_ins_strict']}; closest >= DWA-unguarded's in "
             f"{d['unguarded_closest_ge_dwa_or_walk_in']} episodes, by median {d['unguarded_closest_ge_dwa_scenarios']} of "
             f"{n}" + (f" (not {behind})" if behind else "") + f", median {d['unguarded_closest_median_m']['irl']:.2f} m; "
             f"on time {d['unguarded_time_ok_count']} of {n}; the guard would brake {100 * would[worst]:.0f} % ({worst}), "
             f"{100 * d['unguarded_guard_frac_would_median']:.0f} % median",
             f"DWA unguarded: robot contacts at touching distance {dw['robot_contacts_strict']} (0.65 m: "
             f"{dw['robot_contacts']}), median closest {d['unguarded_closest_median_m']['dwa']:.2f} m",
             f"the learned cost alone keeps people at a distance: "
             f"{_met(d['unguarded_robot_contacts_strict'] == 0 and d['unguarded_closest_ge_dwa_scenarios'] == n)} "
             "(the guard, not the cost, stops the robot for head-on and crossing walkers: the speed profile drives on "
             "at 0.8-1.0 m/s on a path it flagged)")]


def _first_starts(s3: dict | None) -> str:
    """The same summary over the run's first 3 starts: the rule the row had before it took 6."""
    if not isinstance(s3, dict) or "closest_ge_dwa" not in s3:
        return ""
    return (f"; over the first 3 starts of the same run (the rule before): touching contacts "
            f"{(s3.get('irl') or {}).get('robot_contacts_strict', '?')}, closest >= DWA's {s3['closest_ge_dwa']}, "
            f"on time {s3['time_ok_count']} of {len(s3.get('time_ratio_median') or {}) or '?'} ({s3.get('time_ok_episodes', '?')})")


def nav_plan(d: dict) -> list[Row]:
    return [("`nav_plan.py` local plan 100x100", f"{d['plan_ms_100x100']:.1f} ms (best of runs {d['plan_ms_100x100_best']:.1f})",
             f"scipy csgraph (graph built per call) {d['scipy_fresh_ms_100x100']:.1f} ms; pure-Python heap "
             f"{d['python_heap_ms_100x100']:.0f} ms; same path costs (max difference {d['max_cost_rel_diff']:.0e})",
             f"<= {d['goal_plan_ms_100x100']:g} ms: {_met(d['plan_ms_100x100'] <= d['goal_plan_ms_100x100'])}")]


def irl_spacetime(d: dict) -> list[Row]:
    r = d["runs"][0]
    near = r["names"][0]
    ratio = r["learnt"]["ratios_to_step_cost"][near]
    loso = [v["learnt"]["ratios_to_step_cost"][near] for v in (r.get("leave_one_scene_out") or {}).values()]
    counts = {n: v["near_counts_expert_vs_shortest_path"][near] for n, v in r["demos"].items()}
    fewer = [b / a for a, b in counts.values() if a > 0]
    held = [h for h in d["held_out"] if h in r["learnt"]]
    nll = "; ".join(f"{h} learnt {r['learnt'][h]['nll_per_step']:.3f}, shortest path {r['shortest_path'][h]['nll_per_step']:.3f}, "
                    f"hand ratio {r['hand_conflict']['ratios_to_step_cost'][near]:g} {r['hand_conflict'][h]['nll_per_step']:.3f}"
                    for h in held)
    return [(f"`irl_spacetime.py` space-time MaxEnt IRL (cells x {r['horizon_s']:g} s, 8 moves + wait) on ETH/UCY walkers, "
             f"trained on {', '.join(d['trained_on'])}",
             f"walkers are within {near.split('_')[1]} m of someone at the same time {min(fewer):.1f}-{max(fewer):.0f}x less "
             f"often than the shortest path, yet the learnt price is {ratio:.2f} x the step cost"
             + (f" (leave-one-scene-out {min(loso):.2f}-{max(loso):.2f})" if loso else "")
             + f"; held-out NLL per step: {nll}; fit {r['learnt']['fit_s']:.0f} s",
             f"shortest path (no price); the spatial MAP-BIRL ratio {r['spatial_birl']['ratios_to_step_cost'][near]:.3f}; "
             f"the shipped hand ratio", "no goal; mapped to the planner's conflict weight, the social_nav bench did worse than "
             "the hand-set 4.0 (nodes/nav/weights/default.json: conflict_weight.spacetime_experiment), so 4.0 stays")]


def pedestrian_predict(d: dict) -> list[Row]:
    """The learnt predictor, and what the space-time IRL learns when asked of its predictions (recorded in the
    weights file by the run that measured it: ``conflict_weight.predicted_experiment``)."""
    h = max(d["ade_mlp_by_horizon_m"], key=float)
    rows = [(f"`pedestrian_predict.py` ETH/UCY walkers, leave one scene out ({len(d['scenes'])} scenes), "
             f"8 positions 0.4 s apart seen -> {h} s predicted",
             f"ensemble of {d['members']} MLPs (JAX, a correction to constant velocity): ADE / FDE at {h} s "
             f"{d['ade_m']:.3f} / {d['fde_m']:.3f} m, better than constant velocity on {d['mlp_beats_cv_folds']} of "
             f"{len(d['scenes'])} held-out scenes, at 1.2 s {d['ade_mlp_by_horizon_m']['1.2']:.3f} m; "
             f"{d['ms_per_frame_mlp']:.2f} ms per frame of {d['people']} walkers; it foresees "
             f"{100 * d['near_0.5_recall']['mlp']:.0f} % of the 0.5 m encounters (precision "
             f"{d['near_0.5_precision']['mlp']:.2f}); variants chosen on these same held-out scenes",
             f"constant velocity {d['ade_cv_m']:.3f} / {d['fde_cv_m']:.3f} m (1.2 s {d['ade_cv_by_horizon_m']['1.2']:.3f} m), "
             f"foresees {100 * d['near_0.5_recall']['cv']:.0f} %; damped velocity (fitted on the training scenes) "
             f"{d['ade_hand_m']:.3f} / {d['fde_hand_m']:.3f} m",
             f"no goal (a learnt component against its baseline: {100 * (1 - d['ade_m'] / d['ade_cv_m']):.0f} % better at the "
             "longest horizon, a tie at 1.2 s)")]
    try:
        e = json.loads((REPO / "nodes/nav/weights/default.json").read_text())["conflict_weight"]["predicted_experiment"]
        r = e["runs"]["predicted_mlp_ensemble"]
        ratios = e["learnt_ratio_near_0.5_to_step_cost"]
        weight = e["learnt_conflict_weight_mapped"]
        learnt, shipped = e["bench_same_session"][f"learnt_{weight:g}"], e["bench_same_session"]["shipped_4.0"]
    except (OSError, KeyError, ValueError):
        return rows
    loso = list(r["leave_one_scene_out_ratio_near_0.5"].values())
    rows.append(("`pedestrian_predict.py` predictions asked by the space-time MaxEnt IRL (`irl_spacetime.py --others "
                 "predicted`: the others' futures from the fold model that never saw the scene, seen up to t0 only)",
                 f"learnt conflict price {r['learnt_ratio_near_0.5']:.3f} x the step cost (leave-one-scene-out "
                 f"{min(loso):.3f} to {max(loso):.3f}); from the others' recorded positions "
                 f"{ratios['recorded_positions (spacetime_experiment)']:.2f}, from constant velocity on the observed steps "
                 f"{ratios['constant_velocity_from_observed_steps']:.3f}",
                 "the same model on recorded positions; held-out NLL per step equals the shortest path's "
                 + "(" + ", ".join(f"{k} {v:.3f} vs {r['held_out_nll_per_step']['shortest_path'][k]:.3f}"
                                   for k, v in r["held_out_nll_per_step"]["learnt"].items()) + ")",
                 f"no goal; mapped to the planner's conflict weight ({weight:.3f}) the social_nav bench did worse than the "
                 f"hand-set 4.0 (closest >= DWA {learnt['closest_ge_dwa_count']} of {len(learnt['scenarios'])} vs "
                 f"{shipped['closest_ge_dwa_count']} of {len(shipped['scenarios'])}), so 4.0 stays"))
    return rows


def conflict_match(d: dict) -> list[Row]:
    """``--reactive``: the conflict price matched with the planner in the loop among a reactive crowd."""
    prices, planner = d["prices"], d["train_encounters_planner"]
    loso = "/".join(("<=" if v["censored"] == "below" else ">=" if v["censored"] == "above" else "") + f"{v['price']:g}"
                    for v in d["loso_prices"].values())
    lo, hi = d["bootstrap_95"]
    held = "; ".join(f"{n} {100 * h['learnt']['rate']:.1f} vs {100 * h['hand_set']['rate']:.1f} % (walkers "
                     f"{100 * h['human_rate']:.2f} %)" for n, h in d["heldout"].items())
    crowd = "a reactive crowd (social-force agents seeded from the tracks)" if d["crowd"].startswith("reactive") \
        else "the others replayed"
    return [(f"`conflict_match.py` the conflict price by feature matching, the planner in the loop among {crowd}, "
             f"{'/'.join(str(n) for n in d['walkers'].values())} walkers of {', '.join(d['walkers'])}",
             f"{d['feature']}: walkers {100 * d['train_encounters_human']:.2f} %, the planner {100 * planner[0]:.2f} % "
             f"at {prices[0]:g} -> {100 * planner[-1]:.2f} % at {prices[-1]:g} ({len(prices)} prices); matched "
             f"{d['learnt_price']:.2f} ({d['learnt_ratio_to_step_cost']:.2f} x the step cost), bootstrap {lo:g}-{hi:g} "
             f"({100 * d['bootstrap_censored_frac']:.0f} % at the grid's ends), leave-one-scene-out {loso}; held out, "
             f"matched vs 4.0: {held}; {d['secs']:.0f} s",
             "the hand-set 4.0, same walkers",
             "no goal; not identified, and worse than 4.0 on the social_nav bench's real crowds "
             "(nodes/nav/weights/default.json: conflict_weight.reactive_crowd_matching_experiment), so 4.0 stays")]


def sonar_polar(d: dict) -> list[Row]:
    return [("`sonar_polar.py` 1024x1024 fan", f"{d['fan1024_ms']:.2f} ms (LUT, nearest); bilinear on cached cv2 maps "
             f"{d['fan1024_ms_cv2']:.2f} ms",
             f"numpy bilinear {d['fan1024_ms_bilinear']:.1f} ms; max error bilinear {d['max_abs_err']:.0f}, nearest "
             f"{d['max_abs_err_nearest']:.0f} grey levels",
             f"<= {d['goal_fan1024_ms']:g} ms: {_met(d['fan1024_ms'] <= d['goal_fan1024_ms'])}")]


def sonar_two_branch(d: dict) -> list[Row]:
    held = [k for k in d["passes"] if k not in d["chosen_on"] and k != "demo"]
    k = d["min_votes"]
    return [(f"`sonar_two_branch.py` demo pass and {len(held)} check passes: two surface branches from an interior "
             f"leading point (a lever for the completeness goal; min_votes {k} chosen on {', '.join(d['chosen_on'])})",
             f"completeness at >= 90 % within 0.2 m (best over the evidence threshold sweep) on the demo "
             f"{100 * d['demo_fused']:.1f} %; better on {d['held_out_better']} held-out passes, the demo among them ("
             + ", ".join(f"{n} {100 * d['passes'][n][f'fused_{k}']:.1f}" for n in held)
             + f" %); {d['ms_per_ping']:.1f} ms per ping for its votes alone (load average {d['load_average']:g})",
             f"the evidence cloud alone: demo {100 * d['demo_evidence']:.1f} % ("
             + ", ".join(f"{n} {100 * d['passes'][n]['evidence']:.1f}" for n in held) + " %)",
             "no goal (a measured lever): not shipped, too little for its cost")]


def sonar_carving_filter(d: dict) -> list[Row]:
    """``--fresh --fresh2``: the shipped evidence filter beside the default cloud on passes nothing was trained on."""
    rows = []
    what = {"fresh": "--fresh: {n} never-seen passes (tracks heading west, south and diagonally; a four-legged jacket "
                     "no scene has; they informed the current filter's design)",
            "fresh2": "--fresh2: {n} never-seen passes, written down before their first run (an overhanging platform, a "
                      "sloped plate, a pipe rack; the tripod and pier at new headings and depths)"}
    for name, sd in d["sets"].items():
        p, e, dflt = sd["passes"], sd["evidence"], sd["default"]
        worst = min(p, key=lambda n: p[n]["evidence"]["acc_frac_0p2"] - p[n]["default"]["acc_frac_0p2"])
        below = e["passes_acc_below_default_by_2"]
        rows.append(("`sonar_carving_filter.py` " + what.get(name, name + ": {n} passes").format(n=len(p)),
                     f"`keep: evidence` (p >= {d['threshold_p']:g}): median {100 * e['acc_frac_0p2_median']:.1f} % within "
                     f"0.2 m, completeness {100 * e['completeness_0p2_median']:.1f} %, >= 90 % within 0.2 m on "
                     f"{e['passes_acc_ge_0p9']} of {e['passes']}; most below the default: {worst} "
                     f"{100 * p[worst]['evidence']['acc_frac_0p2']:.1f} % / {100 * p[worst]['evidence']['completeness_0p2']:.1f} %",
                     f"the default cloud: median {100 * dflt['acc_frac_0p2_median']:.1f} % / "
                     f"{100 * dflt['completeness_0p2_median']:.1f} %, >= 90 % on {dflt['passes_acc_ge_0p9']} of "
                     f"{dflt['passes']}; on {worst} {100 * p[worst]['default']['acc_frac_0p2']:.1f} % / "
                     f"{100 * p[worst]['default']['completeness_0p2']:.1f} %",
                     (f"default-switch rule fixed before the run (no pass > 2 points less accurate than the default): "
                      f"{_met(not below)}" + (f", {len(below)} of {len(p)} ({', '.join(below)})" if below else "")
                      + "; the evidence filter stays off by default") if name == "fresh2" else
                     "no goal (a check, no longer untouched); the evidence filter stays off by default"))
    return rows


def sonar_cloud(d: dict) -> list[Row]:
    ok = (d["acc_frac_0p2"] >= 0.9, d["completeness_0p2"] >= 0.7, d["ms_per_ping"] <= 5.0)
    return [(f"`sonar_cloud.py` {d['beams']}-beam ping, highlight extension", f"{d['height_ms_per_ping']:.2f} ms; height "
             f"RMSE {100 * d['height_rmse_m']:.1f} cm",
             f"the paper's constant-elevation model {100 * d['height_rmse_m_paper_model']:.1f} cm",
             f"<= 2 ms: {_met(d['height_ms_per_ping'] <= 2.0)}"),
            (f"`sonar_cloud.py` demo pass ({d['demo_pings']} pings), carved cloud (free-space carving, dark evidence, arc voting, "
             f"sigma <= {d['max_sigma_m']:g} m)",
             f"{100 * d['acc_frac_0p2']:.1f} % of points within 0.2 m of the structure (p90 {d['acc_p90_m']:.2f} m), "
             f"completeness {100 * d['completeness_0p2']:.1f} %, {d['ms_per_ping']:.1f} ms per ping "
             f"({d['ms_per_ping_in_view']:.1f} ms on the pings with the structure in view)"
             + (f"; option `occlusion` (off by default: less accurate on the wall and pier) "
                f"{100 * d['occlusion_acc_frac_0p2']:.1f} % / completeness {100 * d['occlusion_completeness_0p2']:.1f} %, "
                f"{d['occlusion_ms_per_ping_in_view']:.1f} ms in view; best completeness at >= 90 % within 0.2 m "
                f"{100 * (d['completeness_at_acc90'] or 0):.1f} % (occlusion {100 * (d['occlusion_completeness_at_acc90'] or 0):.1f} %)"
                if "occlusion_acc_frac_0p2" in d else "")
             + (f"; option `gap_weight` 2 (off by default: less accurate on a one-sided block) "
                f"{100 * d['gaps_acc_frac_0p2']:.1f} % / completeness {100 * d['gaps_completeness_0p2']:.1f} %, best at "
                f">= 90 % {100 * (d['gaps_completeness_at_acc90'] or 0):.1f} %" if "gaps_acc_frac_0p2" in d else "")
             + (f"; option `keep: evidence` (off by default: a learnt filter without a height feature, trained on "
                f"{len(d['evidence_trained_on'])} other simulated passes, threshold p >= {d['evidence_threshold_p']:g} chosen on "
                f"passes left out of training) {100 * d['evidence_acc_frac_0p2']:.1f} % (p90 {d['evidence_acc_p90_m']:.2f} m) / "
                f"completeness {100 * d['evidence_completeness_0p2']:.1f} %, {d['evidence_ms_per_ping']:.1f} ms per ping "
                f"({d['evidence_ms_per_ping_in_view']:.1f} in view)"
                + (f", best completeness at >= 90 % with this pass in view "
                   f"{100 * d['evidence_completeness_at_acc90_chosen_on_demo']:.1f} %"
                   if d.get("evidence_completeness_at_acc90_chosen_on_demo") is not None else "")
                + (f" ({100 * d['evidence_completeness_at_acc90_fine_chosen_on_demo']:.1f} % at p >= "
                   f"{d['evidence_fine_at_p']:g} in 0.025 steps)"
                   if d.get("evidence_completeness_at_acc90_fine_chosen_on_demo") is not None else "")
                + "; the first filter (a height feature, 15 passes, p >= 0.77, its last feature picked with this pass "
                  "in view) gave 92.1 % / 70.6 % here but 69.6 % within 0.2 m on a never-seen jacket crossed above its deck"
                if "evidence_acc_frac_0p2" in d else "")
             + (f"; option `generative` (Westman & Kaess's image model per beam, off by default: parameters chosen on "
                f"3 other passes) alone {100 * d['generative_acc_frac_0p2']:.1f} % / completeness "
                f"{100 * d['generative_completeness_0p2']:.1f} %, {d['generative_ms_per_ping']:.1f} ms; added to "
                f"`keep: evidence` {100 * d['fused_acc_frac_0p2']:.1f} % / {100 * d['fused_completeness_0p2']:.1f} %, "
                f"{d['fused_ms_per_ping']:.1f} ms per ping ({d['fused_ms_per_ping_in_view']:.1f} in view): a point on "
                f"the evidence filter's own trade, not a better one"
                if "fused_acc_frac_0p2" in d else "")
             + (f" (load average {d['load_average']:g} on {d['cpu_count']} cores while timing)"
                if d.get("load_average", 0) > d.get("cpu_count", 99) else ""),
             f"the paper's highlight cloud {100 * d['highlight_acc_frac_0p2']:.1f} % (p90 {d['highlight_acc_p90_m']:.2f} m), "
             f"completeness {100 * d['highlight_completeness_0p2']:.1f} %, {d['highlight_ms_per_ping']:.1f} ms",
             f">= 90 %: {_met(ok[0])}; completeness >= 70 %: {_met(ok[1])}"
             + (f" (one straight pass: {100 * d['ambiguous_frac']:.0f} % of the seen surface has a ghost every view "
                f"measures alike" + (f"; the voting's right points alone, at any sigma, cover "
                                     f"{100 * max(d['completeness_oracle_filter'].values()):.0f} %, and only "
                                     f"{100 * d['pinned_0p2_frac']:.0f} % of the seen surface is pinned to 0.2 m by any "
                                     f"view" if "completeness_oracle_filter" in d else "") + ")" if not ok[1] else "")
             + (f"; the visible surface audited: {100 * d['visible_audit']['back_facing']:.1f} % of it faces away from "
                f"every ping that hit near it; without it completeness is {100 * d['completeness_0p2_facing']:.1f} %, "
                f"`keep: evidence` {100 * d['evidence_completeness_0p2_facing']:.1f} %, its best at >= 90 % "
                f"{100 * d['evidence_completeness_at_acc90_fine_facing_chosen_on_demo']:.1f} % (the rule above is unchanged)"
                if "visible_audit" in d and "evidence_completeness_0p2_facing" in d else "")
             + (f"; with `keep: evidence` >= 90 % and >= 70 %: "
                f"{_met(d['evidence_completeness_0p2'] >= 0.7 and d['evidence_acc_frac_0p2'] >= 0.9)}"
                if "evidence_acc_frac_0p2" in d else "")
             + f"; <= 5 ms: {_met(ok[2])}")]


def nav_flow(d: dict) -> list[Row]:
    ms, epe = d["flow_ms"], d["flow_epe_px"]
    return [("`nav_flow.py` 640x480 flow", f"DIS fast {ms['dis_fast@1']:.1f} ms, end-point error {epe['dis_fast@1']:.2f} px",
             f"Farneback (the paper's) {ms['farneback_fast@1']:.0f} ms, {epe['farneback_fast@1']:.2f} px", "—")]


def transport(d: dict) -> list[Row]:
    rows = [("`transport.py` 64 B round trip p50", f"{d['rtt_p50_us']:.0f} us (p99 {d['rtt_p99_us']:.0f} us)",
             f"raw pyzmq ipc {d['rtt_p50_raw_us']:.0f} us (ratio {d['rtt_ratio']:.2f})",
             f"<= 1.2x: {_met(d['rtt_ratio'] <= 1.2)}")]
    iox = (lambda k: f"; iceoryx2 {d[k]:.2f}x" if d.get(k) is not None else "; iceoryx2 not installed")
    fan = {(f["sinks"], f["size"]): f for f in d.get("fanout", [])}
    f64 = fan.get((8, "64B"))
    return rows + [
        ("`transport.py` 1 MiB one-way, shared memory, node writes into `self.loan` (0 copies)",
         f"{d['mib_msgs_per_s_shm']:.0f} msg/s ({d['mib_ratio_shm']:.2f}x raw); a node left unchanged (1 copy) "
         f"{d['mib_ratio_copy']:.2f}x",
         f"raw pyzmq `copy=False` {d['mib_msgs_per_s_raw']:.0f} msg/s; ours as frames (TETHER_SHM=0) "
         f"{d['mib_ratio_frames']:.2f}x" + iox("iox_mib_ratio") + " with one copy like our unchanged node, its "
         "subscriber busy-polling a core", f">= 4x: {_met(d['mib_ratio_shm'] >= 4)}"),
        ("`transport.py` 8 MiB one-way, shared memory, loaned", f"{d['mib8_msgs_per_s_shm']:.0f} msg/s "
         f"({d['mib8_ratio_shm']:.1f}x raw); node unchanged {d['mib8_ratio_copy']:.2f}x",
         f"raw pyzmq {d['mib8_msgs_per_s_raw']:.0f} msg/s" + iox("iox_mib8_ratio") + " (one copy, busy-polling)",
         f">= 5x: {_met(d['mib8_ratio_shm'] >= 5)}"),
        ("`transport.py` fan-out to 8 sinks, 1 MiB", f"{d['fanout8_ratio']:.2f}x raw pyzmq's aggregate"
         + (f"; 64 B: {f64['ratio']:.2f}x, p99 {f64['p99_us'] / 1e3:.1f} ms" if f64 else ""),
         "raw pyzmq PUB to 8 SUBs" + (f" (64 B p99 {f64['p99_raw_us'] / 1e3:.1f} ms)" if f64 else ""),
         f">= 3x: {_met(d['fanout8_ratio'] >= 3)}"),
        ("`transport.py` 50-node launch to all ready", f"{d['startup50_s']:.1f} s; idle {d['idle_cpu_pct_per_node']:.2f} % CPU "
         f"and {d['pss_mib_per_node']:.0f} MiB (PSS) per node",
         f"100 nodes: {d['sockets100']} sockets (needed {d['sockets100_needed']}), {d['startup100_s']:.1f} s",
         f"<= 5 s: {_met(d['startup50_s'] <= 5)}")]


def sonar_icp(d: dict) -> list[Row]:
    kiss = (f"; KISS-ICP {d['kiss_icp_ms']:.0f} ms, {d['kiss_icp_err_m']:.2f} m / {d['kiss_icp_err_deg']:.2f} deg"
            if d.get("kiss_icp_ms") is not None else "; KISS-ICP not installed")
    n = len(d["structures"])
    worse = d["final_worse_than_nav"]
    return [(f"`sonar_icp.py` registration on simulated tripod pings, {d['trials']} windows (targets built once)",
             f"ours 6 DOF on lower-edge points {d['icp_ms']:.1f} ms, {d['icp_err_m']:.2f} m / {d['icp_err_deg']:.2f} deg; "
             f"on elevation arcs (x, y, yaw) {d['icp_arcs_ms']:.1f} ms, {d['icp_arcs_err_m']:.3f} m / "
             f"{d['icp_arcs_err_deg']:.2f} deg ({d['icp_arcs_check_ms']:.0f} ms with the whole-circle symmetry check); "
             f"model build {d['model_build_ms']:.0f} ms",
             f"small_gicp best accuracy ({d['small_gicp_best']}) {d['small_gicp_ms_best']:.1f} ms, "
             f"{d['small_gicp_err_m_best']:.2f} m / {d['small_gicp_err_deg_best']:.2f} deg; fastest "
             f"({d['small_gicp_fastest']}) {d['small_gicp_ms_fastest']:.1f} ms, {d['small_gicp_err_m_fastest']:.2f} m / "
             f"{d['small_gicp_err_deg_fastest']:.2f} deg{kiss}. On the same points small_gicp wins (better heading, "
             "faster, 20-400x faster target builds); ours wins only with arcs, which small_gicp cannot take",
             "none (a comparison, not a goal)"),
            (f"`sonar_icp.py` the localizer on {n // 2} structures at 3 and 20 deg heading error",
             f"{d['wrong_trusted_total']} trusted corrections wrong by > 0.5 m or 5 deg; symmetric structures "
             f"reported ambiguous; final error worse than navigation alone on {len(worse)} of {n} passes",
             "navigation alone (each pass's nav_err_m in the JSON)",
             f"0 wrong trusted, never worse than navigation: {_met(d['wrong_trusted_total'] == 0 and not worse)}")]


def sonar_pipeline(d: dict) -> list[Row]:
    return [("`sonar_pipeline.py` launched pipeline, 512 beams",
             f"{d['pings_per_s']:.1f} pings/s, ping-to-pose latency {d['latency_ms_p50']:.0f} ms p50; localisation "
             f"{d['loc_err_m']:.3f} m vs {d['nav_err_m']:.2f} m from navigation alone; {d['wrong_trusted']} confident "
             f"wrong poses of {d['trusted_corrections']} trusted",
             f"the simulator alone, in-process: {d['render_only_pings_per_s']:.1f} pings/s (ratio "
             f"{d['pipeline_vs_render_ratio']:.2f})", f">= 15 pings/s: {_met(d['pings_per_s'] >= 15)}")]


def pose_graph(d: dict) -> list[Row]:
    g = d["graphs"]
    names = [k for k in ("M3500", "intel", "FR079") if k in g]
    j = lambda f, key: " / ".join(f.format(g[k][key]) for k in names)          # noqa: E731
    same = all(abs(g[k]["chi2"] - g[k]["chi2_gtsam"]) <= 1e-4 * g[k]["chi2_gtsam"] or g[k]["chi2"] < g[k]["chi2_gtsam"]
               for k in names)
    faster = all(g[k]["cpu_s"] <= g[k]["cpu_s_gtsam"] for k in names)
    hard = g.get("M3500_rot0.2")
    ref = f"GTSAM LM {j('{:.4f}', 'chi2_gtsam')}, {j('{:.3f}', 'cpu_s_gtsam')} s"
    if hard:
        ref += f"; M3500 with 0.2 rad odometry noise: {hard['chi2']:.0f} (chordal start) vs GTSAM {hard['chi2_gtsam']:.0f}"
    return [(f"`pose_graph.py` {' / '.join(names)} from odometry, median of {d['repeats']}",
             f"chi2 {j('{:.4f}', 'chi2')} (g2o convention), {j('{:.3f}', 'cpu_s')} s CPU", ref,
             f"same chi2 within 1e-4 (or lower), CPU <= GTSAM: {_met(same and faster)}")]


def phase_correlation(d: dict) -> list[Row]:
    fam = d["families"]
    ok = d["pc_err_px"] <= 0.1 and d["pc_ms"] <= 5
    sk = [v["skimage_best"]["median_px"] for v in fam.values() if "skimage_best" in v]
    return [(f"`phase_correlation.py` 512x512, {len(fam)} families, exact shifts",
             f"{d['pc_err_px']:.3f} px median, {d['pc_ms']:.1f} ms; rotation {d['rot_err_deg']:.3f} deg "
             f"(p95 {d['rot_err_deg_p95']:.2f}), 180-degree ambiguity right in {100 * d['ambiguity_ok_frac']:.0f} %",
             f"cv2.phaseCorrelate {d['pc_err_px_cv2']:.3f} px, {d['pc_ms_cv2']:.1f} ms; skimage (best setting per "
             f"family) {min(sk):.3f}-{max(sk):.2f} px",
             f"<= 0.1 px at <= 5 ms: {_met(ok)}")]


def mosaic_paper(d: dict) -> list[Row]:
    return [(f"`mosaic_paper.py` seed 08's 8 sub-images, {len(d['seeds'])} seeds",
             f"graph {d['ate_px_graph']:.2f} px (rotated: {d['ate_px_graph_rot']:.2f} px), {d['ms_per_pair']:.1f} ms per pair",
             f"chaining {d['ate_px_chain']:.2f} px (rotated {d['ate_px_chain_rot']:.2f}), navigation prior "
             f"{d['ate_px_nav']:.0f} px, cv2 chaining {d['ate_px_cv2_chain']:.0f} px",
             f"graph < chaining: {_met(d['ate_px_graph'] < d['ate_px_chain'] and d['ate_px_graph_rot'] < d['ate_px_chain_rot'])}")]


def sonar_mosaic(d: dict) -> list[Row]:
    gain = d["ate_m_chain"] / d["ate_m_graph"]
    return [("`sonar_mosaic.py` simulated lawn-mower survey, texture not tuned on",
             f"graph {d['ate_m_graph']:.3f} m RMSE, {d['ms_per_keyframe']:.0f} ms per keyframe, {d['ms_per_ping']:.1f} ms "
             f"per ping ({d['realtime_factor']:.2f} of real time at 10 Hz)",
             f"chaining {d['ate_m_chain']:.3f} m, navigation {d['ate_m_nav']:.3f} m",
             f"graph cuts chaining 5x: {_met(gain >= 5)} ({gain:.1f}x); keeps up at 10 Hz: {_met(d['realtime_factor'] < 1)}")]


def dslam(d: dict) -> list[Row]:
    g, o = d["graphs"], d["outlier_studies"]
    names = list(g)
    kb = lambda v: f"{v / 1000:.0f} kB"                   # noqa: E731
    how = {"ddf": "DDF condensed graphs", "block_gs": "block Gauss-Seidel", "ddf_run8": "DDF, one keyframe in 8"}
    fewer = all(g[k]["bytes_to_1pct"] <= g[k]["bytes_upload_and_return"] for k in names)
    outl = sum(o[k]["outlier_cost_change"] < 0.01 for k in names)
    return [(f"`dslam.py` {len(names)} real graphs cut into R = 4 robots, real wire encoding",
             "to within 1 % of the centralised cost: " + ", ".join(f"{k} {kb(g[k]['bytes_to_1pct'])} "
                                                                 f"({how.get(g[k]['method'], g[k]['method'])})"
                                                                 for k in names)
             + "; 30 % false closures: cost change " + " / ".join(f"{o[k]['outlier_cost_change']:.0e}" for k in names)
             + f", {sum(o[k]['outliers_rejected_frac'] == 1 for k in names)} of {len(names)} with every false one "
             f"rejected; {100 * d['cpu_core_frac']:.0f} % of a core per robot",
             "every robot uploading all its edges to one (and the answer back): "
             + " / ".join(kb(g[k]["bytes_upload_and_return"]) for k in names),
             f"1 % with fewer bytes than upload: {_met(fewer)}; outliers < 1 %: met on {outl} of {len(names)}; "
             f"CPU < 20 %: {_met(d['cpu_core_frac'] < 0.2)}")]


def verify(d: dict) -> list[Row]:
    big = [r for r in d["rows"] if r["states"] >= 100_000]
    ms = [1000 * r["ours_s"] for r in big]
    sizes = sorted({r["states"] for r in d["rows"]})
    return [(f"`verify.py` CTL on growing models ({sizes[0]:,} to {sizes[-1]:,} states)",
             f"{d['states_per_s']:.2e} states/s on {d['largest_states']:,} states ({min(ms):.1f}-{max(ms):.0f} ms per formula)",
             f"pyModelChecking on the same structures and formulas: {'same' if d['agree'] else '**different**'} "
             f"satisfying sets; {d['speedup_vs_pymc']:.0f}x slower (median) at >= 100k states",
             f">= 10x at >= 100k states: {_met(d['speedup_vs_pymc'] >= 10)}")]


def swarm(d: dict) -> list[Row]:
    curves = d["curves"]
    at = lambda name, n: next((p["eff"] for p in curves.get(name, []) if p["n"] == n), float("nan"))   # noqa: E731
    return [(f"`swarm.py` foraging, F/N for N = 1-60, {d['seeds']} seeds per point, theta chosen on other seeds",
             f"{d['realtime_factor_n30']:.0f}x real time at N = 30; open arena: one zone "
             f"{100 * d['eff_gain_one_zone_at_n30']:+.1f} % over no zone at N = 30 ({at('one zone', 30):.2f} vs "
             f"{at('no zone', 30):.2f}), N* = {d['nstar_one_zone']}; wall with a gate: "
             f"{100 * d['eff_gain_gated_at_n30']:+.0f} % at N = 30, N* = {d['nstar_gated']}",
             "no zone, the seed's peer-to-peer hand-over, cache, the adaptive choice; no reference simulator on PyPI "
             "(ARGoS is a C++ application)", f">= 100x real time at N = 30: {_met(d['realtime_factor_n30'] >= 100)}")]


def chaos(d: dict) -> list[Row]:
    ok = (d["nodes_alive_frac"] == 1 and d["lost_uncounted"] == 0 and d["orphans_after_kill"] == 0
          and d["secrets_on_cmdline"] == 0 and d["corrupt_chunks_reported"] == d["corrupt_chunks_injected"]
          and d["decode_errors_counted"] == d["decode_errors_expected"])
    return [(f"`chaos.py` {d['duration_s']:.0f} s under attack",
             f"{100 * d['nodes_alive_frac']:.0f} % of nodes alive, {d['decode_errors_counted']}/"
             f"{d['decode_errors_expected']} malformed frames counted, {d['lost_uncounted']} lost uncounted, "
             f"{d['peak_rss_mb_slow_consumer']:.0f} MB slow consumer, {d['orphans_after_kill']} orphans, "
             f"{d['secrets_on_cmdline']} secrets in argv, {d['corrupt_chunks_reported']}/{d['corrupt_chunks_injected']} "
             "damaged chunks named", "—", f"all goals: {_met(ok)}")]


def ackermann(d: dict) -> list[Row]:
    law = d["fig8_rms_mm_50hz_by_law"]
    ok = d["fig8_rms_mm_50hz"] <= 1 and d["step_us"] <= 100 and d["mpc_ms_h20"] <= 10
    return [("`ackermann.py` figure-eight at 50 Hz",
             f"{1000 * d['fig8_rms_mm_50hz']:.0f} um RMS; controller step {d['step_us']:.0f} us; MPC h20 "
             f"{d['mpc_ms_h20']:.2f} ms",
             f"kinematic baseline {1000 * law['kinematic']:.0f} um, the paper's first law {law['fblin']:.1f} mm "
             f"(singular on crab/spin), MPC {1000 * law['mpc']:.1f} um",
             f"<= 1 mm, <= 100 us, <= 10 ms: {_met(ok)}"),
            ("`ackermann.py` launch/ackermann_can.yaml in lockstep, CSP steering + CSV wheels, SYNC 100 Hz, from rest",
             f"{d['fig8_rms_mm_csp']:.3f} mm RMS, max {d['fig8_max_mm_csp']:.3f} mm"
             + ("" if not d.get("fig8_csp_tripped") else " (SYNC watchdog tripped)"),
             "SYNC " + ", ".join(f"{k} Hz {v:.3f} mm" for k, v in d["fig8_rms_mm_csp_by_sync_hz"].items()
                                 if k != "100"),
             f"<= 1 mm: {_met(d['fig8_rms_mm_csp'] <= 1.0 and not d.get('fig8_csp_tripped'))}")]


def ackermann_can(d: dict) -> list[Row]:
    return [("`ackermann_can.py` over CAN, whole run from rest",
             f"{d['fig8_rms_mm_can']:.2f} mm RMS, max {d['fig8_max_mm_can']:.2f} mm (udp_multicast, real time)"
             + _inprocess_csp(d),
             f"no-bus model {d['fig8_rms_mm_model_nobus']:.3f} mm; launch file in lockstep "
             f"{d['fig8_rms_mm_can_lockstep']:.2f} mm", f"<= 1 cm: {_met(d['fig8_rms_mm_can'] <= 10)}")] + _launched(d)


def _inprocess_csp(d: dict) -> str:
    """The CSP/CSV+SYNC run with master, drives and controller in the bench's one process."""
    if d.get("fig8_rms_mm_can_csp_realtime") is None:
        return ""
    prio = f" at SCHED_FIFO {d['inprocess_rt_priority']}" if d.get("inprocess_rt_priority") else ""
    gap = d.get("can_csp_drive_sync_gap_max_ms")
    frozen = d.get("can_csp_sync_gap_machine_ms")
    why = "" if gap is None or frozen is None else f"longest SYNC gap {gap:.1f} ms, " + (
        f"of which a vCPU was frozen by the host {frozen:.1f} ms" if frozen > 0 else "no vCPU freeze during it")
    if d.get("can_csp_realtime_tripped"):
        return (f"; CSP/CSV+SYNC with master and drives in one process{prio}: SYNC lost, quick stop"
                + (f" ({why}; the drive stops at 35 ms)" if why else " (a stall of over 35 ms)"))
    return (f"; CSP/CSV+SYNC with master and drives in one process{prio}: {d['fig8_rms_mm_can_csp_realtime']:.2f} mm RMS"
            + (f" ({why})" if why else ""))


def _launched(d: dict) -> list[Row]:
    runs = d.get("launched_realtime") or {}
    rt, normal = runs.get("rt_priority") or {}, runs.get("normal") or {}
    if not rt.get("runs") or not normal.get("runs"):
        return []
    return [(f"`ackermann_can.py` the launch file in real time (CSP, SYNC 100 Hz) beside "
             f"{d['launched_busy_processes']} CPU-bound processes",
             f"as shipped (every cyclic node SCHED_FIFO): SYNC lost in {rt['tripped']} of {rt['runs']} runs, "
             f"median {rt['rms_mm_median']:.2f} mm RMS" + (f", max {rt['max_mm_median']:.1f} mm" if "max_mm_median" in rt else ""),
             f"normal scheduling: SYNC lost in {normal['tripped']} of {normal['runs']}, median "
             f"{normal['rms_mm_median']:.2f} mm RMS" + (f", max {normal['max_mm_median']:.1f} mm"
                                                     if "max_mm_median" in normal else ""), "—")]


def stereo_cable(d: dict) -> list[Row]:
    worst = max(d["theory_ratio"].values())
    where = max(d["theory_ratio"], key=d["theory_ratio"].get).replace("@", " at ") + " m"
    real = d.get("real_rectification") or {}
    rows = [("`stereo_cable.py` 640x480 pairs, cable 1.5-4 m, seeds not tuned on",
             f"in tracked order: self-crossing cable {d['rms_mm_crossing']:.1f} mm RMS at 1.5-2.5 m, catenary "
             f"{d['rms_mm_catenary']:.1f} mm; error / theory z^2 sd/(b f) at most {worst:.2f} ({where}); "
             f"{d['ms_per_frame']:.0f} ms "
             f"per frame ({d['fps']:.1f} frames/s)",
             f"nearest point per row {d['rms_mm_row_crossing']:.0f} mm; SGBM on the masked cable (block "
             f"{d['sgbm_block']}, its best) {d['rms_mm_sgbm']:.1f} mm, {d['ms_per_frame_sgbm']:.0f} ms",
             f"<= 1.2x theory: {_met(worst <= 1.2)}; <= 25 mm: {_met(d['rms_mm_crossing'] <= 25)}; "
             f">= 30 frames/s: {_met(d['fps'] >= 30)}")]
    if real:
        rows.append((f"`stereo_cable.py` real rectified chessboard pairs ({real['pairs']})",
                     f"our triangulation: neighbouring corners {real['spacing_mean']:.4f} squares apart (RMS error "
                     f"{100 * real['spacing_rms_err']:.2f} %); rows agree to {real['row_dy_rms_px']:.2f} px",
                     "rectification by OpenCV stereoCalibrate / stereoRectify on the same views", "—"))
    return rows


def selfcal(d: dict) -> list[Row]:
    bm = d["by_motion"]
    rot = bm.get("rotation@0.5", {})
    boug = bm["general@0.5"]["bougnoux_err_median"]
    rows = [("`selfcal.py` synthetic sequences, 8 views, the chessboard camera as truth, seeds not tuned on",
             f"Kruppa + refinement, general motion at 0.5 px: {100 * d['f_err_general']:.2f} % focal error (median); "
             f"pure rotation (infinite homography) {100 * rot.get('f_err_median', float('nan')):.2f} %; critical "
             f"motions flagged {100 * d['critical_flagged_frac']:.0f} %, general {100 * d['false_flag_frac']:.0f} %; "
             f"{d['ms_per_pair']:.0f} ms per pair",
             f"Bougnoux (true principal point) {100 * boug:.2f} %", f"<= 2 %: {_met(d['f_err_general'] <= 0.02)}; "
             f"100 % / 0 % flagged: {_met(d['critical_flagged_frac'] == 1 and d['false_flag_frac'] == 0)}")]
    ch = d.get("chessboard") or {}
    if ch:
        rows.append(("`selfcal.py` real chessboard views (left / right), corners as correspondences only",
                     " / ".join(f"fx {ch[s]['fx']:.1f}" for s in ("left", "right")) + " px: "
                     + " / ".join(f"{100 * ch[s]['f_err']:.1f} %" for s in ("left", "right"))
                     + " (without the distortion estimate " + " / ".join(
                         f"{100 * ch[s]['f_err_no_distortion']:.0f} %" for s in ("left", "right")) + ")",
                     "cv2.calibrateCamera with the board model on the same views: " + " / ".join(
                         f"{ch[s]['fx_ref']:.1f}" for s in ("left", "right")), "—"))
    return rows


def uav_register(d: dict) -> list[Row]:
    bm, sw = d["by_method"], d["sweeps"]
    runs = d["homing"]
    others = "; ".join(f"{m.upper()} {100 * v['success_frac']:.0f} %, {v['pos_err_px']:.2f} px, {v['ms']:.0f} ms"
                       for m, v in bm.items() if m != "sift")
    ratio = sw["sift"]["ratio"]
    rows = [("`uav_register.py` 640x480 views of a map, localisation mode, scale ratio 0.5-2x, any rotation",
             f"SIFT: {100 * d['success_frac']:.1f} % fixed ({100 * bm['sift']['wrong_frac']:.1f} % wrong), "
             f"{d['pos_err_px']:.2f} px, {d['ms_per_frame']:.0f} ms per frame; at 0.25x {100 * ratio['0.25']['success_frac']:.0f} %, "
             f"at 4x {100 * ratio['4.0']['success_frac']:.0f} %; homing from outside the map: "
             f"{sum(r['success'] for r in runs)}/{len(runs)} within 1 m",
             others, f">= 95 %: {_met(d['success_frac'] >= 0.95)}; <= 1 px: {_met(d['pos_err_px'] <= 1)}; <= 50 ms: "
             f"{_met(d['ms_per_frame'] <= 50)}; homing 9/10: {_met(d['homing_success_frac'] >= 0.9)}")]
    real = d.get("real") or {}
    if real.get("sift"):
        r = real["sift"]
        rows.append(("`uav_register.py` 18 real frames to their ortho render, search mode",
                     f"SIFT: {r['registered']}/{r['frames']} registered; held-out position against its GPS "
                     f"{r['pos_err_m_median']:.2f} m median ({r['pos_err_m_max']:.2f} max), heading against the gimbal "
                     f"{r['heading_err_deg_median']:.1f} deg; {r['ms_per_frame']:.0f} ms per 1000x562 frame",
                     "; ".join(f"{m.upper()} {v['registered']}/{v['frames']}, {v['pos_err_m_median']:.2f} m"
                               for m, v in real.items() if m != "sift" and v.get("pos_err_m_median") is not None),
                     "— (GPS is the truth to within its own metres)"))
    return rows


def rl_env(d: dict) -> list[Row]:
    v = d["vectorised"]
    ratio = d["ratio_plain_over_inproc"]
    return [("`rl_env.py` reach-the-point car, env steps/s",
             f"bus in-process {d['steps_per_s_inproc']:,.0f}; over ipc (node process, lockstep) "
             f"{d['steps_per_s_ipc']:,.0f} at N = 1, {v['ipc_n64_shards1']:,.0f} with 64 instances per message "
             f"({v['ipc_n64_shards2']:,.0f} on 2 processes); in-process 64 instances {v['inproc_n64_shards1']:,.0f}",
             f"plain Gymnasium env, same dynamics: {d['steps_per_s_plain']:,.0f} (plain / bus {ratio:.2f}); "
             f"the batched core alone {d['steps_per_s_core']:,.0f}",
             f"in-process within 1.5x: {_met(ratio <= 1.5)}; ipc >= 5,000/s: {_met(d['steps_per_s_ipc'] >= 5000)} "
             f"at N = 1, {_met(v['ipc_n64_shards1'] >= 5000)} vectorised")]


def ppo_target_kl(d: dict) -> list[Row]:
    t = d["by_setting"]

    def cell(mult: int) -> str:
        on = ", ".join(f"{kl} {t[f'lr{mult}x_kl{kl}']['median_return']:.0f} "
                       f"(stops {t[f'lr{mult}x_kl{kl}']['stopped_frac']:.0%})" for kl in (0.03, 0.015, 0.0075))
        return f"lr {mult}x: {on}"

    ref = "; ".join(f"lr {m}x off {t[f'lr{m}x_kl0.0']['median_return']:.0f} (min {t[f'lr{m}x_kl0.0']['min_return']:.0f})"
                    for m in (1, 4, 16))
    return [(f"`ppo_target_kl.py` PPO's approximate-KL stop, CartPole-v1, {d['steps'] // 1000}k steps, "
             f"{d['seeds']} seeds: median held-out return",
             "; ".join(cell(m) for m in (1, 4, 16)), f"the bound off, same run: {ref}",
             "no goal; no bound better at every learning rate: off by default")]


def rl_car(d: dict) -> list[Row]:
    cp, rb, mb = d["cartpole"], d["reach"]["baseline"], d["maze"]["baseline"]
    curve = d["reach"]["curve"]
    seeds = d.get("reach_err_mm_by_seed") or {}
    pooled = (f"over {len(seeds)} training seeds ({', '.join(f'{v:.2f}' for v in seeds.values())} mm each), "
              if seeds else "")
    cps = cp.get("by_seed") or []
    cart = (f"CartPole-v1 after {cp['steps'] // 1000}k steps, {len(cps)} seeds: "
            + ", ".join(f"{c['return_mean']:.0f}" for c in cps) if cps else
            f"CartPole-v1 {cp['return_mean']:.0f} +- {cp['return_std']:.0f}")
    return [("`rl_car.py` PPO (JAX) over the bus, 100 held-out episodes",
             f"reach the point: {d['reach_err_mm_mean']:.2f} +- {d['reach_err_mm_std']:.2f} mm (median "
             f"{d['reach_err_mm_median']:.2f}) {pooled}seed {d.get('reach_median_seed', 0)} "
             f"at {d['reach_steps_picked'] / 1e6:.1f}M steps, picked on validation seeds "
             f"({d['reach_err_mm_mean_end']:.2f} +- {d['reach_err_mm_std_end']:.2f} at {curve[-1]['steps'] / 1e6:.1f}M)"
             + (", trained without eq. (5)'s -1 per step and scored as the paper scores (with it the same 3 seeds "
                "ended 13.96, 395.03, 5145.13 mm: the all-negative returns made unvisited far states look best to a "
                "critic starting at 0)" if d.get("reach_step_cost") == 0 else "")
             + "; maze: exit in "
             f"{100 * d['maze_success_frac']:.0f} % (the paper's straight-line reward), "
             f"{100 * d['maze_success_frac_geodesic']:.0f} % with the corridor distance; "
             f"{d['train_minutes']:.0f} training minutes in all; {cart}",
             f"paper 8.12 +- 1.23 mm; go-to-goal law {rb['mean_mm']:.2g} mm; wall follower {100 * mb['success']:.0f} % "
             f"({mb['steps_mean']:.0f} steps); CartPole published 500",
             f"< 8 mm: {_met(d['reach_err_mm_mean'] < 8)}; maze >= 90 %: {_met(d['maze_success_frac'] >= 0.9)}")]


def pretrain(d: dict) -> list[Row]:
    def cell(ds: str, f: str, key: str) -> str:
        v = d["table"][ds][f][key]
        return f"{sum(v) / len(v):.3f}"

    t = d["table"]
    hands = ""
    if "hands" in t:
        hands = (f"; hand photos ({d['sizes']['hands']['train']} to train) at 10 % labels: random "
                 f"{cell('hands', '0.1', 'random/tuned')}, pre-trained {cell('hands', '0.1', 'autoencoder/tuned')}")
    return [(f"`pretrain.py` seed 07's classifier, accuracy against label fraction, {d['seeds']} seeds",
             f"digits, pre-trained and fine-tuned: gain {d['gain_at_1pct']:+.3f} +- {d['gain_std_at_1pct']:.3f} at 1 % "
             f"labels, {d['gain_at_100pct']:+.3f} at 100 %; frozen features at 10 %: pre-trained "
             f"{cell('digits', '0.1', 'autoencoder/frozen')} vs random {cell('digits', '0.1', 'random/frozen')}{hands}",
             f"random initialisation, same optimiser and steps: {cell('digits', '0.01', 'random/tuned')} / "
             f"{cell('digits', '1.0', 'random/tuned')} at 1 % / 100 %",
             f"gain > 2 std at 1 %: {_met(d['gain_at_1pct'] > 2 * d['gain_std_at_1pct'])}")]


def hand_gesture(d: dict) -> list[Row]:
    a, b = d["methods"]["convexity"], d["methods"]["learned"]
    sa, sb = a["sim"], b["sim"]

    def zo(m: dict) -> str:
        z = m["zero_vs_one"]
        return f"{z['0_as_1'] + z['1_as_0']}/{z['n0'] + z['n1']}"

    rows = [(f"`hand_gesture.py` held-out simulated scenes, {d['n_per_class']} per class (14 classes)",
             f"learned 21-keypoint net: worst class {100 * sb['count_acc_min_class']:.1f} % ({sb['count_acc_min_class_named']}), "
             f"spread two {100 * sb['count_acc']['victory_spread']:.1f} %, 0-vs-1 errors {zo(sb)}; PCK@0.2 palm "
             f"{sb['pck']:.3f} ({sb['kp_err_px_median']:.2f} px median on 128 px); {d['ms_per_frame']:.1f} ms per frame",
             f"OpenCV convexity defects: worst {100 * sa['count_acc_min_class']:.1f} % ({sa['count_acc_min_class_named']}), "
             f"spread two {100 * sa['count_acc']['victory_spread']:.1f} %, 0-vs-1 errors {zo(sa)}; {sa['ms_per_frame']:.2f} ms",
             f">= 97 % every class: {_met(d['count_acc_min_class'] >= 0.97)}; PCK >= 0.9: {_met(d['pck'] >= 0.9)}; "
             f"<= 15 ms: {_met(d['ms_per_frame'] <= 15)}")]
    if b.get("real"):
        rb, ra = b["real"]["count_acc"], a["real"]["count_acc"]
        digits = [k for k in ("1", "2", "3", "4", "5") if k in rb]
        rows.append(("`hand_gesture.py` real sign-language digit photos 1-5 (60 each; evaluation only)",
                     "learned: " + " / ".join(f"{100 * rb[k]:.0f}" for k in digits) + " % for 1-5 (the sim-to-real gap)",
                     "convexity: " + " / ".join(f"{100 * ra[k]:.0f}" for k in digits) + " %",
                     "— (not tuned on them)"))
    return rows


def selfplay(d: dict) -> list[Row]:
    cpu, games = d["cpu_minutes"], d["games"]
    return [("`selfplay.py` SlimeVolley against the built-in baseline, "
             f"{d['episodes']} episodes of the original env",
             f"GA self-play (Algorithm 3, 64 disjoint pairs a round on a bit-exact numpy copy of the game): "
             f"{d['ga_selfplay_score']:+.3f} +- {d['ga_selfplay_score_std']:.3f} after {games['ga']:,} games, "
             f"{cpu['ga']:.1f} CPU min; PPO self-play (champion list) {d['ppo_selfplay_score']:+.3f}, "
             f"PPO against the baseline {d['ppo_baseline_score']:+.3f} after {cpu['ppo_baseline']:.0f} CPU min each; "
             f"best per CPU minute: {d['winner_per_cpu_minute']} (self-play: {d['selfplay_winner_per_cpu_minute']})",
             "leaderboard: GA self-play +0.353, PPO self-play -0.371, PPO +1.377",
             f"GA >= 0.35 within 2 h on 2 cores: {_met(d['ga_selfplay_score'] >= 0.35)} "
             f"(in {cpu['ga']:.0f} CPU min)")]


def captcha(d: dict) -> list[Row]:
    seeds = d.get("by_seed") or {}
    if len(seeds) > 1:              # runs of bench/captcha.py --seed K, merged: one seed says little here
        col = lambda k: " / ".join(f"{s[k]:.3f}" for s in seeds.values())     # noqa: E731
        return [(f"`captcha.py` 4-digit solver judged on {d['test_n']} held-out real captchas, training seeds "
                 + " / ".join(seeds),
                 f"trained on synthetic {col('acc_synthetic')}, on SimGAN-refined {col('acc_refined')} "
                 f"(full-captcha accuracy); {d['train_minutes']:.1f} min training per seed",
                 f"trained on the 600 real labelled captchas {col('acc_real')}",
                 f"refined >= synthetic + {d['goal_gain_points']:.0f} points: "
                 + (_met(True) if all(s["goal_met"] for s in seeds.values()) else
                    f"{_met(False)}, met on {sum(bool(s['goal_met']) for s in seeds.values())} of {len(seeds)} seeds")
                 + " (" + " / ".join(f"{s['gain_points']:+.1f}" for s in seeds.values()) + ")")]
    return [(f"`captcha.py` 4-digit solver judged on {d['test_n']} held-out real captchas",
             f"trained on synthetic {d['acc_synthetic']:.3f}, on SimGAN-refined {d['acc_refined']:.3f} "
             f"(full-captcha accuracy); {d['train_minutes']:.1f} min training ({d['cpu_minutes']:.1f} CPU min)",
             f"trained on the 600 real labelled captchas {d['acc_real']:.3f}",
             f"refined >= synthetic + {d['goal_gain_points']:.0f} points: {_met(d['goal_met'])} "
             f"({d['gain_points']:+.1f})")]


def sonar_refiner(d: dict) -> list[Row]:
    return [("`sonar_refiner.py` simulated 2 m pings against a held-out region of real M1200d pings",
             f"histogram distance {d['gap_raw']:.1f} grey levels raw -> {d['gap_refined']:.1f} SimGAN-refined "
             f"({d['gap_ratio']:.2f}x), speckle {d['speckle_gap_raw']:.3f} -> {d['speckle_gap_refined']:.3f}; "
             f"a fresh discriminator still tells them apart (AUC {d['disc_auc_raw']:.3f} -> {d['disc_auc_refined']:.3f}); "
             f"{d['ms_per_image']:.1f} ms per 1024 x 512 image; {d['train_minutes']:.1f} min training",
             f"hand rule (histogram matching): {d['gap_histmatch']:.1f} grey levels, speckle "
             f"{d['speckle_gap_histmatch']:.3f}, AUC {d['disc_auc_histmatch']:.3f}",
             f"refined gap <= half the raw one at <= 20 ms: {_met(d['goal_met'])}")]


def guard_on_walkers(d: dict) -> list[Row]:
    """The bench builds its own row (``guard_on_walkers.readme_row``); imported here only when it is formatted."""
    sys.path.insert(0, str(Path(__file__).parent))
    from guard_on_walkers import readme_row

    return [readme_row(d)]


#: bench name -> (arguments for --run, formatter)
FORMATTERS: dict[str, tuple[list[str], Callable[[dict], list[Row]]]] = {
    "rl_env": ([], rl_env),
    "rl_car": ([], rl_car),
    "ppo_target_kl": ([], ppo_target_kl),
    "pretrain": ([], pretrain),
    "hand_gesture": ([], hand_gesture),
    "selfplay": ([], selfplay),
    "captcha": ([], captcha),
    "sonar_refiner": ([], sonar_refiner),
    "set_localize": ([], set_localize),
    "winding": ([], winding),
    "ping360": ([], ping360),
    "social_nav": ([], social_nav),
    "irl_spacetime": (["--demos", "60", "--horizons", "6", "--loso"], irl_spacetime),
    "pedestrian_predict": ([], pedestrian_predict),
    "conflict_match": (["--reactive"], conflict_match),
    "guard_on_walkers": ([], guard_on_walkers),
    "nav_plan": ([], nav_plan),
    "sonar_polar": ([], sonar_polar),
    "sonar_cloud": ([], sonar_cloud),
    "sonar_two_branch": ([], sonar_two_branch),
    "sonar_carving_filter": (["--fresh", "--fresh2"], sonar_carving_filter),
    "nav_flow": ([], nav_flow),
    "transport": ([], transport),
    "sonar_icp": ([], sonar_icp),
    "sonar_pipeline": ([], sonar_pipeline),
    "pose_graph": ([], pose_graph),
    "phase_correlation": ([], phase_correlation),
    "mosaic_paper": ([], mosaic_paper),
    "sonar_mosaic": ([], sonar_mosaic),
    "dslam": ([], dslam),
    "verify": ([], verify),
    "swarm": ([], swarm),
    "chaos": ([], chaos),
    "ackermann": ([], ackermann),
    "ackermann_can": ([], ackermann_can),
    "stereo_cable": ([], stereo_cable),
    "selfcal": ([], selfcal),
    "uav_register": ([], uav_register),
}


def run(names: list[str]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name in names:
        args, _ = FORMATTERS[name]
        print(f"running bench/{name}.py --json {' '.join(args)}", file=sys.stderr, flush=True)
        out = subprocess.run([sys.executable, str(REPO / "bench" / f"{name}.py"), "--json", *args],
                             capture_output=True, text=True, cwd=REPO)
        if out.returncode != 0:
            raise SystemExit(f"bench/{name}.py failed:\n{out.stderr[-2000:]}")
        data = last_json(out.stdout)
        (OUT / f"{name}.json").write_text(json.dumps(data, indent=1))


def last_json(text: str) -> dict:
    """The JSON object a bench printed last (some print their table to stdout first)."""
    for line_start in reversed([0] + [i + 1 for i, c in enumerate(text) if c == "\n"]):
        if text.startswith("{", line_start):
            try:
                return json.loads(text[line_start:])
            except json.JSONDecodeError:
                continue
    raise ValueError("no JSON object in the bench's output")


def _table_span(lines: list[str]) -> tuple[int, int]:
    start = lines.index(HEADER)
    end = start + 2
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return start + 2, end


def _bench_of(row: str) -> str:
    cell = row.split("|")[1].strip()
    return cell.split("`")[1].removesuffix(".py") if cell.startswith("`") else ""


def rows(lines: list[str]) -> tuple[list[str], list[str]]:
    """(new table rows, benches whose rows are still typed by hand)."""
    start, end = _table_span(lines)
    out, hand, done = [], [], set()
    for row in lines[start:end]:
        name = _bench_of(row)
        path = OUT / f"{name}.json"
        if name in FORMATTERS and path.exists():
            if name not in done:
                done.add(name)
                out += ["| " + " | ".join(cells) + " |" for cells in FORMATTERS[name][1](json.loads(path.read_text()))]
            continue
        out.append(row)
        hand.append(name or row[:40])
    return out, hand


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", nargs="*", metavar="NAME", help="run these benches (default: every one with a formatter)")
    ap.add_argument("--write", action="store_true", help="rewrite README.md's table from out/bench/*.json")
    ap.add_argument("--check", action="store_true", help="exit 1 if some row is not produced by a formatter")
    args = ap.parse_args()
    if args.run is not None:
        run(args.run or list(FORMATTERS))
    lines = README.read_text().split("\n")
    new, hand = rows(lines)
    if args.write:
        start, end = _table_span(lines)
        README.write_text("\n".join(lines[:start] + new + lines[end:]))
        print(f"README: {len(new) - len(hand)} rows regenerated, {len(hand)} kept as typed", file=sys.stderr)
    if args.check or args.write or args.run is None:
        for name in dict.fromkeys(hand):
            print(f"typed by hand (no formatter or no out/bench/{name}.json): {name}")
        if args.check and hand:
            raise SystemExit(1)


if __name__ == "__main__":
    main()
