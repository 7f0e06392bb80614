"""Dijkstra over an 8-connected cost grid: fast local plans and cost-to-go fields.

The grid's neighbour structure is built once per grid shape in :class:`GridGraph`. A search
writes the edge weights in place into a CSR graph kept with it (row ``i`` = the 3 x 3
neighbourhood of cell ``i``, see :class:`_Stencil`: one strided multiply plus a scatter of
the diagonals cut by obstacles, no allocation) and runs :func:`scipy.sparse.csgraph.dijkstra`
(compiled) on it; that call is most of the time of a plan (about 1 ms for 9000 cells on a
100 x 100 grid, where a new weighted matrix per call added another 0.2-0.5 ms). A
straight-line feasible path, when there is one, gives an upper bound on the answer, passed
as ``limit`` so the search stops expanding beyond it.

Cost model: entering cell ``t`` from a neighbour costs ``step_len * cost[t]`` (step length
1 or sqrt(2) cells), matching the IRL cost C(s, a) = w . phi(s') of the next state. Costs
must be strictly positive (``inf`` = forbidden); a diagonal step is forbidden when either
cell it cuts past is forbidden, so paths never squeeze between two obstacles' corners.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.lib.stride_tricks import as_strided
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
    diag : (D,) int, indices of the diagonal edges.
    side_a, side_b : (D,) int32, the two cells each diagonal edge cuts past.
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
    diag: np.ndarray

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
        diag = np.flatnonzero(a != t)
        return cls(shape=(rows, cols), indptr=indptr, indices=t.astype(np.int32), src=s.astype(np.int32),
                   step=step, side_a=a[diag].astype(np.int32), side_b=b[diag].astype(np.int32),
                   move=move.astype(np.int8), diag=diag)

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
            weight[self.diag[blocked[self.side_a] | blocked[self.side_b]]] = np.inf
        n = self.n_cells
        return csr_matrix((weight, self.indices, self.indptr), shape=(n, n))

    @cached_property
    def _stencil(self) -> "_Stencil":
        return _Stencil(*self.shape)

    def search(self, cost: np.ndarray, source: int, *, reverse: bool = False, limit: float = np.inf
               ) -> tuple[np.ndarray, np.ndarray]:
        """Dijkstra from flat cell ``source`` over validated float64 costs (rows x cols).

        Returns (dist, pred), both (rows * cols,): the least cost (inf = unreachable or beyond
        ``limit``) and each cell's predecessor (negative where none); with ``reverse=True``
        cost-to-go to ``source`` and each cell's successor. Same weights, same edge order and
        so the same result, ties included, as ``dijkstra(self.matrix(cost, reverse=...))``.
        """
        stencil = self._stencil
        with stencil.lock:          # the weight buffer is shared by every search on this graph
            stencil.write(cost, reverse)
            return dijkstra(stencil.matrix, indices=source, return_predecessors=True, limit=limit)


#: step length of each move in a 3 x 3 neighbourhood (the centre is a self-loop, never taken)
_STEP33 = np.hypot(*np.mgrid[-1:2, -1:2]).clip(min=1.0)


class _Stencil:
    """Search workspace of one grid shape: a CSR graph with 9 entries per row, the 3 x 3
    neighbourhood of cell ``i`` in flat-index order, and the buffers its weights are written to.

    The centre and every neighbour off the grid are self-loops ``i -> i``: a positive
    self-loop never shortens a path, so Dijkstra never takes one (scipy skips edges into
    settled cells) and the real edges are scanned in the same order as in
    :meth:`GridGraph.matrix`: same distances, same predecessors, ties included. Weights are
    written in place (no allocation, hence no page faults) by one strided multiply.
    """

    def __init__(self, rows: int, cols: int) -> None:
        n = rows * cols
        self.lock = threading.Lock()
        self.cost = np.ones((rows + 2, cols + 2))          # padded costs; the border stays 1
        self.data = np.empty(9 * n)
        r, c = np.divmod(np.arange(n), cols)
        dr, dc = np.mgrid[-1:2, -1:2].reshape(2, 1, 9)
        rr, cc = r[:, None] + dr, c[:, None] + dc
        inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        indices = np.where(inside, rr * cols + cc, np.arange(n)[:, None]).astype(np.int32).ravel()
        self.matrix = csr_matrix((self.data, indices, np.arange(0, 9 * n + 1, 9, dtype=np.int32)), shape=(n, n))
        if not np.shares_memory(self.matrix.data, self.data):
            raise RuntimeError("scipy copied the CSR weights; the in-place search buffer cannot work")
        # move-major views, so that one ufunc call runs rows x cols inner loops (order="C")
        self.out = self.data.reshape(rows, cols, 3, 3).transpose(2, 3, 0, 1)
        sr, sc = self.cost.strides
        self.target = as_strided(self.cost, (3, 3, rows, cols), (sr, sc, sr, sc), writeable=False)
        self.source = self.cost[None, None, 1:-1, 1:-1]
        self.step = _STEP33[:, :, None, None]
        # the 8 diagonal edges that cut past each cell (a cell's own centre slot where the edge's
        # source is off the grid): from (r, c - dc) by (dr, dc), and from (r - dr, c) by (dr, dc)
        cut = []
        for d_r in (-1, 1):
            for d_c in (-1, 1):
                slot = (d_r + 1) * 3 + d_c + 1
                for sr_, sc_ in ((r, c - d_c), (r - d_r, c)):
                    ok = (sr_ >= 0) & (sr_ < rows) & (sc_ >= 0) & (sc_ < cols)
                    cut.append(np.where(ok, (sr_ * cols + sc_) * 9 + slot, np.arange(n) * 9 + 4))
        self.cut = np.stack(cut, axis=1).astype(np.int32)       # slots < 9 n, int32 like the CSR

    def write(self, cost: np.ndarray, reverse: bool) -> None:
        """Weights for ``cost``: step x cost of the entered cell (of the left cell if ``reverse``),
        inf for a diagonal past a forbidden cell — the very values of :meth:`GridGraph.matrix`."""
        np.copyto(self.cost[1:-1, 1:-1], cost)
        np.multiply(self.source if reverse else self.target, self.step, out=self.out, order="C")
        blocked = np.flatnonzero(np.isinf(cost))
        if blocked.size:
            self.data[self.cut[blocked].reshape(-1)] = np.inf


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
    if (cost > 0).all():            # one pass for the common case (NaN fails it too)
        return cost
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


def smooth_path(cost: np.ndarray, cells: np.ndarray, *, tolerance: float = 0.02) -> np.ndarray:
    """String-pull an 8-connected path: keep only the corners, (m, 2) cells with m <= n.

    From each kept cell, jump to the farthest later cell whose straight line costs no more
    than ``1 + tolerance`` times the path between them. Dijkstra on an 8-grid has many
    equal-cost staircases (straight-then-diagonal or diagonal-then-straight); the straight
    line picks the one a person would walk, which matters for the first waypoint: it makes
    the robot start turning away early instead of driving straight at the obstacle.
    """
    cells = np.asarray(cells, np.int64).reshape(-1, 2)
    if len(cells) <= 2:
        return cells
    d = np.diff(cells, axis=0)
    step = np.hypot(d[:, 0], d[:, 1]) * np.asarray(cost, float)[cells[1:, 0], cells[1:, 1]]
    along = np.concatenate([[0.0], np.cumsum(step)])
    keep, i = [0], 0
    while i < len(cells) - 1:
        j = len(cells) - 1
        while j > i + 1:
            line = path_cost(cost, line_cells(tuple(cells[i]), tuple(cells[j])))
            if line <= (along[j] - along[i]) * (1 + tolerance) + 1e-9:
                break
            j -= 1
        keep.append(j)
        i = j
    return cells[keep]


def _line_limit(cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> float:
    """Search limit: the cost of the straight line when it is free (a feasible path, so an upper
    bound on the optimum; a hair above it so that rounding cannot cut the optimum), else inf."""
    line = line_cells(start, goal)
    if np.isinf(cost[line[1:, 0], line[1:, 1]]).any():      # the common case in clutter: no bound
        return float("inf")
    bound = path_cost(cost, line)
    return bound * (1 + 1e-9) + 1e-9 if np.isfinite(bound) else float("inf")


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
    dist, pred = graph.search(cost, s, limit=_line_limit(cost, divmod(s, cost.shape[1]), goal_rc))
    expanded = int(np.count_nonzero(dist < np.inf))
    if not dist[g] < np.inf:
        return PlanResult(empty, float("inf"), False, f"goal cell {goal_rc} is not reachable from the start (walled off)",
                          expanded)
    back, cur, chain = memoryview(pred), g, [g]        # memoryview: plain ints, fastest scalar reads
    while cur != s:
        cur = back[cur]
        chain.append(cur)
    flat = np.array(chain[::-1], dtype=np.int64)
    cells = np.stack(np.divmod(flat, cost.shape[1]), axis=1)
    return PlanResult(cells, float(dist[g]), True, "", expanded)


def cost_from(cost: np.ndarray, start: tuple[int, int], *, graph: GridGraph | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Least cost from ``start`` to every cell, (rows, cols) (inf = unreachable), and the predecessor
    of each cell (flat index, -1 at the start and unreachable cells); see :func:`backtrack`."""
    cost = check_costs(cost)
    if graph is None or graph.shape != cost.shape:
        graph = GridGraph.of(cost.shape)
    s = _cell(start, cost.shape, "start")
    dist, pred = graph.search(cost, s)
    return dist.reshape(cost.shape), np.where(pred < 0, -1, pred).astype(np.int64).reshape(cost.shape)


def backtrack(pred: np.ndarray, goal: tuple[int, int]) -> np.ndarray:
    """Cells (n, 2) from the search's start to ``goal`` following ``pred`` from :func:`cost_from`."""
    cols = pred.shape[1]
    chain = [int(goal[0]) * cols + int(goal[1])]
    while pred.flat[chain[-1]] >= 0:
        chain.append(int(pred.flat[chain[-1]]))
        if len(chain) > pred.size:
            raise ValueError("predecessor array has a cycle; it does not come from cost_from")
    return np.stack(np.divmod(np.array(chain[::-1], dtype=np.int64), cols), axis=1)


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
    dist, pred = graph.search(cost, g, reverse=True)
    succ = np.where(pred < 0, -1, pred).astype(np.int64)
    succ[g] = g
    return dist.reshape(cost.shape), succ.reshape(cost.shape)
