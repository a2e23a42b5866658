"""Simulation helpers: does composition propagation improve a PQRM map? (issue #6 item 4).

* :func:`sample_compose_tensor` — a Monte Carlo ``[Q, Q, Q]`` composition tensor
  ``P(AB:D | AB:C, BC:D)`` under "four landmarks uniform in a square" (the world prior of the
  study below), with per-row sample counts. Rows never hit stay zero, which
  :func:`~pqrm_jax.compositions.propagation.propagate` treats as "no information" (the path
  is dropped). The exact tensor of the calculus core (``calc.tables.prob_compose``, uniform
  within state, Z eq. 4.28) is preferred where available; this one is the world-matched
  alternative and a cross-check.
* :func:`measure_map` — a PQRM-style map (P eq. 2.9): each observed landmark triplet is
  measured once with Gaussian position noise ``σ``; the inverse sensor model is sampled around
  the measured positions and every ordering of the triplet is classified from the same samples.
* :func:`heldout_study` — maps with and without propagation at equal measurements, scored on
  the held-out (unobserved) triplets and on the observed ones.

>>> import jax
>>> from pqrm_jax import calculi
>>> calc = calculi.get("single_cross")
>>> T, counts = sample_compose_tensor(calc, jax.random.key(0), 20_000, chunk=20_000)
>>> T.shape, bool(abs(T.sum(-1)[counts > 0] - 1).max() < 1e-5)
((4, 4, 4), True)
"""

from __future__ import annotations

from itertools import combinations

import jax
import jax.numpy as jnp
import numpy as np

from .. import triplets as layouts
from ..triplets import ORDERINGS
from .propagation import DEFAULT_EPS, DEFAULT_PATH_WEIGHT, propagate

__all__ = ["sample_compose_tensor", "random_world", "true_states", "measured_rows",
           "place_rows", "measure_map", "score", "heldout_study"]


