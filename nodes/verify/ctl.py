"""CTL with fairness and knowledge: parse a formula, compute where it holds, explain why it fails.

Syntax (``parse``)::

    AG (ping -> AF (handled | dropped))      EX / AX, EF / AF, EG / AG, E[p U q], A[p U q]
    !p   p & q   p | q   p -> q   p <-> q    (also not / and / or), true, false
    K[r1] far     C[r1,r2] gathered           knowledge of agent r1; common knowledge of a group

Atomic propositions are names (``gathered``, ``queued(imager.ping)``, ``"any text"``); a
name the structure does not label is an error listing the closest known ones.

Semantics: the standard one (Clarke, Emerson, Sistla 1986) on total relations (see
:mod:`nodes.verify.kripke` for deadlocks). With fairness constraints F_1..F_k (Buchi: each
visited infinitely often) path quantifiers range over fair paths only: EG is computed
from the strongly connected components of the subgraph where its argument holds -- a
fair component is non-trivial and meets every F_i -- and EX / EU end in states that start
a fair path (``fair = EG true``). K_i p holds in s when p holds in every *reachable* state
agent i cannot tell from s (observation equivalence, the interpreted-systems semantics of
Fagin et al.); C_G p over the union of the agents' equivalences, transitively.

Seed 06 writes the box as "for all worlds t that lead to s"; Kripke semantics quantifies
over the worlds s *leads to* (s R t), which is what its own worked example uses and what
is implemented here.
"""
from __future__ import annotations

import difflib
import re
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from nodes.verify.kripke import Kripke

# -- formulas ----------------------------------------------------------------------------


@dataclass(frozen=True)
class F:
    """A formula node: ``op`` in prop, true, false, not, and, or, implies, iff, EX, AX, EF, AF, EG, AG, EU, AU, K, C."""

    op: str
    args: tuple = ()

    def __str__(self) -> str:
        o, a = self.op, self.args
        if o == "prop":
            return a[0] if re.fullmatch(r"[A-Za-z_][\w./:]*(\([^()]*\))?", a[0]) else f'"{a[0]}"'
        if o in ("true", "false"):
            return o
        if o == "not":
            return f"!{a[0]}"
        if o in ("and", "or", "implies", "iff"):
            sym = {"and": "&", "or": "|", "implies": "->", "iff": "<->"}[o]
            return f"({a[0]} {sym} {a[1]})"
        if o in ("EU", "AU"):
            return f"{o[0]}[{a[0]} U {a[1]}]"
        if o == "K":
            return f"K[{a[0]}] {a[1]}"
        if o == "C":
            return f"C[{','.join(a[0])}] {a[1]}"
        return f"{o} {a[0]}"


def prop(name: str) -> F:
    return F("prop", (name,))


TRUE, FALSE = F("true"), F("false")
_TOKEN = re.compile(r"\s*(?:(<->|->|[()\[\],!&|~])|\"([^\"]*)\"|([A-Za-z_][\w./:]*(?:\([^()]*\))?))")
_UNARY = {"AX", "EX", "AF", "EF", "AG", "EG"}


class FormulaError(ValueError):
    """A formula that does not parse, or names a proposition or agent the model does not have."""


def parse(text: str) -> F:
    """Parse a CTL(K) formula (syntax in the module docstring)."""
    tokens: list[tuple[str, str]] = []
    pos = 0
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if not m:
            raise FormulaError(f"cannot read {text[pos:pos + 20]!r} at column {pos} of {text!r}")
        sym, quoted, word = m.groups()
        tokens.append(("sym", sym) if sym else ("prop", quoted) if quoted is not None else ("word", word))
        pos = m.end()
    parser = _Parser(tokens, text)
    f = parser.iff()
    if parser.i != len(tokens):
        raise FormulaError(f"unexpected {tokens[parser.i][1]!r} in {text!r}")
    return f


