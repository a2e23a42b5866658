"""Plain NumPy reference of the SERGE merge search (Padgett Alg. 2, §3.3).

Runs the trials of :func:`pqrm_jax.serge.serge` one after another in a Python loop, in
NumPy, without the pair-gain cache, with the same seeds and the same random region order, so
that tests and benchmarks can compare the batched program with a plain implementation.

What is shared with the batched search and how closely the results agree:
docs/serge.md §reference.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._hashrng import mix32, to_unit
from .cells import Problem
from .potential import SAL_FLOOR, log_psi1
from .search import SergeResult, compact_result, prepare_inputs

_F32 = np.float32
_FLOOR = _F32(SAL_FLOOR)


def _hash_uniform_np(seed: np.uint32, counter: int, mix: np.ndarray) -> np.ndarray:
    """NumPy twin of ``_hashrng.hash_uniform``; ``mix`` = ``arange(n, uint32) * 0x85EBCA6B``."""
    return to_unit(mix32(mix ^ np.uint32((int(seed) ^ (int(counter) * 0x9E3779B9))
                                         & 0xFFFFFFFF)))


def _trial_np(lab0, mt0, adj0, lb0, bmask, alive0, lp1, seed, mix):
    """One trial (Alg. 2 lines 5–28) in NumPy.

    Returns (labels, |R|, log ψ, log ψ1, log ψ3, steps).
    """
    r0, k = mt0.shape
    ar = np.arange(r0)
    kk = np.arange(k)
    lab, mt, adj, lb, alive = lab0.copy(), mt0.copy(), adj0.copy(), lb0.copy(), alive0.copy()
    logs = np.log(np.maximum(mt[lb, kk], _FLOOR))                     # log S_k
    tried = np.zeros(r0, bool)
    count = int(alive.sum())
    max_iter = r0 * (r0 + 1) + 2
    it = 0
    while it < max_iter:
        cand = alive & ~tried
        if not cand.any():
            break
        n = int(np.argmax(np.where(cand, _hash_uniform_np(seed, it, mix), _F32(-1.0))))
        # gains of merging n with every region m (only the beliefs of n and m change)
        in_n = (lb == n) & bmask
        idx = np.flatnonzero(in_n)
        part_n = np.sum(np.log(np.maximum(mt[n, idx][None, :] + mt[:, idx], _FLOOR))
                        - logs[idx][None, :], axis=1)                 # (R0,) beliefs of n
        other = bmask & ~in_n
        vm = np.log(np.maximum(mt[n] + mt[lb, kk], _FLOOR)) - logs    # (K,) beliefs of m
        part_m = np.bincount(lb[other], weights=vm[other], minlength=r0)[:r0].astype(_F32)
        delta = np.where(adj[n] & alive, part_n + part_m, _F32(-np.inf))
        t = int(np.argmax(delta))
        gain = delta[t] + lp1[count - 1] - lp1[count]
        if gain > 0:                                                  # merge C_n into C_t
            mt[t] += mt[n]
            lb[lb == n] = t
            in_t = lb == t
            logs[in_t] = np.log(np.maximum(mt[t, in_t], _FLOOR))
            alive[n] = False
            row = (adj[t] | adj[n]) & alive & (ar != t)
            adj[t], adj[:, t] = row, row
            lab[lab == n] = t
            count -= 1
            tried[:] = False
        else:
            tried[n] = True
        it += 1
    l3 = np.sum(np.where(bmask, logs, _F32(0)), dtype=_F32)
    l1 = lp1[count]
    return lab, count, _F32(l1 + l3), l1, l3, it


def trial_seeds(key: jax.Array, trials: int, chunk: int = 1024) -> np.ndarray:
    """(trials,) uint32 seeds of :func:`serge`'s trials (same key derivation and chunking)."""
    chunk = min(chunk, trials)
    tt = math.ceil(trials / chunk) * chunk
    keys = jax.random.split(key, tt)[:trials]
    return np.asarray(jax.vmap(lambda k: jax.random.bits(k, (), jnp.uint32))(keys))


