"""The online PQRM map: a recursive Bayes filter per ordered landmark triplet (P §2.2.3).

Offers the map state over every ordered triplet of M landmarks (T = M(M−1)(M−2) rows, for one
or several representations at once) and the mapper's pure ``init``/``update`` functions
(P eq. 2.10, Alg. 1), with static shapes so that ``update`` runs under ``jit``, ``lax.scan``
and ``vmap``. Degenerate evidence never gives a NaN map; it is counted.

The update rule and the handling of conflicts, rejected measurements and non-finite
positions: docs/pqrm.md §map.
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
    DEFAULT_MAX_BYTES,
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

__all__ = ["MapInfo", "MapState", "Mapper", "fuse_rows", "mapper", "ordered_triplets",
           "update_observed", "map_bytes_per_triplet", "check_triplets"]


def check_triplets(triplets, num_landmarks: int) -> np.ndarray:
    """Validate an explicit triplet list ``[T, 3]`` of landmark ids; returns it as int32.

    Raises ``ValueError`` unless every row holds three distinct ids in ``[0, num_landmarks)``
    and no row is repeated; ``TypeError`` for non-integer ids.
    """
    tri = np.asarray(triplets)
    if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] < 1:
        raise ValueError(f"triplets must have shape (T, 3) with T >= 1, got {tri.shape}")
    if not np.issubdtype(tri.dtype, np.integer) or tri.dtype == np.bool_:
        raise TypeError(f"triplets must be integer landmark ids, got dtype {tri.dtype}")
    if np.any(tri < 0) or np.any(tri >= num_landmarks):
        raise ValueError(f"triplet ids must be in [0, {num_landmarks})")
    if np.any((tri[:, 0] == tri[:, 1]) | (tri[:, 0] == tri[:, 2]) | (tri[:, 1] == tri[:, 2])):
        raise ValueError("every triplet needs three distinct landmarks")
    if len(np.unique(tri, axis=0)) != len(tri):
        raise ValueError("triplets contain a repeated row")
    return tri.astype(np.int32)


def map_bytes_per_triplet(representations: Sequence[Calculus | str]) -> int:
    """Estimated bytes per triplet row of a map: its state and one update's temporaries.

    State: 4 B per state and per conflict counter of each representation, 9 B of flags and
    counters; update: means and sigmas (36 B), the root counts (4·Q_root B) and, per
    representation, the measurement and posterior rows (8·Q B).

    >>> map_bytes_per_triplet(("edc",))
    369
    """
    cals = [calculi.get(c) for c in representations]
    state = sum(4 * c.num_states + 4 for c in cals) + 9
    root = root_of(cals[0]).num_states if cals else 0
    return state + 36 + 4 * root + sum(8 * c.num_states for c in cals)


class MapState(NamedTuple):
    """State of a PQRM map (a pytree).

    Attributes:
        probs: representation name → [T, Q] ``p(R^n | Z^n_{1:t})``; all-zero rows are unmapped.
        mapped: [T] bool, the triplet has been initialised.
        num_updates: [T] int32, measurements incorporated (including the initialisation).
        num_conflicts: name → [T] int32, eq. 2.10 products that were zero everywhere (prior kept).
        num_rejected: [T] int32, measurements with no defined sample (not incorporated).
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


class MapInfo(NamedTuple):
    """What one ``update`` call did (the ``info`` of the step convention,
    :mod:`pqrm_jax.protocols`); the running totals are in :class:`MapState`.

    Attributes:
        num_updated: () int32, triplet rows that incorporated this measurement.
        num_conflicts: representation name → () int32, this call's eq. 2.10 conflicts.
        num_rejected: () int32, seen rows whose measurement had no defined sample.
        num_dropped: () int32, visible landmarks dropped for non-finite positions.

    ``update_batch`` gives these with a leading axis ``R``.
    """

    num_updated: jax.Array
    num_conflicts: dict[str, jax.Array]
    num_rejected: jax.Array
    num_dropped: jax.Array


def map_info(old: MapState, new: MapState) -> MapInfo:
    """The :class:`MapInfo` of the step from ``old`` to ``new`` (differences of the counters,
    summed over the triplet axis, the last one; leading batch axes are kept)."""
    def total(a, b):
        return jnp.sum(b - a, axis=-1, dtype=jnp.int32)

    return MapInfo(
        num_updated=total(old.num_updates, new.num_updates),
        num_conflicts={n: total(old.num_conflicts[n], new.num_conflicts[n])
                       for n in new.num_conflicts},
        num_rejected=total(old.num_rejected, new.num_rejected),
        num_dropped=(new.num_dropped - old.num_dropped).astype(jnp.int32),
    )


