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


#: the unary operations' targets: (x, y, z) → LEFT at (y, z, x), RIGHT at (z, x, y), INV at
#: (y, x, z); the composition's inputs and target: (x, y, z), (y, z, w) → (x, y, w)
_LEFT_AT = np.array([_TID[(y, z, x)] for x, y, z in _TRIPLES])
_RIGHT_AT = np.array([_TID[(z, x, y)] for x, y, z in _TRIPLES])
_INV_AT = np.array([_TID[(y, x, z)] for x, y, z in _TRIPLES])
_COMP_B = np.array([_TID[(y, z, 6 - x - y - z)] for x, y, z in _TRIPLES])
_COMP_AT = np.array([_TID[(x, y, 6 - x - y - z)] for x, y, z in _TRIPLES])

#: the most entries of the chunk-pair lookup tables of one composition
_PAIR_TABLE_ENTRIES = 1 << 20


def _chunk_bits(q: int) -> int:
    """Bits per chunk of a set of q atoms: the largest c whose ⌈q/c⌉² pair tables of 4^c
    entries stay within :data:`_PAIR_TABLE_ENTRIES` (q = 20: 8 bits, 9 lookups a
    composition)."""
    c = 1
    while c < q and (-(-q // (c + 1))) ** 2 * 4 ** (c + 1) <= _PAIR_TABLE_ENTRIES:
        c += 1
    return c


def _lift_tables(m: np.ndarray, c: int) -> np.ndarray:
    """[⌈q/c⌉, 2^c] uint64: entry [k, v] = ∪ of the rows m[i] (as masks) over the atoms
    i = c·k + (bits of v), so op(S) = OR over the chunks k of entry [k, chunk k of S]."""
    q = m.shape[0]
    rows = (m.astype(np.uint64) << np.arange(m.shape[1], dtype=np.uint64)).sum(-1,
                                                                          dtype=np.uint64)
    rows = np.concatenate([rows, np.zeros(-q % c, np.uint64)]).reshape(-1, c)
    v = np.arange(1 << c)
    bits = (v[:, None] >> np.arange(c)) & 1  # [2^c, c]
    out = np.zeros((rows.shape[0], 1 << c), np.uint64)
    for b in range(c):
        out |= np.where(bits[None, :, b] == 1, rows[:, b, None], np.uint64(0))
    return out


def _pair_tables(compose: np.ndarray, c: int) -> np.ndarray:
    """[⌈q/c⌉, ⌈q/c⌉, 4^c] uint64: entry [k, l, u·2^c + v] = COMPOSE of the atoms of chunk k
    of a set (bits u) with the atoms of chunk l of another (bits v), as a mask."""
    q = compose.shape[0]
    by_i = np.stack([_lift_tables(compose[i], c) for i in range(q)])  # [i, l, v]
    by_i = np.concatenate([by_i, np.zeros((-q % c,) + by_i.shape[1:], np.uint64)])
    by_i = by_i.reshape(-1, c, *by_i.shape[1:])  # [k, b, l, v]: atom i = c·k + b
    u = np.arange(1 << c)
    bits = (u[:, None] >> np.arange(c)) & 1  # [2^c, c]
    out = np.zeros((by_i.shape[0], by_i.shape[2], 1 << c, 1 << c), np.uint64)  # [k, l, u, v]
    for b in range(c):
        out |= np.where(bits[None, None, :, b, None] == 1, by_i[:, b, :, None, :], np.uint64(0))
    return out.reshape(out.shape[0], out.shape[1], -1)


def _lookup(tables: np.ndarray, s: np.ndarray, c: int) -> np.ndarray:
    """op(S) of masks S through :func:`_lift_tables`."""
    out = np.zeros_like(s)
    mask = np.uint64((1 << c) - 1)
    for k in range(tables.shape[0]):
        out |= tables[k][(s >> np.uint64(c * k)) & mask]
    return out


def path_consistency_refutes(left: np.ndarray, right: np.ndarray, inverse: np.ndarray,
                             compose: np.ndarray, problems: np.ndarray) -> np.ndarray:
    """[P] bool: which compose problems the four-point path-consistency closure refutes.

    The problems are [P, 3] atom indices (AB:C, BC:D, AB:D); the closure runs under the given
    (superset) atom tables. ``left/right/inverse`` [Q, Q] and ``compose`` [Q, Q, Q]
    boolean, indexed by atoms.

    Each problem's network of the 24 ordered triples of its four points holds one Q-bit mask
    per triple; a round applies LEFT, RIGHT and INV to every triple, then the composition
    through the fourth point, each operation as OR-ed table lookups on chunks of the masks
    (:func:`_lift_tables`, :func:`_pair_tables`). Every step only intersects with what the
    tables allow, so the rounds are sound in any order and reach the same greatest fixpoint
    as a triple-by-triple sweep; a problem stops at its own fixpoint or at an empty relation.
    Sets of more than 64 atoms do not fit a mask: then nothing is refuted (all ``False``,
    sound: the build's z3 stage decides those problems).
    """
    P, Q = len(problems), left.shape[0]
    if P == 0 or Q > 64:
        return np.zeros(P, bool)
    c = _chunk_bits(Q)
    L, R, Inv = (_lift_tables(np.asarray(m, bool), c) for m in (left, right, inverse))
    T = _pair_tables(np.asarray(compose, bool), c)
    nk = T.shape[0]
    mask = np.uint64((1 << c) - 1)
    full = np.uint64((1 << Q) - 1)
    rel = np.full((P, 24), full, np.uint64)
    problems = np.asarray(problems, np.int64)
    for (x, y, z), col in (((0, 1, 2), 0), ((1, 2, 3), 1), ((0, 1, 3), 2)):
        rel[:, _TID[(x, y, z)]] = np.left_shift(np.uint64(1), problems[:, col].astype(np.uint64))
    active = np.arange(P)
    while len(active):
        sub = rel[active]
        before = sub.copy()
        sub[:, _LEFT_AT] &= _lookup(L, sub, c)
        sub[:, _RIGHT_AT] &= _lookup(R, sub, c)
        sub[:, _INV_AT] &= _lookup(Inv, sub, c)
        a, b = sub, sub[:, _COMP_B]
        comp = np.zeros_like(a)
        for k in range(nk):
            ak = ((a >> np.uint64(c * k)) & mask) << np.uint64(c)
            for m in range(nk):
                comp |= T[k, m][ak | ((b >> np.uint64(c * m)) & mask)]
        sub[:, _COMP_AT] &= comp
        rel[active] = sub
        done = (sub == 0).any(1) | (sub == before).all(1)
        active = active[~done]
    return (rel == 0).any(1)

__all__ = ["mirror_atoms", "mirror_witness", "representatives", "path_consistency_refutes"]
