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


#: bench name -> (arguments for --run, formatter)
FORMATTERS: dict[str, tuple[list[str], Callable[[dict], list[Row]]]] = {
    "set_localize": ([], set_localize),
    "winding": ([], winding),
    "ping360": ([], ping360),
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
        start = out.stdout.index("{")
        data = json.loads(out.stdout[start:])
        (OUT / f"{name}.json").write_text(json.dumps(data, indent=1))


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