class _Parser:
    def __init__(self, tokens: list[tuple[str, str]], text: str) -> None:
        self.t, self.i, self.text = tokens, 0, text

    def peek(self) -> tuple[str, str] | None:
        return self.t[self.i] if self.i < len(self.t) else None

    def take(self, value: str | None = None) -> tuple[str, str]:
        tok = self.peek()
        if tok is None or (value is not None and tok[1] != value):
            raise FormulaError(f"expected {value or 'more'} in {self.text!r}" + (f", got {tok[1]!r}" if tok else ""))
        self.i += 1
        return tok

    def iff(self) -> F:
        f = self.implies()
        while self.peek() == ("sym", "<->"):
            self.take()
            f = F("iff", (f, self.implies()))
        return f

    def implies(self) -> F:
        f = self.disj()
        if self.peek() == ("sym", "->"):
            self.take()
            return F("implies", (f, self.implies()))
        return f

    def disj(self) -> F:
        return self._left("or", "|", self.conj)

    def conj(self) -> F:
        return self._left("and", "&", self.unary)

    def _left(self, op: str, sym: str, operand) -> F:
        """``operand (sym|op operand)*``, grouped to the left."""
        f = operand()
        while self.peek() in (("sym", sym), ("word", op)):
            self.take()
            f = F(op, (f, operand()))
        return f

    def unary(self) -> F:
        kind, value = self.take()
        if (kind, value) in (("sym", "!"), ("sym", "~"), ("word", "not")):
            return F("not", (self.unary(),))
        if (kind, value) == ("sym", "("):
            f = self.iff()
            self.take(")")
            return f
        if kind == "prop":
            return prop(value)
        if kind == "sym":
            raise FormulaError(f"unexpected {value!r} in {self.text!r}")
        if value in _UNARY:
            return F(value, (self.unary(),))
        if value in ("A", "E") and self.peek() == ("sym", "["):
            self.take("[")
            left = self.iff()
            self.take("U")
            right = self.iff()
            self.take("]")
            return F(value + "U", (left, right))
        if value in ("K", "C") and self.peek() == ("sym", "["):
            self.take("[")
            agents = [self.take()[1]]
            while self.peek() == ("sym", ","):
                self.take()
                agents.append(self.take()[1])
            self.take("]")
            if value == "K" and len(agents) != 1:
                raise FormulaError(f"K takes one agent, got {agents} in {self.text!r}")
            return F(value, (agents[0] if value == "K" else tuple(agents), self.unary()))
        if value == "true":
            return TRUE
        if value == "false":
            return FALSE
        if value in ("A", "E", "U", "K", "C", "and", "or"):
            raise FormulaError(f"{value!r} is a keyword: misplaced in {self.text!r}")
        return prop(value)


# -- checking ----------------------------------------------------------------------------


@dataclass
class Result:
    """Where ``formula`` holds (``sat``), whether it holds in every initial state, and why not.

    ``trace`` is a path from a failing initial state (state names when the structure has
    them); when ``loop_start`` is set the path ends in a cycle back to ``trace[loop_start]``.
    """

    formula: str
    holds: bool
    sat: np.ndarray
    states: int
    edges: int
    seconds: float
    trace: list[object] = field(default_factory=list)
    loop_start: int | None = None
    failing_initial: int = 0

    def explain(self) -> str:
        head = (f"{self.formula}: {'holds' if self.holds else 'FAILS'} ({self.states} states, {self.edges} "
                f"transitions, {1e3 * self.seconds:.1f} ms)")
        if self.holds or not self.trace:
            return head
        lines = [head, f"counterexample from one of {self.failing_initial} failing initial states:"]
        for k, s in enumerate(self.trace):
            mark = "  <- loop starts" if k == self.loop_start else ""
            lines.append(f"  {k:3d}: {s}{mark}")
        if self.loop_start is not None:
            lines.append(f"  ... and back to step {self.loop_start} for ever")
        return "\n".join(lines)


