"""Local planner time vs grid size: in-place stencil Dijkstra vs scipy csgraph (graph built per call) vs pure-Python heap.

    python bench/nav_plan.py [--quick] [--json]

"previous" is the planner before the in-place weights (cached CSR structure, a new weighted
matrix from ``GridGraph.matrix`` per call, then csgraph), kept here for a before/after in the
same run. Every method runs on the same random cost grids (costs 2..12 per cell, 10 % blocked, start
and goal on opposite sides); the costs must agree exactly (checked, max relative
difference printed). The accuracy knob of a grid planner is its resolution: on an empty
room the 8-connected path is longer than the true straight line, and string pulling
removes most of that; both errors are in the table. Writes ``out/nav_plan.png``.
"""
from __future__ import annotations

import argparse
import heapq
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scipy.sparse import coo_matrix  # noqa: E402
from scipy.sparse.csgraph import dijkstra  # noqa: E402

from nodes.nav.dijkstra import (MOVES, GridGraph, _line_limit, check_costs, plan_dijkstra,  # noqa: E402
                                smooth_path)


def previous_plan(cost: np.ndarray, s: tuple[int, int], g: tuple[int, int], graph: GridGraph) -> float:
    """The planner as it was: validate, straight-line limit, a new weighted CSR per call, csgraph, backtrack."""
    cost = check_costs(cost)
    cols = cost.shape[1]
    dist, pred = dijkstra(graph.matrix(cost), indices=s[0] * cols + s[1], return_predecessors=True,
                          limit=_line_limit(cost, s, g))
    chain = [g[0] * cols + g[1]]
    while np.isfinite(dist[chain[0]]) and chain[-1] != s[0] * cols + s[1]:
        chain.append(int(pred[chain[-1]]))
    return float(dist[g[0] * cols + g[1]])


def scipy_fresh(cost: np.ndarray, s: tuple[int, int], g: tuple[int, int]) -> float:
    """The obvious scipy use: build the sparse graph from scratch on every call, then csgraph.dijkstra."""
    rows, cols = cost.shape
    r, c = np.divmod(np.arange(rows * cols), cols)
    src, dst, w = [], [], []
    for dr, dc in MOVES:
        rr, cc = r + dr, c + dc
        ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        t = rr[ok] * cols + cc[ok]
        weight = np.hypot(dr, dc) * cost.ravel()[t]
        if dr and dc:
            side = np.isinf(cost[r[ok], cc[ok]]) | np.isinf(cost[rr[ok], c[ok]])
            weight = np.where(side, np.inf, weight)
        src.append(np.flatnonzero(ok)), dst.append(t), w.append(weight)
    graph = coo_matrix((np.concatenate(w), (np.concatenate(src), np.concatenate(dst))), shape=(rows * cols,) * 2).tocsr()
    dist = dijkstra(graph, indices=s[0] * cols + s[1])
    return float(dist[g[0] * cols + g[1]])


def python_heap(cost: np.ndarray, s: tuple[int, int], g: tuple[int, int]) -> float:
    """A textbook heapq Dijkstra over the same cost model."""
    rows, cols = cost.shape
    dist = {s: 0.0}
    heap = [(0.0, s)]
    done: set[tuple[int, int]] = set()
    moves = [(int(dr), int(dc), float(np.hypot(dr, dc))) for dr, dc in MOVES]
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        done.add(u)
        if u == g:
            return d
        for dr, dc, step in moves:
            v = (u[0] + dr, u[1] + dc)
            if 0 <= v[0] < rows and 0 <= v[1] < cols:
                if dr and dc and (cost[u[0], v[1]] == np.inf or cost[v[0], u[1]] == np.inf):
                    continue
                nd = d + step * cost[v]
                if nd < dist.get(v, np.inf):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
    return float("inf")