class Mapper(NamedTuple):
    """A PQRM map's pure functions and static description (like an optax transformation).

    It follows the step convention of :mod:`pqrm_jax.protocols` (an
    :class:`~pqrm_jax.protocols.Estimator`):

    init() -> MapState
    update(state, key, positions [M, 2], visible [M], sigma) -> (MapState, MapInfo) (jitted)
    update_batch(states, keys [R], positions [R, M, 2], visible [R, M], sigma)
        -> (MapState, MapInfo): R independent maps at once (leading axis R on every leaf),
        equal to ``vmap(update)`` bit for bit but sampling only the triplets that are seen
        (jitted; see ``mapper``); it holds one (S, 6) bank per map, so
        R·(48·S + T·bytes per triplet) must fit ``max_bytes`` (refused up front otherwise).
    """

    init: Callable[[], MapState]
    update: Callable[..., tuple[MapState, MapInfo]]
    triplets: np.ndarray
    calculi: tuple[Calculus, ...]
    num_landmarks: int
    num_samples: int
    update_batch: Callable[..., tuple[MapState, MapInfo]] | None = None


def fuse_rows(prior: jax.Array, meas: jax.Array, mapped: jax.Array, seen: jax.Array
              ) -> tuple[jax.Array, jax.Array]:
    """One PQRM row fusion (P eq. 2.10 with initialisation and the conflict rule).

    The one rule of every PQRM row update in the library (the PQRM map and the qualitative
    BSP executive, ``pqrm_jax.bsp.execute``; docs/pqrm.md §map):

    * a row not ``seen`` keeps ``prior``;
    * a row seen for the first time (``~mapped``) becomes ``meas``;
    * a mapped row becomes ``p(q) ∝ meas(q) · prior(q)``; when that product is zero for every
      state (a **conflict**) the prior is kept and ``conflict`` is True for the row.

    Never a NaN for finite, non-negative inputs. ``qlink.elements.fuse`` is the *floored*
    variant (likelihoods floored before the product, so it never conflicts; docs/pqrm.md §map).
    The normaliser is summed column by column in a fixed order: XLA's row reduction picks its
    summation order from the number of rows, which would make a row's bits depend on how many
    triplets share the call (a sparse map must give exactly the dense map's rows).
    The products pass through ``max(·, 0)`` (a no-op on them) so that LLVM cannot contract a
    product and the running sum into an FMA — which it did in some programs and not in
    others, by fusion, so the dense and sparse maps differed by a few ulps (issue 31).

    Args:
        prior: [..., Q] current rows (ignored where ``~mapped``).
        meas: [..., Q] measurement distributions ``p(q | Z_t)`` (P eq. 2.9).
        mapped: [...] bool, the row holds a distribution.
        seen: [...] bool, the row is measured now (with a defined measurement).

    Returns:
        ``(rows [..., Q], conflict [...] bool)``.

    >>> import jax.numpy as jnp
    >>> prior = jnp.array([[0.5, 0.5, 0.0], [1.0, 0.0, 0.0], [0.2, 0.8, 0.0]])
    >>> meas = jnp.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    >>> rows, conflict = fuse_rows(prior, meas, jnp.array([True, True, False]),
    ...                            jnp.array([True, True, True]))
    >>> rows.tolist(), conflict.tolist()
    ([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [False, True, False])
    """
    post = jnp.maximum(meas * prior, 0.0)  # no FMA into z (see above)
    z = post[..., :1]
    for q in range(1, post.shape[-1]):
        z = z + post[..., q:q + 1]
    conflict = seen & mapped & (z[..., 0] <= 0)
    post = post / jnp.where(z > 0, z, 1.0)
    new = jnp.where((seen & ~mapped)[..., None], meas, prior)
    new = jnp.where((seen & mapped & ~conflict)[..., None], post, new)
    return new, conflict


