"""Feasibility problems behind the operator tables (M§III.B Table II, docs/decisions.md §2.3).

An *atom* of a calculus is one realisable sign pattern of its constraints (a tuple in
{−1,0,1}^k) or, for boundary-inclusive calculi, ``"dou"`` (A=B≠C) / ``"tri"`` (A=B=C).
Each state is a union of atoms. A relation ``XY:Z`` in an atom becomes exact polynomial sign
constraints on the free coordinates: with u = (Z−X)×(Y−X), v = (Z−X)·(Y−X), m = |Z−X|²,
n = |Y−X|², every calculus constraint f(α, β, ρ) is replaced by n^D f(u/n, v/n, m/n), plus
n > 0 (the frame exists). Degenerate atoms say n = 0 and m > 0 (dou) or m = 0 (tri).

Frames (all exact, no loss of generality by similarity invariance): if the first relation
``AB:C`` is non-degenerate, A=(0,0), B=(0,1), C=(x0,x1), D=(x2,x3); if it is ``dou``,
A=B=(0,0), C=(0,1); if ``tri``, A=B=C=(0,0); D stays free.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from functools import lru_cache

import numpy as np

from ..calculi.calculus import Calculus
from ..calculi.poly import Poly
from .feasibility import ProblemBatch

NV = 4  # free coordinates: C = (x0, x1), D = (x2, x3)
NAMES = ("xc", "yc", "xd", "yd")
Point = tuple[Poly, Poly]


def _const(v) -> Poly:
    return Poly.const(NV, v, NAMES)


def _var(i) -> Poly:
    return Poly.var(NV, i, NAMES)


@dataclass
class Problem:
    """A conjunction of exact polynomial sign constraints (None = trivially infeasible)."""

    constraints: list[tuple[Poly, int]] | None
    tag: tuple = field(default=())
    #: search-domain restrictions used by the branch-and-bound only (never by verification)
    domain: list[tuple[Poly, int]] = field(default_factory=list)

    @property
    def trivially_infeasible(self) -> bool:
        return self.constraints is None


def frame(atom_abc) -> dict[str, Point]:
    """Coordinates of A, B, C, D for a problem whose first relation AB:C is ``atom_abc``."""
    return dict(_frame(atom_abc if atom_abc in ("dou", "tri") else "open"))


@lru_cache(maxsize=4)
def _frame(kind: str) -> dict[str, Point]:
    """One set of point polynomials per frame kind.

    Problems share them, so the relation caches below hit by identity.
    """
    z, one = _const(0), _const(1)
    D = (_var(2), _var(3))
    if kind == "dou":
        return {"A": (z, z), "B": (z, z), "C": (z, one), "D": D}
    if kind == "tri":
        return {"A": (z, z), "B": (z, z), "C": (z, z), "D": D}
    return {"A": (z, z), "B": (z, one), "C": (_var(0), _var(1)), "D": D}


def relation(calc: Calculus, atom, X: Point, Y: Point, Z: Point) -> list[tuple[Poly, int]]:
    """Sign constraints saying ``XY:Z`` is in ``atom``."""
    return list(_relation(calc, atom, X, Y, Z))


@lru_cache(maxsize=65536)
def _relation(calc: Calculus, atom, X: Point, Y: Point, Z: Point) -> tuple:
    dx, dy = Y[0] - X[0], Y[1] - X[1]
    ex, ey = Z[0] - X[0], Z[1] - X[1]
    n = dx * dx + dy * dy
    m = ex * ex + ey * ey
    if atom == "dou":
        return ((n, 0), (m, 1))
    if atom == "tri":
        return ((n, 0), (m, 0))
    u = ex * dy - ey * dx
    v = ex * dx + ey * dy
    out = [(n, 1)]
    for poly, s in zip(calc.constraints, atom, strict=True):
        out.append((poly.substitute([u, v, m], homogenize_with=n), int(s)))
    return tuple(out)


def simplify(constraints: list[tuple[Poly, int]]) -> list[tuple[Poly, int]] | None:
    """Drop satisfied constants, merge identical boundaries; None if a contradiction shows."""
    kept: dict[Poly, int] = {}
    for poly, s in constraints:
        if poly.is_constant():
            if (poly.constant() > 0) - (poly.constant() < 0) != s:
                return None
            continue
        norm, lead = poly.normalized()
        s_norm = s * lead
        if norm in kept and kept[norm] != s_norm:
            return None
        kept[norm] = s_norm
    return [(p, s) for p, s in kept.items()]


def atoms(calc: Calculus) -> tuple[list, list[int]]:
    """The atoms of a calculus defined by constraints, and the state of each atom."""
    import itertools

    from ..calculi.calculus import pattern_index

    sign_set = (-1, 0, 1) if calc.boundary_inclusive else (-1, 1)
    out, state = [], []
    for signs in itertools.product(sign_set, repeat=calc.k):
        st = int(calc.sign_table[pattern_index(signs)])
        if st >= 0:
            out.append(tuple(signs))
            state.append(st)
    if calc.degenerate is not None:
        out += ["dou", "tri"]
        state += [calc.dou, calc.tri]
    return out, state


def unary_problem(calc: Calculus, op: str, p, q) -> Problem:
    """Is ``AB:C ∈ p`` compatible with LEFT (BC:A), RIGHT (CA:B) or INVERSE (BA:C) ∈ q?"""
    F = frame(p)
    A, B, C = F["A"], F["B"], F["C"]
    cons = relation(calc, p, A, B, C)
    if op == "left":
        cons += relation(calc, q, B, C, A)
    elif op == "right":
        cons += relation(calc, q, C, A, B)
    elif op == "inverse":
        cons += relation(calc, q, B, A, C)
    else:
        raise ValueError(f"unknown unary operator {op!r}")
    return Problem(simplify(cons), (op, p, q))


def _ratio_bound(X: Point, Y: Point, ratio: float) -> list[tuple[Poly, int]]:
    """|XY| > |AB| / ratio: keeps the search away from a frame's degenerate point."""
    n = (Y[0] - X[0]) ** 2 + (Y[1] - X[1]) ** 2
    return [] if n.is_constant() else [(n - 1 / ratio**2, 1)]