def interleaved_ms(fns: dict, repeats: int) -> dict[str, np.ndarray]:
    """Time each function ``repeats`` times, round-robin, so that load from other processes
    on this shared machine hits every method alike (ratios stay fair). Milliseconds."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            if fn is None:
                continue
            t0 = time.perf_counter()
            fn()
            times[k].append((time.perf_counter() - t0) * 1e3)
    return {k: np.asarray(v) if v else np.array([np.nan]) for k, v in times.items()}


def grid_case(n: int, rng: np.random.Generator) -> tuple[np.ndarray, tuple[int, int], tuple[int, int]]:
    cost = rng.uniform(2.0, 12.0, (n, n))
    cost[rng.random((n, n)) < 0.10] = np.inf
    s, g = (n // 2, 0), (n // 2, n - 1)
    cost[s], cost[g] = 2.0, 2.0
    return cost, s, g


def length_error(n: int) -> tuple[float, float]:
    """Relative excess length of the 8-grid path and of its string-pulled version over the straight line."""
    cost = np.ones((n, n))
    s, g = (0, 0), (n - 1, max(1, (n - 1) // 3))     # a 1:3 slope: the worst kind for an 8-grid
    res = plan_dijkstra(cost, s, g)
    true = np.hypot(g[0] - s[0], g[1] - s[1])
    corners = smooth_path(cost, res.cells)
    pulled = float(np.sum(np.hypot(*np.diff(corners, axis=0).T)))
    return res.cost / true - 1.0, pulled / true - 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    sizes = [25, 50, 100, 200] if args.quick else [25, 50, 100, 200, 400]
    repeats = 15 if args.quick else 61
    rng = np.random.default_rng(0)
    rows, max_rel = [], 0.0
    for n in sizes:
        cost, s, g = grid_case(n, rng)
        graph = GridGraph.of(cost.shape)
        ours = plan_dijkstra(cost, s, g, graph=graph)
        ref = scipy_fresh(cost, s, g)
        py = python_heap(cost, s, g) if n <= 200 else ref
        prev = previous_plan(cost, s, g, graph)
        max_rel = max(max_rel, abs(ours.cost - ref) / ref, abs(py - ref) / ref, abs(prev - ref) / ref)
        slow_ok = n <= (100 if args.quick else 200)
        weighted = graph.matrix(cost)
        t = interleaved_ms({"ours": lambda: plan_dijkstra(cost, s, g, graph=graph),
                            "search": lambda: dijkstra(weighted, indices=s[0] * n + s[1], return_predecessors=True),
                            "previous": lambda: previous_plan(cost, s, g, graph),
                            "scipy": lambda: scipy_fresh(cost, s, g)}, repeats)
        t_py = interleaved_ms({"py": (lambda: python_heap(cost, s, g)) if slow_ok else None}, max(1, repeats // 5))["py"]
        e8, epull = length_error(n)
        rows.append(dict(n=n, ours_ms=float(np.median(t["ours"])), ours_min_ms=float(t["ours"].min()),
                         previous_ms=float(np.median(t["previous"])), search_only_ms=float(np.median(t["search"])),
                         scipy_ms=float(np.median(t["scipy"])), python_ms=float(np.median(t_py)),
                         len_err_8grid=e8, len_err_pulled=epull))
    if not args.json:
        print(f"{'grid':>9} {'ours ms':>9} {'ours min':>9} {'prev ms':>9} {'search':>7} {'scipy ms':>9} {'python ms':>10} {'x prev':>7} "
              f"{'x scipy':>8} {'x python':>9} {'8-grid len err':>15} {'pulled len err':>15}")
        for r in rows:
            print(f"{r['n']:>4}x{r['n']:<4} {r['ours_ms']:9.3f} {r['ours_min_ms']:9.3f} {r['previous_ms']:9.3f} {r['search_only_ms']:7.3f} {r['scipy_ms']:9.3f} "
                  f"{r['python_ms']:10.2f} {r['previous_ms'] / r['ours_ms']:7.2f} "
                  f"{r['scipy_ms'] / r['ours_ms']:8.2f} {r['python_ms'] / r['ours_ms']:9.1f} "
                  f"{100 * r['len_err_8grid']:14.2f}% {100 * r['len_err_pulled']:14.2f}%")
        print(f"costs agree: max relative difference {max_rel:.2e}")
        print("search = csgraph.dijkstra alone on a prebuilt weighted matrix (the floor of any csgraph planner); "
              "prev = the planner before in-place weights")
    plot(rows)
    at100 = next(r for r in rows if r["n"] == 100)
    if args.json:
        print(json.dumps({"plan_ms_100x100": round(at100["ours_ms"], 3), "plan_ms_100x100_best": round(at100["ours_min_ms"], 3),
                          "previous_ms_100x100": round(at100["previous_ms"], 3),
                          "speedup_vs_previous_100x100": round(at100["previous_ms"] / at100["ours_ms"], 2),
                          "csgraph_search_only_ms_100x100": round(at100["search_only_ms"], 3),
                          "scipy_fresh_ms_100x100": round(at100["scipy_ms"], 3),
                          "speedup_vs_scipy_100x100": round(at100["scipy_ms"] / at100["ours_ms"], 2),
                          "python_heap_ms_100x100": round(at100["python_ms"], 2),
                          "speedup_vs_python_100x100": round(at100["python_ms"] / at100["ours_ms"], 1),
                          "max_cost_rel_diff": max_rel, "goal_plan_ms_100x100": 2.0,
                          "rows": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()} for r in rows]}))


def plot(rows: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from figures import save_figure

    out = ROOT / "out"
    out.mkdir(exist_ok=True)
    cells = [r["n"] ** 2 for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for key, label in (("ours_ms", "in-place stencil + csgraph (ours)"), ("previous_ms", "previous: new weighted CSR per call"),
                       ("scipy_ms", "csgraph, graph built per call"), ("search_only_ms", "csgraph call alone (floor)"),
                       ("python_ms", "pure-Python heapq")):
        ax[0].loglog(cells, [r[key] for r in rows], "o-", label=label)
    ax[0].axhline(2.0, color="k", ls=":", label="goal: 2 ms at 100x100")
    ax[0].set_xlabel("grid cells")
    ax[0].set_ylabel("median plan time (ms)")
    ax[0].legend(fontsize=8)
    ax[0].set_title("local plan time vs grid size")
    ax[1].plot([r["n"] for r in rows], [100 * r["len_err_8grid"] for r in rows], "o-", label="8-connected path")
    ax[1].plot([r["n"] for r in rows], [100 * r["len_err_pulled"] for r in rows], "s-", label="string-pulled")
    ax[1].set_xlabel("grid side (cells)")
    ax[1].set_ylabel("path length excess over straight line (%)")
    ax[1].legend(fontsize=8)
    ax[1].set_title("geometric error (1:3 slope, empty grid)")
    save_figure(fig, out / "nav_plan.png", dpi=110)


if __name__ == "__main__":
    main()
