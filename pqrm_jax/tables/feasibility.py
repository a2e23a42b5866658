"""Batched branch-and-bound feasibility for quadratic sign constraints (M§V).

Decides, for a batch of problems, whether some x in a box satisfies every sign constraint
``sign(c_k + b_kᵀx + xᵀA_k x) == s_k`` (s_k ∈ {−1, 0, +1}), in one jit-compiled program,
and returns each problem's status (FEASIBLE with a witness, INFEASIBLE or UNDECIDED — never
guessed; docs/decisions.md §2.3).

Bound, prune, witness and branch steps, the shared frontier of box rows and the per-core
work queues: docs/tables.md §feasibility.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._hashrng import hash_uniform_at
from .._parallel import default_queues, side_by_side

FEASIBLE, INFEASIBLE, UNDECIDED = 1, 0, -1
GROUP = 8  # frontier rows per constraint-table gather (a divisor of the pool size)
RESV = 2  # admission reserves rows for each problem in flight to double its boxes


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
    witness: np.ndarray  # (P, nv) the probe point that satisfied all constraints (FEASIBLE only)
    iterations: int


def _tables(A, b, c, sign, active):
    """Per-problem coefficient table [P, 4·nv + npairs + 2, K], constraint axis minor.

    Rows ``A_ii`` (nv), ``b_i`` (nv), the vertex ``v_i = −b_i / 2A_ii`` of each univariate part (nv;
    +inf where A_ii = 0) and its value ``A_ii v_i² + b_i v_i`` there (nv), ``2 A_ij`` for i < j
    (npairs), ``c``, sign. What a row group of the frontier gathers (one packed gather; inactive
    constraints become ``0 ≥ 0``).
    """
    nv = b.shape[-1]
    A = jnp.where(active[..., None, None], A, 0.0)
    b = jnp.where(active[..., None], b, 0.0)
    ii, jj = np.triu_indices(nv, 1)
    a = jnp.diagonal(A, axis1=-2, axis2=-1)
    v = -b / (2 * jnp.where(a == 0, 1.0, a))
    gv = a * v * v + b * v
    rows = [a, b, jnp.where(a == 0, jnp.inf, v), jnp.where(a == 0, 0.0, gv), 2 * A[:, :, ii, jj],
            jnp.where(active, c, 0.0)[..., None], jnp.where(active, sign, 0)[..., None]]
    return jnp.swapaxes(jnp.concatenate([r.astype(A.dtype) for r in rows], -1), 1, 2)


def _unpack(T, nv):
    """[G, F, K] group tables → dict of [G, 1, K] rows (broadcast over a group's boxes)."""
    npairs = nv * (nv - 1) // 2
    row = [T[:, f, None, :] for f in range(T.shape[1])]
    return dict(a=row[:nv], b=row[nv:2 * nv], v=row[2 * nv:3 * nv], gv=row[3 * nv:4 * nv],
                coef=row[4 * nv:4 * nv + npairs], c=row[-2], s=row[-1])


def _upper(T, l, u, cls):
    """Upper bounds of the (one-sided) constraints of one support class over every box: [G, R, k].

    ``T``: the unpacked tables of each row group's problem; ``l``, ``u``: [G, R, nv] boxes;
    ``cls`` = (offset, k, variables, pairs): the class's constraint columns and the variables
    and variable pairs they use (other terms are zero and skipped). Exact for the separable
    part (each ``A_ii x_i² + b_i x_i`` at both ends and the interior vertex), interval
    products for the cross terms. A constraint ``s·q > 0`` needs only the upper bound of
    ``s·q``, which is exactly −(lower bound of q) for s = −1 (negation is exact), so the
    pruning is that of :mod:`.reference` at half the arithmetic. Written as sums of terms, one
    per variable and pair (XLA's CPU code for reductions over a middle axis is several times
    slower)."""
    off, k, variables, pairs = cls
    col = slice(off, off + k)
    hi = T["c"][..., col]
    for i in variables:
        a, bt, v = T["a"][i][..., col], T["b"][i][..., col], T["v"][i][..., col]
        L = l[..., i, None]
        U = u[..., i, None]
        gl = a * L * L + bt * L
        gu = a * U * U + bt * U
        gvv = jnp.where((v > L) & (v < U), T["gv"][i][..., col], gl)  # v = inf if a = 0
        hi = hi + jnp.maximum(jnp.maximum(gl, gu), gvv)
    for p, i, j in pairs:
        q = (l[..., i] * l[..., j], l[..., i] * u[..., j], u[..., i] * l[..., j],
             u[..., i] * u[..., j])
        plo = jnp.minimum(jnp.minimum(q[0], q[1]), jnp.minimum(q[2], q[3]))[..., None]
        phi = jnp.maximum(jnp.maximum(q[0], q[1]), jnp.maximum(q[2], q[3]))[..., None]
        coef = T["coef"][p][..., col]
        hi = hi + jnp.maximum(coef, 0.0) * phi + jnp.minimum(coef, 0.0) * plo
    return hi


def _values(T, x, cls):
    """The constraints of one support class at points x of each row group's problem.

    x is [M, G, R, nv]; the result is [M, G, R, k].
    """
    off, k, variables, pairs = cls
    col = slice(off, off + k)
    val = T["c"][..., col]
    for i in variables:
        xi = x[..., i, None]
        val = val + (T["b"][i][..., col] + T["a"][i][..., col] * xi) * xi
    for p, i, j in pairs:
        val = val + T["coef"][p][..., col] * (x[..., i] * x[..., j])[..., None]
    return val


def one_sided(batch: ProblemBatch) -> ProblemBatch:
    """The same problems with every constraint in one-sided form.

    ``sign(q) = s ≠ 0`` becomes ``s·q > 0`` (sign 1: strict) and an equality ``q = 0`` the
    pair ``q ≥ 0``, ``−q ≥ 0``
    (sign 0: non-strict; the negated copies are appended). In this form a constraint holds at
    x iff ``sign(q(x)) ≥ sign`` and can hold in a box iff ``sign(upper bound) ≥ sign``."""
    P, K, nv = batch.b.shape
    s = np.where(batch.active & (batch.sign != 0), batch.sign, 1).astype(np.float64)
    eq = batch.active & (batch.sign == 0)
    E = int(eq.sum(1).max()) if eq.any() else 0
    parts = [(batch.A * s[..., None, None], batch.b * s[..., None], batch.c * s,
              (batch.active & (batch.sign != 0)).astype(np.int8), batch.active)]
    if E:
        rank = np.cumsum(eq, 1) - 1
        idx = np.full((P, E), -1)
        p_i, k_i = np.nonzero(eq)
        idx[p_i, rank[p_i, k_i]] = k_i
        take, pad, rows = np.maximum(idx, 0), idx < 0, np.arange(P)[:, None]
        parts.append((np.where(pad[..., None, None], 0.0, -batch.A[rows, take]),
                      np.where(pad[..., None], 0.0, -batch.b[rows, take]),
                      np.where(pad, 0.0, -batch.c[rows, take]), np.zeros((P, E), np.int8),
                      ~pad))
    return ProblemBatch(*(np.concatenate(x, 1) for x in zip(*parts, strict=True)),
                        batch.lo, batch.hi)


def support_classes(batch: ProblemBatch) -> tuple[ProblemBatch, tuple]:
    """One-sided constraints (:func:`one_sided`), reordered by the variables they use.

    Every problem's constraints are put in one-sided form and grouped by the set of variables
    they use.

    Returns the reordered one-sided batch (inactive ``0 ≥ 0`` constraints pad each class to
    its largest count over the batch) and the static class list ``(offset, k, variables,
    pairs)`` used by :func:`_upper` and :func:`_values` to skip the zero terms: an EDC
    compose problem has 24 constraints on C only, D only or both, and the classes halve the
    arithmetic. A class whose variables are another's but one joins that class (fewer kernels
    for a few zero terms). Falls back to one dense class when padding would grow the
    constraint count by more than half."""
    batch = one_sided(batch)
    P, K, nv = batch.b.shape
    diag = np.abs(np.diagonal(batch.A, axis1=-2, axis2=-1))
    used = (np.abs(batch.b) > 0) | (diag > 0) | (np.abs(batch.A).sum(-1) > 0)  # (P, K, nv)
    code = np.where(batch.active, (used * (1 << np.arange(nv))).sum(-1), 0)
    codes = np.unique(code[code != 0])  # inactive constraints (0 ≥ 0) need no class
    for c in codes:  # fewer, wider classes: one more variable's (zero) terms beat a class
        sup = [d for d in codes if d & c == c and bin(d ^ c).count("1") == 1]
        if sup:
            code = np.where(code == c, min(sup), code)
    codes = np.unique(code[code != 0])
    counts = {int(c): int((code == c).sum(1).max()) for c in codes}
    if not counts or sum(counts.values()) > 1.5 * K:
        codes, counts = np.array([(1 << nv) - 1]), {(1 << nv) - 1: K}
        code = np.full_like(code, (1 << nv) - 1)
    triu = list(zip(*np.triu_indices(nv, 1), strict=True))
    cols, classes, off = [], [], 0
    for c in codes:
        c, k = int(c), counts[int(c)]
        rank = np.cumsum(code == c, 1) - 1  # position of each constraint within its class
        idx = np.full((P, k), -1)
        p_i, k_i = np.nonzero(code == c)
        idx[p_i, rank[p_i, k_i]] = k_i
        cols.append(idx)
        variables = tuple(i for i in range(nv) if c >> i & 1)
        pairs = tuple((p, int(i), int(j)) for p, (i, j) in enumerate(triu)
                      if c >> int(i) & 1 and c >> int(j) & 1)
        classes.append((off, k, variables, pairs))
        off += k
    idx = np.concatenate(cols, 1)  # (P, K') original column or -1
    take = np.maximum(idx, 0)
    rows = np.arange(P)[:, None]
    pad = idx < 0
    out = ProblemBatch(
        np.where(pad[..., None, None], 0.0, batch.A[rows, take]),
        np.where(pad[..., None], 0.0, batch.b[rows, take]),
        np.where(pad, 0.0, batch.c[rows, take]), np.where(pad, 0, batch.sign[rows, take]),
        np.where(pad, False, batch.active[rows, take]), batch.lo, batch.hi)
    return out, tuple(classes)


def _all_hold(classes, ok_of):
    """Where every constraint of every support class holds.

    ``ok_of(cls, cols)`` gives one class's [..., k] booleans (``cols`` its constraint columns).
    Reduced as float mins (XLA's CPU code for boolean reductions is slow).
    """
    m = [jnp.min(jnp.where(ok_of(cls, slice(cls[0], cls[0] + cls[1])), 1.0, 0.0), -1)
         for cls in classes]
    return functools.reduce(jnp.minimum, m) > 0


def _align(x, group):
    return (x + group - 1) // group * group


def _admit(st, lo0, hi0, n, pool, group):
    """Queue the next problems (one root box each, a fresh row group) into the free rows.

    Admission keeps Σ_{in flight, not oldest} rows(min(pool, 2·boxes)) ≤ rows − pool: the oldest
    problem can always grow to a full pool, and the others rarely wait for rows."""
    P = st["nbox"].shape[0]
    N = st["own"].shape[0]
    idx = jnp.arange(P, dtype=jnp.int32)
    fl = st["inflight"]
    has = fl.any()
    oldest = jnp.argmax(fl)
    grown = _align(jnp.minimum(pool, RESV * st["nbox"]), group)
    resv = jnp.where(fl & (idx != oldest), grown, 0).sum()
    room = (N - pool - resv) // _align(min(pool, RESV), group) + jnp.where(has, 0, 1)
    k = jnp.clip(jnp.minimum(room, n - st["nxt"]), 0)
    total = _align(st["nbox"], group).sum()
    r = jnp.arange(N, dtype=jnp.int32) - total
    new = (r >= 0) & (r % group == 0) & (r // group < k)
    p = st["nxt"] + r // group
    pj = jnp.clip(p, 0, P - 1)
    adm = (idx >= st["nxt"]) & (idx < st["nxt"] + k)
    return dict(st, l=jnp.where(new[:, None], lo0[pj], st["l"]),
                u=jnp.where(new[:, None], hi0[pj], st["u"]),
                own=jnp.where(new, p, st["own"]), inflight=fl | adm,
                nbox=jnp.where(adm, 1, st["nbox"]), age=jnp.where(adm, 0, st["age"]),
                nxt=st["nxt"] + k)


def _evaluate(T, l, u, own, xs, *, classes: tuple, group: int):
    """Prune and probe every row of the frontier.

    ``keep`` [N] where every constraint can hold in the box, ``good`` [M, N] where probe point m of
    a kept box satisfies every constraint. Each row group's problem table is gathered once.
    """
    N, nv = l.shape
    M = xs.shape[0]
    G = N // group
    Tg = _unpack(T[jnp.maximum(own.reshape(G, group).max(-1), 0)], nv)
    lg, ug = l.reshape(G, group, nv), u.reshape(G, group, nv)

    def can_hold(cls, col):  # each (one-sided) constraint can hold somewhere in the box
        return jnp.sign(_upper(Tg, lg, ug, cls)) >= Tg["s"][..., col]

    keep = (own >= 0) & _all_hold(classes, can_hold).reshape(N)
    xg = xs.reshape(M, G, group, nv)
    good = keep[None] & _all_hold(
        classes, lambda cls, col: jnp.sign(_values(Tg, xg, cls)) >= Tg["s"][..., col]
    ).reshape(M, N)
    return keep, good


def _round(T, st, ids, seed, min_width, *, pool: int, probes: int, max_iters: int, group: int,
           classes: tuple):
    """One bound / prune / witness / branch round for every problem in flight.

    The frontier's rows hold the boxes of the problems in flight, grouped by problem and in
    each problem's box order; a problem's rows start on a multiple of ``group``, so the
    constraint tables are gathered once per group of rows. A problem either runs the whole
    round (exactly the per-problem round of :mod:`.reference`) or, when its children would
    not fit the rows, waits for the next one unchanged (the oldest problem never waits)."""
    l, u, own = st["l"], st["u"], st["own"]
    N, nv = l.shape
    P = st["nbox"].shape[0]
    live = own >= 0
    o = jnp.where(live, own, 0)
    cur = st["nbox"]
    rows0 = _align(cur, group)  # rows each problem holds now
    start0 = jnp.cumsum(rows0) - rows0  # its first row
    ppos = jnp.arange(N, dtype=jnp.int32) - start0[o]  # box position within its problem
    # witness probes: the centre and `probes` uniform points of every box (centres first),
    # drawn at (problem, round, box, probe, coordinate): the same in any batching
    t = hash_uniform_at(seed, ids[o][None, :, None], st["age"][o][None, :, None],
                        ppos[None, :, None],
                        jnp.arange(probes * nv, dtype=jnp.int32).reshape(probes, 1, nv))
    t = t.astype(l.dtype)
    xs = jnp.concatenate([0.5 * (l + u)[None], l[None] + t * (u - l)[None]], 0)
    M = probes + 1
    keep, good = _evaluate(T, l, u, own, xs, classes=classes, group=group)
    # a problem's witness: its first good point in (probe, box) order, as in the reference
    order = jnp.arange(M, dtype=jnp.int32)[:, None] * pool + ppos[None]
    seg = jnp.where(live, own, P)
    first = jax.ops.segment_min(jnp.where(good, order, M * pool).min(0), seg, P + 1)[:P]
    found = first < M * pool
    wit = xs[jnp.minimum(first // pool, M - 1), jnp.clip(start0 + first % pool, 0, N - 1)]
    # survivors keep their order, split while the pool has room (children after them):
    # ranks within a problem from one running count per mask (rows of a problem are
    # contiguous, from start0)
    width = u - l
    splittable = keep & (width.max(-1) > min_width)
    cs = jnp.cumsum(jnp.stack([keep, splittable]).astype(jnp.int32), axis=1)
    cs = jnp.concatenate([jnp.zeros((2, 1), jnp.int32), cs], 1)  # cs[:, r] = count before r
    kpos, spos = cs[:, :N] - cs[:, start0[o]]
    n_keep, n_splittable = cs[:, start0 + cur] - cs[:, start0]
    do_split = splittable & (spos < pool - n_keep[o])
    n_split = jnp.minimum(n_splittable, jnp.maximum(pool - n_keep, 0))
    fl = st["inflight"]
    age = st["age"] + 1
    empty = n_keep == 0
    stuck = (n_split == 0) & ~empty
    finish = fl & (found | empty | stuck | (age >= max_iters))
    verdict = jnp.where(found, FEASIBLE, jnp.where(empty, INFEASIBLE, UNDECIDED))
    # who runs the round: the oldest problem, those that need no more rows, and the others
    # (in queue order) while their growth fits the rows not reserved for the oldest
    idx = jnp.arange(P, dtype=jnp.int32)
    is_old = idx == jnp.argmax(fl)
    cont = fl & ~finish
    need = n_keep + n_split
    grow = jnp.where(cont & ~is_old, jnp.maximum(_align(need, group) - rows0, 0), 0)
    base = jnp.where(fl & ~is_old, rows0, 0).sum()
    run = cont & (is_old | (grow == 0) | (base + jnp.cumsum(grow) <= N - pool))
    count = jnp.where(run, need, jnp.where(cont, cur, 0))
    rows = _align(count, group)
    start = jnp.cumsum(rows) - rows
    r_run = live & run[o]
    r_wait = live & cont[o] & ~run[o]
    dest_a = jnp.where(r_run & keep, start[o] + kpos, jnp.where(r_wait, start[o] + ppos, N))
    dest_b = jnp.where(r_run & do_split, start[o] + n_keep[o] + spos, N)
    axis = jax.nn.one_hot(jnp.argmax(width, -1), nv, dtype=bool)
    mid = 0.5 * (l + u)
    u_a = jnp.where((r_run & do_split)[:, None] & axis, mid, u)  # lower halves stay in place
    l_b = jnp.where(axis, mid, l)  # upper halves go after the survivors
    # one scatter moves boxes and owners (owners ride along as exact small floats)
    fo = own.astype(l.dtype)[:, None]
    src = jnp.concatenate([jnp.concatenate([l, u_a, fo], 1),
                           jnp.concatenate([l_b, u, fo], 1)], 0)
    dst = jnp.concatenate([dest_a, dest_b])
    init = jnp.zeros((N, 2 * nv + 1), l.dtype).at[:, -1].set(-1)
    new = init.at[dst].set(src, mode="drop")
    return dict(st, l=new[:, :nv], u=new[:, nv:2 * nv], own=new[:, -1].astype(jnp.int32),
                inflight=cont, nbox=count, age=jnp.where(run, age, st["age"]),
                status=jnp.where(finish, verdict, st["status"]),
                witness=jnp.where(finish[:, None], wit, st["witness"]))


@partial(jax.jit, static_argnames=("rows", "pool", "max_iters", "probes", "group", "classes"))
def _solve(A, b, c, sign, active, lo0, hi0, ids, min_width, seed, n, *, rows: int, pool: int,
           max_iters: int, probes: int, group: int, classes: tuple):
    """Every problem through one frontier of ``rows`` box rows (a work queue of problems).

    Arrays are padded to a bucket size P; only the first ``n`` (traced) problems are queued.
    """
    P, _, nv = b.shape
    dtype = lo0.dtype
    T = _tables(A, b, c, sign, active)
    st = dict(l=jnp.zeros((rows, nv), dtype), u=jnp.zeros((rows, nv), dtype),
              own=jnp.full(rows, -1, jnp.int32), inflight=jnp.zeros(P, bool),
              nbox=jnp.zeros(P, jnp.int32), age=jnp.zeros(P, jnp.int32),
              status=jnp.full(P, UNDECIDED, jnp.int32), witness=jnp.zeros((P, nv), dtype),
              nxt=jnp.int32(0), it=jnp.int32(0))

    def body(st):
        st = _round(T, st, ids, seed, min_width, pool=pool, probes=probes, max_iters=max_iters,
                    group=group, classes=classes)
        st = _admit(st, lo0, hi0, n, pool, group)
        return dict(st, it=st["it"] + 1)

    st = jax.lax.while_loop(lambda st: st["inflight"].any(), body,
                            _admit(st, lo0, hi0, n, pool, group))
    return st["status"], st["witness"], st["it"]


def solve(batch: ProblemBatch, *, pool: int = 32, max_iters: int = 120,
          min_width: float = 2.0**-24, frontier: int = 1024, probes: int = 2, seed: int = 0,
          chunk: int = 8192, progress: bool = False, desc: str = "feasibility",
          classes: tuple | None = None, parts: int | None = None,
          ids: np.ndarray | None = None) -> Solution:
    """Solve every problem of ``batch`` in jit-compiled work-queue programs (float64).

    The boxes of all problems in flight share one frontier; a decided problem frees its rows for
    the next ones of the queue, so easy problems never wait for hard ones and the work per round
    follows the live boxes (docs/tables.md §feasibility).

    Args:
        batch: the problems (box, quadratic constraints, signs, active masks).
        pool: the most boxes one problem may hold.
        max_iters: the most rounds one problem may run.
        min_width: boxes narrower than this are no longer split.
        frontier: rows of the shared frontier of boxes.
        probes: random probe points per surviving box and round.
        seed: seed of the probe-point hash.
        chunk: problems sent to the device per call (progress is reported per chunk).
        progress: show a progress bar.
        desc: the progress bar's label.
        classes: a batch already in the form of :func:`support_classes` and its class list (so
            that its problems can be solved one at a time by one compiled program); by default
            every chunk is reordered here.
        parts: number of queues run side by side in threads by one compiled program (default:
            one per usable core on CPU, :func:`pqrm_jax._parallel.default_queues`).
        ids: the problems' ids (default: their positions). Probe points are drawn at (problem
            id, round, box, coordinate), so verdicts and witnesses do not depend on ``parts``,
            ``chunk`` or which problems share a batch.

    Returns:
        A :class:`Solution`: per problem FEASIBLE (with a witness), INFEASIBLE or UNDECIDED.

    >>> from pqrm_jax import calculi
    >>> from pqrm_jax.tables import problems as pb
    >>> probs = pb.random_compose_problems(calculi.get("edc"), 8)
    >>> sol = solve(pb.to_batch(probs, 8.0))
    >>> sorted(set(sol.status.tolist())) <= [UNDECIDED, INFEASIBLE, FEASIBLE]
    True
    """
    P = batch.size
    ids = np.arange(P) if ids is None else np.asarray(ids)
    parts = default_queues() if parts is None else parts
    status = np.full(P, UNDECIDED, np.int8)
    witness = np.zeros((P, batch.b.shape[-1]))
    iters = 0
    group = math.gcd(pool, GROUP)  # rows per table gather; a problem's rows start on a multiple
    starts = range(0, P, chunk)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=desc, unit="chunk", leave=False)
    with jax.enable_x64(True):
        for s in starts:
            sub = batch.take(slice(s, s + chunk))
            sub, cls = support_classes(sub) if classes is None else (sub, classes)
            n = sub.size
            k = max(1, min(parts, n // max(1, frontier // pool)))  # each queue fills its rows
            queues = [np.arange(q, n, k) for q in range(k)]  # dealt: hard ones spread out
            m = len(queues[0])
            bucket = 1 << (m - 1).bit_length()  # few distinct shapes → few compiles
            static = dict(rows=max(1, min(frontier // pool, m)) * pool,  # what a queue uses
                          pool=pool, group=group, max_iters=max_iters, probes=probes,
                          classes=cls)

            def run(idx, sub=sub, s=s, bucket=bucket, static=static):
                part = sub.take(np.concatenate([idx, np.repeat(idx[-1:], bucket - len(idx))]))
                # NumPy arguments of the final dtypes: the queues run in threads, and an
                # eager jnp conversion compiles a small program that two threads dispatching
                # it at once would each compile (JAX serialises jit compiles only)
                f64 = partial(np.asarray, dtype=np.float64)
                out = _solve(
                    f64(part.A), f64(part.b), f64(part.c), np.asarray(part.sign, np.int32),
                    np.asarray(part.active, bool), f64(part.lo), f64(part.hi),
                    np.asarray(ids[s + idx].tolist() + [0] * (bucket - len(idx)), np.uint32),
                    np.float64(min_width), np.uint32(seed), np.int32(len(idx)), **static)
                return [np.asarray(x) for x in out]

            results = side_by_side(run, queues)
            for idx, (st, wit, it) in zip(queues, results, strict=True):
                status[s + idx] = st[:len(idx)]
                witness[s + idx] = wit[:len(idx)]
                iters += int(it)
    return Solution(status, witness, iters)