@lru_cache(maxsize=16)
def _compose_domain(kind, box: float) -> tuple:
    """The B&B search-domain bounds of a compose problem (they depend on the frame only)."""
    F = frame(kind)
    A, B, C, D = F["A"], F["B"], F["C"], F["D"]
    return tuple(c for X, Y in ((A, C), (B, C), (A, D), (B, D), (C, D))
                 for c in _ratio_bound(X, Y, box))


def compose_problem(calc: Calculus, p, q, r, box: float = 8.0) -> Problem:
    """Is there a configuration with AB:C ∈ p, BC:D ∈ q and AB:D ∈ r? (M§III.B)"""
    F = frame(p)
    A, B, C, D = F["A"], F["B"], F["C"], F["D"]
    parts = (_simplified(calc, p, A, B, C), _simplified(calc, q, B, C, D),
             _simplified(calc, r, A, B, D))
    cons = None if None in parts else _merge(parts)
    domain = list(_compose_domain(p if isinstance(p, str) else "open", box))
    return Problem(cons, ("compose", p, q, r), domain)


@lru_cache(maxsize=65536)
def _simplified(calc: Calculus, atom, X: Point, Y: Point, Z: Point) -> tuple | None:
    """``simplify(relation(…))``, once per part of the compose problems."""
    out = simplify(relation(calc, atom, X, Y, Z))
    return None if out is None else tuple(out)


def _merge(parts) -> list[tuple[Poly, int]] | None:
    """``simplify`` of concatenated simplified parts; None on a sign conflict.

    The parts have no constants left and their boundaries already normalized: the result is
    the same list, first occurrences in order.
    """
    kept: dict[Poly, int] = {}
    for part in parts:
        for poly, s in part:
            if kept.setdefault(poly, s) != s:
                return None
    return list(kept.items())



def random_compose_problems(calc: Calculus, n: int, seed: int = 0) -> list[Problem]:
    """``n`` compose problems on random atom triples that are not trivially infeasible.

    Drawn with ``numpy.random.default_rng(seed)``: the random workload of
    ``benchmarks/bench_tables.py`` and of the reference tests.
    """
    found, _ = atoms(calc)
    rng = np.random.default_rng(seed)
    probs: list[Problem] = []
    while len(probs) < n:
        i, j, k = rng.integers(0, len(found), 3)
        pr = compose_problem(calc, found[i], found[j], found[k])
        if not pr.trivially_infeasible:
            probs.append(pr)
    return probs

@lru_cache(maxsize=4096)
def _disk_inside(calc: Calculus, atom, X: Point, r: Fraction) -> tuple[tuple[Poly, int], ...]:
    """The disk of radius r around X (canonical frame) lies inside the open atom.

    Needs line or circle constraints (weighted degree one in α, β, ρ): a line's signed
    distance must exceed r, a circle's centre distance must clear its radius by r. Cached:
    each atom's disk serves all its pairs.
    """
    import math

    out = []
    for poly, s in zip(calc.constraints, atom, strict=True):
        if poly.weighted_degree() > 1:
            raise NotImplementedError("adjacency needs line/circle constraints")
        t = poly.terms
        k = t.get((0, 0, 1), Fraction(0))
        a = t.get((1, 0, 0), Fraction(0))
        b = t.get((0, 1, 0), Fraction(0))
        c = t.get((0, 0, 0), Fraction(0))
        x, y = X
        if k == 0:
            norm = Fraction(math.sqrt(a * a + b * b))
            out.append((s * (a * x + b * y + c) - r * norm, 1))
            continue
        cx, cy = -a / (2 * k), -b / (2 * k)
        R2 = (a * a + b * b) / (4 * k * k) - c / k
        R = Fraction(math.sqrt(max(R2, 0)))
        d2 = (x - cx) ** 2 + (y - cy) ** 2
        if s * k > 0:  # outside the circle
            out.append((d2 - (R + r) ** 2, 1))
        elif R > r:
            out.append((d2 - (R - r) ** 2, -1))
        else:
            return ((_const(-1), 1),)
    return tuple(out)


