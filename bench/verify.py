"""Model-checking benchmark: our CTL checker against pyModelChecking on the same structures and formulas.

Models that grow: two robots gathering on a ring of n nodes under the ASYNC scheduler (the
largest of the three), and launch graphs of k nodes in a fan-out pipeline with one fault
per node. Both checkers get the very same Kripke structure (converted once, conversion
timed apart) and the same formulas, without fairness -- pyModelChecking's fair-SCC test
is wrong (see nodes/verify/peer.py) -- and must return the same satisfying *sets*, not
only the same verdict. Time is wall time, median of repeats, exploration excluded (it is
reported on its own: it is Python building the states, the same input for both).

The look-compute-move results are recomputed here too: for every algorithm on a ring of 7
and of 9, whether ``AF AG gathered`` holds with fairness under FSYNC, SSYNC and ASYNC, and
the picture of the SSYNC counterexample schedule (robots drawn on the ring step by step).

    python bench/verify.py [--quick] [--json] [--png OUT.png]

``--json`` keys: ``states_per_s`` (ours, on the largest model), ``speedup_vs_pymc`` (median
pyModelChecking time / ours on models of >= 100k states), ``agree`` (every set equal),
``rows`` (per model and formula), ``gathering`` (algorithms that gather, per scheduler).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from nodes.verify.ctl import Checker, parse  # noqa: E402
from nodes.verify.graph_model import GraphEdge, GraphNode, GraphSpec, graph_model  # noqa: E402
from nodes.verify.lcm import FAIRNESS, Algorithm, all_algorithms, gathering_model  # noqa: E402
from nodes.verify.peer import pymc_sat, to_pymc_kripke  # noqa: E402

RING_FORMULAS = ["AF AG gathered", "AG EF gathered", "E[!gathered U (gathered & idle)]", "EG !gathered",
                 "AG (gathered -> AX gathered)"]
GRAPH_FORMULAS = ["AG (published -> AF (handled(n1.x) | counted(n1.x)))", "AG EF settled", "EF dead(n1)",
                  "A[!published U up(src)]"]


def fan_out(k: int) -> GraphSpec:
    """A source feeding k - 1 subscribers, every node restarting once on failure."""
    nodes = (GraphNode("src", "on-failure", 1),) + tuple(GraphNode(f"n{i}", "on-failure", 1) for i in range(1, k))
    return GraphSpec(nodes, tuple(GraphEdge("src/out", f"n{i}", "x", depth=4) for i in range(1, k)))


def timed(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def compare(name: str, k, formulas: list[str], repeats: int) -> list[dict]:
    pk_time, pk = timed(lambda: to_pymc_kripke(k), 1)
    rows = []
    for text in formulas:
        f = parse(text)
        ours_t, ours = timed(lambda: Checker(k).sat(f), repeats)
        theirs_t, theirs = timed(lambda: pymc_sat(k, f, pk), 1 if k.n_states > 50_000 else repeats)
        agree = set(np.flatnonzero(ours).tolist()) == theirs
        rows.append({"model": name, "formula": text, "states": k.n_states, "edges": k.n_edges, "ours_s": ours_t,
                     "pymc_s": theirs_t, "pymc_convert_s": pk_time, "speedup": theirs_t / max(ours_t, 1e-9),
                     "agree": agree})
        print(f"  {name:18s} {k.n_states:8d} states  {text:52s} ours {1e3 * ours_t:8.1f} ms  "
              f"pyModelChecking {1e3 * theirs_t:9.1f} ms  x{theirs_t / max(ours_t, 1e-9):6.1f}  "
              f"{'same sets' if agree else 'DIFFERENT'}", flush=True)
    return rows


def gathering_table(ns: tuple[int, ...]) -> dict[str, dict[str, list[str]]]:
    out: dict[str, dict[str, list[str]]] = {}
    for n in ns:
        out[str(n)] = {}
        for scheduler in ("fsync", "ssync", "async"):
            algos = list(all_algorithms(n))
            ok = [str(a) for a in algos if Checker(gathering_model(n, scheduler, a), FAIRNESS)
                  .check("AF AG gathered").holds]
            out[str(n)][scheduler] = ok
            print(f"  ring {n}, {scheduler}: {len(ok)} of {len(algos)} algorithms gather {ok[:2]}", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small models only")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--png", default=str(REPO / "out" / "verify_bench.png"), help="figure")
    args = ap.parse_args()
    rings = (21, 61, 121) if args.quick else (21, 61, 121, 201, 301)
    fans = (3, 4, 5) if args.quick else (3, 4, 5, 6)
    repeats = 3 if args.quick else 5

    rows, explore = [], []
    print("gathering on a ring, ASYNC (exploration, then both checkers on the same structure):", flush=True)
    for n in rings:
        t0 = time.perf_counter()
        k = gathering_model(n, "async", Algorithm(("toward",) * (n // 2)))
        explore.append({"model": f"ring {n}", "states": k.n_states, "explore_s": time.perf_counter() - t0})
        rows += compare(f"ring {n} async", k, RING_FORMULAS, repeats)
    print("launch graphs, fan-out, one fault per node:", flush=True)
    for m in fans:
        t0 = time.perf_counter()
        k, _ = graph_model(fan_out(m), "src/out", faults=1, max_states=3_000_000)   # compared without fairness
        explore.append({"model": f"fan-out {m}", "states": k.n_states, "explore_s": time.perf_counter() - t0})
        rows += compare(f"fan-out {m} nodes", k, GRAPH_FORMULAS, repeats)

    print("which two-robot algorithms gather (AF AG gathered, fair schedulers):", flush=True)
    table = gathering_table((7, 9) if not args.quick else (7,))

    big = [r for r in rows if r["states"] >= 100_000]
    largest = max(rows, key=lambda r: r["states"])
    largest_rows = [r for r in rows if r["model"] == largest["model"]]
    result = {
        "states_per_s": largest["states"] / statistics.median(r["ours_s"] for r in largest_rows),
        "speedup_vs_pymc": statistics.median(r["speedup"] for r in big) if big else None,
        "agree": all(r["agree"] for r in rows),
        "largest_states": largest["states"],
        "explore": explore, "rows": rows, "gathering": table,
    }
    print(f"ours {result['states_per_s']:.3g} states/s on {largest['states']} states; speed-up over "
          f"pyModelChecking at >= 100k states: {result['speedup_vs_pymc']}; same sets: {result['agree']}", flush=True)
    if args.png:
        plot(Path(args.png), rows)
        print(f"figure: {args.png}")
    if args.json:
        print(json.dumps(result))


def plot(path: Path, rows: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    fig = plt.figure(figsize=(16, 8))
    ax = fig.add_subplot(2, 1, 1)
    for key, label, marker in (("ours_s", "ours (scipy sparse)", "o"), ("pymc_s", "pyModelChecking", "s")):
        for family, colour in (("ring", "C0"), ("fan-out", "C1")):
            sel = [r for r in rows if r["model"].startswith(family)]
            ax.loglog([r["states"] for r in sel], [r[key] for r in sel], marker, color=colour,
                      mfc="none" if key == "pymc_s" else colour, label=f"{label}, {family}")
    ax.set_xlabel("states")
    ax.set_ylabel("seconds per formula (median)")
    ax.set_title("CTL model checking: same structures, same formulas, same answers")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    # the SSYNC counterexample: two robots that always move toward each other never gather
    n = 7
    r = Checker(gathering_model(n, "ssync", Algorithm(("toward",) * 3)), FAIRNESS).check("AF AG gathered")
    steps = r.trace + [r.trace[r.loop_start]]
    ring = np.exp(2j * np.pi * np.arange(n) / n)
    for i, s in enumerate(steps):
        a = fig.add_subplot(2, len(steps), len(steps) + i + 1)
        a.plot(ring.real, ring.imag, "o", color="0.8", ms=10)
        a.plot(ring[s[0]].real, ring[s[0]].imag, "o", color="C3", ms=12)
        a.plot(ring[s[1]].real * 0.75, ring[s[1]].imag * 0.75, "o", color="C2", ms=12)
        who = {1: "r1 acts", 2: "r2 acts", 3: "both act"}[s[2]]
        loop = "  (loop)" if i >= r.loop_start else ""
        a.set_title(f"step {i}: {who}{loop}" if i else "start", fontsize=9)
        a.set_aspect("equal")
        a.axis("off")
    fig.text(0.5, 0.02, "SSYNC counterexample found by the checker (ring of 7, algorithm 'always toward'): "
             "adjacent robots both activated swap places for ever -- a fair schedule that never gathers "
             "(red r1 on the ring, green r2 inside)", ha="center", fontsize=9)
    save_figure(fig, path, dpi=90, rect=(0, 0.04, 1, 1))


if __name__ == "__main__":
    main()
