"""The qualitative map: a 3-uniform hypergraph of state sets, path-consistency update (M§VI).

Offers the map (a uint32 state mask per ordered triple of a fixed landmark capacity), its
update by intersection with measured sets followed by path-consistency propagation to a fixed
point, the per-unordered-triple view of M§VI.A and the true map of a layout. An empty set
rejects the update and keeps the previous map (``inconsistent=True``).

The dense representation, the unary and composition closure, the semi-naive sweeps and
order independence: docs/qrm.md §hypergraph.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi import Calculus
from ..triplets import distinct_mask, states_to_masks, true_states
from .camera import CYCLIC, ImageMeasurement
from .spec import QRMSpec, qrm_spec

__all__ = ["QRMMap", "UpdateReport", "ClosureResult", "empty_map", "closure",
           "apply_relations", "update_image", "cyclic_relations", "true_relations", "true_map",
           "distinct_mask"]


class QRMMap(NamedTuple):
    """The map pytree: ``rel`` [N, N, N] uint32 masks of ``ij:k``; ``known`` [N] bool nodes."""

    rel: jax.Array
    known: jax.Array


class UpdateReport(NamedTuple):
    """Result flags of an update.

    ``inconsistent`` (an empty set appeared; the update was rejected), ``n_empty`` (number of
    empty relations it would have produced), ``sweeps`` (propagation sweeps to the fixed point),
    ``converged`` (``False``: stopped at ``max_sweeps`` before the fixed point, see
    :class:`ClosureResult`).
    """

    inconsistent: jax.Array
    n_empty: jax.Array
    sweeps: jax.Array
    converged: jax.Array


def _spec(calc) -> QRMSpec:
    return calc if isinstance(calc, QRMSpec) else qrm_spec(calc)


def empty_map(n: int, calc: Calculus | str | QRMSpec = "edc") -> QRMMap:
    """A map of capacity ``n`` landmarks with every relation open and no known node.

    Args:
        n: capacity N, an integer ≥ 3.
        calc: the calculus (name, object or its :class:`QRMSpec`).

    Returns:
        The :class:`QRMMap` (``rel`` [N, N, N] all states, ``known`` [N] False; M§VI.A).

    Raises:
        ValueError: for ``n`` < 3 or not an integer.

    >>> m = empty_map(4)
    >>> m.rel.shape, int(m.rel[0, 1, 2]) == (1 << 20) - 1
    ((4, 4, 4), True)
    """
    if not isinstance(n, int) or n < 3:
        raise ValueError(f"map capacity must be an int >= 3, got {n!r}")
    spec = _spec(calc)
    return QRMMap(jnp.full((n, n, n), spec.full, jnp.uint32), jnp.zeros((n,), bool))


def _lift(table, s):
    """Lift a [Q] table of masks to a set: OR of table[i] over the bits i of s."""
    q = table.shape[0]
    bits = ((s[..., None] >> jnp.arange(q, dtype=jnp.uint32)) & 1).astype(bool)
    vals = jnp.where(bits, table, jnp.uint32(0))
    return jax.lax.reduce(vals, np.uint32(0), jax.lax.bitwise_or, (vals.ndim - 1,))


def _compose_chunks(spec: QRMSpec) -> jax.Array:
    """[C, Q, 32] uint32: ``[m, k, v]`` = the states ``i`` with ``k ∈ COMPOSE({i}, {j})`` for
    some ``j`` among the states ``5m + bits of v``.

    So ``H[k] = {i : k ∈ COMPOSE({i}, S)}`` is the OR of these over the C = ⌈Q/5⌉ five-bit
    chunks of S (C gathers), and ``k ∈ COMPOSE(R, S)`` exactly when ``R & H[k] ≠ 0``
    (:func:`_sweep`).
    """
    ct = np.asarray(spec.compose, np.uint32)  # (Q, Q): [i, j] -> mask of k
    q = ct.shape[0]
    nc = -(-q // 5)
    # by_k[j, k] = the mask of the states i with k in COMPOSE({i}, {j}) (distinct bits: a sum)
    bits = (ct[:, :, None] >> np.arange(q, dtype=np.uint32)) & 1  # [i, j, k]
    by_k = (bits.astype(np.uint64) << np.arange(q, dtype=np.uint64)[:, None, None]).sum(0)
    by_k = by_k.astype(np.uint32)
    out = np.zeros((nc, q, 32), np.uint32)
    for m in range(nc):
        for v in range(32):
            for b in range(5):
                if v >> b & 1 and 5 * m + b < q:
                    out[m, :, v] |= by_k[5 * m + b]
    return jnp.asarray(out)


_B_ROWS = 4  # middle landmarks b per composition block (:func:`_sweep`; docs/qrm.md §hypergraph)


def _sweep(spec: QRMSpec, rel, distinct, prev_u, first):
    """One unary + composition sweep → (new rel, rel after the unary step).

    Semi-naive: the composition through a fourth landmark c, middle landmark b (the
    constraints ``rel[:, b, :] ∩= COMPOSE(rel[:, b, c], rel[b, c, :])``) is skipped when
    neither ``rel[:, b, c]`` nor ``rel[b, c, :]`` changed since the previous sweep's
    composition inputs ``prev_u`` (its constraints already hold; the relations only shrink),
    so the fixed point is exactly that of full sweeps. ``first``: no previous sweep. The
    middle landmarks still to visit through c are gathered in blocks of ``_B_ROWS``.
    """
    full = jnp.uint32(spec.full)
    q = spec.num_states
    inv, left, right = (jnp.asarray(t, jnp.uint32) for t in (spec.inverse, spec.left, spec.right))
    r = rel
    r = r & _lift(inv, jnp.transpose(r, (1, 0, 2)))
    r = r & _lift(left, jnp.transpose(r, (1, 2, 0)))  # rel[a,b,c] ∩= LEFT(rel[c,a,b])
    r = r & _lift(right, jnp.transpose(r, (2, 0, 1)))  # rel[a,b,c] ∩= RIGHT(rel[b,c,a])
    r = jnp.where(distinct, r, full)
    changed = r != prev_u
    # todo[b, c]: a composition input through (b, c) changed, rel[a,b,c] or rel[b,c,d]
    todo = first | changed.any(0) | changed.any(2)
    n = r.shape[0]
    idx = jnp.arange(n)
    nb = _B_ROWS
    nblocks = -(-n // nb)

    chunks = _compose_chunks(spec)  # (C, Q, 32), :func:`_compose_chunks`

    def block(c, rows, acc):
        # rows: [nb] middle landmarks, n for padding (read as landmark n - 1, never written);
        # acc: [b, a, d], the constraint on rel[a, b, d] (b leading: a block is whole rows)
        at = jnp.minimum(rows, n - 1)
        s = r[at, c, :]  # (b, d)
        # H[k,b,d] = {i : k ∈ COMPOSE({i}, rel[b,c,d])}: an OR of table lookups, one per 5-bit
        # chunk of rel[b,c,d]
        H = jnp.zeros((q,) + s.shape, jnp.uint32)  # [k, b, d]
        for m in range(chunks.shape[0]):
            H = H | chunks[m][:, (s >> (5 * m)) & 31]
        # g[b,a,d] = COMPOSE(rel[a,b,c], rel[b,c,d]): state k is in it exactly when some
        # state of rel[a,b,c] is in H[k,b,d] (Q bitwise tests a relation, no gather)
        ab = r[:, at, c].T[:, :, None]  # (b, a, 1)
        g = jnp.zeros((nb, n, n), jnp.uint32)
        for k in range(q):
            g = g | jnp.where((ab & H[k][:, None, :]) != 0, jnp.uint32(1 << k), jnp.uint32(0))
        skip = (rows[:, None, None] == c) | (idx[None, :, None] == c) | (idx[None, None, :] == c)
        return acc.at[rows].set(acc[at] & jnp.where(skip, full, g), mode="drop")

    def through(c, acc):
        # the middle landmarks to visit first, in order, then n (padding) to a block multiple
        want = todo[:, c]
        pos = jnp.where(want, jnp.cumsum(want) - 1, nblocks * nb)
        rows = jnp.full((nblocks * nb,), n, jnp.int32).at[pos].set(idx, mode="drop")
        rows = rows.reshape(nblocks, nb)
        count = -(-want.sum() // nb)
        return jax.lax.fori_loop(0, count, lambda i, acc: block(c, rows[i], acc), acc)

    def over_c(c, acc):
        return jax.lax.cond(todo[:, c].any(), through, lambda c, acc: acc, c, acc)

    comp = jax.lax.fori_loop(0, n, over_c, jnp.full_like(r, full))  # [b, a, d]
    return jnp.where(distinct, r & jnp.transpose(comp, (1, 0, 2)), full), r


@partial(jax.jit, static_argnames=("spec", "max_sweeps"))
def _closure(spec: QRMSpec, rel, *, max_sweeps: int, base=None, closed=False):
    """The fixed point below ``rel``. ``base``: an array ``rel`` lies within; when ``closed``
    (a traced bool) says ``base`` is itself a fixed point (a map after a converged update),
    the first sweep is semi-naive against it as the later ones are against the sweep before
    (:func:`_sweep`: only the (middle, fourth) landmark pairs with an input that differs from
    ``base``)."""
    distinct = jnp.asarray(distinct_mask(rel.shape[0]))
    closed = jnp.asarray(closed, bool)
    prev0 = rel if base is None else jnp.where(closed, base, rel)

    def cond(st):
        it, _, _, changed, empty = st
        return changed & ~empty & (it < max_sweeps)

    def body(st):
        it, r, prev_u, _, _ = st
        new, ru = _sweep(spec, r, distinct, prev_u, (it == 0) & ~closed)
        return it + 1, new, ru, jnp.any(new != r), jnp.any(distinct & (new == 0))

    empty0 = jnp.any(distinct & (rel == 0))
    it, r, _, changed, empty = jax.lax.while_loop(
        cond, body, (0, rel, prev0, jnp.asarray(True), empty0))
    n_empty = jnp.sum(distinct & (r == 0))
    # stopped by the sweep cap while the last sweep still changed something
    return r, empty, n_empty, it, empty | ~changed


class ClosureResult(NamedTuple):
    """Result of :func:`closure`.

    rel: (N, N, N) uint32 relation masks after propagation.
    inconsistent: () bool, an empty relation appeared (propagation stopped there).
    n_empty: () int32, number of empty relations.
    sweeps: () int32, sweeps run.
    converged: () bool, the fixed point (or an inconsistency) was reached; ``False`` when
        propagation stopped at ``max_sweeps`` with relations still shrinking — ``rel`` is then
        sound but not yet path-consistent (raise ``max_sweeps``).
    """

    rel: jax.Array
    inconsistent: jax.Array
    n_empty: jax.Array
    sweeps: jax.Array
    converged: jax.Array


def check_max_sweeps(max_sweeps, minimum: int = 1) -> int:
    """``max_sweeps`` as a Python int, or a ValueError that names it.

    Args:
        max_sweeps: a propagation sweep cap (an integer, NumPy integers welcome; not a bool).
        minimum: the least value accepted (1 for a closure; 0 where "no propagation" means
            the map is the intersection of the measured sets, as in
            :func:`pqrm_jax.qrm.run_sequence`).

    Returns:
        ``int(max_sweeps)``.

    Raises:
        ValueError: for a bool, a non-integer or a value below ``minimum``.
    """
    if isinstance(max_sweeps, bool) or not isinstance(max_sweeps, (int, np.integer)) \
            or max_sweeps < minimum:
        raise ValueError(f"max_sweeps must be an integer ≥ {minimum}, got {max_sweeps!r}")
    return int(max_sweeps)


def closure(rel: jax.Array, calc: Calculus | str | QRMSpec = "edc",
            max_sweeps: int = 64) -> ClosureResult:
    """Path-consistency fixed point of a relation array (M§VI.B steps 7–9).

    Returns a :class:`ClosureResult` ``(rel, inconsistent, n_empty, sweeps, converged)``;
    ``converged`` is ``False`` when the ``max_sweeps`` cap stopped it before the fixed point.

    Args:
        rel: [N, N, N] uint32 relation masks of ``ij:k``.
        calc: the calculus (name, object or its :class:`QRMSpec`).
        max_sweeps: propagation sweep cap (an integer ≥ 1).

    Returns:
        The :class:`ClosureResult`.

    Raises:
        ValueError: for a bad ``max_sweeps``.

    >>> r = closure(true_map(jnp.array([[0., 0.], [4., 1.], [1., 3.], [5., 5.]])).rel)
    >>> bool(r.converged), bool(r.inconsistent)
    (True, False)
    """
    return ClosureResult(*_closure(_spec(calc), jnp.asarray(rel, jnp.uint32),
                                   max_sweeps=check_max_sweeps(max_sweeps)))


def _merge(spec, m: QRMMap, meas, nodes, max_sweeps, closed):
    r, empty, n_empty, sweeps, conv = _closure(spec, m.rel & meas, max_sweeps=max_sweeps,
                                               base=m.rel, closed=closed)
    new = QRMMap(jnp.where(empty, m.rel, r), jnp.where(empty, m.known, m.known | nodes))
    return new, UpdateReport(empty, n_empty, sweeps, conv)


@partial(jax.jit, static_argnames=("spec", "max_sweeps"))
def apply_relations_kernel(spec, m: QRMMap, triples, sets, valid, *, max_sweeps, closed=False):
    """:func:`apply_relations` without the checks; ``closed`` (a bool, may be traced): ``m`` is
    a fixed point of the propagation (e.g. the result of a converged update), which lets the
    first sweep skip the fourth landmarks the new relations do not touch (:func:`_closure`)."""
    n = m.rel.shape[0]
    q = spec.num_states
    tri = jnp.where(valid[:, None], triples, n)  # out of range → dropped
    # repeated rows for the same relation are intersected: a state survives only if no row
    # clears it (scatter-max of the cleared bits is an OR over the rows, in any order)
    shifts = jnp.arange(q, dtype=jnp.uint32)
    cleared = jnp.zeros(m.rel.shape + (q,), jnp.uint8)
    for o, (X, Y, Z) in enumerate(CYCLIC):
        off = (((~sets[:, o, None]) >> shifts) & 1).astype(jnp.uint8)  # (T, Q)
        cleared = cleared.at[tri[:, X], tri[:, Y], tri[:, Z]].max(off, mode="drop")
    meas = jnp.uint32(spec.full) & ~jax.lax.reduce(
        jnp.where(cleared.astype(bool), jnp.uint32(1) << shifts, jnp.uint32(0)),
        np.uint32(0), jax.lax.bitwise_or, (3,))
    nodes = jnp.zeros((n,), bool).at[tri.ravel()].set(True, mode="drop")
    return _merge(spec, m, meas, nodes, max_sweeps, closed)


def _check_ids(triples, n):
    t = np.asarray(triples)
    if t.size and (t.min() < 0 or t.max() >= n):
        raise ValueError(f"measurement refers to landmark ids outside the map's capacity "
                         f"0..{n - 1} (got {t.min()}..{t.max()}); an unknown landmark must be "
                         "given an id below the capacity (it is added as a new node)")
    if t.size and np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])):
        raise ValueError("a measured triple repeats a landmark id")


def apply_relations(
    m: QRMMap,
    triples: jax.Array,
    sets: jax.Array,
    calc: Calculus | str | QRMSpec = "edc",
    valid: jax.Array | None = None,
    max_sweeps: int = 64,
) -> tuple[QRMMap, UpdateReport]:
    """Fuse measured cyclic relations into the map (M§VI.B).

    ``triples`` [T, 3] are landmark ids (X, Y, Z) and ``sets`` [T, 3] the masks of XY:Z, YZ:X,
    ZX:Y. New ids become known nodes.

    Rows that measure the same relation (the same triple, or the same relation reached through
    another rotation of the triple) are intersected, so all images of a sequence can be fused
    in one call and reach the fixed point of fusing them one by one (the result is the
    greatest fixed point below all measurements, independent of their order).

    Args:
        m: the map (``rel`` [N, N, N] uint32 masks, ``known`` [N]).
        triples: [T, 3] int landmark ids (X, Y, Z), distinct within a row.
        sets: [T, 3] uint32 masks of XY:Z, YZ:X, ZX:Y.
        calc: the calculus (name, object or its :class:`QRMSpec`).
        valid: optional [T] bool, rows to use.
        max_sweeps: propagation sweep cap (an integer ≥ 1).

    Returns:
        ``(map', report)``: the fused map (unchanged when the update is inconsistent) and its
        :class:`UpdateReport`.

    Raises:
        ValueError: for ids outside the map's capacity, a row repeating an id, or a bad
            ``max_sweeps``.

    >>> m, rep = apply_relations(empty_map(3), [[0, 1, 2]], [[1 << 6, (1 << 20) - 1,
    ...                                                     (1 << 20) - 1]])
    >>> from pqrm_jax.qrm.spec import states_of
    >>> states_of("edc", int(m.rel[1, 2, 0])), bool(rep.inconsistent)   # LEFT(7) = {1, 5}
    (['1', '5'], False)
    """
    spec = _spec(calc)
    triples = jnp.asarray(triples, jnp.int32).reshape(-1, 3)
    sets = jnp.asarray(sets, jnp.uint32).reshape(-1, 3)
    if valid is None:
        valid = jnp.ones(triples.shape[:1], bool)
    if not isinstance(triples, jax.core.Tracer):
        _check_ids(np.asarray(triples)[np.asarray(valid)], m.rel.shape[0])
    return apply_relations_kernel(spec, m, triples, sets, jnp.asarray(valid),
                                  max_sweeps=check_max_sweeps(max_sweeps))


def update_image(m: QRMMap, meas: ImageMeasurement, calc: Calculus | str | QRMSpec = "edc",
                 max_sweeps: int = 64) -> tuple[QRMMap, UpdateReport]:
    """Fuse one :class:`~pqrm_jax.qrm.camera.ImageMeasurement` into the map (M§VI.B).

    Args:
        m: the map.
        meas: the measurement of one image (triples, sets, valid rows).
        calc: the calculus (name, object or its :class:`QRMSpec`).
        max_sweeps: propagation sweep cap.

    Returns:
        ``(map', report)`` as :func:`apply_relations`.

    Raises:
        ValueError: as :func:`apply_relations`.
    """
    return apply_relations(m, meas.triples, meas.sets, calc, meas.valid, max_sweeps)


def cyclic_relations(m: QRMMap) -> tuple[np.ndarray, jax.Array]:
    """The three cyclic relations of every unordered triple i < j < k (M§VI.A).

    Returns ``(triples [E, 3], masks [E, 3])`` of ij:k, jk:i, ki:j.
    """
    n = m.rel.shape[0]
    import itertools

    tri = np.asarray(list(itertools.combinations(range(n), 3)), np.int32)
    i, j, k = tri.T
    return tri, jnp.stack([m.rel[i, j, k], m.rel[j, k, i], m.rel[k, i, j]], -1)


def true_relations(landmarks: jax.Array, calc: Calculus | str | QRMSpec = "edc") -> jax.Array:
    """[N, N, N] int32 true state index of ``ij:k`` (−2 on repeated indices).

    The dense layout of :func:`pqrm_jax.triplets.true_states`.
    """
    return true_states(_spec(calc).calc, landmarks, "dense")


def true_map(landmarks: jax.Array, calc: Calculus | str | QRMSpec = "edc") -> QRMMap:
    """The fully constrained map of a layout (singleton sets of the true states).

    Args:
        landmarks: [N, 2] positions.
        calc: the calculus (name, object or its :class:`QRMSpec`).

    Returns:
        The :class:`QRMMap` with every node known (M§VIII.A reference).
    """
    spec = _spec(calc)
    st = true_relations(landmarks, spec)
    rel = states_to_masks(st, spec.full)
    return QRMMap(rel, jnp.ones((st.shape[0],), bool))
