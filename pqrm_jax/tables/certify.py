"""Exact certification of feasibility problems the branch-and-bound leaves undecided.

z3's nlsat is a complete decision procedure for quantifier-free real polynomial arithmetic,
so an UNDECIDED problem (a solution set of lower dimension, or closures that only touch) is
settled exactly over the whole plane: SAT with a model (an algebraic witness, which we keep
as a float approximation) or UNSAT. It is also the independent oracle of the test suite.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from fractions import Fraction
from multiprocessing import get_context

from ..calculi.poly import Poly

SAT, UNSAT, UNKNOWN = "sat", "unsat", "unknown"


def _z3_expr(poly: Poly, xs):
    import z3

    total = z3.RealVal(0)
    for mono, c in poly.terms.items():
        term = z3.RealVal(f"{c.numerator}/{c.denominator}")
        for x, e in zip(xs, mono, strict=True):
            for _ in range(e):
                term = term * x
        total = total + term
    return total


def decide(constraints: list[tuple[Poly, int]], timeout_ms: int = 20000):
    """(verdict, witness or None) for a conjunction of exact polynomial sign constraints."""
    import z3

    nv = constraints[0][0].nvars if constraints else 0
    xs = z3.Reals(" ".join(f"x{i}" for i in range(nv))) if nv else []
    if nv == 1:
        xs = [xs] if not isinstance(xs, list) else xs
    s = z3.SolverFor("QF_NRA")
    s.set("timeout", timeout_ms)
    for poly, sign in constraints:
        e = _z3_expr(poly, xs)
        s.add(e > 0 if sign > 0 else (e < 0 if sign < 0 else e == 0))
    res = s.check()
    if res == z3.unsat:
        return UNSAT, None
    if res != z3.sat:
        return UNKNOWN, None
    model = s.model()
    wit = []
    for x in xs:
        v = model.eval(x, model_completion=True)
        if z3.is_rational_value(v):
            wit.append(Fraction(v.numerator_as_long(), v.denominator_as_long()))
        else:  # algebraic number
            wit.append(Fraction(v.approx(20).as_fraction()))
    return SAT, wit


def _decide_one(constraints):
    return decide(constraints)


def decide_many(problems: list, workers: int | None = None, progress: bool = False,
                desc: str = "z3") -> list:
    """``decide`` for many constraint lists, on all cores (spawned workers: JAX-safe)."""
    workers = workers or min(os.cpu_count() or 1, 8)
    if workers <= 1 or len(problems) < 16:  # below that, spawning costs more than it saves
        it = problems
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, desc=desc, leave=False)
        return [decide(c) for c in it]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as ex:
        it = ex.map(_decide_one, problems, chunksize=32)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, total=len(problems), desc=desc, leave=False)
        return list(it)
