"""Space-time MaxEnt IRL: a walker's path over (row, col, time step) with a waiting action, learnt from tracks.

The spatial models of :mod:`nodes.nav.irl` have no time: a walker who waits a step and then
crosses a cell someone has just left looks like one who ignores that person. Here a state is
a cell *at a time step*, so features can ask "is another walker near this cell at this
moment" (others' recorded positions, not a prediction), and waiting is an action with its
own price.

Model (Ziebart et al. 2008, finite horizon, deterministic moves). From cell s at step k the
walker takes one of 9 actions (8 moves, wait) into s' at step k + 1, paying

- a move:  len(a) * (c0 + w . phi[k+1, s'])    (len 1 or sqrt 2 cells)
- a wait:  c_wait + w . phi[k+1, s]            (one cell-length of exposure to phi)

and stops (no further cost) on reaching the goal cell; it must reach it within K steps.
P(path) is proportional to exp(-cost). Parameters theta = (c0, c_wait, w_1 .. w_F) are in
units of the model's temperature (1), so only ratios such as w_near / c0 are meaningful.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

#: the 9 actions (d_row, d_col): 8 moves, then the wait (index 8)
ACTIONS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1), (0, 0)])
WAIT = 8
_LEN = np.hypot(ACTIONS[:, 0], ACTIONS[:, 1])           # move length in cells (0 for the wait)
_EXPOSURE = np.where(_LEN > 0, _LEN, 1.0)               # how much of phi an action pays
PARAM_NAMES_FIXED = ("step_cost", "wait_cost")


@dataclass(frozen=True)
class SpaceTimeDemo:
    """One demonstration.

    features : (K + 1, rows, cols, F) float, phi of each cell at each time step (step 0 is never paid).
    path : (n + 1, 2) int, the walker's cell (row, col) at steps 0 .. n; ``path[-1]`` is the goal and
        is not visited before step n; n <= K. Consecutive cells differ by at most one row and one
        column (a repeated cell is a wait).
    """

    features: np.ndarray
    path: np.ndarray

    def __post_init__(self) -> None:
        f, p = np.asarray(self.features, float), np.asarray(self.path, np.int64)
        if f.ndim != 4 or f.shape[0] < 2 or 0 in f.shape[1:3]:
            raise ValueError(f"features must be (K+1 >= 2, rows >= 1, cols >= 1, F), got shape {f.shape}")
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
            raise ValueError(f"path must be (n+1 >= 2, 2) cells, got shape {p.shape}; drop demos without a step")
        if len(p) - 1 > f.shape[0] - 1:
            raise ValueError(f"path has {len(p) - 1} steps but the horizon is {f.shape[0] - 1}; give more feature steps")
        if np.any(p < 0) or np.any(p >= f.shape[1:3]):
            raise ValueError(f"path leaves the {f.shape[1]}x{f.shape[2]} grid; widen the grid margin")
        if np.any(np.abs(np.diff(p, axis=0)) > 1):
            k = int(np.flatnonzero(np.any(np.abs(np.diff(p, axis=0)) > 1, axis=1))[0])
            raise ValueError(f"path jumps more than one cell between steps {k} and {k + 1}; resample the track "
                             "finer (smaller dt) or project it (project_cells)")
        if np.any(np.all(p[:-1] == p[-1], axis=1)):
            raise ValueError("path reaches its goal before its last step; cut it at its first arrival")
        if not np.all(np.isfinite(f)):
            raise ValueError("features must be finite")
        object.__setattr__(self, "features", f)
        object.__setattr__(self, "path", p)

    @property
    def actions(self) -> np.ndarray:
        """(n,) action index of each step."""
        d = np.diff(self.path, axis=0)
        return np.array([int(np.flatnonzero(np.all(ACTIONS == v, axis=1))[0]) for v in d])


def _shift(a: np.ndarray, dr: int, dc: int, fill: float) -> np.ndarray:
    """out[r, c] = a[r + dr, c + dc] (``fill`` off the grid); a is (..., rows, cols)."""
    out = np.full_like(a, fill)
    rows, cols = a.shape[-2:]
    rs, rd = (slice(dr, rows), slice(0, rows - dr)) if dr >= 0 else (slice(0, rows + dr), slice(-dr, rows))
    cs, cd = (slice(dc, cols), slice(0, cols - dc)) if dc >= 0 else (slice(0, cols + dc), slice(-dc, cols))
    out[..., rd, cd] = a[..., rs, cs]
    return out


def soft_policy(demo: SpaceTimeDemo, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finite-horizon soft value iteration backwards in time, to the demo's goal (its last cell).

    Returns
    -------
    log_pi : (K, 9, rows, cols) log P(action | cell, step); -inf for actions off the grid or
        that cannot reach the goal in time (and everywhere a cell cannot).
    log_z : (K + 1, rows, cols) log partition function, log sum over paths to the goal of exp(-cost).
    """
    return _soft_policy(demo.features, tuple(demo.path[-1]), theta)


