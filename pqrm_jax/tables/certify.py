"""Exact certification of feasibility problems the branch-and-bound leaves undecided.

z3's nlsat is a complete decision procedure for quantifier-free real polynomial arithmetic,
so an UNDECIDED problem (a solution set of lower dimension, or closures that only touch) is
settled exactly over the whole plane: SAT with a model (an algebraic witness, which we keep
as a float approximation) or UNSAT. It is also the independent oracle of the test suite.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from fractions import Fraction
from functools import lru_cache

from .._parallel import usable_cpus
from ..calculi.poly import Poly
from ..nlsat import DEFAULT_RLIMIT, SAT, UNKNOWN, UNSAT, decide_job, decide_smtlib

__all__ = ["DEFAULT_RLIMIT", "SAT", "UNKNOWN", "UNSAT", "count_unknown", "decide", "decide_many",
           "decide_smtlib", "pool", "pool_context", "smtlib"]

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
        out.append(f"(assert ({_OP[(sign > 0) - (sign < 0)]} {_lhs(poly)} 0))")
    return "\n".join(out)


@lru_cache(maxsize=1 << 14)
def _lhs(poly: Poly) -> str:
    """SMT-LIB text of one polynomial (a build's problems share most of their polynomials:
    memoised, Polys are immutable and hashable)."""
    terms = [_term(m, c) for m, c in poly.terms.items()] or ["0"]
    return terms[0] if len(terms) == 1 else f"(+ {' '.join(terms)})"


def decide(constraints: list[tuple[Poly, int]], rlimit: int = DEFAULT_RLIMIT):
    """(verdict, witness or None) for a conjunction of exact polynomial sign constraints
    (``rlimit``: see :func:`decide_smtlib`)."""
    nv = constraints[0][0].nvars if constraints else 0
    return decide_smtlib(smtlib(constraints), nv, rlimit)


#: below this many problems a batch is decided in-process unless the process's pool is
#: already running (:func:`pool`): the in-process work of a few hundred problems is about
#: what starting the workers costs
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

    def jobs():  # a generator: the workers decide the first chunks while the rest are written
        return ((smtlib(c), c[0][0].nvars if c else 0, rlimit) for c in problems)

    def shown(it):
        if not progress:
            return it
        from tqdm.auto import tqdm

        return tqdm(it, total=len(problems), desc=desc, leave=False)

    if workers <= 1 or (len(problems) < MIN_POOL_BATCH and workers not in _POOLS):
        return [decide_smtlib(*job) for job in shown(jobs())]
    chunk = max(1, min(32, len(problems) // (4 * workers)))
    try:
        return list(shown(pool(workers).map(decide_job, jobs(), chunksize=chunk)))
    except BrokenProcessPool:  # a worker of the kept pool died: replace the pool once
        return list(shown(pool(workers, fresh=True).map(decide_job, jobs(), chunksize=chunk)))


_POOLS: dict[int, ProcessPoolExecutor] = {}


def pool(workers: int, fresh: bool = False) -> ProcessPoolExecutor:
    """The process's pool of ``workers`` z3 workers (:func:`pool_context`), started on first
    use and kept until the interpreter exits (``fresh``: replace it).

    Starting workers is not cheap even from the forkserver: Python's multiprocessing runs the
    caller's main script again in every worker it starts (the forkserver's ``__main__``
    preload does not take effect on Python 3.11), and a script that imports JAX makes that
    ≈ 1.1 s a pool (measured: an empty two-worker pool from a script importing JAX, 1.1–1.3 s
    each time; 0.02–0.06 s without JAX). Kept, a warm table build starts none.
    """
    ex = _POOLS.get(workers)
    if ex is None or fresh:
        if ex is not None:
            ex.shutdown(wait=False, cancel_futures=True)
        ex = _POOLS[workers] = ProcessPoolExecutor(workers, mp_context=pool_context())
    return ex


def count_unknown(verdicts: list) -> int:
    """How many ``(verdict, witness)`` pairs are ``UNKNOWN`` (the resource limit ran out)."""
    return sum(v == UNKNOWN for v, _ in verdicts)
