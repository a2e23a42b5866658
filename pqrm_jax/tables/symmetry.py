"""Exact shortcuts for table building: mirror symmetry and path-consistency refutation.

Offers the mirror permutation of a calculus's atoms and witnesses (one problem of each
mirror pair is solved) and a batched path-consistency test that refutes compose problems
whose four-point network empties under candidate tables. Sound, not complete: z3 settles the
rest.

Why both shortcuts are exact: docs/tables.md §symmetry.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..calculi.calculus import Calculus
from ..calculi.poly import Poly


def _mirror_poly(p: Poly) -> Poly:
    return Poly(p.nvars, {m: (-c if m[0] % 2 else c) for m, c in p.terms.items()}, p.names)


def mirror_atoms(calc: Calculus, atoms: list) -> list[int] | None:
    """The atom permutation induced by reflection in AB, or None.

    None when the calculus is not mirror symmetric constraint by constraint. Degenerate atoms
    map to themselves.

    >>> from pqrm_jax import calculi
    >>> from pqrm_jax.tables import problems as pb
    >>> at, _ = pb.atoms(calculi.get("edc"))
    >>> sigma = mirror_atoms(calculi.get("edc"), at)
    >>> sorted(sigma) == list(range(len(at))), all(sigma[sigma[i]] == i for i in range(len(at)))
    (True, True)
    """
    norm = [p.normalized() for p in calc.constraints]
    perm, eps = [], []
    for p in calc.constraints:
        q, s = _mirror_poly(p).normalized()
        hit = [j for j, (n, t) in enumerate(norm) if n == q]
        if not hit:
            return None
        perm.append(hit[0])
        eps.append(s * norm[hit[0]][1])
    index = {a: n for n, a in enumerate(atoms)}
    out = []
    for a in atoms:
        if isinstance(a, str):
            out.append(index[a])
            continue
        b = [0] * len(a)
        for i, sgn in enumerate(a):
            b[perm[i]] = eps[i] * sgn
        m = index.get(tuple(b))
        if m is None:
            return None
        out.append(m)
    return out


def mirror_witness(w: list) -> list:
    """Reflect witness coordinates in the line x = 0 (A, B lie on it in every frame)."""
    return [[0.0 - float(x), float(y)] for x, y in w]


def representatives(keys: list[tuple], sigma: list[int] | None,
                    unordered: bool = False) -> list[int]:
    """``rep[n]``: the index of the problem solved for problem n (itself or its mirror)."""
    rep = list(range(len(keys)))
    if sigma is None:
        return rep
    index = {k: n for n, k in enumerate(keys)}
    for n, k in enumerate(keys):
        mk = tuple(sigma[x] for x in k)
        if unordered:
            mk = tuple(sorted(mk))
        m = index.get(mk)
        if m is not None and m < n:
            rep[n] = m
    return rep


_TRIPLES = list(itertools.permutations(range(4), 3))
_TID = {t: n for n, t in enumerate(_TRIPLES)}


def path_consistency_refutes(left: np.ndarray, right: np.ndarray, inverse: np.ndarray,
                             compose: np.ndarray, problems: np.ndarray,
                             max_rounds: int = 50) -> np.ndarray:
    """[P] bool: which compose problems the four-point path-consistency closure refutes.

    The problems are [P, 3] atom indices (AB:C, BC:D, AB:D); the closure runs under the given
    (superset) atom tables.

    ``left/right/inverse`` [Q, Q] and ``compose`` [Q, Q, Q] boolean, indexed by atoms.
    """
    P, Q = len(problems), left.shape[0]
    if P == 0:
        return np.zeros(0, bool)
    rel = np.ones((P, 24, Q), bool)
    rows = np.arange(P)
    for (x, y, z), col in (((0, 1, 2), 0), ((1, 2, 3), 1), ((0, 1, 3), 2)):
        rel[:, _TID[(x, y, z)]] = False
        rel[rows, _TID[(x, y, z)], problems[:, col]] = True
    L, R, Inv = (m.astype(np.float32) for m in (left, right, inverse))
    T = compose.astype(np.float32).reshape(Q * Q, Q)
    # each problem's closure is independent of the others: a round runs only on the problems
    # still open (neither refuted nor at their fixpoint), so each one stops on its own and
    # ends exactly where the closure over all of them would leave it
    active = rows
    for _ in range(max_rounds):
        sub = rel[active]
        before = sub.copy()
        n = len(active)
        for x, y, z in _TRIPLES:
            a = sub[:, _TID[(x, y, z)]].astype(np.float32)
            sub[:, _TID[(y, z, x)]] &= (a @ L) > 0
            sub[:, _TID[(z, x, y)]] &= (a @ R) > 0
            sub[:, _TID[(y, x, z)]] &= (a @ Inv) > 0
        for x, y, z in _TRIPLES:
            w = 6 - x - y - z
            a = sub[:, _TID[(x, y, z)]].astype(np.float32)
            b = sub[:, _TID[(y, z, w)]].astype(np.float32)
            # COMPOSE(a, b) = ∪_{i∈a, j∈b} T[i, j]: (a ⊗ b) · T
            ab = (a[:, :, None] * b[:, None, :]).reshape(n, Q * Q)
            sub[:, _TID[(x, y, w)]] &= (ab @ T) > 0
        rel[active] = sub
        done = (~sub.any(-1)).any(-1) | (sub == before).all(axis=(1, 2))
        active = active[~done]
        if not len(active):
            break
    return (~rel.any(-1)).any(-1)

__all__ = ["mirror_atoms", "mirror_witness", "representatives", "path_consistency_refutes"]