def _soft_policy(f: np.ndarray, goal: tuple[int, int], theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    steps, rows, cols, nf = f.shape
    theta = np.asarray(theta, float)
    if theta.shape != (2 + nf,):
        raise ValueError(f"theta must hold step cost, wait cost and {nf} feature weights, got {theta.shape}")
    cell_cost = f @ theta[2:]                                   # (K+1, rows, cols): w . phi
    log_z = np.full((steps, rows, cols), -np.inf)
    log_z[-1][goal] = 0.0
    log_pi = np.empty((steps - 1, 9, rows, cols))
    for k in range(steps - 2, -1, -1):
        z = np.empty((9, rows, cols))
        for a, (dr, dc) in enumerate(ACTIONS):
            step = theta[1] if a == WAIT else _LEN[a] * theta[0]
            z[a] = _shift(log_z[k + 1] - _EXPOSURE[a] * cell_cost[k + 1], dr, dc, -np.inf) - step
        lz = logsumexp(z, axis=0)                              # -inf where no action reaches the goal
        with np.errstate(invalid="ignore"):
            log_pi[k] = np.where(np.isfinite(lz), z - lz, -np.inf)
        lz[goal] = 0.0                                          # arrived: stops, pays nothing more
        log_z[k] = lz
    return log_pi, log_z


def _action_terms(demo: SpaceTimeDemo, k: int, a: int, r: int, c: int) -> np.ndarray:
    """d cost / d theta of action a from (r, c) at step k."""
    dr, dc = ACTIONS[a]
    g = np.zeros(2 + demo.features.shape[3])
    g[0], g[1] = _LEN[a], float(a == WAIT)
    g[2:] = _EXPOSURE[a] * demo.features[k + 1, r + dr, c + dc]
    return g


def _path_terms(demo: SpaceTimeDemo) -> np.ndarray:
    """d cost / d theta of the demonstrated path: its summed step lengths, waits and exposure to each feature."""
    return sum(_action_terms(demo, k, a, r, c) for k, (a, (r, c)) in enumerate(zip(demo.actions, demo.path[:-1])))


def demo_nll(demo: SpaceTimeDemo, theta: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Negative log-likelihood of the demo's path, its gradient in theta, and the log policy.

    Gradient = demonstrated minus expected cost terms (forward pass from the start cell).
    """
    log_pi, log_z = soft_policy(demo, theta)
    r0, c0 = demo.path[0]
    if not np.isfinite(log_z[0, r0, c0]):
        raise ValueError("the goal cannot be reached from the start within the horizon; give more time steps")
    emp = _path_terms(demo)
    nll = float(np.asarray(theta, float) @ emp + log_z[0, r0, c0])
    f = demo.features
    steps, rows, cols, nf = f.shape
    goal = tuple(demo.path[-1])
    d = np.zeros((rows, cols))
    d[r0, c0] = 1.0
    expected = np.zeros(2 + nf)
    for k in range(steps - 1):
        if d.sum() < 1e-12:
            break
        pi = np.exp(log_pi[k])
        arrive = np.zeros((rows, cols))
        exposed = np.zeros((rows, cols))
        for a, (dr, dc) in enumerate(ACTIONS):
            flow = d * pi[a]
            expected[0] += _LEN[a] * flow.sum()
            expected[1] += flow.sum() if a == WAIT else 0.0
            moved = _shift(flow, -dr, -dc, 0.0)                 # mass now at s + (dr, dc)
            arrive += moved
            exposed += _EXPOSURE[a] * moved
        expected[2:] += np.tensordot(exposed, f[k + 1], axes=([0, 1], [0, 1]))
        arrive[goal] = 0.0                                      # absorbed
        d = arrive
    return nll, emp - expected, log_pi


@dataclass(frozen=True)
class SpaceTimeResult:
    """Learnt parameters: ``theta`` = (step cost c0, wait cost, feature weights ...), temperature 1."""

    theta: np.ndarray
    names: tuple[str, ...]
    nll_per_step: float
    iterations: int
    converged: bool

    def ratio(self, name: str) -> float:
        """A feature's weight relative to the step cost c0 (the scale-free number)."""
        return float(self.theta[self.names.index(name)] / self.theta[0])


def objective(u: np.ndarray, demos: list[SpaceTimeDemo], m: np.ndarray, *, prior: str, lam: float
              ) -> tuple[float, np.ndarray]:
    """Total NLL of theta = m @ u over ``demos`` plus a prior on the feature weights (not c0, c_wait)."""
    theta = m @ u
    total, grad = 0.0, np.zeros_like(theta)
    for demo in demos:
        nll, g, _ = demo_nll(demo, theta)
        total, grad = total + nll, grad + g
    w = theta[2:]
    if prior == "laplace":                                     # smooth |w| (weights may be negative)
        s = np.sqrt(w * w + 1e-6)
        total, grad[2:] = total + lam * float(s.sum()), grad[2:] + lam * w / s
    elif prior == "gaussian":
        total, grad[2:] = total + 0.5 * lam * float(w @ w), grad[2:] + lam * w
    else:
        raise ValueError(f"prior must be 'laplace' or 'gaussian', got {prior!r}")
    return total, m.T @ grad


def learn_spacetime(demos: list[SpaceTimeDemo], names: tuple[str, ...] | list[str], *, prior: str = "laplace",
                    lam: float = 0.5, fixed_ratios: dict[str, float] | None = None, max_iter: int = 200,
                    bound: float = 50.0) -> SpaceTimeResult:
    """Maximum-likelihood (MAP) parameters of the space-time model.

    Parameters
    ----------
    demos : demonstrations, all with F = len(names) features.
    names : the F feature names.
    prior, lam : 'laplace' (smoothed L1) or 'gaussian' (L2) on the feature weights, and its strength
        (on the summed NLL, like :func:`nodes.nav.irl.learn`).
    fixed_ratios : feature name -> weight / c0 held fixed (e.g. all 0: the shortest-path model;
        ``{"near": 2.0}``: the hand-set conflict price); c0 and the wait cost are still learnt.
    bound : |weights| and costs are bounded by this (c0 in [1e-3, bound]).

    Returns
    -------
    SpaceTimeResult with theta (2 + F,) and the training NLL per demonstrated step.
    """
    if not demos:
        raise ValueError("no demonstrations; give at least one SpaceTimeDemo")
    nf = {d.features.shape[3] for d in demos}
    if nf != {len(names)}:
        raise ValueError(f"demos have {sorted(nf)} features but {len(names)} names were given")
    fixed = dict(fixed_ratios or {})
    unknown = set(fixed) - set(names)
    if unknown:
        raise ValueError(f"fixed_ratios names {sorted(unknown)} are not features ({list(names)})")
    full = list(PARAM_NAMES_FIXED) + list(names)
    free = [n for n in full if n not in fixed]
    m = np.zeros((len(full), len(free)))
    for j, n in enumerate(free):
        m[full.index(n), j] = 1.0
    for n, ratio in fixed.items():
        m[full.index(n), 0] = ratio                            # weight = ratio * c0
    bounds = [(1e-3, bound) if n == "step_cost" else (-bound, bound) for n in free]
    u0 = np.array([1.0 if n == "step_cost" else 0.0 for n in free])
    res = minimize(lambda u: objective(u, demos, m, prior=prior, lam=lam), u0, jac=True,
                   method="L-BFGS-B", bounds=bounds, options={"maxiter": max_iter})
    theta = m @ res.x
    steps = sum(len(d.path) - 1 for d in demos)
    nll = sum(demo_nll(d, theta)[0] for d in demos) / steps
    return SpaceTimeResult(theta, tuple(full), nll, int(res.nit), bool(res.success))


def evaluate(demos: list[SpaceTimeDemo], theta: np.ndarray) -> dict[str, float]:
    """Held-out scores: NLL per demonstrated step, and action agreement (the demo's action is the most
    likely one; ties count as agreement), overall and on the demonstrated waits."""
    nll = steps = agree = waits = wait_agree = 0.0
    for d in demos:
        val, _, log_pi = demo_nll(d, theta)
        nll += val
        for k, (a, (r, c)) in enumerate(zip(d.actions, d.path[:-1])):
            hit = log_pi[k, a, r, c] >= np.max(log_pi[k, :, r, c]) - 1e-9
            steps, agree = steps + 1, agree + hit
            if a == WAIT:
                waits, wait_agree = waits + 1, wait_agree + hit
    out = {"demos": len(demos), "steps": int(steps), "nll_per_step": nll / max(steps, 1),
           "action_agreement": agree / max(steps, 1), "waits": int(waits)}
    out["wait_agreement"] = wait_agree / waits if waits else float("nan")
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}


def project_cells(cells: np.ndarray) -> tuple[np.ndarray, int]:
    """Make a resampled cell sequence (n + 1, 2) feasible: each step moves at most one row and one column
    toward the recorded cell (a walker faster than a cell per step lags and catches up). Returns the
    projected cells and how many steps had to be clipped."""
    cells = np.asarray(cells, np.int64)
    out = cells.copy()
    clipped = 0
    for k in range(1, len(cells)):
        d = cells[k] - out[k - 1]
        step = np.clip(d, -1, 1)
        clipped += int(np.any(step != d))
        out[k] = out[k - 1] + step
    return out, clipped


def near_features(centres_xy: np.ndarray, others_xy: np.ndarray, radii_m: tuple[float, ...]) -> np.ndarray:
    """(K + 1, rows, cols, len(radii)) band indicators: the nearest other walker at step k lies in
    [radii[j-1], radii[j]) m of the cell centre (radii[-1] = 0). ``centres_xy`` (rows, cols, 2) m;
    ``others_xy`` (K + 1, P, 2) m, NaN where a walker is not there at that step."""
    radii = np.asarray(radii_m, float)
    if radii.ndim != 1 or len(radii) == 0 or np.any(np.diff(radii) <= 0) or radii[0] <= 0:
        raise ValueError(f"radii_m must be increasing positive distances, got {radii_m}")
    steps, p = others_xy.shape[:2]
    rows, cols = centres_xy.shape[:2]
    out = np.zeros((steps, rows, cols, len(radii)))
    if p == 0:
        return out
    d = np.linalg.norm(centres_xy[None, :, :, None, :] - others_xy[:, None, None, :, :], axis=-1)
    nearest = np.min(np.where(np.isnan(d), np.inf, d), axis=-1)           # (K+1, rows, cols)
    lo = 0.0
    for j, hi in enumerate(radii):
        out[..., j] = (nearest >= lo) & (nearest < hi)
        lo = hi
    return out


def demo_from_track(walker_xy: np.ndarray, others_xy: np.ndarray, *, cell_m: float = 0.25, margin_m: float = 1.5,
                    radii_m: tuple[float, ...] = (0.5, 1.0)) -> tuple[SpaceTimeDemo, int]:
    """A demonstration from a walker's recorded positions at the model's time steps.

    Parameters
    ----------
    walker_xy : (n + 1, 2) m, the walker at steps 0 .. n (its position at step n is the goal).
    others_xy : (K + 1, P, 2) m, everybody else at steps 0 .. K >= n, NaN where absent.
    cell_m, margin_m : grid cell size, and how far the grid reaches beyond the walker's path (m).
        The grid's x axis points from the start to the goal (a narrow grid around the walk).
    radii_m : distance bands of the near-another-walker features.

    Returns
    -------
    (demo, clipped): ``clipped`` steps were faster than one cell and were projected (:func:`project_cells`).
    The path ends at its first arrival in the goal cell.
    """
    walker_xy, others_xy = np.asarray(walker_xy, float), np.asarray(others_xy, float)
    if walker_xy.ndim != 2 or walker_xy.shape[1] != 2 or len(walker_xy) < 2 or not np.all(np.isfinite(walker_xy)):
        raise ValueError(f"walker_xy must be finite (n+1 >= 2, 2) positions, got shape {walker_xy.shape}")
    if others_xy.ndim != 3 or others_xy.shape[2] != 2 or len(others_xy) < len(walker_xy):
        raise ValueError(f"others_xy must be (K+1 >= {len(walker_xy)}, P, 2), got shape {others_xy.shape}")
    heading = walker_xy[-1] - walker_xy[0]
    yaw = float(np.arctan2(heading[1], heading[0])) if np.hypot(*heading) > 1e-9 else 0.0
    rot = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])   # world -> walk frame
    local = (walker_xy - walker_xy[0]) @ rot.T
    lo, hi = local.min(axis=0) - margin_m, local.max(axis=0) + margin_m
    rows, cols = int(np.ceil((hi[1] - lo[1]) / cell_m)), int(np.ceil((hi[0] - lo[0]) / cell_m))
    cells = np.column_stack([(local[:, 1] - lo[1]) // cell_m, (local[:, 0] - lo[0]) // cell_m]).astype(np.int64)
    cells, clipped = project_cells(cells)
    first = int(np.flatnonzero(np.all(cells == cells[-1], axis=1))[0])
    if first == 0:
        raise ValueError("the walker ends in the cell it starts from; it demonstrates nothing")
    cells = cells[:first + 1]
    cr, cc = np.meshgrid(lo[1] + (np.arange(rows) + 0.5) * cell_m, lo[0] + (np.arange(cols) + 0.5) * cell_m,
                         indexing="ij")
    centres = np.stack([cc, cr], axis=-1)                                  # walk frame (x, y)
    others = (others_xy - walker_xy[0]) @ rot.T
    return SpaceTimeDemo(near_features(centres, others, radii_m), cells), clipped


def feature_counts(demos: list[SpaceTimeDemo], theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Summed cost terms (step length, waits, exposure to each feature) of the demonstrated paths, and
    their expectation under the model ``theta`` (same start, goal and horizon): how often walkers
    really are near someone against how often a walker of that model would be."""
    emp = np.zeros(2 + demos[0].features.shape[3]) if demos else np.zeros(2)
    exp = emp.copy()
    for d in demos:
        _, g, _ = demo_nll(d, theta)
        e = _path_terms(d)
        emp, exp = emp + e, exp + e - g
    return emp, exp


def sample_path(features: np.ndarray, start: tuple[int, int], goal: tuple[int, int], theta: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
    """A path (n + 1, 2) drawn from the model ``theta`` from ``start`` to ``goal`` over ``features``
    (K + 1, rows, cols, F): synthetic demonstrations with a known cost."""
    f = np.asarray(features, float)
    log_pi, log_z = _soft_policy(f, tuple(goal), theta)
    if not np.isfinite(log_z[0][tuple(start)]):
        raise ValueError("the goal cannot be reached from the start within the horizon; give more time steps")
    path = [np.asarray(start, np.int64)]
    for k in range(len(log_pi)):
        if tuple(path[-1]) == tuple(goal):
            break
        p = np.exp(log_pi[k][:, path[-1][0], path[-1][1]])
        path.append(path[-1] + ACTIONS[rng.choice(9, p=p / p.sum())])
    return np.array(path)
