"""Exact certification of feasibility problems the branch-and-bound leaves undecided.

z3's nlsat is a complete decision procedure for quantifier-free real polynomial arithmetic,
so an UNDECIDED problem (a solution set of lower dimension, or closures that only touch) is
settled exactly over the whole plane: SAT with a model (an algebraic witness, which we keep
as a float approximation) or UNSAT. It is also the independent oracle of the test suite.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from fractions import Fraction

from .._parallel import usable_cpus
from ..calculi.poly import Poly
from ..nlsat import DEFAULT_RLIMIT, SAT, UNKNOWN, UNSAT, decide_job, decide_smtlib

__all__ = ["DEFAULT_RLIMIT", "SAT", "UNKNOWN", "UNSAT", "count_unknown", "decide", "decide_many",
           "decide_smtlib", "pool_context", "smtlib"]

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


def decide(constraints: list[tuple[Poly, int]], rlimit: int = DEFAULT_RLIMIT):
    """(verdict, witness or None) for a conjunction of exact polynomial sign constraints
    (``rlimit``: see :func:`decide_smtlib`)."""
    nv = constraints[0][0].nvars if constraints else 0
    return decide_smtlib(smtlib(constraints), nv, rlimit)


#: below this many problems a batch is decided in-process: the in-process work of a few
#: hundred problems is about what starting the workers costs where only ``spawn`` exists
MIN_POOL_BATCH = 256


def pool_context() -> multiprocessing.context.BaseContext:
    """The start method of the z3 workers: JAX-safe and cheap.

    Forking the caller is not safe once JAX has started its threads, and a spawned worker
    re-imports the package (≈ 2.4 s of JAX import each, every build). Where the platform has
    it (Linux, macOS) the workers fork from Python's forkserver, a fresh interpreter started
    once per process that preloads only :mod:`pqrm_jax.nlsat` (z3, no JAX): a warm table build
    starts its pool in milliseconds. Elsewhere, ``spawn``.
    """
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["pqrm_jax.nlsat"])
        return ctx
    return multiprocessing.get_context("spawn")


def decide_many(problems: list, workers: int | None = None, progress: bool = False,
                desc: str = "z3", rlimit: int = DEFAULT_RLIMIT) -> list:
    """``decide`` for many constraint lists, on the usable cores.

    The workers (:func:`pool_context`) get the SMT-LIB text, not the polynomials. The
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
    with ProcessPoolExecutor(workers, mp_context=pool_context()) as ex:
        it = ex.map(decide_job, jobs, chunksize=32)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(it, total=len(jobs), desc=desc, leave=False)
        return list(it)


def count_unknown(verdicts: list) -> int:
    """How many ``(verdict, witness)`` pairs are ``UNKNOWN`` (the resource limit ran out)."""
    return sum(v == UNKNOWN for v, _ in verdicts)
