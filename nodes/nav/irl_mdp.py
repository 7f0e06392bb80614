"""The IRL grid MDP (see :mod:`nodes.nav.irl`): demonstrations, cell costs, exact Q-values and
their gradients, the MaxEnt path likelihood; shared by the learners and their scores.

States are the cells of a local grid, actions the 8 moves to a neighbour (and, for a demo
with exit cells, leaving the grid); a move costs its length times ``c0 + w . phi`` of the
cell it enters. Cost-to-go is exact (Dijkstra), so Q* is piecewise linear in w.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix, identity
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import spsolve

from nodes.nav.dijkstra import MOVES, GridGraph, cost_to_go

STEP_COST = 2.0
_STEP = np.hypot(MOVES[:, 0], MOVES[:, 1])
_MOVE_INDEX = np.array([0, 1, 2, 3, -1, 4, 5, 6, 7])   # (d_row + 1) * 3 + (d_col + 1) -> index in MOVES


@dataclass(frozen=True)
class Demo:
    """One demonstration: a cell path over a feature grid.

    ``features`` (rows, cols, K) >= 0 (binary in the paper); ``path`` (n, 2) int (row, col)
    of successive 8-neighbour cells, the last one being the goal; ``blocked`` (rows, cols)
    bool marks forbidden cells (static obstacles), or None. ``exit_cells`` (rows, cols) float:
    where the expert may leave the grid, the distance (cells) still left to its goal from
    there, ``inf`` elsewhere; the path's last cell must be one. None: the last cell is the goal.
    """

    features: np.ndarray
    path: np.ndarray
    blocked: np.ndarray | None = None
    exit_cells: np.ndarray | None = None


def check_demo(demo: Demo) -> Demo:
    """Validate and normalise a demo (drops repeated cells); raise ``ValueError`` saying what is wrong."""
    f = np.asarray(demo.features, dtype=np.float64)
    if f.ndim != 3 or f.shape[0] < 1 or f.shape[1] < 1:
        raise ValueError(f"demo features must be rows x cols x K, got shape {f.shape}")
    if not np.isfinite(f).all() or (f < 0).any():
        raise ValueError("demo features must be finite and >= 0 (binary feature bins)")
    p = np.asarray(demo.path, dtype=np.int64).reshape(-1, 2)
    if len(p) and ((p < 0).any() or (p[:, 0] >= f.shape[0]).any() or (p[:, 1] >= f.shape[1]).any()):
        raise ValueError(f"demo path leaves the {f.shape[0]} x {f.shape[1]} grid; clip or split the path first")
    if len(p) > 1:
        keep = np.concatenate([[True], (np.diff(p, axis=0) != 0).any(axis=1)])
        p = p[keep]
    if len(p) > 1 and (np.abs(np.diff(p, axis=0)).max(axis=1) > 1).any():
        raise ValueError("demo path cells must be 8-neighbours; resample the track at the grid resolution")
    blocked = None if demo.blocked is None else np.asarray(demo.blocked, dtype=bool)
    if blocked is not None:
        if blocked.shape != f.shape[:2]:
            raise ValueError(f"blocked mask shape {blocked.shape} != grid shape {f.shape[:2]}")
        if len(p) and blocked[p[:, 0], p[:, 1]].any():
            raise ValueError("demo path crosses a blocked cell; the map and the path disagree")
    exits = None if demo.exit_cells is None else np.asarray(demo.exit_cells, dtype=np.float64)
    if exits is not None:
        if exits.shape != f.shape[:2] or np.isnan(exits).any() or (exits < 0).any():
            raise ValueError(f"exit_cells must be a {f.shape[:2]} grid of distances >= 0 (inf = no exit), no NaN")
        if len(p) and not np.isfinite(exits[p[-1, 0], p[-1, 1]]):
            raise ValueError("a demo with exit cells must end on one: cut the path where it first reaches them")
    return Demo(f, p, blocked, exits)


def cell_costs(features: np.ndarray, weights: np.ndarray, *, step_cost: float = STEP_COST,
               blocked: np.ndarray | None = None) -> np.ndarray:
    """Per-cell cost ``step_cost + features @ weights`` (rows, cols); ``inf`` where blocked.

    Strictly positive whenever ``step_cost > 0`` and weights, features >= 0.
    """
    w = np.asarray(weights, dtype=np.float64)
    f = np.asarray(features, dtype=np.float64)
    if f.shape[-1] != w.size:
        raise ValueError(f"{w.size} weights for {f.shape[-1]} features; the weights file does not match this grid")
    cost = step_cost + f @ w
    if blocked is not None:
        cost = np.where(blocked, np.inf, cost)
    return cost


def _neighbours(shape: tuple[int, int], cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Target cells (m, 8, 2) of the 8 moves from ``cells`` (m, 2), and which are in the grid."""
    t = cells[:, None, :] + MOVES[None, :, :]
    ok = (t[..., 0] >= 0) & (t[..., 0] < shape[0]) & (t[..., 1] >= 0) & (t[..., 1] < shape[1])
    return np.where(ok[..., None], t, 0), ok


