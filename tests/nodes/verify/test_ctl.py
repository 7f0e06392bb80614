"""The CTL checker: against pyModelChecking on its fragment, fairness against a textbook fixpoint, hard cases."""
from __future__ import annotations

import numpy as np
import pytest

from nodes.verify.ctl import Checker, FormulaError, parse
from nodes.verify.kripke import Kripke, StateBoundExceeded, explore

FORMULAS = ["AG (p -> AF q)", "E[p U q]", "A[p U q]", "EG p", "AF EG q", "EX !p & AX q", "AG EF p",
            "!E[!q U (p & !q)]", "(p <-> q) | EF (p & EG !q)", "AX AX p -> EF q"]


def random_kripke(rng: np.random.Generator) -> Kripke:
    n = int(rng.integers(2, 30))
    edges = rng.integers(0, n, (int(rng.integers(n, 3 * n)), 2))
    return Kripke.from_edges(n, edges, {"p": np.flatnonzero(rng.random(n) < 0.5),
                                        "q": np.flatnonzero(rng.random(n) < 0.4)}, [0])


def test_same_sets_as_pymodelchecking():
    pytest.importorskip("pyModelChecking")
    from nodes.verify.peer import pymc_sat, to_pymc_kripke

    rng = np.random.default_rng(7)
    for _ in range(25):
        k = random_kripke(rng)
        pk, c = to_pymc_kripke(k), Checker(k)
        for text in FORMULAS:
            f = parse(text)
            assert set(np.flatnonzero(c.sat(f)).tolist()) == pymc_sat(k, f, pk), text


def fair_eg_fixpoint(k: Kripke, p: np.ndarray, fair_sets: list[np.ndarray]) -> set[int]:
    """Emerson-Lei: Z = nu Z. p & AND_i EX E[p U (Z & F_i)], by plain set iteration."""
    succ = [set(k.succ[s].indices.tolist()) for s in range(k.n_states)]
    P = {s for s in range(k.n_states) if p[s]}
    Z = set(P)
    while True:
        new = set(P)
        for fs in fair_sets:
            target = {s for s in Z if fs[s]}
            eu = set(target)
            grow = True
            while grow:
                grow = False
                for s in P - eu:
                    if succ[s] & eu:
                        eu.add(s)
                        grow = True
            new &= {s for s in range(k.n_states) if succ[s] & eu}
        if new == Z:
            return Z
        Z = new


def test_fair_eg_agrees_with_the_emerson_lei_fixpoint():
    rng = np.random.default_rng(11)
    for _ in range(40):
        k = random_kripke(rng)
        fair = [rng.random(k.n_states) < 0.3 for _ in range(int(rng.integers(1, 3)))]
        p = k.labels["p"] | (rng.random(k.n_states) < 0.3)
        got = set(np.flatnonzero(Checker(k, fair)._eg(p)).tolist())
        assert got == fair_eg_fixpoint(k, p, fair)


def test_a_fair_cycle_without_self_loops_counts():
    """pyModelChecking's fair-SCC test rejects this two-state cycle (no self-loop); fair paths exist."""
    k = Kripke.from_edges(2, [(0, 1), (1, 0)], {"p": [0]}, [0])
    c = Checker(k, [k.labels["p"]])
    assert c.check("EG true").holds and c.check("AG AF p").holds and not c.check("AG p").holds


def test_counterexamples_are_real_paths():
    # 0 -> 1 -> 2 -> 1 (a q-free loop), 0 -> 3 (q)
    k = Kripke.from_edges(4, [(0, 1), (1, 2), (2, 1), (0, 3), (3, 3)], {"q": [3]}, [0])
    r = Checker(k).check("AF q")
    assert not r.holds and r.trace == [0, 1, 2] and r.loop_start == 1
    r = Checker(k).check("AG !q")
    assert not r.holds and r.trace == [0, 3] and r.loop_start is None
    # under fairness "visit q infinitely often" the q-free loop is not a fair path
    assert Checker(k, ["q"]).check("AF q").holds


def test_deadlocks_are_labelled_and_found():
    k = Kripke.from_edges(3, [(0, 1), (1, 2)], {}, [0])        # 2 has no successor
    r = Checker(k).check("AG !deadlock")
    assert not r.holds and r.trace == [0, 1, 2]
    assert Checker(k).check("AF AG deadlock").holds            # it stays there for ever


def test_empty_structure_and_empty_fairness():
    empty = Kripke.from_edges(0, [], {}, [])
    r = Checker(empty).check("AG false")
    assert r.holds and r.states == 0 and r.failing_initial == 0
    k = Kripke.from_edges(2, [(0, 1), (1, 0)], {"p": []}, [0])
    unfair = Checker(k, ["p"])                                 # p never holds: no path is fair
    assert not unfair.fair.any()
    assert not unfair.sat(parse("EG true")).any()


def test_formula_errors_are_clear():
    k = Kripke.from_edges(1, [(0, 0)], {"gathered": [0]}, [0])
    with pytest.raises(FormulaError, match="did you mean gathered"):
        Checker(k).check("AF gatherd")
    with pytest.raises(FormulaError, match="unknown agent"):
        Checker(k).check("K[r9] gathered")
    for bad in ("AG (", "p &", "E[p q]", "AG )"):
        with pytest.raises(FormulaError):
            parse(bad)
    assert str(parse("A[p U !q] -> K[r1] EF \"x y\"")) == '(A[p U !q] -> K[r1] EF "x y")'


def test_knowledge_over_observation_equivalence():
    # states (x, y) in {0,1}^2, all reachable; agent a sees x, agent b sees y
    states = [(x, y) for x in (0, 1) for y in (0, 1)]
    k = explore([(0, 0)], lambda s: [((s[0] + 1) % 2, s[1]), (s[0], (s[1] + 1) % 2)],
                {"x": lambda s: s[0] == 1, "y": lambda s: s[1] == 1, "both": lambda s: s == (1, 1)},
                observe={"a": lambda s: s[0], "b": lambda s: s[1]})
    c = Checker(k)
    names = list(k.names)
    assert sorted(names) == states
    kx = c.sat(parse("K[a] x"))
    assert [bool(kx[names.index(s)]) for s in states] == [s[0] == 1 for s in states]
    assert not c.sat(parse("K[a] y")).any() and not c.sat(parse("K[a] !y")).any()
    assert c.sat(parse("K[a] (x | !x)")).all()
    assert not c.sat(parse("C[a,b] x")).any() and c.sat(parse("C[a,b] (x | !x)")).all()


def test_exploration_stops_at_the_bound_with_what_it_explored():
    with pytest.raises(StateBoundExceeded) as err:
        explore([0], lambda s: [s + 1], {"p": lambda s: s % 2 == 0}, max_states=50)
    assert err.value.explored == 50 and err.value.partial.n_states == 50 and "50 states" in str(err.value)
