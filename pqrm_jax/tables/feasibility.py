"""Batched branch-and-bound feasibility for quadratic sign constraints (M§V, SPEC §2.3).

Each problem asks for an x in a box [lo, hi] ⊂ R^nv with ``sign(q_k(x)) == s_k`` for every
active constraint k, where ``q_k(x) = c_k + b_kᵀx + xᵀA_k x`` and s_k ∈ {−1, 0, +1}
(strict inequalities and equalities). All problems of a batch run in one jit-compiled
``lax.while_loop``; every problem in flight owns a fixed-capacity pool of boxes (static
shapes, masks).

Per iteration and box:

* **bound**: a valid enclosure of q_k over the box, exact for the separable part (each
  ``A_ii x_i² + b_i x_i`` is minimised/maximised exactly, vertex included) plus interval
  products for the cross terms (M§V's cases 1–3 are exact under this bound);
* **prune** the box if some constraint cannot take its sign there (``> 0`` needs hi > 0,
  ``< 0`` needs lo < 0, ``= 0`` needs lo ≤ 0 ≤ hi);
* **witness**: if the box centre satisfies every constraint, the problem is feasible and the
  centre is kept as its witness (re-verified exactly by the caller);
* **branch**: surviving boxes are split in half along their longest edge while the pool has
  room; boxes narrower than ``min_width`` are no longer split.

Problems run through a work queue of ``slots`` in-flight problems inside one
``lax.while_loop``: a decided problem frees its slot for the next one, so the batch never waits
for its slowest member (``benchmarks/bench_tables.py`` compares it with the plain-NumPy
per-problem reference :mod:`.reference` and with this step run with one slot).

A problem is FEASIBLE (witness found), INFEASIBLE (no box left: no solution inside the box,
up to the floating-point evaluation of dyadic boxes), or UNDECIDED (boxes left at the limit;
typically solutions on a lower-dimensional set or closures that touch — never guessed).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

FEASIBLE, INFEASIBLE, UNDECIDED = 1, 0, -1


@dataclass
class ProblemBatch:
    """Dense arrays for P problems with K constraint slots over nv variables (numpy)."""

    A: np.ndarray  # (P, K, nv, nv) symmetric
    b: np.ndarray  # (P, K, nv)
    c: np.ndarray  # (P, K)
    sign: np.ndarray  # (P, K) in {-1, 0, 1}
    active: np.ndarray  # (P, K) bool
    lo: np.ndarray  # (P, nv)
    hi: np.ndarray  # (P, nv)

    @property
    def size(self) -> int:
        return self.c.shape[0]

    def take(self, idx) -> ProblemBatch:
        return ProblemBatch(*(getattr(self, f)[idx] for f in
                              ("A", "b", "c", "sign", "active", "lo", "hi")))


@dataclass
class Solution:
    status: np.ndarray  # (P,) FEASIBLE / INFEASIBLE / UNDECIDED
    witness: np.ndarray  # (P, nv) box centre that satisfied all constraints (FEASIBLE only)
    iterations: int


def _bounds(A, b, c, l, u):
    """Lower/upper bounds of every constraint over every box: (P, B, K) each."""
    nv = l.shape[-1]
    diag = jnp.diagonal(A, axis1=-2, axis2=-1)  # (P, K, nv)
    a = diag[:, None]  # (P, 1, K, nv)
    bb = b[:, None]
    L = l[:, :, None, :]  # (P, B, 1, nv)
    U = u[:, :, None, :]
    gl = a * L * L + bb * L
    gu = a * U * U + bb * U
    safe_a = jnp.where(a == 0, 1.0, a)
    v = -bb / (2 * safe_a)
    inside = (a != 0) & (v > L) & (v < U)
    gv = jnp.where(inside, a * v * v + bb * v, gl)
    g_lo = jnp.minimum(jnp.minimum(gl, gu), gv).sum(-1)
    g_hi = jnp.maximum(jnp.maximum(gl, gu), gv).sum(-1)
    lo = c[:, None] + g_lo
    hi = c[:, None] + g_hi
    if nv > 1:
        ii, jj = np.triu_indices(nv, 1)
        coef = 2 * A[:, :, ii, jj]  # (P, K, npairs)
        p1 = l[..., ii] * l[..., jj]
        p2 = l[..., ii] * u[..., jj]
        p3 = u[..., ii] * l[..., jj]
        p4 = u[..., ii] * u[..., jj]
        plo = jnp.minimum(jnp.minimum(p1, p2), jnp.minimum(p3, p4))  # (P, B, npairs)
        phi = jnp.maximum(jnp.maximum(p1, p2), jnp.maximum(p3, p4))
        pos = jnp.maximum(coef, 0.0)
        neg = jnp.minimum(coef, 0.0)
        lo = lo + jnp.einsum("pkn,pbn->pbk", pos, plo) + jnp.einsum("pkn,pbn->pbk", neg, phi)
        hi = hi + jnp.einsum("pkn,pbn->pbk", pos, phi) + jnp.einsum("pkn,pbn->pbk", neg, plo)
    return lo, hi


def _values(A, b, c, x):
    """q_k at points x (P, B, nv) → (P, B, K)."""
    quad = jnp.einsum("pbi,pkij,pbj->pbk", x, A, x)
    return c[:, None] + jnp.einsum("pki,pbi->pbk", b, x) + quad


def _step(A, b, c, sign, active, l, u, alive, key, min_width, pool, probes):
    """One bound / prune / witness / branch round for S slots → updated pools and verdicts."""
    S, _, nv = l.shape
    slots = jnp.arange(pool)
    blo, bhi = _bounds(A, b, c, l, u)
    s = sign[:, None, :]
    act = active[:, None, :]
    ok = jnp.where(s > 0, bhi > 0, jnp.where(s < 0, blo < 0, (blo <= 0) & (bhi >= 0)))
    keep = alive & jnp.all(ok | ~act, axis=-1)
    # witness probes: the centre and `probes` uniform points of every box
    t = jax.random.uniform(key, (probes,) + l.shape, l.dtype)
    xs = jnp.concatenate([0.5 * (l + u)[None], l[None] + t * (u - l)[None]], 0)
    x = jnp.moveaxis(xs, 0, 1).reshape(S, -1, nv)
    val = _values(A, b, c, x)
    sat = jnp.where(s > 0, val > 0, jnp.where(s < 0, val < 0, val == 0))
    good = jnp.tile(keep, (1, probes + 1)) & jnp.all(sat | ~act, axis=-1)
    found = good.any(-1)
    first = jnp.argmax(good, axis=-1)
    witness = jnp.take_along_axis(x, first[:, None, None], 1)[:, 0]
    # compact survivors to the front of each pool, then split while there is room
    order = jnp.argsort(~keep, axis=-1, stable=True)
    l = jnp.take_along_axis(l, order[..., None], 1)
    u = jnp.take_along_axis(u, order[..., None], 1)
    n_keep = keep.sum(-1)
    width = u - l
    splittable = (slots[None] < n_keep[:, None]) & (width.max(-1) > min_width)
    rank = jnp.cumsum(splittable, axis=-1) - 1
    do_split = splittable & (rank < (pool - n_keep)[:, None])
    n_split = do_split.sum(-1)
    onehot = jax.nn.one_hot(jnp.argmax(width, axis=-1), nv, dtype=bool)
    mid = 0.5 * (l + u)
    u_child1 = jnp.where(do_split[..., None] & onehot, mid, u)
    l_child2 = jnp.where(onehot, mid, l)
    src_rank = slots[None] - n_keep[:, None]  # child 2 of the r-th split box → slot n_keep + r
    split_pos = jnp.argsort(~do_split, axis=-1, stable=True)
    src = jnp.take_along_axis(split_pos, jnp.clip(src_rank, 0, pool - 1), -1)
    is_new = (src_rank >= 0) & (src_rank < n_split[:, None])
    new_l = jnp.where(is_new[..., None], jnp.take_along_axis(l_child2, src[..., None], 1), l)
    new_u = jnp.where(is_new[..., None], jnp.take_along_axis(u, src[..., None], 1), u_child1)
    alive = slots[None] < (n_keep + n_split)[:, None]
    empty = n_keep == 0
    stuck = (n_split == 0) & (n_keep > 0)
    return new_l, new_u, alive, found, witness, empty, stuck


@partial(jax.jit, static_argnames=("slots", "pool", "max_iters", "probes"))
def _solve(A, b, c, sign, active, lo0, hi0, min_width, key, n, *, slots: int, pool: int,
           max_iters: int, probes: int):
    """Work queue: ``slots`` problems are in flight; a finished slot takes the next problem.

    Arrays are padded to a bucket size P; only the first ``n`` (traced) problems are queued.
    """
    P, _, nv = b.shape
    S = slots
    dtype = lo0.dtype

    def fresh(idx):
        ok = idx < n
        j = jnp.clip(idx, 0, P - 1)
        l = jnp.zeros((S, pool, nv), dtype).at[:, 0].set(lo0[j])
        u = jnp.zeros((S, pool, nv), dtype).at[:, 0].set(hi0[j])
        alive = jnp.zeros((S, pool), bool).at[:, 0].set(ok)
        return jnp.where(ok, idx, -1), l, u, alive

    prob, l, u, alive = fresh(jnp.arange(S, dtype=jnp.int32))
    state = dict(prob=prob, l=l, u=u, alive=alive, age=jnp.zeros(S, jnp.int32),
                 nxt=jnp.int32(S), status=jnp.full(P, UNDECIDED, jnp.int32),
                 witness=jnp.zeros((P, nv), dtype), key=key, it=jnp.int32(0))

    def cond(st):
        return (st["prob"] >= 0).any()

    def body(st):
        key, sub = jax.random.split(st["key"])
        j = jnp.clip(st["prob"], 0, P - 1)
        busy = st["prob"] >= 0
        l, u, alive, found, wit, empty, stuck = _step(
            A[j], b[j], c[j], sign[j], active[j] & busy[:, None], st["l"], st["u"],
            st["alive"] & busy[:, None], sub, min_width, pool, probes)
        age = st["age"] + 1
        verdict = jnp.where(found, FEASIBLE, jnp.where(empty, INFEASIBLE, UNDECIDED))
        done = busy & (found | empty | stuck | (age >= max_iters))
        tgt = jnp.where(done, st["prob"], P)  # P = out of bounds: dropped
        status = st["status"].at[tgt].set(verdict, mode="drop")
        witness = st["witness"].at[tgt].set(wit, mode="drop")
        # refill finished slots with the next problems of the queue
        rank = (jnp.cumsum(done) - 1).astype(jnp.int32)
        new_idx = st["nxt"] + rank
        np_, nl, nu, na = fresh(new_idx)
        d = done[:, None, None]
        return dict(prob=jnp.where(done, np_, st["prob"]), l=jnp.where(d, nl, l),
                    u=jnp.where(d, nu, u), alive=jnp.where(done[:, None], na, alive),
                    age=jnp.where(done, 0, age), nxt=st["nxt"] + done.sum(dtype=jnp.int32),
                    status=status, witness=witness, key=key, it=st["it"] + 1)

    st = jax.lax.while_loop(cond, body, state)
    return st["status"], st["witness"], st["it"]


def solve(batch: ProblemBatch, *, pool: int = 32, max_iters: int = 120,
          min_width: float = 2.0**-24, slots: int = 64, probes: int = 2, seed: int = 0,
          chunk: int = 4096, progress: bool = False, desc: str = "feasibility") -> Solution:
    """Solve every problem of ``batch`` in one jit-compiled work-queue program (float64).

    ``slots`` problems are in flight at a time, each with a pool of ``pool`` boxes; a slot
    whose problem is decided (or reaches ``max_iters`` rounds) takes the next one, so easy
    problems never wait for hard ones. ``chunk`` problems go to the device per call (progress).
    """
    P = batch.size
    status = np.full(P, UNDECIDED, np.int8)
    witness = np.zeros((P, batch.b.shape[-1]))
    iters = 0
    starts = range(0, P, chunk)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=desc, unit="chunk", leave=False)
    with jax.enable_x64(True):
        for s in starts:
            sub = batch.take(slice(s, s + chunk))
            n = sub.size
            S = min(slots, n)
            bucket = max(S, 1 << (n - 1).bit_length())  # few distinct shapes → few compiles
            if bucket > n:
                sub = ProblemBatch(*(np.concatenate([x, np.repeat(x[-1:], bucket - n, 0)])
                                     for x in (sub.A, sub.b, sub.c, sub.sign, sub.active,
                                               sub.lo, sub.hi)))
            st, wit, it = _solve(
                jnp.asarray(sub.A, jnp.float64), jnp.asarray(sub.b, jnp.float64),
                jnp.asarray(sub.c, jnp.float64), jnp.asarray(sub.sign, jnp.int32),
                jnp.asarray(sub.active), jnp.asarray(sub.lo, jnp.float64),
                jnp.asarray(sub.hi, jnp.float64), jnp.float64(min_width),
                jax.random.PRNGKey(seed + s), jnp.int32(n), slots=S, pool=pool,
                max_iters=max_iters, probes=probes)
            status[s:s + n] = np.asarray(st)[:n]
            witness[s:s + n] = np.asarray(wit)[:n]
            iters += int(it)
    return Solution(status, witness, iters)
