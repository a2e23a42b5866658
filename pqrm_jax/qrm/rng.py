"""Relative Neighbourhood Graph from the qualitative map (M§VII.A, Alg. 2).

Landmarks A, B are RNG neighbours iff no third landmark lies in their lune, i.e. iff no C
has ``AB:C`` in the EDC lune states {7, 8, 13, 14} (|AC| < |AB| and |BC| < |AB|). From an
incompletely constrained map, Alg. 2 keeps a candidate edge unless some C's open states all
lie in the lune, and gives it the cost ``w_ij = Σ_k conflicts_k / open_k / N``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi import Calculus
from .hypergraph import QRMMap
from .spec import QRMSpec, popcount, qrm_spec

__all__ = ["RNGEstimate", "rng_estimate", "true_rng"]


class RNGEstimate(NamedTuple):
    """``edges`` [N, N] bool symmetric candidate edges among known nodes.

    ``cost`` [N, N] float32 Alg. 2 edge costs (0 on non-edges); ``total_cost`` Σ_{i<j} w_ij.
    """

    edges: jax.Array
    cost: jax.Array
    total_cost: jax.Array


@partial(jax.jit, static_argnames="lune")
def rng_estimate_kernel(rel, known, *, lune: int):
    n = rel.shape[0]
    idx = jnp.arange(n)
    open_ = popcount(rel).astype(jnp.float32)
    conf = popcount(rel & jnp.uint32(lune)).astype(jnp.float32)
    third = known[None, None, :] & (idx[:, None, None] != idx[None, None, :]) & \
        (idx[None, :, None] != idx[None, None, :])
    pair = known[:, None] & known[None, :] & (idx[:, None] != idx[None, :])
    blocked = jnp.any(third & (open_ > 0) & (open_ == conf), -1)
    n_known = jnp.maximum(known.sum(), 1).astype(jnp.float32)
    w = jnp.sum(jnp.where(third & (open_ > 0), conf / jnp.maximum(open_, 1.0), 0.0), -1) / n_known
    edges = pair & ~blocked
    edges = edges & edges.T
    w = jnp.where(edges, jnp.maximum(w, w.T), 0.0)
    return RNGEstimate(edges, w, 0.5 * w.sum())


def rng_estimate(m: QRMMap, calc: Calculus | str | QRMSpec = "edc") -> RNGEstimate:
    """Alg. 2: RNG candidate edges and costs from the map (EDC or EDC-with-merged-lune).

    Args:
        m: the map.
        calc: the calculus (name, object or its :class:`QRMSpec`).

    Returns:
        The :class:`RNGEstimate` (``edges`` [N, N] bool, ``cost`` [N, N], ``total_cost``).

    >>> import jax.numpy as jnp
    >>> from pqrm_jax.qrm.hypergraph import true_map
    >>> pts = jnp.array([[0.0, 0.0], [2.0, 0.0], [1.1, 0.3]])   # 2 lies in the lune of 0, 1
    >>> est = rng_estimate(true_map(pts))
    >>> est.edges.astype(int).tolist(), float(est.total_cost)
    ([[0, 0, 1], [0, 0, 1], [1, 1, 0]], 0.0)
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    if spec.lune == 0:
        raise ValueError(f"calculus {spec.calc.name!r} has no lune states; the RNG estimate "
                         "(M Alg. 2) needs 'edc' or 'edc_lune'")
    return rng_estimate_kernel(m.rel, m.known, lune=int(spec.lune))


def true_rng(points) -> np.ndarray:
    """Brute-force RNG (lune test) of [N, 2] points: [N, N] bool.

    Args:
        points: [N, 2] positions.

    Returns:
        [N, N] bool symmetric adjacency of the relative neighbourhood graph (M§VII.A).
    """
    p = np.asarray(points, np.float64)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    n = len(p)
    lune = np.maximum(d[:, None, :], d[None, :, :]) < d[:, :, None]  # [i, j, k]
    idx = np.arange(n)
    lune[:, :, idx] &= True
    lune[idx, :, idx] = False
    lune[:, idx, idx] = False
    e = ~lune.any(-1)
    np.fill_diagonal(e, False)
    return e
