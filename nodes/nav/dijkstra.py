"""Dijkstra over an 8-connected cost grid: fast local plans and cost-to-go fields.

The grid's neighbour structure (CSR ``indptr``/``indices``, step lengths, corner cells)
is built once per grid shape in :class:`GridGraph`; a plan only gathers the edge weights
from the cell costs (one vectorised ``take``) and runs :func:`scipy.sparse.csgraph.dijkstra`
(compiled). A straight-line feasible path gives an upper bound on the answer, passed as
``limit`` so the search stops expanding beyond it — most local plans touch a fraction of
the grid.

Cost model: entering cell ``t`` from a neighbour costs ``step_len * cost[t]`` (step length
1 or sqrt(2) cells), matching the IRL cost C(s, a) = w . phi(s') of the next state. Costs
must be strictly positive (``inf`` = forbidden); a diagonal step is forbidden when either
cell it cuts past is forbidden, so paths never squeeze between two obstacles' corners.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

#: the 8 moves (d_row, d_col), in a fixed order (ties resolve the same way on every run)
MOVES = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)], dtype=np.int64)


@dataclass(frozen=True, eq=False)
class GridGraph:
    """Cached 8-neighbour structure of a ``rows x cols`` grid (build once, plan many times).

    Attributes
    ----------
    shape : (rows, cols)
    indptr, indices : CSR structure; edge ``e`` goes from cell ``src[e]`` to ``indices[e]``
        (flat indices ``row * cols + col``).
    src : (E,) int32, source cell of each edge.
    step : (E,) float64, step length in cells (1 or sqrt 2).
    side_a, side_b : (E,) int32, the two cells a diagonal edge cuts past (both = target for
        straight edges).
    move : (E,) int8, index into :data:`MOVES`.
    """

    shape: tuple[int, int]
    indptr: np.ndarray
    indices: np.ndarray
    src: np.ndarray
    step: np.ndarray
    side_a: np.ndarray
    side_b: np.ndarray
    move: np.ndarray

    @classmethod
    def of(cls, shape: tuple[int, int]) -> "GridGraph":
        """Build the structure for a grid of ``shape = (rows, cols)`` (both >= 1)."""
        rows, cols = int(shape[0]), int(shape[1])
        if rows < 1 or cols < 1:
            raise ValueError(f"grid shape must be at least 1 x 1, got {shape}")
        n = rows * cols
        r, c = np.divmod(np.arange(n, dtype=np.int64), cols)
        parts = []
        for k, (dr, dc) in enumerate(MOVES):
            rr, cc = r + dr, c + dc
            ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            s = np.flatnonzero(ok)
            t = rr[ok] * cols + cc[ok]
            a = r[ok] * cols + cc[ok]   # same row, new column
            b = rr[ok] * cols + c[ok]   # new row, same column
            if dr == 0 or dc == 0:
                a = b = t
            parts.append((s, t, a, b, np.full(s.size, np.hypot(dr, dc)), np.full(s.size, k)))
        s, t, a, b, step, move = (np.concatenate(p) for p in zip(*parts))
        order = np.lexsort((t, s))
        s, t, a, b, step, move = s[order], t[order], a[order], b[order], step[order], move[order]
        indptr = np.searchsorted(s, np.arange(n + 1)).astype(np.int32)
        return cls(shape=(rows, cols), indptr=indptr, indices=t.astype(np.int32), src=s.astype(np.int32),
                   step=step, side_a=a.astype(np.int32), side_b=b.astype(np.int32), move=move.astype(np.int8))

    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1]

    def matrix(self, cost: np.ndarray, *, reverse: bool = False) -> csr_matrix:
        """Sparse weighted adjacency for cell costs ``cost`` (rows x cols).

        ``reverse=True`` gives the transposed graph (same structure, since the neighbour
        relation is symmetric): a search from the goal then yields cost-to-go.
        """
        flat = np.asarray(cost, dtype=np.float64).reshape(-1)
        weight = self.step * flat[self.src if reverse else self.indices]
        blocked = np.isinf(flat)
        if blocked.any():
            corner = blocked[self.side_a] | blocked[self.side_b]
            weight[corner] = np.inf
        n = self.n_cells
        return csr_matrix((weight, self.indices, self.indptr), shape=(n, n))


@dataclass(frozen=True)
class PlanResult:
    """Outcome of :func:`plan_dijkstra`.

    ``cells`` is (n, 2) int (row, col) from start to goal inclusive (empty when
    unreachable); ``cost`` the path cost (inf when unreachable); ``reason`` says why not.
    """

    cells: np.ndarray
    cost: float
    reachable: bool
    reason: str = ""
    expanded: int = 0


def check_costs(cost: np.ndarray) -> np.ndarray:
    """Validate a cost grid: 2-D, strictly positive, ``inf`` allowed, no NaN; returns float64."""
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2 or cost.size == 0:
        raise ValueError(f"cost grid must be a non-empty 2-D array (rows x cols), got shape {cost.shape}")
    if np.isnan(cost).any():
        raise ValueError("cost grid contains NaN; mark forbidden cells with inf, unknown cells with a finite cost")
    if (cost <= 0).any():
        raise ValueError(f"costs must be strictly positive (got min {cost.min():.3g}); add a step cost > 0 — "
                         "zero or negative costs make loops free")
    return cost


def _cell(cell: tuple[int, int] | np.ndarray, shape: tuple[int, int], what: str) -> int:
    r, c = int(cell[0]), int(cell[1])
    if not (0 <= r < shape[0] and 0 <= c < shape[1]):
        raise ValueError(f"{what} cell {(r, c)} is outside the {shape[0]} x {shape[1]} grid; clamp it to the grid first")
    return r * shape[1] + c


def line_cells(start: tuple[int, int], goal: tuple[int, int]) -> np.ndarray:
    """An 8-connected straight-ish path from ``start`` to ``goal`` (inclusive), (n, 2) int."""
    (r0, c0), (r1, c1) = start, goal
    n = max(abs(r1 - r0), abs(c1 - c0))
    if n == 0:
        return np.array([[r0, c0]], dtype=np.int64)
    t = np.arange(n + 1) / n
    return np.stack([np.rint(r0 + t * (r1 - r0)), np.rint(c0 + t * (c1 - c0))], axis=1).astype(np.int64)


def path_cost(cost: np.ndarray, cells: np.ndarray) -> float:
    """Cost of an 8-connected cell path under the planner's cost model (start cell not counted)."""
    cells = np.asarray(cells, dtype=np.int64)
    if len(cells) < 2:
        return 0.0
    d = np.diff(cells, axis=0)
    if (np.abs(d).max(axis=1) > 1).any():
        raise ValueError("path cells must be 8-neighbours of each other")
    steps = np.hypot(d[:, 0], d[:, 1])
    c = np.asarray(cost, dtype=np.float64)
    total = float(np.sum(steps * c[cells[1:, 0], cells[1:, 1]]))
    diag = (d[:, 0] != 0) & (d[:, 1] != 0)
    if diag.any():
        a = c[cells[:-1][diag, 0], cells[1:][diag, 1]]
        b = c[cells[1:][diag, 0], cells[:-1][diag, 1]]
        if np.isinf(a).any() or np.isinf(b).any():
            return float("inf")
    return total


