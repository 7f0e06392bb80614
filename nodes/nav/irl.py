"""Inverse reinforcement learning of a grid cost C(s, a) = |a| (c0 + w . phi(s')): MAP-BIRL and MaxEnt.

MDP (Kim & Pineau 2016, section 4): states are the cells of a local grid, actions the 8
moves to a neighbour cell, and the cost of a move is its length (1 or sqrt 2 cells) times
the cost of the cell it enters, ``c0 + w . phi(s')`` with ``phi`` the cell's binary
features. A demonstration is a cell path; it ends at its last cell (the goal), or, when it
has exit cells, it leaves the grid from its last cell (see "Exits" below).

Why undiscounted, goal-terminated, strictly positive costs (the paper writes a discounted
MDP, eq. 1): with discounting and costs that can be zero or negative, the cheapest plan
for an expert standing near a cheap cell is to circle in it forever — an infinite loop
discounted to a finite total beats walking to the goal, so the learnt "optimal" policy
never reaches it and demonstrations that do reach it look irrational. We instead
terminate at the goal, do not discount, and keep every cost >= c0 > 0: the step cost c0
(``step_cost``) is fixed and the feature weights are constrained to w >= 0 (features are
>= 0). Then every loop costs something, cost-to-go is a shortest-path distance (Dijkstra,
exact, no horizon to tune) and the planner (:mod:`nodes.nav.dijkstra`) optimises exactly
the cost the learner fitted. Since the paper's features come in one-hot groups
(high/medium/low), w >= 0 loses nothing: adding a constant to a group only adds a step
cost, and the Laplace prior then pins each group's cheapest bin at 0.

Exits (the planner's local problem). The local planner (:mod:`nodes.nav.social_planner`)
does not plan to a fixed cell: it picks the cell on a rim ``subgoal_m`` ahead that minimises
cost-so-far + step cost x the distance still left to the global goal from there. A
demonstration cut to a fixed horizon and ended at its own last cell hides why the expert
went where it went: the straight line to that cell passes beside a person as often as the
expert did (measured on the oracle logs: in 4 of 102 demos the shortest path to the
demo's own end crossed more crowd than the expert), so nothing can be learnt about people.
``Demo.exit_cells`` gives the rim: for each cell the expert may leave the grid from, the
distance (cells) still left to its goal; leaving there costs that distance x the step
cost, and leaving is one more action in each rim cell. The expert then chose its exit as
well as its path, against every other way around the crowd.

MaxEnt additionally needs the path partition function sum_paths exp(-cost) to converge,
i.e. costs above the branching entropy: with 4 straight and 4 diagonal moves that holds
for every cell when 4 exp(-c0) + 4 exp(-sqrt(2) c0) < 1 (c0 > 1.77); the default c0 = 2.

The MDP itself (demos, costs, Q-values, the MaxEnt path likelihood) is :mod:`nodes.nav.irl_mdp`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from nodes.nav.dijkstra import GridGraph, path_cost, plan_dijkstra
from nodes.nav.irl_mdp import (STEP_COST, Demo, check_demo, cell_costs, cost_to_exits, maxent_demo,
                               q_values)


@dataclass(frozen=True)
class IrlResult:
    """Learnt weights (K,) for ``c0 + w . phi``, the objective reached and how."""

    weights: np.ndarray
    step_cost: float
    method: str
    objective: float
    iterations: int
    converged: bool
    message: str = ""


def _prior(w: np.ndarray, prior: str, lam: float, penalised: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Negative log prior and its gradient (w >= 0 so |w| = w for the Laplace prior).

    ``penalised`` (K,) bool leaves out weights with a flat prior (the learnt step cost).
    """
    m = np.ones_like(w) if penalised is None else np.asarray(penalised, dtype=float)
    if prior == "laplace":
        return lam * float(m @ w), lam * m
    if prior == "gaussian":
        return 0.5 * lam * float(m @ (w * w)), lam * m * w
    raise ValueError(f"prior must be 'laplace' or 'gaussian', got {prior!r}")


