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
from ..triplets import ordered_triplets  # the rows layout (re-exported as pqrm.ordered_triplets)
from .measurement import (
    aggregation_matrix,
    counts_to_probabilities,
    edc_block_counts,
    is_edc,
    key_to_edc_state,
    root_counts,
    root_identity,
    root_of,
    sample_bank,
)

__all__ = ["MapState", "Mapper", "mapper", "ordered_triplets", "update_observed"]


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
    update_batch(states, keys (R,), positions (R, M, 2), visible (R, M), sigma) -> MapState
        R independent maps at once (leading axis R on every leaf), equal to ``vmap(update)``
        bit for bit but sampling only the triplets that are seen (jitted; see ``mapper``).
    """

    init: Callable[[], MapState]
    update: Callable[..., MapState]
    triplets: np.ndarray
    calculi: tuple[Calculus, ...]
    num_landmarks: int
    num_samples: int
    update_batch: Callable[..., MapState] | None = None


def _bayes(prior, meas, mapped, seen):
    """Eq. 2.10 with initialisation and the conflict rule; returns (new, conflict)."""
    post = meas * prior
    z = jnp.sum(post, axis=-1, keepdims=True)
    conflict = seen & mapped & (z[:, 0] <= 0)
    post = post / jnp.where(z > 0, z, 1.0)
    new = jnp.where((seen & ~mapped)[:, None], meas, prior)
    new = jnp.where((seen & mapped & ~conflict)[:, None], post, new)
    return new, conflict


def _prepare(positions, visible, sigma, triplets):
    """Per-call inputs of the kernel: (means (T,3,2), sigma (T,3), seen (T,), dropped ())."""
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
    seen = jnp.all(seen_lm[tri], axis=-1)
    return pos[tri], sig[tri], seen, dropped


def _apply_counts(state: MapState, counts, seen, dropped, *, cals) -> MapState:
    """Eq. 2.10 for every seen triplet from its root-calculus sample counts (T, Q_root)."""
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


def _update_impl(state: MapState, key, positions, visible, sigma, *, triplets, cals, root,
                 num_samples, chunk_triplets):
    means, sig, seen, dropped = _prepare(positions, visible, sigma, triplets)
    counts = root_counts(key, means, sig, root=root, num_samples=num_samples,
                          chunk_triplets=chunk_triplets)
    return _apply_counts(state, counts, seen, dropped, cals=cals)


def _update_batch_impl(state: MapState, keys, positions, visible, sigma, *, triplets, cals,
                       root, num_samples, chunk_triplets, block, groups):
    r, m = positions.shape[:2]
    sigma = jnp.asarray(sigma)
    if sigma.ndim == 1:  # one sigma per call
        sigma = sigma[:, None]
    sigma = jnp.broadcast_to(sigma, (r, m))
    means, sig, seen, dropped = jax.vmap(partial(_prepare, triplets=triplets))(
        positions, visible, sigma)
    if not is_edc(root):
        counts = jax.vmap(partial(root_counts, root=root, num_samples=num_samples,
                                  chunk_triplets=chunk_triplets))(keys, means, sig)
        return jax.vmap(partial(_apply_counts, cals=cals))(state, counts, seen, dropped)
    # sparse path: sample and update only the seen triplets, compacted across the R maps
    t = means.shape[1]
    g = groups
    if g < 1 or r % g:
        raise ValueError(f"{r} maps cannot be split into {g} groups")
    z = jax.vmap(lambda k: sample_bank(k, num_samples, means.dtype))(keys)  # (R, c, C, 6)
    rows = (state.probs, state.mapped, state.num_updates, state.num_conflicts,
            state.num_rejected)

    def grouped(x):  # (R, T, ...) → (G, R/G·T, ...)
        return x.reshape(g, (r // g) * t, *x.shape[2:])

    z = z.reshape(g, r // g, *z.shape[1:])
    rows = jax.tree_util.tree_map(grouped, rows)
    group_fn = partial(_sparse_group_update, n=t, block=block, cals=cals)
    rows = jax.vmap(group_fn)(z, grouped(means.reshape(r, t, 6)), grouped(sig),
                              grouped(seen), rows)
    probs, mapped, num_updates, num_conflicts, num_rejected = jax.tree_util.tree_map(
        lambda x: x.reshape(r, t, *x.shape[2:]), rows)
    return MapState(probs=probs, mapped=mapped, num_updates=num_updates,
                    num_conflicts=num_conflicts, num_rejected=num_rejected,
                    num_dropped=state.num_dropped + dropped, step=state.step + 1)


def _sparse_group_update(z, m, s, mask, rows, *, n: int, block: int, cals):
    """Eq. 2.9 + 2.10 for the seen rows of one group of maps, ``block`` rows at a time.

    z (Rg, c, C, 6) banks of the Rg maps; m (Rg·N, 6), s (Rg·N, 3), mask (Rg·N,) per triplet
    row (map-major); rows = (probs, mapped, num_updates, num_conflicts, num_rejected) flattened
    the same way. The seen rows are compacted (``jnp.nonzero``, static size) and a
    ``lax.while_loop`` runs ⌈#seen / block⌉ pieces, so every seen row is updated and nothing
    else is computed. Each row's arithmetic is that of the dense ``update`` (same bank, same
    kernel, same eq. 2.10), so the results are identical.
    """
    total = mask.shape[0]
    blk = max(1, min(block, total))
    nblk_max = -(-total // blk)
    order = jnp.nonzero(mask, size=total, fill_value=total)[0].astype(jnp.int32)
    order = jnp.concatenate([order, jnp.full(nblk_max * blk - total, total, jnp.int32)])
    num_seen = jnp.sum(mask, dtype=jnp.int32)
    inv = np.argsort(key_to_edc_state())

    def body(carry):
        p, buf = carry
        idx = jax.lax.dynamic_slice(order, (p * blk,), (blk,))
        valid = idx < total
        safe = jnp.where(valid, idx, 0)
        zc = jnp.transpose(z[safe // n], (1, 2, 3, 0))  # this block's banks (c, C, 6, blk)
        counts = edc_block_counts(m[safe].T, s[safe].T, zc)[:, inv]
        probs, mapped, num_updates, num_conflicts, num_rejected = jax.tree_util.tree_map(
            lambda x: x[safe], rows)
        sub = MapState(probs, mapped, num_updates, num_conflicts, num_rejected,
                       jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
        new = _apply_counts(sub, counts, valid, jnp.zeros((), jnp.int32), cals=cals)
        new_rows = (new.probs, new.mapped, new.num_updates, new.num_conflicts,
                    new.num_rejected)
        # new rows go to a compact buffer (in place); the map is scattered once after the loop
        buf = jax.tree_util.tree_map(
            lambda x, y: jax.lax.dynamic_update_slice_in_dim(x, y, p * blk, axis=0), buf,
            new_rows)
        return p + 1, buf

    buf0 = jax.tree_util.tree_map(lambda x: jnp.zeros((nblk_max * blk, *x.shape[1:]), x.dtype),
                                  rows)
    _, buf = jax.lax.while_loop(lambda c: c[0] * blk < num_seen, body, (jnp.int32(0), buf0))
    # pieces never run hold zeros at padding positions (index ``total``): dropped
    rows = jax.tree_util.tree_map(lambda x, y: x.at[order].set(y, mode="drop"), rows, buf)
    return rows


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
    sparse_block: int = 1024,
) -> Mapper:
    """A PQRM map over all ordered triplets of ``num_landmarks`` landmarks (P Alg. 1).

    ``update`` samples eq. 2.9 for all T triplets (static shapes) and masks the unseen ones.
    ``update_batch(states, keys, positions, visible, sigma, groups=1)`` updates R maps at once
    (sigma: scalar, (R,) or (R, M)): with the EDC as root it gathers the seen triplets of all R
    maps into pieces of ``sparse_block`` rows (sampling and eq. 2.10 per piece) so
    the sampling work is proportional to what is seen (in Padgett's study about 1 triplet in
    8), with results identical to ``jax.vmap(update)`` for the same keys; ``groups`` (static)
    compacts that many slices of the R maps independently (one per device when sharded).

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
    roots = {root_identity(c) for c in cals}
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

    batch_impl = jax.jit(partial(_update_batch_impl, triplets=triplets, cals=cals, root=root,
                                 num_samples=int(num_samples),
                                 chunk_triplets=int(chunk_triplets), block=int(sparse_block)),
                         static_argnames=("groups",))

    def update_batch(state: MapState, keys: jax.Array, positions: jax.Array,
                     visible: jax.Array, sigma, groups: int = 1) -> MapState:
        """``vmap(update)`` over R maps, sampling only the seen triplets (same results)."""
        r = np.shape(positions)[0] if np.ndim(positions) == 3 else None
        if r is None or np.shape(positions) != (r, num_landmarks, 2):
            raise ValueError(f"positions must have shape (R, {num_landmarks}, 2), "
                             f"got {tuple(np.shape(positions))}")
        if np.shape(visible) != (r, num_landmarks):
            raise ValueError(f"visible must have shape ({r}, {num_landmarks}), "
                             f"got {tuple(np.shape(visible))}")
        if np.shape(sigma) not in ((), (r,), (r, num_landmarks)):
            raise ValueError(f"sigma must be a scalar, ({r},) or ({r}, {num_landmarks})")
        if np.shape(keys)[:1] != (r,):
            raise ValueError(f"keys must have leading shape ({r},)")
        _check_sigma(sigma)
        return batch_impl(state, keys, positions, visible, sigma, groups=int(groups))

    return Mapper(init, update, triplets, cals, int(num_landmarks), int(num_samples),
                  update_batch)


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
    ids = ids.astype(np.intp)  # checked integers above; seeing nothing gives float64 ``[]``
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
