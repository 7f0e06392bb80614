"""Explicit-state Kripke structures as arrays, and their construction by bounded breadth-first exploration.

A structure is a successor relation in CSR form (``scipy.sparse``), one boolean array per
atomic proposition, the initial states, and optionally one observation array per agent
(state -> what that agent can tell apart, for the epistemic operator K_i). Everything the
checker does is a sparse matrix product, a breadth-first search or a strongly connected
component decomposition in scipy's compiled graph routines -- no Python loop over states.

CTL is defined on total relations. A state without a successor (a deadlock) is given a
self-loop and labelled ``deadlock``, so ``AG !deadlock`` asks for its absence and every
other formula reads the deadlock as "stays there for ever" (NuSMV's convention).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Hashable, Iterable, Mapping, Sequence

import numpy as np
from scipy import sparse

DEADLOCK = "deadlock"


@dataclass
class Kripke:
    """``succ`` (S x S CSR, s -> t), ``labels`` prop -> (S,) bool, ``initial`` (S,) bool,
    ``observations`` agent -> (S,) int (equal values: the agent cannot tell the states apart),
    ``names`` optional printable state names (for traces)."""

    succ: sparse.csr_matrix
    labels: dict[str, np.ndarray]
    initial: np.ndarray
    observations: dict[str, np.ndarray] = field(default_factory=dict)
    names: Sequence[object] | None = None

    def __post_init__(self) -> None:
        n = self.succ.shape[0]
        if self.succ.shape != (n, n):
            raise ValueError(f"successor matrix must be square, got {self.succ.shape}")
        self.initial = np.asarray(self.initial, bool)
        if self.initial.shape != (n,):
            raise ValueError(f"initial must be a ({n},) bool array")
        for name, value in self.labels.items():
            if np.shape(value) != (n,):
                raise ValueError(f"label {name!r} must be a ({n},) bool array")
        for agent, obs in self.observations.items():
            if np.shape(obs) != (n,):
                raise ValueError(f"observation of agent {agent!r} must be a ({n},) int array")
        succ = sparse.csr_matrix(self.succ, dtype=np.int8)
        succ.data[:] = 1
        dead = np.diff(succ.indptr) == 0
        if dead.any():
            idx = np.flatnonzero(dead)
            succ = (succ + sparse.csr_matrix((np.ones(len(idx), np.int8), (idx, idx)), shape=(n, n))).tocsr()
        succ.sum_duplicates()
        succ.data[:] = 1
        self.succ = succ
        self.labels = {k: np.asarray(v, bool) for k, v in self.labels.items()}
        self.labels[DEADLOCK] = dead | self.labels.get(DEADLOCK, np.zeros(n, bool))
        self._pred: sparse.csr_matrix | None = None

    @property
    def n_states(self) -> int:
        return self.succ.shape[0]

    @property
    def n_edges(self) -> int:
        return int(self.succ.nnz)

    @property
    def pred(self) -> sparse.csr_matrix:
        """Predecessor relation (the transpose, in CSR), built once."""
        if self._pred is None:
            self._pred = self.succ.T.tocsr()
        return self._pred

    def name(self, s: int) -> object:
        return self.names[s] if self.names is not None else s

    @classmethod
    def from_edges(cls, n_states: int, edges: Iterable[tuple[int, int]], labels: Mapping[str, Iterable[int]],
                   initial: Iterable[int], **kw: object) -> "Kripke":
        """Small structures by hand: edges as (s, t) pairs, labels and initial states as index lists."""
        e = np.asarray(list(edges), np.int64).reshape(-1, 2)
        succ = sparse.csr_matrix((np.ones(len(e), np.int8), (e[:, 0], e[:, 1])), shape=(n_states, n_states))
        lab = {}
        for k, idx in labels.items():
            arr = np.zeros(n_states, bool)
            arr[list(idx)] = True
            lab[k] = arr
        init = np.zeros(n_states, bool)
        init[list(initial)] = True
        return cls(succ, lab, init, **kw)


class StateBoundExceeded(RuntimeError):
    """Exploration reached ``max_states``; ``explored`` says how far it got (a partial structure)."""

    def __init__(self, explored: int, frontier: int, partial: Kripke) -> None:
        super().__init__(f"state space exceeds the bound of {explored} states ({frontier} more states were "
                         f"waiting to be expanded); raise max_states or abstract the model")
        self.explored, self.frontier, self.partial = explored, frontier, partial


def explore(initial: Iterable[Hashable], successors: Callable[[Hashable], Iterable[Hashable]],
            props: Mapping[str, Callable[[Hashable], bool]], *, max_states: int = 1_000_000,
            observe: Mapping[str, Callable[[Hashable], Hashable]] | None = None) -> Kripke:
    """Breadth-first construction from hashable states.

    ``successors(state)`` yields next states; ``props[name](state)`` labels them;
    ``observe[agent](state)`` gives what the agent sees (any hashable). Raises
    :class:`StateBoundExceeded` (carrying the partial structure) past ``max_states``.
    """
    index: dict[Hashable, int] = {}
    states: list[Hashable] = []
    rows: list[int] = []
    cols: list[int] = []
    queue: deque[int] = deque()
    for s in initial:
        if s not in index:
            index[s] = len(states)
            states.append(s)
            queue.append(index[s])
    n_init = len(states)
    exceeded = False
    while queue:
        i = queue.popleft()
        for t in successors(states[i]):
            j = index.get(t)
            if j is None:
                if len(states) >= max_states:
                    exceeded = True
                    queue.appendleft(i)
                    break
                j = index[t] = len(states)
                states.append(t)
                queue.append(j)
            rows.append(i)
            cols.append(j)
        if exceeded:
            break
    n = len(states)
    succ = sparse.csr_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    labels = {k: np.fromiter((bool(f(s)) for s in states), bool, n) for k, f in props.items()}
    obs = {}
    for agent, f in (observe or {}).items():
        codes: dict[Hashable, int] = {}
        obs[agent] = np.fromiter((codes.setdefault(f(s), len(codes)) for s in states), np.int64, n)
    init = np.zeros(n, bool)
    init[:n_init] = True
    k = Kripke(succ, labels, init, observations=obs, names=states)
    if exceeded:
        raise StateBoundExceeded(n, len(queue), k)
    return k