def _prepare(positions, visible, sigma, triplets):
    """Per-call inputs of the kernel: (means [T, 3, 2], sigma [T, 3], seen [T], dropped ())."""
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
    if PREPARE_BARRIER:
        # per landmark, once: without the barrier XLA fuses the observation's arithmetic into
        # the per-triplet gathers and recomputes it for every one of the T rows
        pos, sig, seen_lm = jax.lax.optimization_barrier((pos, sig, seen_lm))
    # a triplet is seen when its three landmarks are: counted by one product with the
    # landmark–triplet incidence (exact small integers) — as a per-triplet gather of three
    # flags XLA:CPU took longer than the rest of a padgett-mc step's bookkeeping
    inc = np.zeros((m, len(triplets)), np.float32)  # three distinct ids a triplet
    inc[np.asarray(triplets), np.arange(len(triplets))[:, None]] = 1.0
    seen = (seen_lm.astype(jnp.float32) @ jnp.asarray(inc)) == 3.0
    return pos[tri], sig[tri], seen, dropped


def _merge_counts(fine: jax.Array, calc: Calculus) -> jax.Array:
    """``fine @ aggregation_matrix(calc)`` as column sums: [..., Q_root] → [..., Q].

    Sums of at most Q_root integers ≤ S, exact in float32 while S·Q_root ≤ 2**24 (S up to
    838 860 samples for the EDC), so then equal to the product bit for bit (beyond, both
    round; their last bits may differ); with the six small products a padgett-mc level took
    1.45x as long (XLA:CPU emitted them as naive dots in the sparse update's piece loop;
    docs/pqrm.md §map).
    """
    agg = aggregation_matrix(calc)
    cols = []
    for q in range(agg.shape[1]):
        src = np.flatnonzero(agg[:, q])
        col = fine[..., src[0]]
        for j in src[1:]:
            col = col + fine[..., j]
        cols.append(col)
    return jnp.stack(cols, axis=-1)


