"""Exact oracle of the camera measurement: z3 on the polynomial systems (M§IV–V, Table III).

For one triple of bearings in range order (near, mid, far) the unit bearing vectors are
rational points *exactly* on the unit circle within ~1e-16 of ``(cos θ, sin θ)``
(:func:`exact_vectors`), so the structural identities of the geometry hold exactly (a
landmark at the camera, equal ranges). With the camera at the origin and ranges ``d_s`` the
landmarks are ``P_s = d_s w_s``; each EDC constraint of a cyclic relation XY:Z is the
quadratic form ``c_n n + c_u u + c_v v + c_m m`` in ``d`` (``n = |Y−X|²``, ``m = |Z−X|²``,
``u = (Z−X)×(Y−X)``, ``v = (Z−X)·(Y−X)``).
The forms are homogeneous of degree 2, so the slice ``d_far = 1`` is exact (scale-free), and
a state is feasible iff its strict sign pattern holds at some ``(d_near, d_mid)`` with
``0 < d_near < d_mid < 1``.

Ties in the range order (``d_near = d_mid`` or ``d_mid = d_far``) and the limit of a landmark
at the camera (``d_near = 0``) change nothing: a state is an open set of ``d``, and an open set
meets the closed cone ``0 ≤ d_near ≤ d_mid ≤ d_far`` iff it meets its interior. The decision is
z3's nlsat (complete for real polynomial arithmetic, as in :mod:`pqrm_jax.tables.certify`);
feasible verdicts come with a witness that is re-verified in exact rational arithmetic.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from ..calculi.poly import Poly
from ..tables.certify import DEFAULT_RLIMIT, SAT, UNSAT, decide
from .spec import CYCLIC, QRMSpec, qrm_spec

__all__ = ["exact_vectors", "exact_forms", "exact_signs", "decide_state", "oracle_sets",
           "settle_undecided"]


def exact_vectors(bearings) -> list[tuple[Fraction, Fraction]]:
    """Exact rational *unit* vectors of 3 bearings (within ~1e-16 of ``(cos θ, sin θ)``).

    ``w = ((1 − t²)/(1 + t²), 2t/(1 + t²))`` with ``t`` the float64 ``tan(θ/2)`` as a
    rational (the negated vector of ``θ − π`` when ``|θ|`` is past π/2): exactly on the unit
    circle, so the structural identities of the geometry (``|w|² = 1``) hold exactly.
    """
    b = np.asarray(bearings, np.float64).reshape(3)
    if not np.all(np.isfinite(b)):
        raise ValueError(f"non-finite bearing in {b.tolist()}")
    out = []
    for theta in b:
        th = float(np.remainder(theta + np.pi, 2 * np.pi) - np.pi)  # (−π, π]
        flip = abs(th) > np.pi / 2
        t = Fraction(float(np.tan((th - np.copysign(np.pi, th) if flip else th) / 2)))
        den = 1 + t * t
        x, y = (1 - t * t) / den, 2 * t / den
        out.append((-x, -y) if flip else (x, y))
    return out


def exact_forms(spec: QRMSpec, bearings) -> list[list[list[list[Fraction]]]]:
    """``Q[o][k]`` = exact symmetric 3×3 matrix of constraint k of cyclic relation o over d."""
    w = exact_vectors(bearings)
    lin = [[Fraction(c) for c in row] for row in np.asarray(spec.lin)]
    out = []
    for X, Y, Z in CYCLIC:
        # D = P_Y − P_X and E = P_Z − P_X as linear maps of d: coefficient vectors per axis
        D = [[(w[Y][ax] if s == Y else 0) - (w[X][ax] if s == X else 0) for s in range(3)]
             for ax in range(2)]
        E = [[(w[Z][ax] if s == Z else 0) - (w[X][ax] if s == X else 0) for s in range(3)]
             for ax in range(2)]

        def sym(f):
            return [[(f(s, r) + f(r, s)) / 2 for r in range(3)] for s in range(3)]

        n = sym(lambda s, r: D[0][s] * D[0][r] + D[1][s] * D[1][r])  # noqa: B023
        m = sym(lambda s, r: E[0][s] * E[0][r] + E[1][s] * E[1][r])  # noqa: B023
        v = sym(lambda s, r: E[0][s] * D[0][r] + E[1][s] * D[1][r])  # noqa: B023
        u = sym(lambda s, r: E[0][s] * D[1][r] - E[1][s] * D[0][r])  # noqa: B023
        rel = []
        for cn, cu, cv, cm in lin:
            rel.append([[cn * n[s][r] + cu * u[s][r] + cv * v[s][r] + cm * m[s][r]
                         for r in range(3)] for s in range(3)])
        out.append(rel)
    return out


def _slice_poly(Q) -> Poly:
    """The form ``dᵀQd`` on the slice ``d = (x0, x1, 1)`` as an exact polynomial."""
    t = {(2, 0): Q[0][0], (1, 1): 2 * Q[0][1], (0, 2): Q[1][1], (1, 0): 2 * Q[0][2],
         (0, 1): 2 * Q[1][2], (0, 0): Q[2][2]}
    return Poly(2, t)


def exact_signs(spec: QRMSpec, bearings, d) -> np.ndarray:
    """(3, K) exact signs of every constraint at ranges ``d`` (3 rationals or floats)."""
    d = [Fraction(x) for x in d]
    F = exact_forms(spec, bearings)
    out = np.zeros((3, spec.k), np.int8)
    for o in range(3):
        for k in range(spec.k):
            Q = F[o][k]
            val = sum(Q[s][r] * d[s] * d[r] for s in range(3) for r in range(3))
            out[o, k] = (val > 0) - (val < 0)
    return out


def decide_state(spec: QRMSpec, F, o: int, atom: int, rlimit: int = DEFAULT_RLIMIT) -> bool:
    """Exact feasibility of one atom of relation ``o`` for exact forms ``F``
    (:func:`exact_forms`): z3 over ``0 < d_near < d_mid < d_far = 1``; a SAT witness is
    re-verified in rational arithmetic (``AssertionError`` otherwise), an unknown verdict
    (z3's deterministic resource limit ``rlimit`` exhausted, never a wall-clock timeout, so
    the answer does not depend on the machine's load) raises ``RuntimeError``."""
    x0, x1 = Poly.var(2, 0), Poly.var(2, 1)
    polys = [_slice_poly(F[o][k]) for k in range(spec.k)]
    cons = [(p, int(s)) for p, s in zip(polys, spec.atom_signs[atom], strict=True)]
    cons += [(x0, 1), (x1 - x0, 1), (1 - x1, 1)]
    verdict, wit = decide(cons, rlimit)
    if verdict == UNSAT:
        return False
    if verdict != SAT:
        raise RuntimeError(f"z3 gave up on relation {o}, atom {atom} (resource limit "
                           f"rlimit={rlimit} exhausted)")
    for p, s in cons:
        val = p.evaluate(wit)
        assert (val > 0) - (val < 0) == s, "z3 witness does not verify"
    return True


def oracle_sets(bearings, calc: str | QRMSpec = "edc", rlimit: int = DEFAULT_RLIMIT) -> np.ndarray:
    """(3,) uint32 exact feasible-state masks of ``01:2, 12:0, 20:1`` for one triple
    (every atom decided by :func:`decide_state`).

    >>> from pqrm_jax.qrm.spec import states_of
    >>> import numpy as np
    >>> P = np.array([[2.0, 0.5], [1.0, 3.0], [-4.0, 1.5]])   # near, mid, far
    >>> states_of("edc", int(oracle_sets(np.arctan2(P[:, 1], P[:, 0]))[0]))
    ['1', '5', '11']
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    F = exact_forms(spec, bearings)
    sets = np.zeros(3, np.uint32)
    for o in range(3):
        for atom in range(spec.num_atoms):
            if decide_state(spec, F, o, atom, rlimit):
                sets[o] |= np.uint32(1 << int(spec.atom_state[atom]))
    return sets


def settle_undecided(spec: QRMSpec, bearings, sets, undecided, rlimit: int = DEFAULT_RLIMIT):
    """The exact stage: every undecided state of a measurement decided by z3.

    ``bearings`` (T, 3), ``sets``/``undecided`` (T, 3) uint32 masks from the kernel (bearing
    tolerance 0). Returns ``(sets, n_decided)``: the exact sets
    (undecided states kept only if feasible) and the number of z3 decisions made.
    """
    b = np.asarray(bearings, np.float64)
    sets = np.array(sets, np.uint32)
    und = np.asarray(undecided, np.uint32)
    n = 0
    atoms_of = {st: np.flatnonzero(spec.atom_state == st) for st in range(spec.num_states)}
    for t in np.flatnonzero(und.any(-1)):
        F = exact_forms(spec, b[t])
        for o in range(3):
            for st in range(spec.num_states):
                if int(und[t, o]) >> st & 1:
                    n += 1
                    if not any(decide_state(spec, F, o, int(a), rlimit)
                               for a in atoms_of[st]):
                        sets[t, o] &= np.uint32(~(1 << st) & 0xFFFFFFFF)
    return sets, n