def birl_objective(w: np.ndarray, demos: list[Demo], *, beta: float = 1.0, step_cost: float = STEP_COST,
                   prior: str = "laplace", lam: float = 0.1, penalised: np.ndarray | None = None,
                   graphs: dict[tuple[int, int], GridGraph] | None = None, step_col: int | None = None
                   ) -> tuple[float, np.ndarray]:
    """Negative log posterior of MAP-BIRL (Choi & Kim 2011) and its (sub)gradient.

    Likelihood: Boltzmann-rational expert, P(a | s) = exp(-beta Q*(s, a)) / sum_b exp(-beta Q*(s, b)),
    Q* from the exact cost-to-go. dQ*/dw = features of the move + feature sums along the
    optimal path from its target (Q* is piecewise linear in w).
    """
    graphs = {} if graphs is None else graphs
    nll, grad = _prior(w, prior, lam, penalised)
    for demo in demos:
        shape = demo.features.shape[:2]
        graph = graphs.setdefault(shape, GridGraph.of(shape))
        q, dq, expert, _ = q_values(demo, w, step_cost, graph, step_col)
        z = -beta * q
        lse = logsumexp(z, axis=1, keepdims=True)
        p = np.exp(z - lse)
        rows = np.arange(len(expert))
        nll -= float(np.sum(z[rows, expert] - lse[:, 0]))
        grad = grad + beta * np.sum(dq[rows, expert] - np.einsum("ma,mak->mk", p, dq), axis=0)
    return nll, grad


def maxent_objective(w: np.ndarray, demos: list[Demo], *, step_cost: float = STEP_COST,
                     prior: str = "gaussian", lam: float = 0.1, penalised: np.ndarray | None = None,
                     graphs: dict[tuple[int, int], GridGraph] | None = None, step_col: int | None = None
                     ) -> tuple[float, np.ndarray]:
    """Negative log likelihood of MaxEnt IRL (Ziebart 2008), P(path) ∝ exp(-cost), plus a prior.

    Goal-terminated and undiscounted: z = A z + e_goal with A[s, s'] = exp(-C(s, s')), solved
    directly (sparse LU); the state visitation from the start solves the transposed system.
    """
    graphs = {} if graphs is None else graphs
    nll, grad = _prior(w, prior, lam, penalised)
    for demo in demos:
        shape = demo.features.shape[:2]
        part, part_grad = maxent_demo(demo, w, step_cost, graphs.setdefault(shape, GridGraph.of(shape)), step_col)
        nll += part
        grad = grad + part_grad
    return nll, grad