def _apply_counts(state: MapState, counts, seen, dropped, *, cals) -> MapState:
    """Eq. 2.10 for every seen triplet from its root-calculus sample counts [T, Q_root]."""
    defined = jnp.sum(counts, axis=-1) > 0
    use = seen & defined
    fine = counts.astype(jnp.float32)
    probs, conflicts = {}, {}
    for c in cals:
        meas = counts_to_probabilities(_merge_counts(fine, c))
        new, conflict = fuse_rows(state.probs[c.name], meas, state.mapped, use)
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
    new = _apply_counts(state, counts, seen, dropped, cals=cals)
    return new, map_info(state, new)


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
        new = jax.vmap(partial(_apply_counts, cals=cals))(state, counts, seen, dropped)
        return new, map_info(state, new)
    # sparse path: sample and update only the seen triplets, compacted across the R maps
    t = means.shape[1]
    g = groups
    if g < 1 or r % g:
        raise ValueError(f"{r} maps cannot be split into {g} groups")
    z = jax.vmap(lambda k: sample_bank(k, num_samples, means.dtype, sample_major=True))(
        keys)  # (R, c, 6, C)
    rows = (state.probs, state.mapped, state.num_updates, state.num_conflicts,
            state.num_rejected)

    def grouped(x):  # (R, T, ...) → (G, R/G·T, ...)
        return x.reshape(g, (r // g) * t, *x.shape[2:])

    z = z.reshape(g, r // g, *z.shape[1:])
    rows = jax.tree_util.tree_map(grouped, rows)
    # the most rows seen in a group (unbatched, so that the buffer choice below is a real
    # branch, not a select running both sides under vmap)
    most_seen = jnp.max(jnp.sum(grouped(seen), axis=1, dtype=jnp.int32))
    args = (z, grouped(means.reshape(r, t, 6)), grouped(sig), grouped(seen), rows)
    if g == 1:  # not under vmap: XLA:CPU copies the whole map for a batched scatter
        rows = jax.tree_util.tree_map(lambda x: x[None], _sparse_group_update(
            *jax.tree_util.tree_map(lambda x: x[0], args), most_seen=most_seen, n=t,
            block=block, cals=cals, mode=BUFFER_MODE))
    else:  # groups under vmap (one per device): the direct scatter would copy the map
        mode = "full" if BUFFER_MODE == "direct" else BUFFER_MODE
        rows = jax.vmap(partial(_sparse_group_update, most_seen=most_seen, n=t, block=block,
                                cals=cals, mode=mode))(*args)
    probs, mapped, num_updates, num_conflicts, num_rejected = jax.tree_util.tree_map(
        lambda x: x.reshape(r, t, *x.shape[2:]), rows)
    new = MapState(probs=probs, mapped=mapped, num_updates=num_updates,
                   num_conflicts=num_conflicts, num_rejected=num_rejected,
                   num_dropped=state.num_dropped + dropped, step=state.step + 1)
    return new, map_info(state, new)


SMALL_BUFFER_FRACTION = 4  # the small compact buffer holds 1/4 of a group's rows
#: how the sparse update writes its updated rows into the map (all bit-identical; measured in
#: docs/pqrm.md §map): "direct" — each piece scattered into the map that the piece loop
#: carries (in place: work in proportion to the rows seen; with ``groups`` > 1, under
#: ``vmap``, "full" is used instead); "full" — a zeroed buffer of all
#: rows, filled piece by piece and scattered into the map after the loop (work in
#: proportion to all rows, every step); "cond" — the ``lax.cond`` between a quarter-size
#: and a full buffer (two copies of the piece loop; XLA copies the map state), kept as
#: bench_padgett's in-process reference
BUFFER_MODE = "direct"
#: compute the per-landmark inputs once before the per-triplet gathers (docs/pqrm.md §map)
PREPARE_BARRIER = True


def _seen_order(mask: jax.Array, block: int) -> tuple[jax.Array, jax.Array, int, int]:
    """The rows of ``mask`` [N] that are seen, in order, padded with N to whole pieces.

    Returns ``(order [P·blk] int32, number seen () int32, blk, P)``: pieces of
    ``blk = min(block, N)`` rows (at least 1), ``P = ⌈N / blk⌉`` of them at most. The
    values of ``jnp.nonzero(mask, size=N, fill_value=N)`` padded with N, from one running
    count and one scatter (each seen row to its rank; ``jnp.nonzero`` takes two running
    counts, a scatter-add and a concatenation: a padgett-mc level took 6 % more CPU,
    docs/benchmarks.md §bench_padgett).
    """
    total = mask.shape[0]
    blk = max(1, min(block, total))
    nblk_max = -(-total // blk)
    mask = jnp.asarray(mask, bool)
    rows = jnp.arange(total, dtype=jnp.int32)
    rank = jnp.cumsum(mask, dtype=jnp.int32) - 1  # of each seen row among the seen rows
    slot = jnp.where(mask, rank, nblk_max * blk)  # the rows not seen: out of range, dropped
    order = jnp.full(nblk_max * blk, total, jnp.int32).at[slot].set(rows, mode="drop")
    return order, jnp.sum(mask, dtype=jnp.int32), blk, nblk_max


def _sparse_group_update(z, m, s, mask, rows, *, most_seen, n: int, block: int, cals,
                         mode: str):
    """Eq. 2.9 + 2.10 for the seen rows of one group of maps, ``block`` rows at a time.

    z [Rg, c, 6, C] banks of the Rg maps (sample-major); m [Rg·N, 6], s [Rg·N, 3], mask
    [Rg·N] per triplet row (map-major); rows = (probs, mapped, num_updates, num_conflicts,
    num_rejected) flattened the same way. The seen rows are compacted (:func:`_seen_order`,
    static size) and a ``lax.while_loop`` runs ⌈#seen / block⌉ pieces, each scattered into
    the map the loop carries, so every seen row is updated and nothing else is computed (in
    Padgett's study about 1 row in 8 is seen). Each row's arithmetic is that of the dense
    ``update`` (same bank, same kernel, same eq. 2.10), so the results are
    identical. ``mode``: how the rows reach the map (:data:`BUFFER_MODE`).
    """
    total = mask.shape[0]
    order, num_seen, blk, nblk_max = _seen_order(mask, block)
    inv = np.argsort(key_to_edc_state())

    def piece_rows(idx, src):
        """Rows ``idx`` [blk] of ``src`` updated (``total``: padding, a dummy row)."""
        valid = idx < total
        safe = jnp.where(valid, idx, 0)
        zc = jnp.transpose(z[safe // n], (1, 2, 3, 0))  # this block's banks (c, 6, C, blk)
        counts = edc_block_counts(m[safe].T, s[safe].T, zc)[:, inv]
        probs, mapped, num_updates, num_conflicts, num_rejected = jax.tree_util.tree_map(
            lambda x: x[safe], src)
        sub = MapState(probs, mapped, num_updates, num_conflicts, num_rejected,
                       jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
        new = _apply_counts(sub, counts, valid, jnp.zeros((), jnp.int32), cals=cals)
        return (new.probs, new.mapped, new.num_updates, new.num_conflicts, new.num_rejected)

    def piece(p, buf):
        """Piece ``p`` (rows ``order[p·blk : (p+1)·blk]``) into ``buf`` at ``p·blk``."""
        new_rows = piece_rows(jax.lax.dynamic_slice(order, (p * blk,), (blk,)), rows)
        # new rows go to a compact buffer (in place); the map is scattered after the loop
        return jax.tree_util.tree_map(
            lambda x, y: jax.lax.dynamic_update_slice_in_dim(x, y, p * blk, axis=0),
            buf, new_rows)

    def pieces(nblk: int):
        buf0 = jax.tree_util.tree_map(lambda x: jnp.zeros((nblk * blk, *x.shape[1:]), x.dtype),
                                      rows)
        _, buf = jax.lax.while_loop(lambda c: c[0] * blk < num_seen,
                                    lambda c: (c[0] + 1, piece(c[0], c[1])),
                                    (jnp.int32(0), buf0))
        # pieces never run hold zeros at padding positions (index ``total``): dropped
        return jax.tree_util.tree_map(
            lambda x, y: x.at[order[:nblk * blk]].set(y, mode="drop"), rows, buf)

    if mode == "direct":
        def direct(p, rows):
            """Piece ``p`` scattered straight into ``rows`` (padding dropped)."""
            idx = jax.lax.dynamic_slice(order, (p * blk,), (blk,))
            # read from the carried map: reading the map before the loop keeps it alive
            # beside the carried one (a level 1.3x as long, docs/pqrm.md §map)
            new_rows = piece_rows(idx, rows)
            return jax.tree_util.tree_map(lambda x, y: x.at[idx].set(y, mode="drop"),
                                          rows, new_rows)

        return jax.lax.while_loop(lambda c: c[0] * blk < num_seen,
                                  lambda c: (c[0] + 1, direct(c[0], c[1])),
                                  (jnp.int32(0), rows))[1]
    small = -(-nblk_max // SMALL_BUFFER_FRACTION)
    if mode == "cond":
        if small >= nblk_max:
            return pieces(nblk_max)
        return jax.lax.cond(most_seen <= small * blk, lambda: pieces(small),
                            lambda: pieces(nblk_max))
    return pieces(nblk_max)  # "full"


def _check_map_bytes(t: int, cals, max_bytes, *, dense: bool) -> None:
    if max_bytes is None:
        return
    need = t * map_bytes_per_triplet(cals)
    if need > max_bytes:
        what = "the dense map over all ordered triplets" if dense else "this map"
        raise ValueError(
            f"{what} has {t} triplets, about {need / 2**30:.2f} GiB (≈ "
            f"{map_bytes_per_triplet(cals)} B per triplet) > max_bytes = "
            f"{max_bytes / 2**30:.2f} GiB: pass triplets=[[i, j, k], ...] (a sparse map over "
            "only the triplets you need) or raise max_bytes")


def _check_real(x, name: str) -> None:
    dt = getattr(x, "dtype", None)
    if dt is None:
        dt = np.asarray(x).dtype
    if jnp.issubdtype(dt, jnp.complexfloating):
        raise TypeError(f"{name} is complex ({dt}); positions must be real")


def _check_sigma(sigma) -> None:
    _check_real(sigma, "sigma")
    if isinstance(sigma, jax.core.Tracer):
        return
    s = np.asarray(sigma, dtype=float)
    if np.any(np.isnan(s)) or np.any(s < 0) or np.any(np.isinf(s)):
        raise ValueError(f"sigma must be finite and non-negative, got {s.tolist()}")


def _resolve(representations, num_landmarks, num_samples, triplets, max_bytes):
    """Check the mapper's configuration; returns (calculi, triplets [T, 3] int32)."""
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
    if triplets is None:
        if isinstance(num_landmarks, int | np.integer) and num_landmarks >= 3:
            t_dense = int(num_landmarks) * (int(num_landmarks) - 1) * (int(num_landmarks) - 2)
            _check_map_bytes(t_dense, cals, max_bytes, dense=True)
        return cals, ordered_triplets(num_landmarks)
    if not isinstance(num_landmarks, int | np.integer) or num_landmarks < 3:
        raise ValueError(f"a PQRM map needs at least three landmarks, got "
                         f"{num_landmarks!r}")
    triplets = check_triplets(triplets, int(num_landmarks))
    _check_map_bytes(triplets.shape[0], cals, max_bytes, dense=False)
    return cals, triplets


def _check_update_args(m: int, positions, visible, sigma) -> None:
    """Host-side checks of one ``update`` call's shapes and ``sigma`` (M landmarks)."""
    if np.shape(positions) != (m, 2):
        raise ValueError(f"positions must have shape ({m}, 2), "
                         f"got {tuple(np.shape(positions))}")
    if np.shape(visible) != (m,):
        raise ValueError(f"visible must have shape ({m},), got {tuple(np.shape(visible))}")
    if np.ndim(sigma) not in (0, 1) or (np.ndim(sigma) == 1 and np.shape(sigma) != (m,)):
        raise ValueError(f"sigma must be a scalar or ({m},)")
    _check_real(positions, "positions")
    _check_sigma(sigma)


def _check_batch_args(m: int, t: int, cals, num_samples: int, max_bytes, keys, positions,
                      visible, sigma) -> None:
    """Host-side checks of one ``update_batch`` call (shapes, ``sigma``, memory)."""
    r = np.shape(positions)[0] if np.ndim(positions) == 3 else None
    if r is None or np.shape(positions) != (r, m, 2):
        raise ValueError(f"positions must have shape (R, {m}, 2), "
                         f"got {tuple(np.shape(positions))}")
    if np.shape(visible) != (r, m):
        raise ValueError(f"visible must have shape ({r}, {m}), "
                         f"got {tuple(np.shape(visible))}")
    if np.shape(sigma) not in ((), (r,), (r, m)):
        raise ValueError(f"sigma must be a scalar, ({r},) or ({r}, {m})")
    if np.shape(keys)[:1] != (r,):
        raise ValueError(f"keys must have leading shape ({r},)")
    _check_real(positions, "positions")
    _check_sigma(sigma)
    # the sparse path holds one (S, 6) bank per map and R·T rows of state
    need = r * (int(num_samples) * 6 * 8 + t * map_bytes_per_triplet(cals))
    if max_bytes is not None and need > max_bytes:
        raise ValueError(
            f"update_batch of {r} maps needs about {need / 2**30:.2f} GiB (one bank of "
            f"num_samples = {num_samples} draws and {t} triplet rows per map) > max_bytes = "
            f"{max_bytes / 2**30:.2f} GiB: update fewer maps per call, lower num_samples, "
            "pass triplets=..., or raise max_bytes")


def mapper(
    representations: Sequence[Calculus | str] = ("edc",),
    num_landmarks: int = 10,
    num_samples: int = 256,
    *,
    chunk_triplets: int = 4096,
    sparse_block: int = 1024,
    triplets=None,
    max_bytes: int | None = DEFAULT_MAX_BYTES,
) -> Mapper:
    """A PQRM map over all ordered triplets of ``num_landmarks`` landmarks (P Alg. 1).

    ``triplets`` (T, 3) makes a sparse map over only those ordered triplets (same interface,
    rows identical to the dense map's rows for them); the dense map has
    T = M(M−1)(M−2) rows of about :func:`map_bytes_per_triplet` bytes, and a map whose
    estimate exceeds ``max_bytes`` (``None``: no check) is refused with ``ValueError``.

    ``update(state, key, positions, visible, sigma) -> (state, MapInfo)`` (the step convention
    of :mod:`pqrm_jax.protocols`) samples eq. 2.9 for all T triplets (static shapes) and masks
    the unseen ones.
    ``update_batch(states, keys, positions, visible, sigma, groups=1)`` updates R maps at once
    (sigma: scalar, [R] or [R, M]): with the EDC as root it gathers the seen triplets of all R
    maps into pieces of ``sparse_block`` rows (sampling and eq. 2.10 per piece) so the sampling
    work is proportional to what is seen (in Padgett's study about 1 triplet in 8), with results
    identical to ``jax.vmap(update)`` for the same keys; ``groups`` (static) compacts that many
    slices of the R maps independently (one per device when sharded).

    Args:
        representations: the calculi mapped at once (objects or registered names); all must be
            merges of one root calculus.
        num_landmarks: M, the landmark capacity (T = M(M−1)(M−2) ordered triplets).
        num_samples: S, samples per triplet per update.
        chunk_triplets: triplets per sampling block (bounds the working set).
        sparse_block: rows per piece of the batched sparse update.
        triplets: ``[T, 3]`` int landmark ids of a sparse map (``None``: every ordered triplet).
        max_bytes: refuse a map (or an ``update_batch`` call) whose estimated memory exceeds
            this many bytes (``None``: no check).

    Returns:
        A :class:`Mapper` of pure functions (``init``, ``update``, ``update_batch``).

    Raises:
        ValueError: for no or duplicate representations, representations without a common root
            calculus, or a non-positive ``num_samples``; the returned functions raise for inputs
            of the wrong shape and bad ``sigma``.

    >>> import jax, jax.numpy as jnp
    >>> pq = mapper(("edc", "lr"), num_landmarks=4, num_samples=64)
    >>> st = pq.init()
    >>> pos = jnp.array([[0., 0.], [0., 10.], [5., 5.], [-5., 2.]])
    >>> st, info = pq.update(st, jax.random.key(0), pos, jnp.array([True, True, True, False]),
    ...                      0.5)
    >>> int(st.mapped.sum()), st.probs["lr"].shape      # the 6 orderings of landmarks 0, 1, 2
    (6, (24, 2))
    >>> int(info.num_updated), int(info.num_conflicts["lr"])
    (6, 0)
    >>> sp = mapper(("edc", "lr"), num_landmarks=4, num_samples=64, triplets=[[0, 1, 2]])
    >>> sp.init().probs["lr"].shape
    (1, 2)
    """
    cals, triplets = _resolve(representations, num_landmarks, num_samples, triplets, max_bytes)
    t = triplets.shape[0]
    root = root_of(cals[0])
    m = num_landmarks

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
               sigma) -> tuple[MapState, MapInfo]:
        """Incorporate one measurement of all landmarks (eq. 2.10); see docs/pqrm.md §map."""
        _check_update_args(m, positions, visible, sigma)
        return impl(state, key, positions, visible, sigma)

    batch_impl = jax.jit(partial(_update_batch_impl, triplets=triplets, cals=cals, root=root,
                                 num_samples=int(num_samples),
                                 chunk_triplets=int(chunk_triplets), block=int(sparse_block)),
                         static_argnames=("groups",))

    def update_batch(state: MapState, keys: jax.Array, positions: jax.Array,
                     visible: jax.Array, sigma, groups: int = 1) -> tuple[MapState, MapInfo]:
        """``vmap(update)`` over R maps, sampling only the seen triplets (same results)."""
        _check_batch_args(m, t, cals, num_samples, max_bytes, keys, positions, visible, sigma)
        return batch_impl(state, keys, positions, visible, sigma, groups=int(groups))

    return Mapper(init, update, triplets, cals, int(num_landmarks), int(num_samples),
                  update_batch)


def update_observed(pq: Mapper, state: MapState, key: jax.Array, ids, positions,
                    sigma) -> tuple[MapState, MapInfo]:
    """Eager convenience: update with the landmarks ``ids`` [K] seen at ``positions`` [K, 2].

    Fewer than three ids observe no triplet: the map is returned unchanged except ``step``.

    Args:
        pq: the mapper (:func:`mapper`).
        state: the current :class:`MapState`.
        key: PRNG key of this update's samples.
        ids: [K] int landmark ids, distinct, in ``[0, num_landmarks)``.
        positions: [K, 2] measured positions (robot frame).
        sigma: noise std, scalar or [K] (one per id).

    Returns:
        ``(MapState, MapInfo)``, as ``pq.update``.

    Raises:
        ValueError: for duplicate or out-of-range ids, NaN/inf positions and bad ``sigma``.
    """
    ids = np.asarray(ids)
    _check_real(positions, "positions")
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
    with np.errstate(over="ignore", invalid="ignore"):
        spread = positions.max(axis=0, initial=0) - positions.min(axis=0, initial=0)
    if not np.all(np.isfinite(spread)):
        raise ValueError("differences between observed positions overflow float32; translate "
                         "or rescale the positions")
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
