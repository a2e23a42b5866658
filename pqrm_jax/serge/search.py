"""The SERGE merge search (Padgett Alg. 2, §3.3) as one batched, jit-compiled program.

Offers the batched search over T random-order trials (the best trial by log ψ is kept), the
same trial run one at a time for comparison, and the direct pair-gain evaluation that the
incremental cache is tested against. Regions stay contiguous by construction (ψ2 = 1).

Trial convergence, blocks of trials, the incremental potential and the bit-set bookkeeping:
docs/serge.md §search.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._hashrng import hash_uniform
from .._parallel import default_queues, side_by_side
from .cells import Problem
from .potential import SAL_FLOOR, check_params, log_psi1

BLOCK = 8          # beliefs of the merged region evaluated per inner step
WIDTH = 64         # trials per vmapped block (the per-trial state then stays in cache)


def _setup(mass, adj, belief_region, lab0, active):
    r0 = mass.shape[1]
    ar = jnp.arange(r0)
    onehot = (lab0[:, None] == ar[None, :]) & active[:, None]
    oh = onehot.astype(mass.dtype)
    mt = oh.T @ mass.T                                                # (R0, K) region-major
    a = (oh.T @ adj.astype(mass.dtype) @ oh) > 0
    a = a & ~jnp.eye(r0, dtype=bool)
    alive = jnp.any(onehot, axis=0)
    lb = lab0[belief_region]
    bmask = active[belief_region]
    lab = jnp.where(active, lab0, -1)
    return lab, mt, a, lb, alive, bmask


def pair_gains(mt, a, lb, alive, bmask):
    """Direct [R0, R0] saliency gain of merging every adjacent alive pair (n, m).

    ``G[n, m] = Σ_{k ∈ n ∪ m} log(M_kn + M_km) − log M_{k L_k}`` (−inf where not adjacent).
    Symmetric; the initial value of the merge search's incremental cache.
    """
    r0, k = mt.shape
    ar = jnp.arange(r0)
    sal = mt.T[jnp.arange(k), lb]                                     # (K,) S_k
    logs = jnp.log(jnp.maximum(sal, SAL_FLOOR))
    p = jnp.log(jnp.maximum(mt[:, None, :] + mt[None, :, :], SAL_FLOOR)) - logs
    own = (lb[None, :] == ar[:, None]) & bmask[None, :]               # (R0, K) k ∈ region
    aff = own[:, None, :] | own[None, :, :]
    g = jnp.sum(jnp.where(aff, p, 0.0), axis=2)
    ok = a & alive[:, None] & alive[None, :]
    return jnp.where(ok, g, -jnp.inf)


def _ctz(x):
    """Count of trailing zero bits of uint32 x (32 for x = 0)."""
    return jax.lax.population_count((x & (~x + jnp.uint32(1))) - jnp.uint32(1)).astype(jnp.int32)


def _pop_lowest(words, n):
    """Indices of the n lowest set bits of the bit set ``words`` (uint32, 32 per word).

    Returns them in increasing order, whether each was found, and the remaining set
    (elementwise integer ops: cheap under vmap, unlike a cumsum, sort or scatter).
    """
    idx, found = [], []
    for _ in range(n):
        i_s, f_s = jnp.int32(0), jnp.bool_(False)
        new = []
        for w in range(words.shape[0]):
            x = words[w]
            hit = ~f_s & (x != 0)
            i_s = jnp.where(hit, 32 * w + _ctz(x), i_s)
            new.append(jnp.where(hit, x & (x - jnp.uint32(1)), x))
            f_s = f_s | hit
        words = jnp.stack(new)
        idx.append(i_s)
        found.append(f_s)
    return jnp.stack(idx), jnp.stack(found), words


def _argmax(x):
    """(first index of the maximum, maximum) of a NaN-free vector.

    ``jnp.argmax`` as two plain reductions (a variadic argmax reduction is slow on CPU under
    vmap).
    """
    m = jnp.max(x)
    return jnp.min(jnp.where(x == m, jnp.arange(x.shape[0], dtype=jnp.int32), x.shape[0])), m


def _bitset(mask):
    """(R, ceil(K/32)) uint32 bit sets of a [R, K] bool mask (bit k%32 of word k//32)."""
    r, k = mask.shape
    nw = -(-k // 32)
    bits = jnp.pad(mask, ((0, 0), (0, 32 * nw - k))).reshape(r, nw, 32).astype(jnp.uint32)
    return jnp.sum(bits << jnp.arange(32, dtype=jnp.uint32), axis=2, dtype=jnp.uint32)


def _row_gain(mt, row_t, t, lb, logs, sal, bmask, words):
    """[R0] gain of merging the (just merged) region t with every region m.

    Computed from the beliefs of t (in blocks of ``BLOCK`` in increasing index order, a while
    loop over the blocks
    actually used) and the beliefs of each m (a segment sum over all beliefs). ``words``: the
    bit set of the beliefs of t (empty for a rejected merge, whose row is discarded: no
    blocks)."""
    r0, k = mt.shape
    in_t = (lb == t) & bmask
    def cond(c):
        return jnp.any(c[1] != 0)

    def body(c):
        j, words, acc = c
        idx, valid, words = _pop_lowest(words, BLOCK)
        cols = mt[:, idx]                                             # (R0, BLOCK)
        v = jnp.log(jnp.maximum(row_t[idx][None, :] + cols, SAL_FLOOR)) - logs[idx][None, :]
        return j + 1, words, acc + jnp.sum(jnp.where(valid[None, :], v, 0.0), axis=1)

    _, _, part_t = jax.lax.while_loop(cond, body, (jnp.int32(0), words,
                                                   jnp.zeros(r0, mt.dtype)))
    vm = jnp.log(jnp.maximum(sal + row_t, SAL_FLOOR)) - logs          # (K,) for k in m
    vm = jnp.where(bmask & ~in_t, vm, 0.0)
    part_m = jax.ops.segment_sum(vm, jnp.where(bmask & ~in_t, lb, r0), num_segments=r0 + 1)
    return part_t + part_m[:r0]


def _init_state(mass, adj, belief_region, lab0, active):
    """Key-independent start of every trial (computed once, shared by all trials)."""
    lab, mt, a, lb, alive, bmask = _setup(mass, adj, belief_region, lab0, active)
    k = mass.shape[0]
    sal = mt.T[jnp.arange(k), lb]
    logs = jnp.log(jnp.maximum(sal, SAL_FLOOR))
    g = pair_gains(mt, a, lb, alive, bmask)
    bs = _bitset((lb[None, :] == jnp.arange(mt.shape[0])[:, None]) & bmask[None, :])
    return lab, mt, g, lb, logs, sal, alive, bmask, bs


def _trial_fns(init, mu, sigma, max_steps=None, branch=False):
    """(start, cond, body) of one merge-search trial (Alg. 2 lines 5–28) from ``init``.

    ``init`` is the shared start; ``body(s, active)`` is one step; with ``active`` False it leaves
    ``s`` unchanged (the batched program steps every trial of a block until all have converged).
    """
    lab, mt, g, lb, logs, sal, alive, bmask, bs = init
    k_static, r0 = mt.shape[1], mt.shape[0]
    ar = jnp.arange(r0)
    k_max = jnp.sum(bmask)
    count = jnp.sum(alive)
    max_iter = r0 * (r0 + 1) + 2 if max_steps is None else max_steps

    def lp1(c):
        return log_psi1(c, mu, sigma, k_max, k_static)

    def merge(s, n, t, accept):
        # merge C_n into C_t; with ``accept`` False every update is a no-op (the branch-free
        # form used when batched: only rows t and n of the state are touched, never the
        # whole [R0, K] / [R0, R0] arrays)
        lab, mt, g, lb, logs, sal, alive, bs = s
        row_t = mt[t] + jnp.where(accept, mt[n], 0.0)
        words = jnp.where(accept, bs[t] | bs[n], 0)                  # beliefs of t ∪ n
        bs = bs.at[t].set(jnp.where(accept, words, bs[t]))
        mt = mt.at[t].set(row_t)
        lb = jnp.where((lb == n) & accept, t, lb)
        in_t = (lb == t) & accept
        logs = jnp.where(in_t, jnp.log(jnp.maximum(row_t, SAL_FLOOR)), logs)
        sal = jnp.where(in_t, row_t, sal)
        alive = alive & ~((ar == n) & accept)
        adj_t = (jnp.isfinite(g[t]) | jnp.isfinite(g[n])) & alive & (ar != t)
        gt = jnp.where(adj_t, _row_gain(mt, row_t, t, lb, logs, sal, bmask, words),
                       -jnp.inf)
        gt = jnp.where(accept, gt, g[t])
        g = g.at[t].set(gt).at[:, t].set(gt)
        lab = jnp.where((lab == n) & accept, t, lab)
        return lab, mt, g, lb, logs, sal, alive, bs

    def start(key):
        seed = jax.random.bits(key, (), jnp.uint32)
        return (lab, mt, g, lb, logs, sal, alive, jnp.zeros(r0, bool), count, seed,
                jnp.int32(0), bs)

    def cond(s):
        alive, tried, it = s[6], s[7], s[10]
        return jnp.any(alive & ~tried) & (it < max_iter)

    def body(s, active=True):
        *st, tried, count, seed, it, bs = s
        st = (*st, bs)
        g, alive = st[2], st[6]
        cand = alive & ~tried
        n, _ = _argmax(jnp.where(cand, hash_uniform(seed, it.astype(jnp.uint32), r0), -1.0))
        delta = jnp.where(alive, g[n], -jnp.inf)
        t, best = _argmax(delta)
        gain = best + lp1(count - 1) - lp1(count)
        accept = (gain > 0) & active
        if branch:
            st = jax.lax.cond(accept, lambda s: merge(s, n, t, True), lambda s: s, tuple(st))
        else:
            st = merge(tuple(st), n, t, accept)
        tried = jnp.where(accept, False, tried | ((ar == n) & active))
        *st, bs = st
        return (*st, tried, jnp.where(accept, count - 1, count), seed,
                it + jnp.asarray(active, jnp.int32), bs)

    return start, cond, body


def _run_trial(init, mu, sigma, key, max_steps=None, branch=False):
    """One merge-search trial (Alg. 2 lines 5–28) from the shared start ``init``.

    Returns the final state (jit-able). ``max_steps`` stops early (tests of the incremental cache).
    ``branch`` applies the merge under ``lax.cond`` (skips work for a single trial; under vmap a
    cond becomes a select over the whole state, so the batched program uses the branch-free form).
    Both give the same result. The batched program runs the same step (:func:`_run_block`).
    """
    start, cond, body = _trial_fns(init, mu, sigma, max_steps, branch)
    return jax.lax.while_loop(cond, body, start(key))


def _run_block(init, mu, sigma, keys):
    """The trials of ``keys`` stepped together in one while loop over the block.

    Each step is a vmapped trial step masked by whether that trial is still running (a vmapped
    while loop would instead select the whole state of every trial at every step).
    """
    start, cond, body = _trial_fns(init, mu, sigma)
    vcond, vbody = jax.vmap(cond), jax.vmap(body)

    def bbody(c):
        s, act = c
        s = vbody(s, act)
        return s, vcond(s)

    s0 = jax.vmap(start)(keys)
    s, _ = jax.lax.while_loop(lambda c: jnp.any(c[1]), bbody, (s0, vcond(s0)))
    return s


def _trial(mass, adj, belief_region, lab0, active, mu, sigma, key):
    """One trial from the problem (setup + search); used one at a time by the reference."""
    init = _init_state(mass, adj, belief_region, lab0, active)
    return _result(init, _run_trial(init, mu, sigma, key), mu, sigma)


def _result(init, s, mu, sigma):
    bmask = init[7]
    lab, mt, g, lb, logs, sal, alive, tried, count, seed, it = s[:11]
    k_static = mt.shape[1]
    lp3 = jnp.sum(jnp.where(bmask, logs, 0.0))
    l1 = log_psi1(count, mu, sigma, jnp.sum(bmask), k_static)
    return lab, count, l1 + lp3, l1, lp3, it


@partial(jax.jit, static_argnames=("width",))
def _trials_batched(mass, adj, belief_region, lab0, active, mu, sigma, keys, width):
    init = _init_state(mass, adj, belief_region, lab0, active)
    def f(kk):
        return jax.vmap(lambda s: _result(init, s, mu, sigma))(_run_block(init, mu, sigma, kk))

    t = keys.shape[0]
    if width >= t:
        return f(keys)
    out = jax.lax.map(f, keys.reshape(t // width, width, *keys.shape[1:]))
    return jax.tree.map(lambda x: x.reshape(t, *x.shape[2:]), out)


_init_jit = jax.jit(_init_state)


@partial(jax.jit, static_argnames=("branch",))
def _one_trial(init, mu, sigma, key, branch=True):
    return _result(init, _run_trial(init, mu, sigma, key, branch=branch), mu, sigma)


@dataclass(frozen=True)
class SergeResult:
    """Best SR map of a SERGE run.

    Attributes:
        problem: the problem that was solved.
        mu: the count prior's mean used.
        sigma: the count prior's standard deviation used.
        region_of_init: [R0] compact region 0..|R|−1 of every initial region (−1 inactive).
        cell_labels: [N] region of every fine cell (−1 outside the active part).
        belief_labels: [K] ``L^B`` (−1 for beliefs outside the active part).
        n_regions: |R|, the number of regions of the best map.
        log_psi: ``log_psi1 + log_psi3`` (ψ2 = 1) of the best trial.
        log_psi1: log of the count prior ψ1 of the best map.
        log_psi3: log of the saliency term ψ3 of the best map.
        trial_log_psi: [T] log ψ of every trial.
        iterations: [T] merge-search steps of every trial.
    """

    problem: Problem
    mu: int
    sigma: float
    region_of_init: np.ndarray
    cell_labels: np.ndarray
    belief_labels: np.ndarray
    n_regions: int
    log_psi: float
    log_psi1: float
    log_psi3: float
    trial_log_psi: np.ndarray
    iterations: np.ndarray

    def label_points(self, points) -> np.ndarray:
        """Region of each point [..., 2] (outside the grid → nearest border cell)."""
        return self.cell_labels[np.asarray(self.problem.grid.cell_of(np.asarray(points)))]

    def saliency(self) -> np.ndarray:
        """[K] saliency S_k of each belief in its region (training beliefs)."""
        pm = np.asarray(self.problem.cell_mass, np.float64)
        own = self.cell_labels[None, :] == np.asarray(self.belief_labels)[:, None]  # (K, N)
        return (pm * own).sum(1)


def compact_result(problem: Problem, lab: np.ndarray, mu, sigma, logs, iters, best) -> SergeResult:
    lab = np.asarray(lab)
    reps = np.unique(lab[lab >= 0])
    remap = np.full(problem.n_init, -1, dtype=np.int64)
    remap[reps] = np.arange(len(reps))
    region_of_init = np.where(lab >= 0, remap[np.maximum(lab, 0)], -1)
    cell_labels = region_of_init[problem.cell_region]
    br = np.asarray(problem.belief_region)
    belief_labels = region_of_init[br]
    lp, l1, l3 = (float(np.asarray(x)[best]) for x in logs)
    return SergeResult(problem, int(mu), float(sigma), region_of_init, cell_labels,
                       belief_labels, len(reps), lp, l1, l3, np.asarray(logs[0]),
                       np.asarray(iters))


def prepare_inputs(problem: Problem, mu, sigma, active, start):
    r0 = problem.n_init
    active = np.ones(r0, bool) if active is None else np.asarray(active, bool)
    if active.shape != (r0,):
        raise ValueError(f"serge: active must have shape ({r0},), got {active.shape}")
    k_max = int(active[np.asarray(problem.belief_region)].sum())
    n_act = int(active.sum())
    if n_act == 0:
        raise ValueError("serge: no active initial region")
    check_params(mu, sigma, k_max, problem.grid.n_cells)
    lab0 = np.arange(r0) if start is None else np.asarray(start, np.int64)
    if lab0.shape != (r0,) or np.any(lab0[lab0] != lab0):
        raise ValueError("serge: start must map every initial region to a representative "
                         "initial region (start[start] == start)")
    return (problem.mass, problem.adj, problem.belief_region, jnp.asarray(lab0, jnp.int32),
            jnp.asarray(active), jnp.float32(mu), jnp.float32(sigma))


def serge(
    key: jax.Array,
    problem: Problem,
    mu: int,
    sigma: float = 2.0,
    *,
    trials: int | None = None,
    active=None,
    start=None,
    chunk: int = 1024,
) -> SergeResult:
    """Run SERGE (Alg. 2) with ``trials`` random-order trials batched; keep the best map.

    Args:
        key: PRNG key; trial i depends only on its own key, so results do not depend on
            ``chunk`` or on the number of queues.
        problem: the SERGE problem (initial regions, masses, adjacency; :func:`initial_cells`).
        mu: the count prior's mean number of regions, an integer in 1..min(K, N).
        sigma: the count prior's standard deviation (finite, ≥ 0).
        trials: number of trials T; defaults to 100·K + 1 (P§3.3 suggests T > 100·K).
        active: [R0] bool, restricts the search to some initial regions and their beliefs (a
            branch of the resolution tree, P§3.3.1).
        start: [R0] a coarser contiguous partition to start from instead of ``C_init`` (used by
            the relaxed optimiser).
        chunk: trials per key split (keeps the key derivation independent of T).

    Returns:
        The best trial by log ψ as a :class:`SergeResult` (with every trial's log ψ).

    Raises:
        ValueError: for ``trials < 1``, ``mu`` outside 1..min(K, N) or a bad ``sigma``.

    >>> import jax, numpy as np
    >>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells, serge
    >>> xy = np.stack(np.meshgrid(np.arange(3.), np.arange(3.)), -1).reshape(-1, 2) * 10
    >>> p = initial_cells(jax.random.PRNGKey(0),
    ...                   GaussianBeliefs(xy, np.tile(np.eye(2) * .2, (9, 1, 1))),
    ...                   Grid((-5., -5.), (25., 25.), (30, 30)))
    >>> r = serge(jax.random.PRNGKey(0), p, mu=4, sigma=2.0, trials=64)
    >>> r.n_regions, abs(round(r.log_psi3, 4))
    (4, 0.0)
    """
    args = prepare_inputs(problem, mu, sigma, active, start)
    t = 100 * problem.k + 1 if trials is None else int(trials)
    if t < 1:
        raise ValueError(f"serge: trials must be ≥ 1, got {trials}")
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"serge: chunk must be an integer ≥ 1, got {chunk!r}")
    chunk = min(int(chunk), t)
    tt = math.ceil(t / chunk) * chunk
    # key derivation unchanged (split into a multiple of ``chunk``); a trial depends only on
    # its own key, so only the first t are run, in vmapped blocks of WIDTH trials
    keys = jax.random.split(key, tt)[:t]
    width = min(WIDTH, t)
    q = max(1, min(default_queues(), t // width))  # blocks dealt to side-by-side queues
    tp = math.ceil(t / (width * q)) * width * q
    if tp > t:
        keys = jnp.concatenate([keys, jnp.repeat(keys[-1:], tp - t, axis=0)])
    outs = side_by_side(lambda kq: [np.asarray(x) for x in _trials_batched(*args, kq, width)],
                        [keys[i * tp // q:(i + 1) * tp // q] for i in range(q)])
    lab, _, lp, l1, l3, it = (np.concatenate(x)[:t] for x in zip(*outs, strict=True))
    best = int(np.argmax(lp))
    return compact_result(problem, lab[best], mu, sigma, (lp, l1, l3), it, best)


def serge_sequential(key: jax.Array, problem: Problem, mu: int, sigma: float = 2.0, *,
                     trials: int, active=None, start=None, branch: bool = False) -> SergeResult:
    """Reference: the trials of :func:`serge`, one at a time in a Python loop of jitted trials.

    The keys are those of :func:`serge` with ``chunk ≥ trials``; the shared start is computed
    once.
    ``branch`` applies each merge under ``lax.cond`` (skips the merge work on rejected
    steps); the default is the branch-free step that the batched program vmaps. On one core
    of a 2-core CPU the two take 13–28 µs per step (noisy; the cond form is the faster),
    against ≈ 1.5 µs per trial-step batched; same results either way.

    Args:
        key, problem, mu, sigma, trials, active, start: as :func:`serge`.
        branch: apply each merge under ``lax.cond``.

    Returns:
        :class:`SergeResult`, equal to :func:`serge`'s.
    """
    args = prepare_inputs(problem, mu, sigma, active, start)
    keys = jax.random.split(key, trials)
    mass, adj, belief_region, lab0, active, mu_, sigma_ = args
    init = _init_jit(mass, adj, belief_region, lab0, active)      # shared start, once
    outs = [jax.tree.map(np.asarray, _one_trial(init, mu_, sigma_, keys[i], branch))
            for i in range(trials)]
    lab = np.stack([o[0] for o in outs])
    lp, l1, l3, it = (np.array([o[j] for o in outs]) for j in (2, 3, 4, 5))
    best = int(np.argmax(lp))
    return compact_result(problem, lab[best], mu, sigma, (lp, l1, l3), it, best)