def sample_compose_tensor(calc, key, num_samples: int = 2_000_000, chunk: int = 500_000):
    """Monte Carlo composition tensor under four landmarks i.i.d. uniform in a square.

    Args:
        calc: the calculus (object or registered name).
        key: PRNG key.
        num_samples: configurations of four landmarks drawn.
        chunk: configurations per compiled call.

    Returns:
        ``(tensor, counts)``: the [Q, Q, Q] float32 ``tensor[a, b, c] = P(AB:D = c | AB:C = a,
        BC:D = b)`` (rows sum to 1 where ``counts[a, b] > 0``, else 0) and the [Q, Q] sample
        counts. The sampling error of a row is about ``sqrt(p(1-p)/counts)``.
    """
    q = calc.num_states
    hist = np.zeros((q, q, q), np.int64)

    @jax.jit
    def one(k):
        pts = jax.random.uniform(k, (chunk, 4, 2))
        a, b, c, d = (pts[:, i] for i in range(4))
        s1, s2, s3 = calc.classify(a, b, c), calc.classify(b, c, d), calc.classify(a, b, d)
        ok = (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
        flat = jnp.where(ok, (s1 * q + s2) * q + s3, q ** 3)
        return jnp.bincount(flat, length=q ** 3 + 1)[: q ** 3]

    done = 0
    while done < num_samples:
        key, sub = jax.random.split(key)
        hist += np.asarray(one(sub)).reshape(q, q, q)
        done += chunk
    counts = hist.sum(-1)
    tensor = np.where(counts[..., None] > 0, hist / np.maximum(counts, 1)[..., None], 0.0)
    return tensor.astype(np.float32), counts


def random_world(key, num_landmarks: int, size: float = 100.0) -> jax.Array:
    """Landmarks i.i.d. uniform in a ``size × size`` square (P§2.3.1)."""
    return jax.random.uniform(key, (num_landmarks, 2)) * size


def true_states(calc, pos) -> np.ndarray:
    """``[L, L, L]`` true state of every ordered triplet (sentinel < 0 on repeated landmarks).

    The dense layout of :func:`pqrm_jax.triplets.true_states` (repeated entries as classified).
    """
    return np.asarray(layouts.true_states(calc, pos, "dense", mask_repeated=False))


def measured_rows(calc, key, pos, trip, sigma, samples: int = 256) -> jax.Array:
    """[N, 6, Q] PQRM rows of the triplets ``trip`` [N, 3], one per ordering (P eq. 2.9).

    Each triplet is measured once with Gaussian position noise ``sigma``; the inverse sensor
    model is sampled ``samples`` times around the measured positions and the six orderings
    (:data:`pqrm_jax.triplets.ORDERINGS`, in that order) are classified from the same samples.
    A row with no defined sample is uniform. Traceable (``jit``/``vmap``); the draws of a
    triplet depend only on ``key`` and its row index (threefry is partitionable), so padding
    ``trip`` with more rows leaves the first rows unchanged.

    Args:
        calc: the calculus.
        key: PRNG key of the noise and the samples.
        pos: [L, 2] true landmark positions (float32).
        trip: [N, 3] int landmark ids of the triplets.
        sigma: std of the position noise (and of the inverse sensor model).
        samples: samples per triplet.

    Returns:
        [N, 6, Q] float32 distributions.
    """
    q = calc.num_states
    k1, k2 = jax.random.split(key)
    true = pos[trip]                                               # (N, 3, 2)
    z = true + sigma * jax.random.normal(k1, true.shape)           # one measurement each
    xs = z[:, None] + sigma * jax.random.normal(k2, (trip.shape[0], samples, 3, 2))
    rows = []
    for p in ORDERINGS:
        s = calc.classify(xs[:, :, p[0]], xs[:, :, p[1]], xs[:, :, p[2]])   # (N, S)
        cnt = (jax.nn.one_hot(s, q) * (s >= 0)[..., None]).sum(1)
        tot = cnt.sum(-1, keepdims=True)
        rows.append(jnp.where(tot > 0, cnt / jnp.maximum(tot, 1), 1.0 / q))
    return jnp.stack(rows, 1)


def measure_map(calc, key, pos, observed_triplets, sigma: float, samples: int = 256):
    """PQRM-style measurement of the given unordered triplets (each measured once).

    The rows of :func:`measured_rows`, placed in a dense map.

    Args:
        calc: the calculus.
        key: PRNG key of the noise and the samples.
        pos: [L, 2] true landmark positions.
        observed_triplets: the unordered triplets measured.
        sigma: std of the Gaussian position noise (and of the inverse sensor model).
        samples: samples per triplet.

    Returns:
        ``probs`` [L, L, L, Q] and ``observed`` [L, L, L]; unobserved rows are uniform.
    """
    pos = jnp.asarray(pos, jnp.float32)
    n, q = pos.shape[0], calc.num_states
    trip = np.asarray(sorted(observed_triplets), dtype=np.int32).reshape(-1, 3)
    probs = np.full((n, n, n, q), 1.0 / q, np.float32)
    observed = np.zeros((n, n, n), bool)
    if len(trip) == 0:
        return probs, observed
    rows = np.asarray(measured_rows(calc, key, pos, jnp.asarray(trip), sigma, samples))
    place_rows(probs, observed, trip, rows)
    return probs, observed


def place_rows(probs: np.ndarray, observed: np.ndarray, trip: np.ndarray,
               rows: np.ndarray) -> None:
    """Write the rows [N, 6, Q] of :func:`measured_rows` of the triplets ``trip`` [N, 3] into
    the dense map ``probs`` [L, L, L, Q] and mark them in ``observed`` [L, L, L] (in place)."""
    for o, p in enumerate(ORDERINGS):
        ii, jj, kk = trip[:, p[0]], trip[:, p[1]], trip[:, p[2]]
        probs[ii, jj, kk] = rows[:, o]
        observed[ii, jj, kk] = True


def score(probs, truth, mask) -> dict[str, float]:
    """Error rate of the ML state, mean entropy (nats), mean −log P(truth) and Brier score.

    An empty ``mask`` is a documented sentinel, not an error: ``n`` is 0 and the four means
    are NaN (a mean over no triplet is undefined); callers check ``n`` before averaging.
    """
    p = np.asarray(probs, np.float64)[mask]
    t = np.asarray(truth)[mask]
    if len(t) == 0:
        return {"n": 0, "error": np.nan, "entropy": np.nan, "nll": np.nan, "brier": np.nan}
    pt = p[np.arange(len(t)), t]
    ent = -(p * np.log(np.where(p > 0, p, 1.0))).sum(-1)
    onehot = np.eye(p.shape[-1])[t]
    return {"n": int(len(t)), "error": float(np.mean(p.argmax(-1) != t)),
            "entropy": float(ent.mean()), "nll": float(np.mean(-np.log(np.maximum(pt, 1e-12)))),
            "brier": float(np.mean(((p - onehot) ** 2).sum(-1)))}


def heldout_study(calc, tensor, key, *, num_landmarks: int = 20, fraction: float = 0.25,
                  sigma: float = 5.0, runs: int = 5, samples: int = 256,
                  eps: float = DEFAULT_EPS, path_weight: float = DEFAULT_PATH_WEIGHT,
                  rounds: int = 1) -> dict[str, dict[str, float]]:
    """Maps with vs without propagation at equal measurements (issue #6 item 4).

    Each run draws a world, observes a random ``fraction`` of the unordered triplets and
    scores, averaged over runs:

    * ``heldout/uniform`` — unobserved triplets without propagation (uniform rows),
    * ``heldout/marginal`` — unobserved triplets predicted by the state frequencies of the
      observed ML states (the best prior-only guess a map without propagation can make),
    * ``heldout/propagated`` — unobserved triplets after :func:`propagate` (``mode="fill"``);
      targets without any path keep the uniform row and are counted as such,
    * ``observed/measured`` and ``observed/fused`` — observed triplets before and after
      ``mode="fuse"``.

    Args:
        calc: the calculus.
        tensor: [Q, Q, Q] probabilistic composition tensor.
        key: PRNG key; each run splits its own keys off it in turn.
        num_landmarks: landmarks per world (uniform in a 100 m square).
        fraction: probability that an unordered triplet is observed.
        sigma: std of the position noise (m).
        runs: worlds averaged.
        samples: inverse-sensor samples per triplet.
        eps: smoothing of the fusion rule.
        path_weight: tempering exponent of each composition path.
        rounds: propagation rounds.

    Returns:
        A dict from each score name above to its error rate, mean entropy, mean −log P(truth)
        and Brier score (and the coverage of the propagated held-out triplets).
    """
    if not 0.0 < float(fraction) < 1.0:
        raise ValueError(f"fraction must be in (0, 1) (observed and held-out triplets both "
                         f"needed), got {fraction!r}")
    if int(runs) < 1 or int(num_landmarks) < 3:
        raise ValueError(f"need runs >= 1 and num_landmarks >= 3, got {runs!r}, "
                         f"{num_landmarks!r}")
    q = calc.num_states
    acc: dict[str, list[dict[str, float]]] = {}
    for _ in range(runs):
        key, kw, ko, km = jax.random.split(key, 4)
        pos = random_world(kw, num_landmarks)
        truth = true_states(calc, pos)
        allt = list(combinations(range(num_landmarks), 3))
        rng = np.random.default_rng(np.asarray(jax.random.key_data(ko)).ravel()[-1])
        pick = rng.random(len(allt)) < fraction
        chosen = [t for t, s in zip(allt, pick, strict=True) if s]
        probs, obs = measure_map(calc, km, pos, chosen, sigma, samples)
        distinct = truth >= 0
        held = distinct & ~obs
        ml = probs[obs].argmax(-1)
        marg = np.bincount(ml, minlength=q) + 1.0
        marg = np.broadcast_to(marg / marg.sum(), probs.shape)
        fill = propagate(probs, obs, tensor, mode="fill", eps=eps, path_weight=path_weight,
                         rounds=rounds)
        fuse = propagate(probs, obs, tensor, mode="fuse", eps=eps, path_weight=path_weight)
        safe = np.where(distinct, truth, 0)
        rows = {
            "heldout/uniform": score(probs, safe, held),
            "heldout/marginal": score(marg, safe, held),
            "heldout/propagated": score(fill.probs, safe, held),
            "observed/measured": score(probs, safe, obs),
            "observed/fused": score(fuse.probs, safe, obs),
        }
        rows["heldout/propagated"]["coverage"] = float(np.asarray(fill.filled)[held].mean())
        for k, v in rows.items():
            acc.setdefault(k, []).append(v)
    # runs whose score set is empty (n = 0, NaN means) are left out of that score's average
    out = {}
    for k, v in acc.items():
        used = [r for r in v if r["n"] > 0]
        out[k] = {m: float(np.mean([r[m] for r in (v if m == "n" else used)]))
                  if (m == "n" or used) else float("nan") for m in v[0]}
    return out
