"""The SERGE merge search (Padgett Alg. 2, §3.3) as one batched, jit-compiled program.

One *trial* starts from ``C_init`` (one contiguous region per belief) and repeatedly picks a
random current region ``C_n``, evaluates merging it into each neighbouring region ``C_m``
(beliefs assigned to ``C_n`` follow it, Alg. 2 lines 13–19) and applies the best merge when it
raises ψ (lines 20–26). A trial has converged when every current region has been tried since
the last merge without an improving merge (the random choice of line 10 is made without
replacement among the untried regions). Merging two adjacent connected regions gives a
connected region, so ψ2 = 1 throughout — contiguity is guaranteed by construction.

All T trials are independent and run as one ``vmap`` of a ``lax.while_loop`` with static
shapes: the state of a trial is the (R0,) map from initial regions to current regions, the
(K, R0) belief-by-region masses, the (R0, R0) region adjacency and masks. The best trial by
log ψ is kept (Alg. 2 lines 28–32).

Only the beliefs assigned to ``C_n`` or ``C_m`` change saliency under a merge, so the gain of
merging n into m is ``Σ_{k: L_k ∈ {n, m}} [log(M_kn + M_km) − log M_{k L_k}]`` plus the change of
log ψ1; it is evaluated for all m at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .cells import Problem
from .potential import SAL_FLOOR, check_params, log_psi1, log_saliency


def _hash_uniform(seed, counter, n):
    """n uniforms in [0, 1) from a uint32 seed and counter (a cheap integer hash; much faster
    than threefry when batched over thousands of trials)."""
    x = seed ^ (counter * jnp.uint32(0x9E3779B9)) ^ (jnp.arange(n, dtype=jnp.uint32)
                                                     * jnp.uint32(0x85EBCA6B))
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    x = x ^ (x >> 16)
    return (x >> 8).astype(jnp.float32) * (1.0 / (1 << 24))


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


def _trial(mass, adj, belief_region, lab0, active, mu, sigma, key):
    """One merge-search trial (Alg. 2 lines 5–28); jit/vmap-able.

    Written with one-hot masks instead of scatters so that, batched over trials, every
    update is a fused element-wise pass.
    """
    k_static, r0 = mass.shape
    ar = jnp.arange(r0)
    lab, mt, a, lb, alive, bmask = _setup(mass, adj, belief_region, lab0, active)
    k_max = jnp.sum(bmask)
    count = jnp.sum(alive)
    max_iter = r0 * (r0 + 1) + 2
    logs = log_saliency(mt.T, lb)                                     # (K,) log S_k

    def lp1(c):
        return log_psi1(c, mu, sigma, k_max, k_static)

    def cond(s):
        lab, mt, a, lb, logs, alive, tried, count, key, it = s
        return jnp.any(alive & ~tried) & (it < max_iter)

    def body(s):
        lab, mt, a, lb, logs, alive, tried, count, key, it = s
        cand = alive & ~tried
        n = jnp.argmax(jnp.where(cand, _hash_uniform(key, it.astype(jnp.uint32), r0), -1.0))
        e_n = ar == n
        mn = mt[n]                                                    # (K,) masses of C_n
        newlog = jnp.log(jnp.maximum(mn[None, :] + mt, SAL_FLOOR))    # (R0 candidates, K)
        in_n = lb == n
        affected = (in_n[None, :] | (lb[None, :] == ar[:, None])) & bmask[None, :]
        delta = jnp.sum(jnp.where(affected, newlog - logs[None, :], 0.0), axis=1)
        delta = jnp.where(a[n], delta, -jnp.inf)
        t = jnp.argmax(delta)
        gain = delta[t] + lp1(count - 1) - lp1(count)
        accept = gain > 0
        # merge C_n into C_t (a no-op when not accepted: both masks are then empty)
        acc_t = (ar == t) & accept
        acc_n = e_n & accept
        row_n = a[n]
        mt = jnp.where(acc_n[:, None], 0.0, mt + acc_t[:, None] * mn[None, :])
        a = (a | (acc_t[:, None] & row_n[None, :]) | (row_n[:, None] & acc_t[None, :]))
        a = a & ~acc_n[:, None] & ~acc_n[None, :] & ~jnp.eye(r0, dtype=bool)
        moved = (in_n | (lb == t)) & accept
        logs = jnp.where(moved, newlog[t], logs)
        lb = jnp.where(in_n & accept, t, lb)
        lab = jnp.where((lab == n) & accept, t, lab)
        alive = alive & ~acc_n
        tried = jnp.where(accept, False, tried | e_n)
        return (lab, mt, a, lb, logs, alive, tried, jnp.where(accept, count - 1, count), key,
                it + 1)

    tried = jnp.zeros(r0, bool)
    seed = jax.random.bits(key, (), jnp.uint32)
    s = jax.lax.while_loop(cond, body, (lab, mt, a, lb, logs, alive, tried, count, seed, 0))
    lab, mt, a, lb, logs, alive, tried, count, key, it = s
    lp3 = jnp.sum(jnp.where(bmask, logs, 0.0))
    l1 = lp1(count)
    return lab, count, l1 + lp3, l1, lp3, it


_trial_jit = jax.jit(_trial)


@partial(jax.jit, static_argnames=("chunk",))
def _trials_batched(mass, adj, belief_region, lab0, active, mu, sigma, keys, chunk):
    f = jax.vmap(_trial, in_axes=(None, None, None, None, None, None, None, 0))
    t = keys.shape[0]
    if chunk >= t:
        return f(mass, adj, belief_region, lab0, active, mu, sigma, keys)
    nchunk = t // chunk
    out = jax.lax.map(lambda kk: f(mass, adj, belief_region, lab0, active, mu, sigma, kk),
                      keys.reshape(nchunk, chunk, *keys.shape[1:]))
    return jax.tree.map(lambda x: x.reshape(t, *x.shape[2:]), out)


@dataclass(frozen=True)
class SergeResult:
    """Best SR map of a SERGE run.

    * ``region_of_init`` (R0,): compact region 0..|R|−1 of every initial region (−1 inactive);
    * ``cell_labels`` (N,): region of every fine cell (−1 outside the active part);
    * ``belief_labels`` (K,): ``L^B`` (−1 for beliefs outside the active part);
    * ``log_psi = log_psi1 + log_psi3`` (ψ2 = 1); ``trial_log_psi`` (T,) of every trial.
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
        """Region of each point (..., 2) (outside the grid → nearest border cell)."""
        return self.cell_labels[np.asarray(self.problem.grid.cell_of(np.asarray(points)))]

    def saliency(self) -> np.ndarray:
        """(K,) saliency S_k of each belief in its region (training beliefs)."""
        pm = np.asarray(self.problem.cell_mass, np.float64)
        return np.array([pm[k, self.cell_labels == self.belief_labels[k]].sum()
                         for k in range(pm.shape[0])])