def plan_dijkstra(cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int], *,
                  graph: GridGraph | None = None) -> PlanResult:
    """Least-cost 8-connected path from ``start`` to ``goal`` over a cell cost grid.

    Parameters
    ----------
    cost : (rows, cols) float
        Strictly positive cost per cell per cell-length; ``inf`` forbids a cell.
    start, goal : (row, col)
        Cells inside the grid. The start cell's own cost is not counted (the robot is
        already there, even if it is marked forbidden).
    graph : GridGraph, optional
        Cached structure for ``cost.shape`` (pass one to plan repeatedly without rebuilding).

    Returns
    -------
    PlanResult
        ``reachable=False`` with a reason when the goal is forbidden or cut off; never hangs.
        Equal-cost ties resolve identically on every run (fixed edge order).
    """
    cost = check_costs(cost)
    if graph is None or graph.shape != cost.shape:
        graph = GridGraph.of(cost.shape)
    s, g = _cell(start, cost.shape, "start"), _cell(goal, cost.shape, "goal")
    goal_rc = (g // cost.shape[1], g % cost.shape[1])
    empty = np.zeros((0, 2), dtype=np.int64)
    if np.isinf(cost.flat[g]):
        return PlanResult(empty, float("inf"), False, f"goal cell {goal_rc} is inside an obstacle (infinite cost)")
    if s == g:
        return PlanResult(np.array([goal_rc], dtype=np.int64), 0.0, True)
    bound = path_cost(cost, line_cells(divmod(s, cost.shape[1]), goal_rc))
    limit = bound * (1 + 1e-9) + 1e-9 if np.isfinite(bound) else np.inf
    dist, pred = dijkstra(graph.matrix(cost), indices=s, return_predecessors=True, limit=limit)
    if not np.isfinite(dist[g]):
        return PlanResult(empty, float("inf"), False, f"goal cell {goal_rc} is not reachable from the start (walled off)",
                          int(np.isfinite(dist).sum()))
    chain = [g]
    while chain[-1] != s:
        chain.append(int(pred[chain[-1]]))
    flat = np.array(chain[::-1], dtype=np.int64)
    cells = np.stack(np.divmod(flat, cost.shape[1]), axis=1)
    return PlanResult(cells, float(dist[g]), True, "", int(np.isfinite(dist).sum()))


def cost_to_go(cost: np.ndarray, goal: tuple[int, int], *, graph: GridGraph | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Least cost from every cell to ``goal`` and each cell's next cell on that path.

    Returns
    -------
    value : (rows, cols) float
        Cost-to-go (0 at the goal, inf where the goal cannot be reached).
    successor : (rows, cols) int
        Flat index of the next cell towards the goal; the goal points to itself, cells
        that cannot reach it hold -1.
    """
    cost = check_costs(cost)
    if graph is None or graph.shape != cost.shape:
        graph = GridGraph.of(cost.shape)
    g = _cell(goal, cost.shape, "goal")
    dist, pred = dijkstra(graph.matrix(cost, reverse=True), indices=g, return_predecessors=True)
    succ = np.where(pred < 0, -1, pred).astype(np.int64)
    succ[g] = g
    return dist.reshape(cost.shape), succ.reshape(cost.shape)
