"""Probabilistic composition P(AB:D = s3 | AB:C = s1, BC:D = s2) (Z eq. 2.4 / 4.28).

Uniform-within-state priors need a bounded domain: C is uniform over ``state ∩ [−W, W]²`` in
the AB frame and D uniform over ``state ∩ [−W, W]²`` in the BC frame (canonical units,
W = ``window``, default 3 |AB|). Samples of each state are drawn from a large pool of uniform
points grouped by state, so thin states get their share; every (s1, s2) pair gets
``per_pair`` configurations, and the binomial standard error of each entry is at most
0.5/√per_pair. Entries outside the exact composition table are zero by construction.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi.calculus import Calculus


def _state_pool(calc, key, n, window):
    pts = jax.random.uniform(key, (n, 2), minval=-window, maxval=window)
    st = calc.classify(jnp.zeros(2), jnp.asarray([0.0, 1.0]), pts)
    order = jnp.argsort(st)
    st_sorted = st[order]
    Q = calc.num_states
    starts = jnp.searchsorted(st_sorted, jnp.arange(Q))
    counts = jnp.searchsorted(st_sorted, jnp.arange(Q), side="right") - starts
    return pts[order], starts, counts


@partial(jax.jit, static_argnums=(0, 2, 3))
def _tensor(calc: Calculus, key, pool: int, per_pair: int, window: float):
    Q = calc.num_states
    k1, k2, k3, k4 = jax.random.split(key, 4)
    pc, sc, cc = _state_pool(calc, k1, pool, window)
    pd, sd, cd = _state_pool(calc, k2, pool, window)
    s1 = jnp.repeat(jnp.arange(Q), Q)
    s2 = jnp.tile(jnp.arange(Q), Q)

    def one_pair(args):
        a, b, ka, kb = args
        ia = sc[a] + jnp.floor(jax.random.uniform(ka, (per_pair,)) * cc[a]).astype(jnp.int32)
        ib = sd[b] + jnp.floor(jax.random.uniform(kb, (per_pair,)) * cd[b]).astype(jnp.int32)
        C = pc[jnp.clip(ia, 0, pool - 1)]
        Dp = pd[jnp.clip(ib, 0, pool - 1)]  # (α', β') of D in the BC frame
        B = jnp.asarray([0.0, 1.0])
        e = C - B
        right = jnp.stack([e[:, 1], -e[:, 0]], -1)
        D = B + Dp[:, 1:2] * e + Dp[:, 0:1] * right
        s3 = calc.classify(jnp.zeros(2), B, D)
        valid = s3 >= 0
        return jnp.zeros(Q).at[jnp.where(valid, s3, 0)].add(valid.astype(jnp.float32))

    ka = jax.random.split(k3, Q * Q)
    kb = jax.random.split(k4, Q * Q)
    counts = jax.lax.map(one_pair, (s1, s2, ka, kb))
    return counts.reshape(Q, Q, Q), cc, cd


def prob_compose(calc: Calculus, *, seed: int = 0, pool: int = 1 << 21,
                 per_pair: int = 4000, window: float = 3.0) -> dict:
    """Sampled tensor P[s1, s2, s3] with its sampling error (open calculi only).

    Args:
        calc: an open calculus.
        seed: seed of the point pool and the configurations.
        pool: uniform points drawn in the window and grouped by state.
        per_pair: configurations per (s1, s2) pair.
        window: half-width W of the bounded domain, in |AB| units (docs/decisions.md §2.3).

    Returns:
        A dict with ``P`` [Q, Q, Q] (rows sum to 1 where the pair was sampled, else 0), the
        per-pair counts ``n`` [Q, Q], ``stderr_max`` (0.5/√per_pair), the pool counts per state
        and the settings used.

    Raises:
        ValueError: for a boundary-inclusive calculus.
    """
    if calc.boundary_inclusive:
        raise ValueError("uniform-within-state priors are undefined for boundary relations "
                         f"(measure zero) of {calc.name!r}; use an open calculus")
    counts, cc, cd = _tensor(calc, jax.random.PRNGKey(seed), pool, per_pair, window)
    counts = np.asarray(counts, np.float64)
    tot = counts.sum(-1, keepdims=True)
    P = np.divide(counts, tot, out=np.zeros_like(counts), where=tot > 0)
    return {"P": P, "n": tot[..., 0], "stderr_max": float(0.5 / np.sqrt(per_pair)),
            "pool_counts": np.asarray(cc).tolist(), "window": window, "per_pair": per_pair,
            "seed": seed}