def _path_features(succ: np.ndarray, cost_feat: np.ndarray, step_of: np.ndarray, goal: int,
                   leave: np.ndarray | None = None) -> np.ndarray:
    """Feature sums along each cell's optimal path to the goal, by pointer doubling (N, K).

    ``leave`` (N, K): the features of a node's own step when that step is to the goal
    (the exit features of a rim cell whose successor is the virtual exit node).
    """
    nxt = np.where(succ < 0, goal, succ)
    acc = step_of[:, None] * cost_feat[nxt]
    acc[nxt == np.arange(nxt.size)] = 0.0
    acc[succ < 0] = 0.0
    if leave is not None:
        to_goal = (nxt == goal) & (np.arange(nxt.size) != goal) & (succ >= 0)
        acc[to_goal] = leave[to_goal]
    for _ in range(int(np.log2(max(nxt.size, 2))) + 2):   # a shortest-path tree is at most N deep
        if (nxt == goal).all():
            break
        acc = acc + acc[nxt]
        nxt = nxt[nxt]
    return acc


def cost_to_exits(cost: np.ndarray, exit_cost: np.ndarray, *, graph: GridGraph | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Least cost from every cell to leave the grid (walk, then pay ``exit_cost`` where leaving).

    ``exit_cost`` (rows, cols): the price of leaving from each cell, ``inf`` where one cannot.
    Returns value (rows, cols), inf where no exit is reachable, and each cell's successor as a
    flat index, ``rows * cols`` (the virtual exit node) for a cell that best leaves right there
    and -1 where no exit is reachable. Dijkstra from a virtual exit node over the reversed graph.
    """
    cost = np.asarray(cost, dtype=np.float64)
    graph = graph if graph is not None and graph.shape == cost.shape else GridGraph.of(cost.shape)
    n = graph.n_cells
    ex = np.asarray(exit_cost, dtype=np.float64).reshape(-1)
    term = np.flatnonzero(np.isfinite(ex))
    if not len(term):
        raise ValueError("no exit cell: give exit_cost finite somewhere (or use cost_to_go with a goal)")
    m = graph.matrix(cost, reverse=True).tocoo()
    # + 1e-12: an explicit zero-weight edge must stay an edge
    rows = np.concatenate([m.row, np.full(term.size, n)])
    cols = np.concatenate([m.col, term])
    data = np.concatenate([m.data, ex[term] + 1e-12])
    keep = np.isfinite(data)
    big = csr_matrix((data[keep], (rows[keep], cols[keep])), shape=(n + 1, n + 1))
    dist, pred = dijkstra(big, indices=n, return_predecessors=True)
    succ = np.where(pred < 0, -1, pred).astype(np.int64)[:n]
    return dist[:n].reshape(cost.shape), succ


def exit_terms(demo: Demo, w: np.ndarray, step_cost: float, step_col: int | None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Exit cost (rows * cols,) and its gradient (rows * cols, K): distance left x the total step cost."""
    dist = demo.exit_cells.reshape(-1)                            # type: ignore[union-attr]
    total = step_cost + (float(w[step_col]) if step_col is not None else 0.0)
    grad = np.zeros((dist.size, w.size))
    if step_col is not None:
        grad[:, step_col] = np.where(np.isfinite(dist), dist, 0.0)
    return dist * total, grad


def q_values(demo: Demo, w: np.ndarray, step_cost: float, graph: GridGraph, step_col: int | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Q (m, 9), dQ/dw (m, 9, K) for every action from each path cell, expert action index (m,).

    Actions 0..7 are the moves of :data:`MOVES`, 8 is leaving the grid (only where the demo
    has exit cells; its Q is inf elsewhere). ``step_col``: the feature column that is the
    learnt extra step cost (all ones), which also prices the distance left after an exit.
    """
    if demo.exit_cells is not None:
        return q_values_exits(demo, w, step_cost, graph, step_col)
    f = demo.features
    shape = f.shape[:2]
    cost = cell_costs(f, w, step_cost=step_cost, blocked=demo.blocked)
    goal = tuple(demo.path[-1])
    value, succ = cost_to_go(cost, goal, graph=graph)
    flat_f = f.reshape(-1, f.shape[2])
    flat_succ = succ.reshape(-1)
    d = np.stack(np.divmod(np.maximum(flat_succ, 0), shape[1]), axis=1) - np.stack(
        np.divmod(np.arange(flat_succ.size), shape[1]), axis=1)
    along = _path_features(flat_succ, flat_f, np.hypot(d[:, 0], d[:, 1]), goal[0] * shape[1] + goal[1])
    cells = demo.path[:-1]
    tgt, ok = _neighbours(shape, cells)
    tflat = tgt[..., 0] * shape[1] + tgt[..., 1]
    corner_a = cost[cells[:, None, 0], tgt[..., 1]]
    corner_b = cost[tgt[..., 0], cells[:, None, 1]]
    q = _STEP[None, :] * cost.reshape(-1)[tflat] + value.reshape(-1)[tflat]
    q = np.where(ok & np.isfinite(corner_a) & np.isfinite(corner_b), q, np.inf)
    dq = _STEP[None, :, None] * flat_f[tflat] + along[tflat]
    move = demo.path[1:] - cells
    expert = _MOVE_INDEX[(move[:, 0] + 1) * 3 + move[:, 1] + 1]
    q = np.concatenate([q, np.full((len(cells), 1), np.inf)], axis=1)
    dq = np.concatenate([dq, np.zeros((len(cells), 1, dq.shape[2]))], axis=1)
    return q, dq, expert, value


def q_values_exits(demo: Demo, w: np.ndarray, step_cost: float, graph: GridGraph, step_col: int | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`q_values` for a demo that leaves the grid: every path cell, then leaving from the last."""
    f = demo.features
    shape = f.shape[:2]
    n = shape[0] * shape[1]
    cost = cell_costs(f, w, step_cost=step_cost, blocked=demo.blocked)
    exit_cost, exit_grad = exit_terms(demo, w, step_cost, step_col)
    value, succ = cost_to_exits(cost, exit_cost.reshape(shape), graph=graph)
    flat_f = np.vstack([f.reshape(n, -1), np.zeros((1, f.shape[2]))])
    node = np.arange(n)
    nxt = np.where((succ < 0) | (succ == n), node, succ)
    d = np.stack(np.divmod(nxt, shape[1]), axis=1) - np.stack(np.divmod(node, shape[1]), axis=1)
    along = _path_features(np.append(succ, n), flat_f, np.append(np.hypot(d[:, 0], d[:, 1]), 0.0), n,
                           leave=np.vstack([exit_grad, np.zeros((1, f.shape[2]))]))[:n]
    cells = demo.path
    tgt, ok = _neighbours(shape, cells)
    tflat = tgt[..., 0] * shape[1] + tgt[..., 1]
    corner_a = cost[cells[:, None, 0], tgt[..., 1]]
    corner_b = cost[tgt[..., 0], cells[:, None, 1]]
    flat_v = value.reshape(-1)
    q = _STEP[None, :] * cost.reshape(-1)[tflat] + flat_v[tflat]
    q = np.where(ok & np.isfinite(corner_a) & np.isfinite(corner_b), q, np.inf)
    here = cells[:, 0] * shape[1] + cells[:, 1]
    q = np.concatenate([q, exit_cost[here][:, None]], axis=1)
    dq = np.concatenate([_STEP[None, :, None] * flat_f[tflat] + along[tflat], exit_grad[here][:, None, :]], axis=1)
    move = demo.path[1:] - demo.path[:-1]
    expert = np.append(_MOVE_INDEX[(move[:, 0] + 1) * 3 + move[:, 1] + 1], 8)
    return q, dq, expert, value


def maxent_demo(demo: Demo, w: np.ndarray, step_cost: float, g: GridGraph,
                 step_col: int | None = None) -> tuple[float, np.ndarray]:
    """MaxEnt negative log likelihood of one demo path and its gradient.

    A path ends at the goal (the demo's last cell, absorbing) or, with exit cells, by leaving
    the grid from any exit cell and paying its exit cost there (a rim cell can also be
    walked through).
    """
    f = demo.features
    shape = f.shape[:2]
    n = g.n_cells
    start, last = (int(c[0] * shape[1] + c[1]) for c in (demo.path[0], demo.path[-1]))
    cost = cell_costs(f, w, step_cost=step_cost, blocked=demo.blocked)
    weight = g.matrix(cost).data
    if demo.exit_cells is None:
        exit_cost, exit_grad = np.full(n, np.inf), np.zeros((n, f.shape[2]))
        exit_cost[last] = 0.0
        value = cost_to_go(cost, divmod(last, shape[1]), graph=g)[0].reshape(-1)
        absorbing = g.src == last
    else:
        exit_cost, exit_grad = exit_terms(demo, w, step_cost, step_col)
        value = cost_to_exits(cost, exit_cost.reshape(shape), graph=g)[0].reshape(-1)
        absorbing = np.zeros(g.src.size, bool)
    # z(s) = sum over paths out of s of exp(-cost) underflows for long or costly paths;
    # solve for y(s) = z(s) exp(V(s)) instead, V the hard cost-to-go: the same linear system
    # up to a diagonal scaling, with every coefficient exp(-(C + V(s') - V(s))) in [0, 1].
    ok = np.isfinite(value[g.src]) & np.isfinite(value[g.indices]) & np.isfinite(weight) & ~absorbing
    coef = np.zeros_like(weight)
    coef[ok] = np.exp(-(weight[ok] + value[g.indices[ok]] - value[g.src[ok]]))
    leave = np.isfinite(exit_cost) & np.isfinite(value)
    rhs = np.zeros(n)
    rhs[leave] = np.exp(-(exit_cost[leave] - value[leave]))
    a = csr_matrix((coef, g.indices, g.indptr), shape=(n, n))
    eye = identity(n, format="csc")
    y = spsolve((eye - a).tocsc(), rhs)
    if not np.all(np.isfinite(y)) or y[start] <= 0:
        raise ValueError("MaxEnt partition function diverged; raise step_cost (needs > 1.77)")
    safe_y = np.where(y > 0, y, 1.0)
    p_edge = np.where(ok, coef * y[g.indices] / safe_y[g.src], 0.0)
    visits = spsolve((eye - csr_matrix((p_edge, (g.indices, g.src)), shape=(n, n))).tocsc(),
                     np.eye(1, n, start).ravel())
    flat_f = f.reshape(n, -1)
    expected = (visits[g.src] * p_edge * g.step) @ flat_f[g.indices] + (visits * rhs / safe_y) @ exit_grad
    d = np.diff(demo.path, axis=0)
    steps = np.hypot(d[:, 0], d[:, 1])
    nxt = demo.path[1:, 0] * shape[1] + demo.path[1:, 1]
    expert = steps @ flat_f[nxt] + exit_grad[last]
    nll = (float(np.sum(steps * cost.reshape(-1)[nxt])) + float(exit_cost[last]) + float(np.log(y[start]))
           - float(value[start]))
    return nll, expert - expected