def learn(demos: list[Demo], *, method: str = "birl", prior: str = "laplace", lam: float = 0.1,
          beta: float = 1.0, step_cost: float = STEP_COST, learn_step_cost: bool = True,
          w_max: float = 50.0, max_iter: int = 200) -> IrlResult:
    """Learn feature weights from demonstrations by MAP-BIRL (``"birl"``) or MaxEnt (``"maxent"``).

    Parameters
    ----------
    demos : list of Demo
        Paths with at least one move (single-cell demos are skipped); all with K features.
    prior, lam : 'laplace' (L1, drives useless features to exactly 0) or 'gaussian' (L2), and its strength.
    beta : Boltzmann rationality of the expert (BIRL only).
    step_cost : floor c0 > 0 of the cost per cell length; must exceed 1.77 for MaxEnt.
    learn_step_cost : also learn an extra, unpenalised step cost b >= 0 (returned in
        ``IrlResult.step_cost = c0 + b``). Without it a one-hot group whose bins all get the
        same weight would stand in for a step cost, and the prior could not zero it.
    w_max : upper bound on each weight (keeps a never-varying or never-visited feature finite).

    Returns
    -------
    IrlResult with weights (K,) >= 0 and the total step cost.
    """
    if step_cost <= 0:
        raise ValueError(f"step_cost must be > 0 (got {step_cost}); zero costs let the expert loop for free")
    if method == "maxent" and 4 * np.exp(-step_cost) + 4 * np.exp(-np.sqrt(2) * step_cost) >= 1:
        raise ValueError(f"MaxEnt needs step_cost > 1.77 for its path sum to converge, got {step_cost}")
    if method not in ("birl", "maxent"):
        raise ValueError(f"method must be 'birl' or 'maxent', got {method!r}")
    _prior(np.zeros(1), prior, lam)
    checked = [d for d in (check_demo(d) for d in demos) if len(d.path) >= 2]
    if not checked:
        raise ValueError("no demonstration has a move; give paths of at least two distinct cells")
    ks = {d.features.shape[2] for d in checked}
    if len(ks) != 1:
        raise ValueError(f"demos disagree on the number of features: {sorted(ks)}")
    k = ks.pop()
    penalised = np.ones(k, dtype=bool)
    if learn_step_cost:
        checked = [Demo(np.concatenate([d.features, np.ones(d.features.shape[:2] + (1,))], axis=2), d.path, d.blocked,
                        d.exit_cells) for d in checked]
        penalised = np.append(penalised, False)
    graphs: dict[tuple[int, int], GridGraph] = {}
    objective = birl_objective if method == "birl" else maxent_objective
    extra = {"beta": beta} if method == "birl" else {}

    def fun(w: np.ndarray) -> tuple[float, np.ndarray]:
        return objective(w, checked, step_cost=step_cost, prior=prior, lam=lam, penalised=penalised,
                         graphs=graphs, step_col=k if learn_step_cost else None, **extra)

    res = minimize(fun, np.full(penalised.size, 0.1), jac=True, method="L-BFGS-B",
                   bounds=[(0.0, w_max)] * penalised.size, options={"maxiter": max_iter})
    w = np.clip(res.x, 0.0, w_max)
    w[w < 1e-6] = 0.0
    total_step = step_cost + (float(w[k]) if learn_step_cost else 0.0)
    return IrlResult(w[:k].copy(), total_step, method, float(res.fun), int(res.nit), bool(res.success), str(res.message))


def action_agreement(demos: list[Demo], weights: np.ndarray, *, step_cost: float = STEP_COST) -> float:
    """Expected fraction of expert moves a planner with ``weights`` repeats (ties broken at random)."""
    hits, total = 0.0, 0
    graphs: dict[tuple[int, int], GridGraph] = {}
    for demo in (check_demo(d) for d in demos):
        if len(demo.path) < 2:
            continue
        shape = demo.features.shape[:2]
        q, _, expert, _ = q_values(demo, np.asarray(weights, float), step_cost,
                                    graphs.setdefault(shape, GridGraph.of(shape)))
        best = q.min(axis=1, keepdims=True)
        optimal = q <= best + 1e-9 * np.maximum(1.0, best)
        # a tie counts as 1 / (number of equally good moves): uniform costs must not score 100 %
        hits += float(np.sum(optimal[np.arange(len(expert)), expert] / optimal.sum(axis=1)))
        total += len(expert)
    if total == 0:
        raise ValueError("no demonstration has a move to compare")
    return hits / total


def expected_value_difference(demos: list[Demo], weights: np.ndarray, true_weights: np.ndarray, *,
                              step_cost: float = STEP_COST, true_step_cost: float = STEP_COST) -> float:
    """Mean extra true cost of planning with ``weights`` instead of ``true_weights`` (>= 0, 0 = as good).

    For each demo: true cost of the path planned from its start to its goal under the
    learnt cost, minus the true optimal cost; averaged over demos.
    """
    out = []
    for demo in (check_demo(d) for d in demos):
        if len(demo.path) < 2:
            continue
        start, goal = tuple(demo.path[0]), tuple(demo.path[-1])
        true_cost = cell_costs(demo.features, true_weights, step_cost=true_step_cost, blocked=demo.blocked)
        learnt = cell_costs(demo.features, weights, step_cost=step_cost, blocked=demo.blocked)
        if demo.exit_cells is not None:
            out.append(_exit_value_difference(demo, true_cost, learnt, true_step_cost, step_cost))
            continue
        planned = plan_dijkstra(learnt, start, goal)
        optimal = plan_dijkstra(true_cost, start, goal)
        out.append(path_cost(true_cost, planned.cells) - optimal.cost)
    if not out:
        raise ValueError("no demonstration has a move to compare")
    return float(np.mean(out))


