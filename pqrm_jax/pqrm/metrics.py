"""Map-quality metrics of P §2.3.1 and §2.3.2 (pure, jit/vmap-able).

All functions take a [T, Q] map ``probs``, the true states ``truth`` [T] and a ``mask`` [T]
of the triplets to evaluate (mapped triplets with a defined truth); they return means over the
masked triplets (NaN-free: an empty mask gives 0 and ``count`` says so). The metrics that
compare with ``truth`` drop from the mask every triplet whose truth is undefined (a negative
sentinel such as ``BOUNDARY``/``DEGENERATE``, or an index ≥ Q): an undefined truth is neither
a correct nor a wrong estimate, so it is never counted (they evaluate ``mask & defined``).

* mean map entropy, eq. 2.11 (nats; ``0·log 0 = 0``);
* error rate of the maximum-likelihood (ML) state (ties: the lowest state index);
* top-n error rate (P Fig. 2.16): the truth is not among the n most likely states (stable
  order, so n = 1 is the ML error rate);
* mean probability of the ML state (P Fig. 2.11b);
* neighbour distance of the ML state to the truth (P Fig. 2.5/2.6), from a [Q, Q] distance
  matrix (``calc.neighbor_distance``);
* confusion matrix ``[truth, estimate]``;
* error locations: C in the normalised AB frame (A=(0,0), B=(0,1)), P Fig. 2.8.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import triplets as layouts
from ..calculi import Calculus, classify_all

__all__ = [
    "entropy", "mean_map_entropy", "ml_states", "error_rate", "topn_error_rates",
    "ml_probability", "neighbor_distance", "confusion_matrix", "normalized_positions",
    "true_states", "true_states_all", "random_neighbor_distance", "masked_mean", "defined_mask",
    "truth_rank",
]


def masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of ``x`` over ``mask`` (0 for an empty mask)."""
    mask = jnp.asarray(mask, bool)
    n = jnp.sum(mask)
    return jnp.sum(jnp.where(mask, x, 0.0)) / jnp.maximum(n, 1)


def entropy(probs: jax.Array) -> jax.Array:
    """Entropy in nats of each row, ``−Σ p log p`` with ``0 log 0 = 0``."""
    p = jnp.asarray(probs)
    return -jnp.sum(jnp.where(p > 0, p * jnp.log(jnp.where(p > 0, p, 1.0)), 0.0), axis=-1)


def mean_map_entropy(probs: jax.Array, mask: jax.Array) -> jax.Array:
    """``H_mean = Σ_n H^n / N`` over the masked triplets (P eq. 2.11)."""
    return masked_mean(entropy(probs), mask)


def ml_states(probs: jax.Array) -> jax.Array:
    """Index of the maximum-likelihood state per row (lowest index on ties)."""
    return jnp.argmax(probs, axis=-1).astype(jnp.int32)


def defined_mask(truth: jax.Array, mask: jax.Array, num_states: int) -> jax.Array:
    """``mask`` without the triplets whose truth is undefined (negative sentinel or ≥ Q).

    >>> print(defined_mask(jnp.array([0, -1, 2, 5]), jnp.array([True, True, True, True]), 3))
    [ True False  True False]
    """
    truth = jnp.asarray(truth)
    return jnp.asarray(mask, bool) & (truth >= 0) & (truth < num_states)


def error_rate(probs: jax.Array, truth: jax.Array, mask: jax.Array) -> jax.Array:
    """Fraction of masked triplets (with a defined truth) whose ML state is not the truth."""
    mask = defined_mask(truth, mask, probs.shape[-1])
    return masked_mean((ml_states(probs) != truth).astype(jnp.float32), mask)


def truth_rank(probs: jax.Array, truth: jax.Array) -> jax.Array:
    """[T] position of the truth in each row sorted most likely first (stable: ties by index).

    A count instead of a sort: ``#{j : p_j > p_t} + #{j < t : p_j = p_t}`` in the total order
    of ``jnp.argsort`` (−0 = +0, NaN after every number, NaNs equal), so it equals the position
    of ``truth`` in ``jnp.argsort(-probs, stable=True)`` for every input, at O(Q) per row and
    without a sort. A truth outside ``[0, Q)`` gives 0 (the metrics mask it out).

    Args:
        probs: [T, Q] map rows.
        truth: [T] int true state per row.

    Returns:
        [T] int32 ranks (0: the truth is the ML state).

    >>> print(truth_rank(jnp.array([[0.1, 0.5, 0.1, 0.3]]), jnp.array([2])))  # 0.5, 0.3, tie 0
    [3]
    """
    probs = jnp.asarray(probs)
    q = probs.shape[-1]
    t = jnp.asarray(truth)
    ok = (t >= 0) & (t < q)
    tc = jnp.clip(t, 0, q - 1)
    pt = jnp.take_along_axis(probs, tc[:, None], axis=-1)  # (T, 1)
    nan_j, nan_t = jnp.isnan(probs), jnp.isnan(pt)
    before = (probs > pt) | (~nan_j & nan_t)  # −p_j < −p_t in the sort's total order
    tie = (probs == pt) | (nan_j & nan_t)
    earlier = jnp.arange(q)[None, :] < tc[:, None]
    rank = jnp.sum(before | (tie & earlier), axis=-1, dtype=jnp.int32)
    return jnp.where(ok, rank, 0)