class Checker:
    """Model checker over one structure; ``fairness`` are formulas (or (S,) bool arrays) that
    fair paths visit infinitely often. Results of subformulas are cached."""

    def __init__(self, kripke: Kripke, fairness: Sequence[F | str | np.ndarray] = ()) -> None:
        self.k = kripke
        self._cache: dict[F, np.ndarray] = {}
        self._fair_sets = [self._as_set(c) for c in fairness]
        self._fair: np.ndarray | None = None
        self._reach: np.ndarray | None = None

    def _as_set(self, c: F | str | np.ndarray) -> np.ndarray:
        if isinstance(c, np.ndarray):
            return c.astype(bool)
        return self.sat(parse(c) if isinstance(c, str) else c)

    @property
    def fair(self) -> np.ndarray:
        """States from which a fair path starts (all states without fairness constraints)."""
        if self._fair is None:
            n = self.k.n_states
            self._fair = self._eg(np.ones(n, bool)) if self._fair_sets else np.ones(n, bool)
        return self._fair

    # -- the public verb --------------------------------------------------------------
    def check(self, formula: F | str) -> Result:
        t0 = time.perf_counter()
        f = parse(formula) if isinstance(formula, str) else formula
        sat = self.sat(f)
        init = self.k.initial & self.fair if self._fair_sets else self.k.initial
        failing = np.flatnonzero(init & ~sat)
        trace: list[int] = []
        loop = None
        if len(failing):
            trace, loop = self._witness(negate(f), int(failing[0]), depth=4)
        return Result(str(f), not len(failing), sat, self.k.n_states, self.k.n_edges, time.perf_counter() - t0,
                      [self.k.name(s) for s in trace], loop, len(failing))

    def sat(self, f: F) -> np.ndarray:
        """(S,) bool: the states where ``f`` holds."""
        hit = self._cache.get(f)
        if hit is None:
            hit = self._cache[f] = self._sat(f)
        return hit

    def _sat(self, f: F) -> np.ndarray:
        o, a, n = f.op, f.args, self.k.n_states
        if o == "prop":
            if a[0] not in self.k.labels:
                close = difflib.get_close_matches(a[0], list(self.k.labels), n=3)
                known = ", ".join(sorted(self.k.labels)[:12])
                raise FormulaError(f"unknown proposition {a[0]!r}" + (f" (did you mean {', '.join(close)}?)" if close
                                                                       else f"; the model labels: {known}"))
            return self.k.labels[a[0]]
        if o == "true":
            return np.ones(n, bool)
        if o == "false":
            return np.zeros(n, bool)
        if o == "not":
            return ~self.sat(a[0])
        if o == "and":
            return self.sat(a[0]) & self.sat(a[1])
        if o == "or":
            return self.sat(a[0]) | self.sat(a[1])
        if o == "implies":
            return ~self.sat(a[0]) | self.sat(a[1])
        if o == "iff":
            return self.sat(a[0]) == self.sat(a[1])
        if o == "EX":
            return self._ex(self.sat(a[0]))
        if o == "AX":
            return ~self._ex(~self.sat(a[0]))
        if o == "EF":
            return self._eu(np.ones(n, bool), self.sat(a[0]))
        if o == "AF":
            return ~self._eg(~self.sat(a[0]))
        if o == "EG":
            return self._eg(self.sat(a[0]))
        if o == "AG":
            return ~self._eu(np.ones(n, bool), ~self.sat(a[0]))
        if o == "EU":
            return self._eu(self.sat(a[0]), self.sat(a[1]))
        if o == "AU":
            p, q = self.sat(a[0]), self.sat(a[1])
            return ~(self._eu(~q, ~p & ~q) | self._eg(~q))
        if o == "K":
            return self._knows(a[0], self.sat(a[1]))
        if o == "C":
            return self._common(a[0], self.sat(a[1]))
        raise FormulaError(f"unknown operator {o!r}")

    # -- fixpoints as graph searches ----------------------------------------------------
    def _ex(self, x: np.ndarray) -> np.ndarray:
        target = x & self.fair if self._fair_sets else x
        return np.asarray(self.k.succ @ target.astype(np.int32)).ravel() > 0

    def _eu(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """E[p U q]: backward breadth-first search from q through p states."""
        q = q & self.fair if self._fair_sets else q
        return _spread(self.k.pred, q, p)

    def _eg(self, p: np.ndarray) -> np.ndarray:
        """EG p under fairness: reach, within p, a non-trivial SCC of the p-subgraph meeting every F_i."""
        if not p.any():
            return np.zeros(self.k.n_states, bool)
        return _spread(self.k.pred, self._fair_core(p)[0], p)

    def _fair_core(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States of the p-subgraph's fair SCCs (non-trivial, meeting every F_i), the p states
        ``idx`` and each one's SCC number ``comp``."""
        idx = np.flatnonzero(p)
        sub = self.k.succ[idx][:, idx]
        ncomp, comp = csgraph.connected_components(sub, directed=True, connection="strong")
        size = np.bincount(comp, minlength=ncomp)
        loops = np.zeros(ncomp, bool)
        loops[comp[sub.diagonal() > 0]] = True
        good = (size > 1) | loops
        for fs in self._fair_sets:
            good &= np.bincount(comp[fs[idx]], minlength=ncomp) > 0
        core = np.zeros(self.k.n_states, bool)
        core[idx[good[comp]]] = True
        return core, idx, comp

    def reachable(self) -> np.ndarray:
        if self._reach is None:
            self._reach = _spread(self.k.succ, self.k.initial, np.ones(self.k.n_states, bool))
        return self._reach

    def _observation(self, agent: str) -> np.ndarray:
        obs = self.k.observations.get(agent)
        if obs is None:
            raise FormulaError(f"unknown agent {agent!r}; the model's agents: {sorted(self.k.observations) or 'none'}")
        return obs

    def _knows(self, agent: str, x: np.ndarray) -> np.ndarray:
        obs = self._observation(agent)
        bad = np.zeros(int(obs.max(initial=-1)) + 1, bool)
        bad[obs[self.reachable() & ~x]] = True
        return ~bad[obs]

    def _common(self, agents: tuple[str, ...], x: np.ndarray) -> np.ndarray:
        n = self.k.n_states
        reach = self.reachable()
        rows, cols, offset = [], [], n
        for agent in agents:
            obs = self._observation(agent)
            s = np.flatnonzero(reach)
            rows.append(s)
            cols.append(offset + obs[s])
            offset += int(obs.max(initial=-1)) + 1
        r, c = np.concatenate(rows), np.concatenate(cols)
        g = sparse.csr_matrix((np.ones(len(r), np.int8), (r, c)), shape=(offset, offset))
        _, comp = csgraph.connected_components(g, directed=False)
        bad = np.zeros(offset, bool)
        bad[comp[np.flatnonzero(reach & ~x)]] = True
        # an unreachable state's group is that of the reachable states its agents confuse it with
        out = ~bad[comp[:n]]
        for agent in agents:
            obs = self._observation(agent)
            cls_bad = np.zeros(int(obs.max(initial=-1)) + 1, bool)
            cls_bad[obs[reach & ~out]] = True
            out &= ~cls_bad[obs] | reach
        return out

    # -- witnesses and counterexamples ----------------------------------------------------
    def _witness(self, f: F, s: int, depth: int) -> tuple[list[int], int | None]:
        """A path from ``s`` showing ``f`` holds there (f is an E-form after negation)."""
        o, a = f.op, f.args
        if depth <= 0 or not self.sat(f)[s]:
            return [s], None
        if o == "or":
            pick = a[0] if self.sat(a[0])[s] else a[1]
            return self._witness(pick, s, depth)
        if o == "and":
            pick = next((g for g in a if g.op not in ("prop", "true", "false", "not")), a[0])
            return self._witness(pick, s, depth)
        if o == "EX":
            target = self.sat(a[0]) & (self.fair if self._fair_sets else True)
            t = int(next(t for t in self.k.succ[s].indices if target[t]))
            rest, loop = self._witness(a[0], t, depth - 1)
            return [s] + rest, None if loop is None else loop + 1
        if o in ("EF", "EU"):
            p = np.ones(self.k.n_states, bool) if o == "EF" else self.sat(a[0])
            goal = a[-1]
            q = self.sat(goal) & (self.fair if self._fair_sets else True)
            path = _path(self.k.succ, s, q, p)
            rest, loop = self._witness(goal, path[-1], depth - 1)
            return path[:-1] + rest, None if loop is None else loop + len(path) - 1
        if o == "EG":
            return self._lasso(s, self.sat(a[0]))
        return [s], None

    def _lasso(self, s: int, p: np.ndarray) -> tuple[list[int], int]:
        """A path from ``s`` through ``p`` into a fair cycle inside ``p`` (EG p's witness)."""
        core, idx, comp = self._fair_core(p)
        prefix = _path(self.k.succ, s, core, p)
        entry = prefix[-1]
        inside = np.zeros(self.k.n_states, bool)
        inside[idx[comp == comp[np.searchsorted(idx, entry)]]] = True
        cycle, here = [], entry
        for fs in self._fair_sets:
            if not fs[here]:
                leg = _path(self.k.succ, here, fs & inside, inside)
                cycle += leg[:-1]
                here = leg[-1]
        # close the cycle: back to the entry through at least one transition
        nxt = [int(t) for t in self.k.succ[here].indices if inside[t]]
        if entry in nxt:
            cycle.append(here)
        else:
            back = _path(self.k.succ, nxt[0], np.eye(1, self.k.n_states, entry, dtype=bool).ravel(), inside)
            cycle += [here] + back[:-1]
        return prefix[:-1] + cycle, len(prefix) - 1


def negate(f: F) -> F:
    """The negation with ``not`` pushed through the top operators (into E-forms where possible)."""
    o, a = f.op, f.args
    table = {"AG": "EF", "AF": "EG", "AX": "EX", "EF": "AG", "EG": "AF", "EX": "AX"}
    if o in table:
        return F(table[o], (negate(a[0]),))
    if o == "not":
        return a[0]
    if o == "and":
        return F("or", (negate(a[0]), negate(a[1])))
    if o == "or":
        return F("and", (negate(a[0]), negate(a[1])))
    if o == "implies":
        return F("and", (a[0], negate(a[1])))
    if o == "AU":
        p, q = a
        return F("or", (F("EU", (negate(q), F("and", (negate(p), negate(q))))), F("EG", (negate(q),))))
    if o == "true":
        return FALSE
    if o == "false":
        return TRUE
    return F("not", (f,))


# -- graph helpers -----------------------------------------------------------------------


def _gather(m: sparse.csr_matrix, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column indices of the given CSR rows, concatenated, and the row each came from."""
    start, stop = m.indptr[rows], m.indptr[rows + 1]
    counts = stop - start
    total = int(counts.sum())
    if not total:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    owner = np.repeat(np.arange(len(rows)), counts)
    offs = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return m.indices[start[owner] + offs], rows[owner]


def _spread(adj: sparse.csr_matrix, seeds: np.ndarray, through: np.ndarray) -> np.ndarray:
    """States reached from ``seeds`` along ``adj`` while staying in ``through`` (seeds always count)."""
    seen = seeds.copy()
    frontier = np.flatnonzero(seeds)
    while len(frontier):
        nxt, _ = _gather(adj, frontier)
        nxt = np.unique(nxt[through[nxt] & ~seen[nxt]])
        seen[nxt] = True
        frontier = nxt
    return seen


def _path(succ: sparse.csr_matrix, src: int, target: np.ndarray, allowed: np.ndarray) -> list[int]:
    """Shortest path from ``src`` to a ``target`` state through ``allowed`` states (src itself may be a target)."""
    if target[src]:
        return [src]
    parent = np.full(succ.shape[0], -1, np.int64)
    parent[src] = src
    frontier = np.array([src])
    while len(frontier):
        nxt, frm = _gather(succ, frontier)
        keep = (parent[nxt] < 0) & (allowed[nxt] | target[nxt])
        nxt, frm = nxt[keep], frm[keep]
        nxt, first = np.unique(nxt, return_index=True)
        parent[nxt] = frm[first]
        hit = nxt[target[nxt]]
        if len(hit):
            path = [int(hit[0])]
            while path[-1] != src:
                path.append(int(parent[path[-1]]))
            return path[::-1]
        frontier = nxt
    raise RuntimeError("no path: the witness search and the fixpoint disagree")
