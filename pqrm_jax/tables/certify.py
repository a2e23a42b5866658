"""Exact certification of feasibility problems the branch-and-bound leaves undecided.

z3's nlsat is a complete decision procedure for quantifier-free real polynomial arithmetic,
so an UNDECIDED problem (a solution set of lower dimension, or closures that only touch) is
settled exactly over the whole plane: SAT with a model (an algebraic witness, which we keep
as a float approximation) or UNSAT. It is also the independent oracle of the test suite.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from fractions import Fraction
from multiprocessing import get_context

from .._parallel import usable_cpus
from ..calculi.poly import Poly

SAT, UNSAT, UNKNOWN = "sat", "unsat", "unknown"

#: z3's deterministic resource limit per decision (``rlimit``, counted in z3's own work
#: units, not seconds), so a verdict never depends on the machine's load: the same problem
#: is decided the same way on a busy and on a quiet machine. The hardest of 512 random EDC
#: compose problems needs about 1.7e5 units (DCC: 3e3); 8e7 units take about 20 s of CPU
#: here, the wall-clock timeout used before. A problem that exhausts it is ``UNKNOWN`` —
#: counted by every caller (``tables.build``: "open"; the camera oracle raises).
DEFAULT_RLIMIT = 80_000_000


_OP = {1: ">", -1: "<", 0: "="}


def _number(c: Fraction) -> str:
    mag = str(abs(c.numerator)) if c.denominator == 1 else f"(/ {abs(c.numerator)} {c.denominator})"
    return f"(- {mag})" if c < 0 else mag


def _term(mono: tuple[int, ...], c: Fraction) -> str:
    xs = [f"x{i}" for i, e in enumerate(mono) for _ in range(e)]
    return f"(* {_number(c)} {' '.join(xs)})" if xs else _number(c)


def smtlib(constraints: list[tuple[Poly, int]]) -> str:
    """SMT-LIB 2 text of a conjunction of polynomial sign constraints over x0, x1, …

    z3 parses it in C: about four times faster than building the terms through its Python
    API, and the same formula (same verdicts and models)."""
    nv = constraints[0][0].nvars if constraints else 0
    out = [f"(declare-fun x{i} () Real)" for i in range(nv)]
    for poly, sign in constraints:
        terms = [_term(m, c) for m, c in poly.terms.items()] or ["0"]
        lhs = terms[0] if len(terms) == 1 else f"(+ {' '.join(terms)})"
        out.append(f"(assert ({_OP[(sign > 0) - (sign < 0)]} {lhs} 0))")
    return "\n".join(out)


def decide_smtlib(text: str, nv: int, rlimit: int = DEFAULT_RLIMIT):
    """(verdict, witness or None) for the SMT-LIB text of a conjunction over x0 … x{nv−1}.

    ``rlimit`` bounds each solver attempt by z3's deterministic resource counter (never a
    wall-clock timeout): a verdict is the same under any machine load; ``UNKNOWN`` when the
    limit is exhausted (deterministically so).

    z3's ``qfnra-nlsat`` tactic (preprocessing, then nlsat) first; if it gives up, z3's full
    QF_NRA strategy (further nlsat settings, then its SMT core). On the EDC and DCC builds the
    tactic decides everything, with the same verdicts and models as QF_NRA, in about half
    to two thirds of its time."""
    import z3

    if isinstance(rlimit, bool) or int(rlimit) != rlimit or rlimit < 1:
        raise ValueError(f"rlimit must be a positive integer, got {rlimit!r}")
    for solver in (lambda: z3.Tactic("qfnra-nlsat").solver(), lambda: z3.SolverFor("QF_NRA")):
        s = solver()
        s.set("rlimit", int(rlimit))
        s.from_string(text)
        res = s.check()
        if res != z3.unknown:
            break
    if res == z3.unsat:
        return UNSAT, None
    if res != z3.sat:
        return UNKNOWN, None
    model = s.model()
    wit = []
    for i in range(nv):
        v = model.eval(z3.Real(f"x{i}"), model_completion=True)
        if z3.is_rational_value(v):
            wit.append(Fraction(v.numerator_as_long(), v.denominator_as_long()))
        else:  # algebraic number
            wit.append(Fraction(v.approx(20).as_fraction()))
    return SAT, wit


def decide(constraints: list[tuple[Poly, int]], rlimit: int = DEFAULT_RLIMIT):
    """(verdict, witness or None) for a conjunction of exact polynomial sign constraints
    (``rlimit``: see :func:`decide_smtlib`)."""
    nv = constraints[0][0].nvars if constraints else 0
    return decide_smtlib(smtlib(constraints), nv, rlimit)


def _decide_one(job: tuple[str, int]):
    return decide_smtlib(*job)


#: below this many problems a batch is decided in-process: starting spawned workers (each
#: imports the package, hence JAX) costs 1–2 s, the in-process work of a few hundred problems
MIN_POOL_BATCH = 256


def decide_many(problems: list, workers: int | None = None, progress: bool = False,
                desc: str = "z3", rlimit: int = DEFAULT_RLIMIT) -> list:
    """``decide`` for many constraint lists, on the usable cores.

    The workers are spawned (JAX-safe) and get the SMT-LIB text, not the polynomials. The
    verdicts do not depend on the worker count or the load (``rlimit``, deterministic);
    :func:`count_unknown` counts the ``UNKNOWN`` ones.
    """
    workers = workers or min(usable_cpus(), 8)
    jobs = [(smtlib(c), c[0][0].nvars if c else 0, rlimit) for c in problems]
    if workers <= 1 or len(jobs) < MIN_POOL_BATCH:
        it = jobs
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, desc=desc, leave=False)
        return [decide_smtlib(*job) for job in it]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as ex:
        it = ex.map(_decide_one, jobs, chunksize=32)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, total=len(jobs), desc=desc, leave=False)
        return list(it)


def count_unknown(verdicts: list) -> int:
    """How many ``(verdict, witness)`` pairs are ``UNKNOWN`` (the resource limit ran out)."""
    return sum(v == UNKNOWN for v, _ in verdicts)