def _short_rational(x: float | Fraction) -> Fraction:
    """x exactly if rational, else the shortest decimal that rounds to the float x."""
    return x if isinstance(x, Fraction | int) else Fraction(repr(float(x)))


def adjacency_problem(calc: Calculus, p, q, r: float) -> Problem:
    """Do open atoms p and q meet with positive angle? (conceptual neighbours, P§2.3.1)

    True iff disks of radius r inside p and inside q have centres closer than 8r: regions
    sharing an edge or a corner with sectors of ≳ 30° qualify (EDC's triple points have 60°
    sectors), zero-angle cusp contacts do not (a cusp of width ~t²/2 holds such a disk only
    at a distance t ~ 2√r from its tip).

    A float r is read as the shortest decimal that rounds to it (1e-2 → 1/100, not the
    float's binary value 0.01000000000000000020816…): the same radius to 1e-18, and z3
    decides the contact cases about ten times faster with short rationals.
    """
    r = _short_rational(r)
    F = _frame("open")
    C, D = F["C"], F["D"]
    cons = [*_disk_inside(calc, p, C, r), *_disk_inside(calc, q, D, r), (_gap(r), -1)]
    return Problem(simplify(cons), ("adjacent", p, q))


@lru_cache(maxsize=16)
def _gap(r: Fraction) -> Poly:
    """|C − D|² − (8r)²."""
    F = _frame("open")
    (xc, yc), (xd, yd) = F["C"], F["D"]
    return (xc - xd) ** 2 + (yc - yd) ** 2 - (8 * r) ** 2


def to_batch(problems: list[Problem], box: float) -> ProblemBatch:
    """Dense quadratic-form arrays for the solver (problems must not be trivially infeasible)."""
    K = max((len(pr.constraints) + len(pr.domain) for pr in problems), default=1) or 1
    P = len(problems)
    # problems share their polynomial objects: each distinct one's form once (by id), then
    # every (problem, slot) filled by one fancy-indexed assignment; entry 0 is never
    # referenced, it keeps the stacks well-shaped for an empty list of problems
    forms: dict[int, int] = {}
    fc, fb, fA, fv = [0.0], [np.zeros(NV)], [np.zeros((NV, NV))], [np.zeros(NV, bool)]
    ii, kk, ff, ss = [], [], [], []
    for i, pr in enumerate(problems):
        for k, (poly, s) in enumerate(pr.constraints + pr.domain):
            j = forms.get(id(poly))
            if j is None:
                j = forms[id(poly)] = len(fc)
                c0, b0, A0 = poly.quadratic_form()
                fc.append(c0)
                fb.append(np.asarray(b0, float))
                fA.append(np.asarray(A0, float))
                fv.append(np.isin(np.arange(NV), list(poly.variables())))
            ii.append(i)
            kk.append(k)
            ff.append(j)
            ss.append(s)
    ff = np.asarray(ff, np.int64)
    A = np.zeros((P, K, NV, NV))
    b = np.zeros((P, K, NV))
    c = np.zeros((P, K))
    sign = np.zeros((P, K), np.int8)
    active = np.zeros((P, K), bool)
    used = np.zeros((P, NV), bool)
    A[ii, kk] = np.stack(fA)[ff]
    b[ii, kk] = np.stack(fb)[ff]
    c[ii, kk] = np.asarray(fc)[ff]
    sign[ii, kk] = ss
    active[ii, kk] = True
    np.logical_or.at(used, np.asarray(ii, np.int64), np.stack(fv)[ff])
    lo = np.where(used, -box, 0.0)
    hi = np.where(used, box, 0.0)
    return ProblemBatch(A, b, c, sign, active, lo, hi)


def verify(problem: Problem, x) -> bool:
    """Exact (rational) check that x satisfies every constraint of the problem."""
    if problem.constraints is None:
        return False
    for poly, s in problem.constraints:
        val = poly.evaluate(list(x))
        if (val > 0) - (val < 0) != s:
            return False
    return True