def _compact(problem: Problem, lab: np.ndarray, mu, sigma, logs, iters, best) -> SergeResult:
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


def _inputs(problem: Problem, mu, sigma, active, start):
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
    problem: Problem,
    mu: int,
    sigma: float = 2.0,
    *,
    key: jax.Array,
    trials: int | None = None,
    active=None,
    start=None,
    chunk: int = 1024,
) -> SergeResult:
    """Run SERGE (Alg. 2) with ``trials`` random-order trials batched; keep the best map.

    ``trials`` defaults to 100·K + 1 (P§3.3 suggests T > 100·K). ``active`` (R0,) bool
    restricts the search to some initial regions and their beliefs (a branch of the resolution
    tree, P§3.3.1); ``start`` (R0,) starts from a coarser contiguous partition instead of
    ``C_init`` (used by the relaxed optimiser).

    >>> import jax, numpy as np
    >>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells, serge
    >>> xy = np.stack(np.meshgrid(np.arange(3.), np.arange(3.)), -1).reshape(-1, 2) * 10
    >>> p = initial_cells(GaussianBeliefs(xy, np.tile(np.eye(2) * .2, (9, 1, 1))),
    ...                   Grid((-5., -5.), (25., 25.), (30, 30)))
    >>> r = serge(p, mu=4, sigma=2.0, key=jax.random.PRNGKey(0), trials=64)
    >>> r.n_regions, abs(round(r.log_psi3, 4))
    (4, 0.0)
    """
    args = _inputs(problem, mu, sigma, active, start)
    t = 100 * problem.k + 1 if trials is None else int(trials)
    if t < 1:
        raise ValueError(f"serge: trials must be ≥ 1, got {trials}")
    chunk = min(chunk, t)
    tt = math.ceil(t / chunk) * chunk
    keys = jax.random.split(key, tt)
    lab, count, lp, l1, l3, it = _trials_batched(*args, keys, chunk)
    lab, lp, l1, l3, it = (np.asarray(x)[:t] for x in (lab, lp, l1, l3, it))
    best = int(np.argmax(lp))
    return _compact(problem, lab[best], mu, sigma, (lp, l1, l3), it, best)


def serge_sequential(problem: Problem, mu: int, sigma: float = 2.0, *, key: jax.Array,
                     trials: int, active=None, start=None) -> SergeResult:
    """Reference: the same trials (same keys as :func:`serge` with ``chunk ≥ trials``) run
    one at a time in a Python loop of jitted single trials."""
    args = _inputs(problem, mu, sigma, active, start)
    keys = jax.random.split(key, trials)
    outs = [jax.tree.map(np.asarray, _trial_jit(*args, keys[i])) for i in range(trials)]
    lab = np.stack([o[0] for o in outs])
    lp, l1, l3, it = (np.array([o[j] for o in outs]) for j in (2, 3, 4, 5))
    best = int(np.argmax(lp))
    return _compact(problem, lab[best], mu, sigma, (lp, l1, l3), it, best)