def _exit_value_difference(demo: Demo, true_cost: np.ndarray, learnt: np.ndarray, true_step: float,
                           step: float) -> float:
    """Extra true cost (walk + exit) of leaving the grid the learnt way instead of the true best way."""
    n = true_cost.size
    exits = demo.exit_cells.reshape(-1)                              # type: ignore[union-attr]
    best, _ = cost_to_exits(true_cost, demo.exit_cells * true_step)  # type: ignore[operator]
    _, succ = cost_to_exits(learnt, demo.exit_cells * step)          # type: ignore[operator]
    start = int(np.ravel_multi_index(tuple(demo.path[0]), true_cost.shape))
    walk = [start]
    while succ[walk[-1]] != n:                   # the learnt plan, up to the cell it leaves from
        if succ[walk[-1]] < 0 or len(walk) > n:
            return float("inf")
        walk.append(int(succ[walk[-1]]))
    cells = np.stack(np.unravel_index(walk, true_cost.shape), axis=1)
    return path_cost(true_cost, cells) + float(exits[walk[-1]]) * true_step - float(best.reshape(-1)[start])


#: features appended after the paper's 12 (nodes.nav.features.CONFLICT): a weights file learnt without them prices them 0
APPENDED_FEATURES = frozenset({"conflict"})


@dataclass(frozen=True)
class CostWeights:
    """What the learner writes and the cost node reads: named weights and the step cost.

    The JSON form is ``{"names": [...], "weights": [...], "step_cost": c0, ...extra}``
    (``extra`` keeps provenance and held-out metrics). Never pickled.
    """

    names: tuple[str, ...]
    weights: np.ndarray
    step_cost: float = STEP_COST
    extra: dict | None = None

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=np.float64).reshape(-1)
        if len(self.names) != w.size:
            raise ValueError(f"{w.size} weights for {len(self.names)} names; the weights file is inconsistent")
        if not np.isfinite(w).all() or (w < 0).any() or not self.step_cost > 0:
            raise ValueError("weights must be finite and >= 0 and step_cost > 0 (costs must stay strictly positive)")
        object.__setattr__(self, "weights", w)

    def to_json(self) -> str:
        body = {"names": list(self.names), "weights": [round(float(v), 6) for v in self.weights],
                "step_cost": round(float(self.step_cost), 6)}
        body.update(self.extra or {})
        return json.dumps(body, indent=2)

    @classmethod
    def from_json(cls, text: str) -> "CostWeights":
        body = json.loads(text)
        if not isinstance(body, dict) or "weights" not in body or "names" not in body:
            raise ValueError("a weights file is a JSON object with 'names', 'weights' and 'step_cost'")
        extra = {k: v for k, v in body.items() if k not in ("names", "weights", "step_cost")}
        return cls(tuple(str(n) for n in body["names"]), np.asarray(body["weights"], float),
                   float(body.get("step_cost", STEP_COST)), extra)

    def vector_for(self, names: list[str] | tuple[str, ...], k: int) -> np.ndarray:
        """Weights ordered like a grid's ``names`` (K = ``k``); by position when the grid has no names."""
        if not names:
            if k != len(self.weights):
                raise ValueError(f"grid has {k} unnamed features, weights have {len(self.weights)}")
            return self.weights
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index and n not in APPENDED_FEATURES]
        if missing:
            raise ValueError(f"no weight for features {missing}; relearn the weights for this feature layout")
        # a feature appended to the paper's 12 after a weights file was learnt weighs 0 there: the old cost, unchanged
        return np.array([self.weights[index[n]] if n in index else 0.0 for n in names])
