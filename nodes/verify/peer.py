"""Our structures and formulas in pyModelChecking's terms, to cross-check the checker (test and bench only).

pyModelChecking is the peer on its CTL fragment without fairness. Two of its defects are
known and measured in ``tests/nodes/verify/test_ctl.py``: its LTL and CTL* modules return
wrong sets, and its fair-SCC test rejects every strongly connected component whose first
state has no self-loop (``Kripke.get_fair_states``), so its fair CTL is not a reference
either. Fairness is cross-checked by other means (brute-force lassos in the tests).
"""
from __future__ import annotations

from nodes.verify.ctl import F
from nodes.verify.kripke import Kripke


def to_pymc_kripke(k: Kripke):
    from pyModelChecking import Kripke as PKripke

    succ = k.succ.tocoo()
    labels = {s: set() for s in range(k.n_states)}
    for name, arr in k.labels.items():
        for s in arr.nonzero()[0]:
            labels[int(s)].add(name)
    return PKripke(S=list(range(k.n_states)), S0=[int(s) for s in k.initial.nonzero()[0]],
                   R=list(zip(succ.row.tolist(), succ.col.tolist())), L=labels)


def to_pymc_formula(f: F):
    from pyModelChecking import CTL as C

    o, a = f.op, f.args
    if o == "prop":
        return C.AtomicProposition(a[0])
    if o in ("true", "false"):
        return C.Bool(o == "true")
    if o == "not":
        return C.Not(to_pymc_formula(a[0]))
    if o in ("and", "or", "implies"):
        cls = {"and": C.And, "or": C.Or, "implies": C.Imply}[o]
        return cls(to_pymc_formula(a[0]), to_pymc_formula(a[1]))
    if o == "iff":
        p, q = to_pymc_formula(a[0]), to_pymc_formula(a[1])
        return C.Or(C.And(p, q), C.And(C.Not(p), C.Not(q)))
    unary = {"AX": C.AX, "EX": C.EX, "AF": C.AF, "EF": C.EF, "AG": C.AG, "EG": C.EG}
    if o in unary:
        return unary[o](to_pymc_formula(a[0]))
    if o == "EU":
        return C.EU(to_pymc_formula(a[0]), to_pymc_formula(a[1]))
    if o == "AU":
        return C.AU(to_pymc_formula(a[0]), to_pymc_formula(a[1]))
    raise ValueError(f"pyModelChecking has no {o!r}")


def pymc_sat(k: Kripke, f: F, pk=None) -> set[int]:
    """The states pyModelChecking says satisfy ``f`` (``pk``: a converted structure to reuse)."""
    from pyModelChecking.CTL import modelcheck

    return {int(s) for s in modelcheck(pk if pk is not None else to_pymc_kripke(k), to_pymc_formula(f))}
