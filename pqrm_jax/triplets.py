"""One vocabulary for maps over landmark triplets: the layouts and their converters.

A map over ``M`` landmarks holds one relation ``ij:k`` per ordered triplet of distinct
landmarks. Three layouts are used by the subpackages:

* **rows** (PQRM, :mod:`pqrm_jax.pqrm`): ``[T, ...]`` with ``T = M(M−1)(M−2)`` rows in
  :func:`ordered_triplets` order (lexicographic in ``(i, j, k)``), e.g. probabilities
  ``[T, Q]``.
* **dense** (compositions, :mod:`pqrm_jax.compositions`): ``[M, M, M, ...]`` indexed by
  ``(i, j, k)``, e.g. probabilities ``[L, L, L, Q]``; entries with a repeated index are not
  relations (:func:`distinct_mask` is False there).
* **masks** (QRM, :mod:`pqrm_jax.qrm`): the dense layout ``[N, N, N]`` of uint32 bitmasks, bit
  ``q`` set when state ``q`` is still possible (:func:`states_to_masks`,
  :func:`masks_to_sets`).
* **elements** (Q-Link, :mod:`pqrm_jax.qlink`, P §4.2): ``[E, 6, Q]`` over ``E`` unordered
  triplets whose ids ``[E, 3]`` are sorted ascending; axis 1 runs over the six
  :data:`ORDERINGS` of each id row (:func:`elements_to_dense`).

The six orderings of a triplet and the unary operators between them (INVERSE ``AB:C → BA:C``,
LEFT ``AB:C → BC:A``, RIGHT ``AB:C → CA:B``, P §2.2.2 and Z §2.2) are :data:`ORDERINGS`,
:data:`INVERSE_OF`, :data:`LEFT_OF`, :data:`RIGHT_OF` and :data:`ORDERING_INDEX`; the
Link-Graph adjacency of a set of triplets (P §4.3.2, Z Def. 2.3.1) is
:func:`link_adjacency`.

>>> import numpy as np
>>> ordered_triplets(3).tolist()
[[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]]
>>> rows = np.arange(6)
>>> dense = rows_to_dense(rows, 3, fill=-1)
>>> int(dense[1, 2, 0]), int(dense[0, 0, 1])
(3, -1)
>>> dense_to_rows(dense, 3).tolist() == rows.tolist()
True
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .calculi.protocol import DEGENERATE

__all__ = [
    "LAYOUTS", "num_triplets", "ordered_triplets", "distinct_mask", "cyclic_mask",
    "rows_to_dense", "dense_to_rows", "states_to_masks", "masks_to_sets", "sets_to_masks",
    "true_states", "row_points",
    "ORDERINGS", "INVERSE_OF", "LEFT_OF", "RIGHT_OF", "ORDERING_INDEX", "elements_to_dense",
    "shared_landmarks", "link_adjacency",
]

#: The layouts :func:`true_states` can return.
LAYOUTS = ("rows", "dense")


def num_triplets(num_landmarks: int) -> int:
    """``T = M(M−1)(M−2)``, the number of ordered triplets of distinct landmarks (P §2.3).

    Args:
        num_landmarks: ``M``.

    Returns:
        ``T`` (an int; 0 for ``M < 3``).
    """
    m = int(num_landmarks)
    return m * (m - 1) * (m - 2)


def ordered_triplets(num_landmarks: int) -> np.ndarray:
    """Every ordered triplet ``(i, j, k)`` of distinct landmark ids (the rows layout, P §2.3).

    Args:
        num_landmarks: ``M >= 3``.

    Returns:
        ``[M(M−1)(M−2), 3]`` int32, lexicographic in ``(i, j, k)``.

    Raises:
        ValueError: for ``M < 3`` or a non-integer ``M``.
    """
    if not isinstance(num_landmarks, int | np.integer) or num_landmarks < 3:
        raise ValueError(f"a PQRM map needs at least three landmarks, got {num_landmarks!r}")
    m = int(num_landmarks)
    i, j, k = np.meshgrid(np.arange(m), np.arange(m), np.arange(m), indexing="ij")
    keep = (i != j) & (i != k) & (j != k)
    return np.stack([i[keep], j[keep], k[keep]], axis=-1).astype(np.int32)


#: ``[6, 3]`` int32, the six orderings of a triplet: row ``o`` lists the positions
#: ``(a, b, c)`` of A, B, C, so ordering ``o`` of ids ``(x0, x1, x2)`` is the relation
#: ``x_a x_b : x_c``. The same order as :func:`ordered_triplets` ``(3)``.
ORDERINGS = ordered_triplets(3)
ORDERINGS.setflags(write=False)


def _ordering_map(perm) -> np.ndarray:
    """``[6]`` int32: ordering ``o`` → the ordering ``(o[perm[0]], o[perm[1]], o[perm[2]])``."""
    rows = [tuple(r) for r in ORDERINGS.tolist()]
    out = np.array([rows.index(tuple(r[i] for i in perm)) for r in rows], np.int32)
    out.setflags(write=False)
    return out


#: ``[6]`` int32, INVERSE: the ordering ``AB:C`` → ``BA:C`` (index into :data:`ORDERINGS`).
INVERSE_OF = _ordering_map((1, 0, 2))
#: ``[6]`` int32, LEFT (homing): ``AB:C`` → ``BC:A``.
LEFT_OF = _ordering_map((1, 2, 0))
#: ``[6]`` int32, RIGHT (shortcut): ``AB:C`` → ``CA:B``.
RIGHT_OF = _ordering_map((2, 0, 1))
#: ``[3, 3]`` int32: ``ORDERING_INDEX[a, b]`` is the ordering with A at position ``a`` and B at
#: position ``b`` (−1 where ``a == b``).
ORDERING_INDEX = np.full((3, 3), -1, np.int32)
ORDERING_INDEX[ORDERINGS[:, 0], ORDERINGS[:, 1]] = np.arange(6, dtype=np.int32)
ORDERING_INDEX.setflags(write=False)


def elements_to_dense(ids, probs, num_landmarks: int, fill=0.0) -> np.ndarray:
    """Elements ``[E, 6, Q]`` (ids ``[E, 3]``) → dense ``[M, M, M, Q]`` (NumPy).

    Args:
        ids: ``[E, 3]`` int landmark ids of each element (any order within a row).
        probs: ``[E, 6, Q]``, the distribution of each of the six :data:`ORDERINGS` of the
            element's id row.
        num_landmarks: ``M`` (ids in ``[0, M)``).
        fill: value of the entries no element covers.

    Returns:
        ``[M, M, M, Q]``: ``out[x_a, x_b, x_c] = probs[e, o]`` for ``(a, b, c) = ORDERINGS[o]``.

    Raises:
        ValueError: for shapes that do not match or ids outside ``[0, M)``.

    >>> import numpy as np
    >>> p = np.arange(6, dtype=float).reshape(1, 6, 1)
    >>> d = elements_to_dense([[0, 1, 2]], p, 3)
    >>> float(d[0, 1, 2, 0]), float(d[1, 0, 2, 0]), float(d[2, 1, 0, 0])
    (0.0, 2.0, 5.0)
    """
    ids, probs = np.asarray(ids), np.asarray(probs)
    m = int(num_landmarks)
    if ids.ndim != 2 or ids.shape[1] != 3 or probs.shape[:2] != (ids.shape[0], 6):
        raise ValueError(f"ids must be [E, 3] and probs [E, 6, Q], got {ids.shape} and "
                         f"{probs.shape}")
    if ids.size and (ids.min() < 0 or ids.max() >= m):
        raise ValueError(f"ids must be in [0, {m})")
    out = np.full((m, m, m, *probs.shape[2:]), fill, np.result_type(probs, np.float32))
    trip = ids[:, ORDERINGS]                                        # [E, 6, 3]
    out[trip[..., 0], trip[..., 1], trip[..., 2]] = probs
    return out


def shared_landmarks(ids, num_landmarks: int | None = None) -> np.ndarray:
    """The landmarks two triplets share, ``|L_i ∩ L_j|`` (P §4.3.2; NumPy).

    Args:
        ids: ``[E, 3]`` int landmark ids, three distinct per row.
        num_landmarks: ``M`` (default ``max(ids) + 1``).

    Returns:
        ``[E, E]`` int32, zero diagonal.

    Raises:
        ValueError: when ``ids`` is not ``[E, 3]``.

    >>> shared_landmarks([[0, 1, 2], [1, 2, 3], [3, 4, 5]]).tolist()
    [[0, 2, 0], [2, 0, 1], [0, 1, 0]]
    """
    ids = np.asarray(ids)
    if ids.ndim != 2 or ids.shape[1] != 3:
        raise ValueError(f"ids must be [E, 3], got shape {ids.shape}")
    e = ids.shape[0]
    m = int(ids.max()) + 1 if num_landmarks is None and e else int(num_landmarks or 0)
    inc = np.zeros((m, e), np.float32)
    inc[ids, np.arange(e)[:, None]] = 1.0
    s = np.rint(inc.T @ inc).astype(np.int32)
    np.fill_diagonal(s, 0)
    return s


def link_adjacency(ids, beta: int, num_landmarks: int | None = None) -> np.ndarray:
    """The Link-Graph adjacency ``[E, E]`` bool: ``|L_i ∩ L_j| >= beta``, ``i != j``.

    Q-Link's Link Graph (P §4.3.2) for any ``beta >= 1``; ``beta = 2`` is the Link-Graph of
    Z Def. 2.3.1 (two triplets linked when they share two landmarks).

    Args:
        ids: ``[E, 3]`` int landmark ids.
        beta: the least number of shared landmarks of an edge, 1..3.
        num_landmarks: ``M`` (default ``max(ids) + 1``).

    Returns:
        ``[E, E]`` bool, symmetric, False on the diagonal.

    Raises:
        ValueError: for ``beta`` outside ``1..3``.

    >>> link_adjacency([[0, 1, 2], [1, 2, 3], [3, 4, 5]], 2).astype(int).tolist()
    [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    if isinstance(beta, bool) or not isinstance(beta, int | np.integer) or not 1 <= beta <= 3:
        raise ValueError(f"beta must be an int in 1..3, got {beta!r}")
    return shared_landmarks(ids, num_landmarks) >= beta


def distinct_mask(n: int) -> np.ndarray:
    """Where the dense layout holds relations: ``i``, ``j``, ``k`` pairwise distinct.

    Args:
        n: landmarks ``M``.

    Returns:
        ``[n, n, n]`` bool.
    """
    i, j, k = np.ix_(np.arange(n), np.arange(n), np.arange(n))
    return (i != j) & (j != k) & (i != k)


def cyclic_mask(n: int) -> np.ndarray:
    """One representative per cyclic class of each unordered triple (M §VI.B).

    True at ``i < j < k`` and at its two rotations ``(j, k, i)``, ``(k, i, j)``: the cyclic
    relations ``ij:k``, ``jk:i``, ``ki:j`` of each triple (used for QRM metrics).

    Args:
        n: landmarks ``N``.

    Returns:
        ``[n, n, n]`` bool.

    >>> int(cyclic_mask(4).sum())      # 4 triples x 3 cyclic relations
    12
    """
    i, j, k = np.ix_(np.arange(n), np.arange(n), np.arange(n))
    inc = (i < j) & (j < k)
    return inc | np.transpose(inc, (2, 0, 1)) | np.transpose(inc, (1, 2, 0))


def _xp(x):
    return jnp if isinstance(x, jax.Array) else np


def rows_to_dense(rows, num_landmarks: int, fill=0):
    """Rows ``[T, ...]`` (:func:`ordered_triplets` order) → dense ``[M, M, M, ...]``.

    NumPy in, NumPy out; a JAX array gives a JAX array (traceable).

    Args:
        rows: ``[T, ...]`` with ``T = M(M−1)(M−2)``.
        num_landmarks: ``M``.
        fill: value of the entries with a repeated index.

    Returns:
        ``[M, M, M, ...]`` of the dtype of ``rows``.

    Raises:
        ValueError: when ``rows`` does not have ``T`` rows.
    """
    trip = ordered_triplets(num_landmarks)
    xp = _xp(rows)
    rows = xp.asarray(rows)
    if rows.shape[:1] != (len(trip),):
        raise ValueError(f"rows must have {len(trip)} rows for {num_landmarks} landmarks, got "
                         f"shape {tuple(rows.shape)}")
    m = int(num_landmarks)
    i, j, k = trip[:, 0], trip[:, 1], trip[:, 2]
    if xp is np:
        out = np.full((m, m, m, *rows.shape[1:]), fill, rows.dtype)
        out[i, j, k] = rows
        return out
    return jnp.full((m, m, m, *rows.shape[1:]), fill, rows.dtype).at[i, j, k].set(rows)


def dense_to_rows(dense, num_landmarks: int):
    """Dense ``[M, M, M, ...]`` → rows ``[T, ...]`` in :func:`ordered_triplets` order.

    Args:
        dense: ``[M, M, M, ...]`` (NumPy or JAX; the result is of the same kind).
        num_landmarks: ``M``.

    Returns:
        ``[M(M−1)(M−2), ...]``.

    Raises:
        ValueError: when the leading shape is not ``(M, M, M)``.
    """
    trip = ordered_triplets(num_landmarks)
    xp = _xp(dense)
    dense = xp.asarray(dense)
    m = int(num_landmarks)
    if dense.shape[:3] != (m, m, m):
        raise ValueError(f"dense map must have leading shape ({m}, {m}, {m}), got "
                         f"{tuple(dense.shape)}")
    return dense[trip[:, 0], trip[:, 1], trip[:, 2]]


def states_to_masks(states, full):
    """Dense states → the masks layout: ``1 << state``, ``full`` where the state is < 0 (M §VI).

    Args:
        states: ``[N, N, N]`` int state indices (sentinels < 0 mean "unknown").
        full: the mask of all states, ``(1 << Q) − 1``.

    Returns:
        ``[N, N, N]`` uint32 bitmasks.
    """
    st = jnp.asarray(states)
    return jnp.where(st >= 0, jnp.uint32(1) << jnp.maximum(st, 0).astype(jnp.uint32),
                     jnp.uint32(full))


def masks_to_sets(masks, num_states: int) -> jax.Array:
    """uint32 bitmasks → bool state sets (bit ``q`` ↔ state ``q``; M §VI).

    Args:
        masks: ``[...]`` uint32.
        num_states: ``Q``.

    Returns:
        ``[..., Q]`` bool.
    """
    m = jnp.asarray(masks, jnp.uint32)
    return ((m[..., None] >> jnp.arange(num_states, dtype=jnp.uint32)) & 1).astype(bool)


def sets_to_masks(sets) -> np.ndarray:
    """bool state sets → uint32 bitmasks, the inverse of :func:`masks_to_sets` (M §VI).

    NumPy (a concrete array): the operator tables and test maps are built with it.

    Args:
        sets: ``[..., Q]`` bool (``Q`` ≤ 32).

    Returns:
        ``[...]`` uint32, bit ``q`` set where state ``q`` is in the set.

    >>> sets_to_masks(np.array([[True, False, True], [False, False, False]])).tolist()
    [5, 0]
    """
    sets = np.asarray(sets)
    w = np.uint64(1) << np.arange(sets.shape[-1], dtype=np.uint64)
    return (sets.astype(np.uint64) * w).sum(-1).astype(np.uint32)


def row_points(landmarks, triplets=None) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The points (A, B, C) of the rows of ``triplets`` in a world of landmarks.

    The one gather behind :func:`true_states` (rows layout) and the per-row PQRM metrics.

    Args:
        landmarks: ``[M, 2]`` world positions.
        triplets: ``[T, 3]`` landmark ids (default: all :func:`ordered_triplets`).

    Returns:
        ``(a, b, c)``, each ``[T, 2]``.

    >>> a, b, c = row_points(jnp.array([[0., 0.], [0., 1.], [1., 0.5]]))
    >>> c.tolist()[:2]                                   # rows 012, 021
    [[1.0, 0.5], [0.0, 1.0]]
    """
    p = jnp.asarray(landmarks)
    tri = jnp.asarray(ordered_triplets(p.shape[0]) if triplets is None else triplets)
    return p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]


def true_states(calc, landmarks, layout: str = "rows", *, triplets=None,
                mask_repeated: bool = True) -> jax.Array:
    """True state of ``ij:k`` for a world of landmarks ``[M, 2]``, in the chosen layout.

    Args:
        calc: a :class:`~pqrm_jax.calculi.TernaryCalculus` (``classify`` is called).
        landmarks: ``[M, 2]`` world positions.
        layout: ``"rows"`` → ``[T]`` (rows of ``triplets``, default :func:`ordered_triplets`);
            ``"dense"`` → ``[M, M, M]``.
        triplets: rows layout only, ``[T, 3]`` landmark ids (default: all ordered triplets).
        mask_repeated: dense only; entries with a repeated index are ``DEGENERATE`` (−2) when
            True, else whatever ``classify`` gives there.

    Returns:
        int32 state indices (sentinels < 0 as in :mod:`pqrm_jax.calculi.protocol`).

    >>> import jax.numpy as jnp
    >>> from pqrm_jax import calculi
    >>> lm = jnp.array([[0., 0.], [0., 1.], [1., 0.5]])
    >>> true_states(calculi.get("lr"), lm).tolist()          # rows: 012, 021, 102, ...
    [1, 0, 0, 1, 1, 0]
    >>> int(true_states(calculi.get("lr"), lm, "dense")[0, 1, 2])
    1
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    p = jnp.asarray(landmarks)
    if layout == "rows":
        return calc.classify(*row_points(p, triplets))
    n = p.shape[0]
    a = jnp.broadcast_to(p[:, None, None], (n, n, n, 2))
    b = jnp.broadcast_to(p[None, :, None], (n, n, n, 2))
    c = jnp.broadcast_to(p[None, None, :], (n, n, n, 2))
    st = calc.classify(a, b, c)
    if mask_repeated:
        st = jnp.where(jnp.asarray(distinct_mask(n)), st, DEGENERATE)
    return st