def topn_error_rates(probs: jax.Array, truth: jax.Array, mask: jax.Array) -> jax.Array:
    """[Q] error rates for n = 1..Q: truth not among the n most likely states (Fig. 2.16)."""
    q = probs.shape[-1]
    rank = truth_rank(probs, truth)
    wrong = rank[:, None] >= jnp.arange(1, q + 1)[None, :]  # (T, Q)
    m = defined_mask(truth, mask, q)
    return jnp.sum(jnp.where(m[:, None], wrong, False), axis=0) / jnp.maximum(jnp.sum(m), 1)


def ml_probability(probs: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean probability of the ML state over the masked triplets (P Fig. 2.11b)."""
    return masked_mean(jnp.max(probs, axis=-1), mask)


def neighbor_distance(probs: jax.Array, truth: jax.Array, mask: jax.Array,
                      distance: jax.Array) -> jax.Array:
    """Mean conceptual-neighbour distance ``distance[ML, truth]`` (P §2.3.1, Fig. 2.6)."""
    d = jnp.asarray(distance)[ml_states(probs), jnp.clip(truth, 0, probs.shape[-1] - 1)]
    return masked_mean(d.astype(jnp.float32), defined_mask(truth, mask, probs.shape[-1]))


def random_neighbor_distance(distance) -> float:
    """Neighbour distance of a uniformly random estimate averaged over uniform truths."""
    return float(np.mean(np.asarray(distance, dtype=float)))


def confusion_matrix(probs: jax.Array, truth: jax.Array, mask: jax.Array) -> jax.Array:
    """[Q, Q] int32 counts ``[truth, ML estimate]`` over the masked triplets (P Fig. 2.9)."""
    q = probs.shape[-1]
    idx = jnp.clip(truth, 0, q - 1) * q + ml_states(probs)
    w = defined_mask(truth, mask, q).astype(jnp.int32)
    return jnp.zeros(q * q, jnp.int32).at[idx].add(w).reshape(q, q)


def true_states(calc: Calculus, landmarks: jax.Array, triplets) -> jax.Array:
    """[T] true state of ``AB:C`` for each triplet (i, j, k) of world landmarks [M, 2].

    The rows layout of :func:`pqrm_jax.triplets.true_states`.
    """
    return layouts.true_states(calc, landmarks, "rows", triplets=triplets)


def true_states_all(calcs, landmarks: jax.Array, triplets) -> tuple[jax.Array, ...]:
    """[T] true states of each triplet in each of ``calcs``, as :func:`true_states` per calculus.

    One sign evaluation serves a calculus and all its merges
    (:func:`pqrm_jax.calculi.classify_all`): Padgett's six representations cost one
    classification, with results equal to :func:`true_states` bit for bit.

    Args:
        calcs: the calculi (any ``TernaryCalculus``).
        landmarks: [M, 2] world positions.
        triplets: [T, 3] landmark ids of the rows.

    Returns:
        One int32 [T] array per calculus, in the order of ``calcs``.
    """
    return classify_all(calcs, *layouts.row_points(landmarks, triplets))


def normalized_positions(landmarks: jax.Array, triplets) -> tuple[jax.Array, jax.Array]:
    """C in the canonical AB frame (α, β) [T, 2] and |AB| [T] for each triplet (P Fig. 2.8).

    Right of AB is α > 0 (docs/decisions.md §2); A = B gives NaN coordinates.
    """
    a, b, c = layouts.row_points(landmarks, triplets)
    d, e = b - a, c - a
    n = jnp.sum(d * d, axis=-1)
    u = e[:, 0] * d[:, 1] - e[:, 1] * d[:, 0]
    v = jnp.sum(e * d, axis=-1)
    nn = jnp.where(n > 0, n, jnp.nan)
    return jnp.stack([u / nn, v / nn], axis=-1), jnp.sqrt(n)