def serge_reference(
    key: jax.Array,
    problem: Problem,
    mu: int,
    sigma: float = 2.0,
    *,
    trials: int | None = None,
    active=None,
    start=None,
    chunk: int = 1024,
    return_trials: bool = False,
) -> SergeResult | tuple[SergeResult, np.ndarray]:
    """Plain NumPy SERGE (Alg. 2, P§3.3), one trial at a time.

    The trials of :func:`serge` (same arguments, same seeds for trial i) run one after another;
    the best map by log ψ is kept (docs/serge.md §reference).

    Args:
        key: PRNG key, split as :func:`serge` splits it.
        problem: the SERGE problem.
        mu: the count prior's mean number of regions.
        sigma: the count prior's standard deviation.
        trials: number of trials; defaults to 100·K + 1 as in :func:`serge`.
        active: [R0] bool, restrict the search to some initial regions.
        start: [R0] a coarser contiguous partition to start from.
        chunk: trials per key split, as in :func:`serge`.
        return_trials: also return the final labels of every trial.

    Returns:
        The best trial as a :class:`~pqrm_jax.serge.search.SergeResult`; with ``return_trials``
        also the [T, R0] final labels of every trial.

    Raises:
        ValueError: for ``trials < 1`` or bad prior parameters.

    >>> import jax, numpy as np
    >>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells
    >>> xy = np.stack(np.meshgrid(np.arange(3.), np.arange(3.)), -1).reshape(-1, 2) * 10
    >>> p = initial_cells(jax.random.PRNGKey(0),
    ...                   GaussianBeliefs(xy, np.tile(np.eye(2) * .2, (9, 1, 1))),
    ...                   Grid((-5., -5.), (25., 25.), (30, 30)))
    >>> r = serge_reference(jax.random.PRNGKey(0), p, mu=4, sigma=2.0, trials=64)
    >>> r.n_regions, abs(round(r.log_psi3, 4))
    (4, 0.0)
    """
    mass, adj, belief_region, lab0, act, _, _ = (np.asarray(x) for x in
                                                 prepare_inputs(problem, mu, sigma, active, start))
    t = 100 * problem.k + 1 if trials is None else int(trials)
    if t < 1:
        raise ValueError(f"serge_reference: trials must be ≥ 1, got {trials}")
    seeds = trial_seeds(key, t, chunk)

    # key-independent start (as search._setup): region masses, adjacency, beliefs
    r0 = mass.shape[1]
    lab0 = lab0.astype(np.int64)
    oh = ((lab0[:, None] == np.arange(r0)[None, :]) & act[:, None]).astype(_F32)
    mt0 = (oh.T @ mass.T.astype(_F32)).astype(_F32)                   # (R0, K)
    a0 = (oh.T @ adj.astype(_F32) @ oh) > 0
    np.fill_diagonal(a0, False)
    alive0 = oh.any(axis=0)
    lb0 = lab0[belief_region]
    bmask = act[belief_region]
    labs0 = np.where(act, lab0, -1)
    # log ψ1(c) for c = 0..R0 (eq. 3.5), the program's own float32 values, evaluated once
    lp1 = np.asarray(log_psi1(jnp.arange(r0 + 1), _F32(mu), _F32(sigma), int(bmask.sum()),
                              int(bmask.size)), _F32)
    mix = np.arange(r0, dtype=np.uint32) * np.uint32(0x85EBCA6B)

    outs = [_trial_np(labs0, mt0, a0, lb0, bmask, alive0, lp1, s, mix) for s in seeds]
    lab = np.stack([o[0] for o in outs])
    lp, l1, l3 = (np.array([o[j] for o in outs], _F32) for j in (2, 3, 4))
    it = np.array([o[5] for o in outs], np.int32)
    best = int(np.argmax(lp))
    res = compact_result(problem, lab[best], mu, sigma, (lp, l1, l3), it, best)
    return (res, lab) if return_trials else res
