"""The online PQRM map: a recursive Bayes filter per ordered landmark triplet (P §2.2.3).

The map holds ``p(R^n | Z^n_{1:t})`` for every ordered triplet n = (i, j, k) of distinct
landmarks (P §2.3: "the reported results record all possible orderings"), for one or several
representations at once. An update with the landmarks seen at time t (Alg. 1):

* every triplet whose three landmarks are all seen gets the measurement distribution
  ``p(R^n | Z^n_t)`` (eq. 2.9, :mod:`.measurement`) — one sampling pass for all
  representations, which must be merges of one root calculus (the EDC for Padgett's six);
* a triplet already in the map is updated by eq. 2.10,
  ``p_t(q) ∝ p(q | Z_t) · p_{t-1}(q)``; a triplet seen for the first time is initialised with
  ``p(q | Z_t)``; triplets not seen keep their distribution.

Everything has static shapes (T = M(M−1)(M−2) rows for M landmarks, masks for what was seen),
so ``update`` runs under ``jit``, ``lax.scan`` over time and ``vmap`` over Monte Carlo runs.

Documented handling of degenerate evidence (never a NaN map):

* **Conflict** — the product in eq. 2.10 is zero for every state (the sampled likelihood is
  zero on all states the prior allows; with finite S this happens at low noise near state
  boundaries): the prior is kept and ``num_conflicts`` of that triplet and representation is
  incremented.
* **Rejected measurement** — no sample had a defined state (σ = 0 with a landmark exactly on a
  boundary or two landmarks coincident): the triplet is not updated, ``num_rejected`` counts it.
* **Non-finite positions** of a landmark flagged visible: the landmark is treated as not seen
  at this step and ``num_dropped`` counts it. Eager :func:`update_observed` raises instead.
* Negative or NaN ``sigma`` raises ``ValueError`` when concrete; inside ``jit`` a NaN sigma makes
  every sample undefined, i.e. every seen triplet is a rejected measurement.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from ..calculi import Calculus
from .measurement import _root_counts, aggregation_matrix, counts_to_probabilities, root_of

__all__ = ["MapState", "Mapper", "mapper", "ordered_triplets", "update_observed"]


def ordered_triplets(num_landmarks: int) -> np.ndarray:
    """(M(M−1)(M−2), 3) int32: every ordered triplet (i, j, k) of distinct landmark ids."""
    if not isinstance(num_landmarks, int | np.integer) or num_landmarks < 3:
        raise ValueError(f"a PQRM map needs at least three landmarks, got {num_landmarks!r}")
    m = int(num_landmarks)
    i, j, k = np.meshgrid(np.arange(m), np.arange(m), np.arange(m), indexing="ij")
    keep = (i != j) & (i != k) & (j != k)
    return np.stack([i[keep], j[keep], k[keep]], axis=-1).astype(np.int32)


class MapState(NamedTuple):
    """State of a PQRM map (a pytree).

    probs: representation name → (T, Q) ``p(R^n | Z^n_{1:t})``; all-zero rows are unmapped.
    mapped: (T,) bool, the triplet has been initialised.
    num_updates: (T,) int32, measurements incorporated (including the initialisation).
    num_conflicts: name → (T,) int32, eq. 2.10 products that were zero everywhere (prior kept).
    num_rejected: (T,) int32, measurements with no defined sample (not incorporated).
    num_dropped: () int32, visible landmarks dropped for non-finite positions.
    step: () int32, number of update calls.
    """

    probs: dict[str, jax.Array]
    mapped: jax.Array
    num_updates: jax.Array
    num_conflicts: dict[str, jax.Array]
    num_rejected: jax.Array
    num_dropped: jax.Array
    step: jax.Array


class Mapper(NamedTuple):
    """A PQRM map's pure functions and static description (like an optax transformation).

    init() -> MapState
    update(state, key, positions (M, 2), visible (M,), sigma) -> MapState (jitted)
    """

    init: Callable[[], MapState]
    update: Callable[..., MapState]
    triplets: np.ndarray
    calculi: tuple[Calculus, ...]
    num_landmarks: int
    num_samples: int


def _bayes(prior, meas, mapped, seen):
    """Eq. 2.10 with initialisation and the conflict rule; returns (new, conflict)."""
    post = meas * prior
    z = jnp.sum(post, axis=-1, keepdims=True)
    conflict = seen & mapped & (z[:, 0] <= 0)
    post = post / jnp.where(z > 0, z, 1.0)
    new = jnp.where((seen & ~mapped)[:, None], meas, prior)
    new = jnp.where((seen & mapped & ~conflict)[:, None], post, new)
    return new, conflict


def _update_impl(state: MapState, key, positions, visible, sigma, *, triplets, cals, root,
                 num_samples, chunk_triplets):
    m = positions.shape[0]
    dtype = jnp.result_type(positions, jnp.float32)
    positions = positions.astype(dtype)
    finite = jnp.all(jnp.isfinite(positions), axis=-1)
    visible = jnp.asarray(visible, bool)
    dropped = jnp.sum(visible & ~finite).astype(jnp.int32)
    seen_lm = visible & finite
    pos = jnp.where(finite[:, None], positions, 0.0)
    sig = jnp.broadcast_to(jnp.asarray(sigma, dtype), (m,))
    tri = jnp.asarray(triplets)
    means = pos[tri]  # (T, 3, 2)
    counts = _root_counts(key, means, sig[tri], root=root, num_samples=num_samples,
                          chunk_triplets=chunk_triplets)
    seen = jnp.all(seen_lm[tri], axis=-1)
    defined = jnp.sum(counts, axis=-1) > 0
    use = seen & defined
    fine = counts.astype(jnp.float32)
    probs, conflicts = {}, {}
    for c in cals:
        meas = counts_to_probabilities(fine @ jnp.asarray(aggregation_matrix(c)))
        new, conflict = _bayes(state.probs[c.name], meas, state.mapped, use)
        probs[c.name] = new
        conflicts[c.name] = state.num_conflicts[c.name] + conflict.astype(jnp.int32)
    return MapState(
        probs=probs,
        mapped=state.mapped | use,
        num_updates=state.num_updates + use.astype(jnp.int32),
        num_conflicts=conflicts,
        num_rejected=state.num_rejected + (seen & ~defined).astype(jnp.int32),
        num_dropped=state.num_dropped + dropped,
        step=state.step + 1,
    )


def _check_sigma(sigma) -> None:
    if isinstance(sigma, jax.core.Tracer):
        return
    s = np.asarray(sigma, dtype=float)
    if np.any(np.isnan(s)) or np.any(s < 0) or np.any(np.isinf(s)):
        raise ValueError(f"sigma must be finite and non-negative, got {s.tolist()}")


def mapper(
    representations: Sequence[Calculus | str] = ("edc",),
    num_landmarks: int = 10,
    num_samples: int = 256,
    *,
    chunk_triplets: int = 4096,
) -> Mapper:
    """A PQRM map over all ordered triplets of ``num_landmarks`` landmarks (P Alg. 1).

    >>> import jax, jax.numpy as jnp
    >>> pq = mapper(("edc", "lr"), num_landmarks=4, num_samples=64)
    >>> st = pq.init()
    >>> pos = jnp.array([[0., 0.], [0., 10.], [5., 5.], [-5., 2.]])
    >>> st = pq.update(st, jax.random.key(0), pos, jnp.array([True, True, True, False]), 0.5)
    >>> int(st.mapped.sum()), st.probs["lr"].shape      # the 6 orderings of landmarks 0, 1, 2
    (6, (24, 2))
    """
    cals = tuple(calculi.get(c) for c in representations)
    if not cals:
        raise ValueError("mapper needs at least one representation")
    names = [c.name for c in cals]
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate representations: {names}")
    roots = {root_of(c).definition_hash for c in cals}
    if len(roots) != 1:
        raise ValueError("all representations of one map must be merges of one root calculus "
                         "(one sampling pass serves them all)")
    if not isinstance(num_samples, int | np.integer) or num_samples < 1:
        raise ValueError(f"num_samples must be a positive integer, got {num_samples!r}")
    triplets = ordered_triplets(num_landmarks)
    t = triplets.shape[0]
    root = root_of(cals[0])

    def init() -> MapState:
        zeros = jnp.zeros(t, jnp.int32)
        return MapState(
            probs={c.name: jnp.zeros((t, c.num_states), jnp.float32) for c in cals},
            mapped=jnp.zeros(t, bool), num_updates=zeros,
            num_conflicts={c.name: zeros for c in cals}, num_rejected=zeros,
            num_dropped=jnp.zeros((), jnp.int32), step=jnp.zeros((), jnp.int32),
        )

    impl = jax.jit(partial(_update_impl, triplets=triplets, cals=cals, root=root,
                           num_samples=int(num_samples), chunk_triplets=int(chunk_triplets)))

    def update(state: MapState, key: jax.Array, positions: jax.Array, visible: jax.Array,
               sigma) -> MapState:
        """Incorporate one measurement of all landmarks (eq. 2.10); see the module doc."""
        if np.shape(positions) != (num_landmarks, 2):
            raise ValueError(f"positions must have shape ({num_landmarks}, 2), "
                             f"got {tuple(np.shape(positions))}")
        if np.shape(visible) != (num_landmarks,):
            raise ValueError(f"visible must have shape ({num_landmarks},), "
                             f"got {tuple(np.shape(visible))}")
        if np.ndim(sigma) not in (0, 1) or (np.ndim(sigma) == 1
                                            and np.shape(sigma) != (num_landmarks,)):
            raise ValueError(f"sigma must be a scalar or ({num_landmarks},)")
        _check_sigma(sigma)
        return impl(state, key, positions, visible, sigma)

    return Mapper(init, update, triplets, cals, int(num_landmarks), int(num_samples))


def update_observed(pq: Mapper, state: MapState, key: jax.Array, ids, positions,
                    sigma) -> MapState:
    """Eager convenience: update with the landmarks ``ids`` (K,) seen at ``positions`` (K, 2).

    Raises ``ValueError`` for duplicate or out-of-range ids, NaN/inf positions and bad sigma.
    Fewer than three ids observe no triplet: the map is returned unchanged except ``step``.
    """
    ids = np.asarray(ids)
    positions = np.asarray(positions, dtype=np.float32)
    if ids.ndim != 1 or positions.shape != (ids.shape[0], 2):
        raise ValueError(f"ids (K,) and positions (K, 2) expected, got {ids.shape} and "
                         f"{positions.shape}")
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        raise ValueError("landmark ids must be integers")
    if len(np.unique(ids)) != len(ids):
        raise ValueError(f"duplicate landmark ids: {ids.tolist()}")
    if np.any(ids < 0) or np.any(ids >= pq.num_landmarks):
        raise ValueError(f"landmark ids must be in [0, {pq.num_landmarks}), got {ids.tolist()}")
    if not np.all(np.isfinite(positions)):
        raise ValueError("positions contain NaN or infinite measurements")
    _check_sigma(sigma)
    full = np.zeros((pq.num_landmarks, 2), np.float32)
    vis = np.zeros(pq.num_landmarks, bool)
    full[ids] = positions
    vis[ids] = True
    sig = np.asarray(sigma, np.float32)
    if sig.ndim == 1:
        if sig.shape != ids.shape:
            raise ValueError("per-landmark sigma must have one entry per id")
        s = np.zeros(pq.num_landmarks, np.float32)
        s[ids] = sig
        sig = s
    return pq.update(state, key, jnp.asarray(full), jnp.asarray(vis), sig)
