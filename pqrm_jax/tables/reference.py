"""Plain-NumPy per-problem reference of the batched branch-and-bound (M§V, docs/decisions.md §2.3).

The same algorithm as :mod:`pqrm_jax.tables.feasibility` — interval bound (exact separable
quadratic part, vertex included, interval products for the cross terms), prune by sign,
witness probes (box centre plus ``probes`` uniform points per box), split the survivors along
their longest edge while the pool has room — run one problem at a time in a Python loop, each
round vectorised over that problem's boxes with NumPy (float64).

It exists as the team-standard speed reference for ``benchmarks/bench_tables.py`` (speed is
reported as a ratio against a plain NumPy implementation of the same algorithm) and as an
independent cross-check of the JAX solver's verdicts. The witness probes are drawn at
(problem, round, box, coordinate) by the same counter hash (``_hashrng.hash_uniform_at``), so
both solvers probe the same points and must return the same verdicts and witnesses.
"""

from __future__ import annotations

import numpy as np

from .._hashrng import hash_uniform_at
from .feasibility import FEASIBLE, INFEASIBLE, UNDECIDED, ProblemBatch, Solution

__all__ = ["solve_reference", "solve_one"]


def _sign_ok(sign: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Can a constraint of this sign hold on a range [lo, hi]? (elementwise)

    ``> 0`` needs hi > 0, ``< 0`` needs lo < 0, ``= 0`` needs lo ≤ 0 ≤ hi: all three are
    sign(lo) ≤ s ≤ sign(hi).
    """
    return (np.sign(lo) <= sign) & (np.sign(hi) >= sign)


def solve_one(A: np.ndarray, b: np.ndarray, c: np.ndarray, sign: np.ndarray,
              lo0: np.ndarray, hi0: np.ndarray, *, pool: int = 32, max_iters: int = 120,
              min_width: float = 2.0**-24, probes: int = 2, seed: int = 0,
              pid: int = 0) -> tuple[int, np.ndarray, int]:
    """Branch-and-bound for one problem with K *active* constraints over nv variables.

    Each round is this problem's round of the batched solver (same bound, prune, probes, split
    and termination).

    Args:
        A: [K, nv, nv] symmetric quadratic parts.
        b: [K, nv] linear parts.
        c: [K] constants.
        sign: [K] the required signs in {−1, 0, +1}.
        lo0: [nv] lower corner of the box.
        hi0: [nv] upper corner of the box.
        pool: the most boxes the problem may hold.
        max_iters: the most rounds.
        min_width: boxes narrower than this are no longer split.
        probes: random probe points per surviving box and round.
        seed: seed of the probe-point hash.
        pid: the problem's id in the probe stream.

    Returns:
        ``(status, witness [nv], rounds)``.
    """
    A = np.asarray(A, np.float64)
    b = np.asarray(b, np.float64)
    c = np.asarray(c, np.float64)
    sign = np.asarray(sign)
    nv = b.shape[-1]
    # separable part in [nv, B, K] layout: the reduction over nv adds contiguous blocks
    a = np.diagonal(A, axis1=-2, axis2=-1).T[:, None, :]  # (nv, 1, K)
    bs = b.T[:, None, :]
    has_a = a != 0
    v = -bs / (2 * np.where(has_a, a, 1.0))  # vertex of a x_i² + b x_i (used where a ≠ 0)
    g_v = a * v * v + bs * v
    ii, jj = np.triu_indices(nv, 1)
    coef = 2 * A[:, ii, jj]  # (K, npairs)
    A_t = A.reshape(A.shape[0], nv * nv).T  # (nv², K): q_k(x) quadratic part = (x⊗x) @ A_t
    pos_t = np.maximum(coef, 0.0).T  # (npairs, K)
    neg_t = np.minimum(coef, 0.0).T
    l = np.asarray(lo0, np.float64)[None].copy()  # (B, nv), B = boxes alive
    u = np.asarray(hi0, np.float64)[None].copy()
    witness = 0.5 * (l[0] + u[0])
    for it in range(1, max_iters + 1):
        B = l.shape[0]
        # bound: exact separable part (ends and interior vertex), interval cross products
        L = l.T[:, :, None]  # (nv, B, 1)
        U = u.T[:, :, None]
        gl = a * L * L + bs * L  # (nv, B, K)
        gu = a * U * U + bs * U
        gv = np.where(has_a & (v > L) & (v < U), g_v, gl)
        blo = c + np.minimum(np.minimum(gl, gu), gv).sum(0)  # (B, K)
        bhi = c + np.maximum(np.maximum(gl, gu), gv).sum(0)
        if nv > 1:
            li, lj, ui, uj = l[:, ii], l[:, jj], u[:, ii], u[:, jj]
            p1, p2, p3, p4 = li * lj, li * uj, ui * lj, ui * uj
            plo = np.minimum(np.minimum(p1, p2), np.minimum(p3, p4))  # (B, npairs)
            phi = np.maximum(np.maximum(p1, p2), np.maximum(p3, p4))
            blo = blo + plo @ pos_t + phi @ neg_t
            bhi = bhi + phi @ pos_t + plo @ neg_t
        # prune
        keep = _sign_ok(sign, blo, bhi).all(-1)  # (B,)
        # witness probes: all centres first, then each probe for every box (as _round)
        t = hash_uniform_at(np.uint32(seed), np.uint32(pid), np.uint32(it - 1),
                            np.arange(B, dtype=np.uint32)[None, :, None],
                            np.arange(probes * nv, dtype=np.uint32).reshape(probes, 1, nv))
        t = t.astype(np.float64)
        x = np.concatenate([(0.5 * (l + u))[None], l[None] + t * (u - l)[None]], 0)
        x = x.reshape(-1, nv)
        val = c + x @ b.T + (x[:, :, None] * x[:, None, :]).reshape(-1, nv * nv) @ A_t
        good = np.tile(keep, probes + 1) & (np.sign(val) == sign).all(-1)
        hit = np.flatnonzero(good)
        witness = x[hit[0] if hit.size else 0]
        if hit.size:
            return FEASIBLE, witness, it
        # compact the survivors, then split while the pool has room
        l, u = l[keep], u[keep]
        n_keep = l.shape[0]
        if n_keep == 0:
            return INFEASIBLE, witness, it
        width = u - l
        splittable = width.max(-1) > min_width
        do_split = splittable & (np.cumsum(splittable) <= pool - n_keep)
        if not do_split.any():
            return UNDECIDED, witness, it  # stuck
        rows = np.flatnonzero(do_split)
        axis = width[rows].argmax(-1)
        mid = 0.5 * (l[rows, axis] + u[rows, axis])
        l2 = l[rows].copy()
        u2 = u[rows].copy()
        l2[np.arange(rows.size), axis] = mid  # upper halves go to the end of the pool
        u[rows, axis] = mid  # lower halves stay in place
        l = np.concatenate([l, l2])
        u = np.concatenate([u, u2])
    return UNDECIDED, witness, max_iters


def solve_reference(batch: ProblemBatch, *, pool: int = 32, max_iters: int = 120,
                    min_width: float = 2.0**-24, probes: int = 2, seed: int = 0) -> Solution:
    """Solve the problems of ``batch`` one at a time (see :func:`solve_one`).

    Problem ``i`` draws its probes with id ``i``, as :func:`.feasibility.solve` does, so the
    statuses agree exactly.

    Args:
        batch: the problems.
        pool: the most boxes one problem may hold.
        max_iters: the most rounds per problem.
        min_width: boxes narrower than this are no longer split.
        probes: random probe points per surviving box and round.
        seed: seed of the probe-point hash.

    Returns:
        A :class:`~pqrm_jax.tables.feasibility.Solution`; its ``iterations`` is the total number
        of rounds over all problems.
    """
    P = batch.size
    status = np.full(P, UNDECIDED, np.int8)
    witness = np.zeros((P, batch.b.shape[-1]))
    rounds = 0
    for i in range(P):
        act = np.asarray(batch.active[i], bool)
        st, w, it = solve_one(batch.A[i][act], batch.b[i][act], batch.c[i][act],
                              batch.sign[i][act], batch.lo[i], batch.hi[i], pool=pool,
                              max_iters=max_iters, min_width=min_width, probes=probes,
                              seed=seed, pid=i)
        status[i], witness[i] = st, w
        rounds += it
    return Solution(status, witness, rounds)
