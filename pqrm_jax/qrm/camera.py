"""Camera measurement of qualitative states (M§IV, Table III; M§V feasibility).

Turns one image — the bearings of the visible landmarks and the order of their ranges — into
the set of feasible EDC states of every visible triple and each of its three cyclic
relations, batched over triples by one branch-and-bound kernel. A state is removed only when
it is proven infeasible, so the true state is never dropped (docs/decisions.md §4).

How it works (the bounded range-cone parametrisation, the shared subdivision, checkpoints,
limits, and why not the generic table solver): docs/qrm.md §camera.
"""

from __future__ import annotations

import itertools
from functools import cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi import Calculus
from .exact_camera import corner_rule, range_forms, sweep_witnesses
from .spec import QRMSpec, qrm_spec

__all__ = ["TripleMeasurement", "ImageMeasurement", "measure_triples", "measure_image",
           "select_nearest", "slot_triples", "CYCLIC", "cone_forms"]

#: the three cyclic relations of a slot triple (near, mid, far) = (0, 1, 2): XY:Z
CYCLIC = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
_EPS = 2e-5  # relative safety margin on certain signs (float32 rounding ~1e-7)


class TripleMeasurement(NamedTuple):
    """Kernel output for T triples (slot order near, mid, far).

    Attributes:
        sets: [T, 3] uint32 state masks of the cyclic relations (0,1:2), (1,2:0), (2,0:1).
        undecided: [T, 3] uint32 states kept without a witness (neither proven nor excluded);
            all zero after the exact stage.
        exact_decisions: number of states the exact stage (z3) decided.
    """

    sets: jax.Array
    undecided: jax.Array
    exact_decisions: int = 0


class ImageMeasurement(NamedTuple):
    """One image's measurement (M§IV) of the ``n`` nearest visible landmarks.

    Attributes:
        ids: [S] int32 landmark id of each slot, nearest first; −1 for empty slots.
        triples: [T, 3] int32 landmark ids (near, mid, far) of every slot triple s0 < s1 < s2.
        sets: [T, 3] uint32 measured state masks of ``ids[t0] ids[t1] : ids[t2]``,
            ``ids[t1] ids[t2] : ids[t0]`` and ``ids[t2] ids[t0] : ids[t1]``.
        valid: [T] bool, all three slots hold a visible landmark.
        undecided: [T, 3] uint32 states kept undecided at the depth limit.
    """

    ids: jax.Array
    triples: jax.Array
    sets: jax.Array
    valid: jax.Array
    undecided: jax.Array


# --------------------------------------------------------------------------------------
# constraint forms over the ordering cone
# --------------------------------------------------------------------------------------
def _quadratic_forms(bearings):
    """[…, 3] bearings → n, m, u, v forms (…, O=3, 3, 3) over d for the cyclic relations."""
    w = jnp.stack([jnp.cos(bearings), jnp.sin(bearings)], -1)  # (..., 3 slots, 2)
    eye = jnp.eye(3, dtype=w.dtype)
    out = []
    for X, Y, Z in CYCLIC:
        # linear maps d -> point difference, [..., 2, 3]
        ld = w[..., Y, :, None] * eye[Y] - w[..., X, :, None] * eye[X]
        le = w[..., Z, :, None] * eye[Z] - w[..., X, :, None] * eye[X]
        n = jnp.einsum("...is,...ir->...sr", ld, ld)
        m = jnp.einsum("...is,...ir->...sr", le, le)
        v = jnp.einsum("...is,...ir->...sr", le, ld)
        u = (le[..., 0, :, None] * ld[..., 1, None, :] - le[..., 1, :, None] * ld[..., 0, None, :])
        sym = lambda q: 0.5 * (q + jnp.swapaxes(q, -1, -2))  # noqa: E731
        out.append(jnp.stack([n, sym(u), sym(v), m], -3))  # (..., 4, 3, 3)
    return jnp.stack(out, -4)  # (..., O, 4, 3, 3)


def cone_forms(spec: QRMSpec, bearings):
    """Monomial coefficients […, O, K, 3, 3] of every constraint over (a, b) ∈ [0, 1]².

    ``coef[..., o, k, i, j]`` multiplies ``a^i b^j``. Constraints whose constant term
    (the ``d_far²`` coefficient) vanishes structurally are divided by ``b``.
    """
    forms = _quadratic_forms(bearings)  # (..., O, 4, 3, 3)
    lin = jnp.asarray(spec.lin, forms.dtype)  # (K, 4)
    F = jnp.einsum("kc,...ocsr->...oksr", lin, forms)  # (..., O, K, 3, 3) over d
    z = jnp.zeros_like(F[..., 0, 0])
    # d = (ab, b, 1): d0² = a²b², 2d0d1 = ab², d1² = b², 2d0d2 = ab, 2d1d2 = b, d2² = 1
    C = jnp.stack([
        jnp.stack([F[..., 2, 2], 2 * F[..., 1, 2], F[..., 1, 1]], -1),  # a^0 b^{0,1,2}
        jnp.stack([z, 2 * F[..., 0, 2], 2 * F[..., 0, 1]], -1),  # a^1
        jnp.stack([z, z, F[..., 0, 0]], -1),  # a^2
    ], -2)
    scale = jnp.max(jnp.abs(C), axis=(-1, -2), keepdims=True)
    # the d_far² coefficient is an integer combination of |w|² = 1: exact zero test is safe
    divide = jnp.abs(C[..., 0:1, 0:1]) <= 1e-4 * scale
    shifted = jnp.concatenate([C[..., 1:], jnp.zeros_like(C[..., :1])], -1)
    return jnp.where(divide, shifted, C)


# --------------------------------------------------------------------------------------
# the batched kernel
# --------------------------------------------------------------------------------------
def _powers(x):
    return jnp.stack([jnp.ones_like(x), x, x * x], -1)


def _monomials(a, b):
    """(..., ) → [..., 9] values of a^i b^j, flattened i-major."""
    return (_powers(a)[..., :, None] * _powers(b)[..., None, :]).reshape(*a.shape, 9)


def _atom_masks_to_states(atom_mask, atom_state):
    """[...] uint32 atom masks → state masks."""
    bits = (atom_mask[..., None] >> jnp.arange(atom_state.shape[0], dtype=jnp.uint32)) & 1
    vals = jnp.where(bits.astype(bool), jnp.uint32(1) << atom_state.astype(jnp.uint32),
                     jnp.uint32(0))
    return jax.lax.reduce(vals, np.uint32(0), jax.lax.bitwise_or, (vals.ndim - 1,))


def _state_masks_to_atoms(state_mask, atom_state):
    bits = (state_mask[..., None] >> atom_state.astype(jnp.uint32)) & 1
    vals = jnp.where(bits.astype(bool),
                     jnp.uint32(1) << jnp.arange(atom_state.shape[0], dtype=jnp.uint32),
                     jnp.uint32(0))
    return jax.lax.reduce(vals, np.uint32(0), jax.lax.bitwise_or, (vals.ndim - 1,))


def _or_reduce(x, axis):
    return jax.lax.reduce(x, np.uint32(0), jax.lax.bitwise_or, (axis,))


def _and_reduce(x, axis):
    return jax.lax.reduce(x, np.uint32(0xFFFFFFFF), jax.lax.bitwise_and, (axis,))


#: compaction checkpoints of the kernel: after this many rounds the triples that still have
#: useful boxes are gathered into a buffer of half the rows (when they fit)
_CHECKPOINTS = (3, 6)
_MIN_COMPACT_ROWS = 32  # smaller batches run the plain loop (gathers would cost more)


@partial(jax.jit, static_argnames=("spec", "pool", "depth", "sweep"))
def _kernel(spec: QRMSpec, bearings, target_states, *, pool: int, depth: int,
            sweep: bool = False):
    T = bearings.shape[0]
    O, K = len(CYCLIC), spec.k
    coef = cone_forms(spec, bearings).reshape(T, O * K, 9)  # (T, OK, 9)
    pos = jnp.asarray(spec.pos, jnp.uint32)
    neg = jnp.asarray(spec.neg, jnp.uint32)
    amb = jnp.asarray(spec.amb, jnp.uint32)
    pattern_atom = jnp.asarray(spec.pattern_atom)
    atom_state = jnp.asarray(spec.atom_state)
    weights = jnp.asarray(3 ** np.arange(K), jnp.int32)
    target = _state_masks_to_atoms(target_states, atom_state)  # (T, O)

    def evaluate(cpn, target, sig, hst, box, alive, proven):
        R, QK = cpn.shape[0], cpn.shape[1] // 2
        a0, a1, b0, b1 = (box[..., i] for i in range(4))
        nb = box.shape[1]
        # monomials at the low corner, the high corner and the centre (all ≥ 0 on the box)
        mono = jnp.concatenate([_monomials(a0, b0), _monomials(a1, b1),
                                _monomials(0.5 * (a0 + a1), 0.5 * (b0 + b1))], 1)
        # one batched product gives m·c⁺ and m·c⁻ for the three monomial sets
        d = jnp.einsum("tbm,tqm->tbq", mono, cpn)  # (R, 3B, 2QK)
        lp, ln = d[:, :nb, :QK], d[:, :nb, QK:]
        hp, hn = d[:, nb:2 * nb, :QK], d[:, nb:2 * nb, QK:]
        cp_, cn_ = d[:, 2 * nb:, :QK], d[:, 2 * nb:, QK:]
        lo, hi = lp + hn, hp + ln
        tol = _EPS * (hp - hn) + 1e-30  # m_hi · |c|
        val = cp_ + cn_
        tol_c = _EPS * (cp_ - cn_) + 1e-30  # m_centre · |c|
        # Bernstein enclosure on the box (tighter: its excess shrinks like the box size
        # squared): f = Σ C_ij a^i b^j has the coefficients La C Lbᵀ in the Bernstein basis
        # of the box, with La rows (1, a0, a0²), (1, (a0+a1)/2, a0·a1), (1, a1, a1²)
        C3 = (cpn[:, :QK] + cpn[:, QK:]).reshape(R, QK, 3, 3)
        La = jnp.stack([_powers(a0), jnp.stack([jnp.ones_like(a0), 0.5 * (a0 + a1), a0 * a1],
                                               -1), _powers(a1)], -2)  # (R, B, 3, 3)
        Lb = jnp.stack([_powers(b0), jnp.stack([jnp.ones_like(b0), 0.5 * (b0 + b1), b0 * b1],
                                               -1), _powers(b1)], -2)
        # (La ⊗ Lb) vec(C): one batched product per row, like the monomial bound
        K9 = (La[:, :, :, None, :, None] * Lb[:, :, None, :, None, :]).reshape(R, nb, 9, 9)
        bern = jnp.einsum("rbmn,rqn->rbmq", K9, C3.reshape(R, QK, 9))  # (R, B, 9, QK)
        # rounding: |La|·|C|·|Lb|ᵀ ≤ Σ|C_ij| a1^i b1^j (rows of La, Lb are bounded by the
        # monomials at the high corner), so the monomial tolerance covers it
        bpos = jnp.min(bern, -2) > tol
        bneg = jnp.max(bern, -2) < -tol
        cert = jnp.where((lo > tol) | bpos, 1, jnp.where((hi < -tol) | bneg, -1, 0))
        # the corner d_near = 0, d_mid = d_far (a = 0, b = 1): a constraint vanishing there
        # has the sign of its gradient on small boxes at the corner (exact_camera)
        at = ((a0 == 0) & (b1 == 1))[..., None] & (a1[..., None] <= hst[:, None]) & \
            ((1 - b0)[..., None] <= hst[:, None]) & (sig[:, None] != 0)
        cert = jnp.where(at, sig[:, None], cert).reshape(R, -1, O, K)
        cmask = jnp.where(cert == 1, pos, jnp.where(cert == -1, neg, amb))
        compat = _and_reduce(cmask, 3)  # (R, B, O)
        compat = jnp.where(alive[..., None], compat, jnp.uint32(0))
        full = jnp.all(cert != 0, -1) & alive[..., None]
        proven = proven | _or_reduce(jnp.where(full, compat, jnp.uint32(0)), 1)
        # witness at the box centre
        sc = jnp.where(val > tol_c, 1, jnp.where(val < -tol_c, -1, 0)).reshape(R, -1, O, K)
        idx = jnp.sum((sc + 1) * weights, -1)
        atom = pattern_atom[idx]
        ok = jnp.all(sc != 0, -1) & (atom >= 0) & alive[..., None]
        wit = jnp.where(ok, jnp.uint32(1) << jnp.maximum(atom, 0).astype(jnp.uint32),
                        jnp.uint32(0))
        proven = proven | _or_reduce(wit, 1)
        need = target & ~proven  # (R, O)
        useful = alive & jnp.any((compat & need[:, None, :]) != 0, -1)
        return compat, useful, proven

    slots = jnp.arange(pool)

    def split(box, useful):
        order = jnp.argsort(~useful, axis=-1, stable=True)
        box = jnp.take_along_axis(box, order[..., None], 1)
        u = useful.sum(-1)  # (R,)
        n_split = jnp.minimum(u, (pool - u) // 3)
        s = slots[None]
        in_first = s < u[:, None]
        rel = s - u[:, None]
        is_child = (rel >= 0) & (rel < 3 * n_split[:, None])
        src = jnp.where(in_first, s, jnp.where(is_child, rel // 3, 0))
        child = jnp.where(in_first, jnp.where(s < n_split[:, None], 0, -1),
                          jnp.where(is_child, 1 + rel % 3, -1))
        sb = jnp.take_along_axis(box, src[..., None], 1)
        a0, a1, b0, b1 = (sb[..., i] for i in range(4))
        am, bm = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
        hi_a = (child % 2) == 1
        hi_b = child >= 2
        na0 = jnp.where(child < 0, a0, jnp.where(hi_a, am, a0))
        na1 = jnp.where(child < 0, a1, jnp.where(hi_a, a1, am))
        nb0 = jnp.where(child < 0, b0, jnp.where(hi_b, bm, b0))
        nb1 = jnp.where(child < 0, b1, jnp.where(hi_b, b1, bm))
        alive = in_first | is_child
        return jnp.stack([na0, na1, nb0, nb1], -1), alive

    def rounds(rows, st, stop):
        """Refine rows until round ``stop`` or until no row has a useful box.

        A row without useful boxes has no live box left after the split: it is final.
        """
        cpn, target, sig, hst = rows

        def cond(c):
            it, _, alive, _ = c
            return (it < stop) & alive.any()

        def body(c):
            it, box, alive, proven = c
            _, useful, proven = evaluate(cpn, target, sig, hst, box, alive, proven)
            box, alive = split(box, useful)
            return it + 1, box, alive, proven

        return jax.lax.while_loop(cond, body, st)

    def finish(rows, st):
        """Rounds to ``depth``, then the final bound: (proven, remaining) atom masks [R, O]."""
        _, box, alive, proven = rounds(rows, st, depth)
        compat, useful, proven = evaluate(*rows, box, alive, proven)
        return proven, _or_reduce(jnp.where(useful[..., None], compat, jnp.uint32(0)), 1)

    def stage(rows, st, level):
        """Run to the next checkpoint, then continue on a compacted half-size buffer.

        The buffer is used when the rows still working fit in it (rows are independent: the
        result is identical; a row without live boxes has nothing remaining).
        """
        if level == len(_CHECKPOINTS) or _CHECKPOINTS[level] >= depth or \
                st[1].shape[0] < _MIN_COMPACT_ROWS:
            return finish(rows, st)
        st = rounds(rows, st, _CHECKPOINTS[level])
        R = st[1].shape[0]
        half = (R + 1) // 2
        busy = st[2].any(-1)

        def compact(st):
            pick = jnp.argsort(~busy, stable=True)[:half]  # busy rows first
            sub = stage(jax.tree.map(lambda x: x[pick], rows),
                        jax.tree.map(lambda x: x if x.ndim == 0 else x[pick], st), level + 1)
            proven, remaining = sub
            return st[3].at[pick].set(proven), jnp.zeros_like(st[3]).at[pick].set(remaining)

        return jax.lax.cond(busy.sum() <= half, compact, lambda st: finish(rows, st), st)

    dtype = coef.dtype
    box = jnp.zeros((T, pool, 4), dtype).at[:, 0].set(jnp.asarray([0.0, 1.0, 0.0, 1.0], dtype))
    alive = jnp.zeros((T, pool), bool).at[:, 0].set(True)
    if sweep:  # witnesses of the arrangement sweep first: the boxes then only exclude
        proven = sweep_witnesses(spec, range_forms(spec, bearings.astype(dtype)))  # (T, O)
    else:
        proven = jnp.zeros((T, O), jnp.uint32)
    cpn = jnp.concatenate([jnp.maximum(coef, 0.0), jnp.minimum(coef, 0.0)], 1)  # (T, 2QK, 9)
    sig, hst = corner_rule(spec, coef.reshape(T, O * K, 3, 3))  # (T, OK)
    proven, remaining = stage((cpn, target, sig, hst), (0, box, alive, proven), 0)
    possible = proven | (remaining & target) | ~target
    all_atoms = jnp.uint32(spec.atom_full)
    sets = _atom_masks_to_states(possible & all_atoms, atom_state)
    und = _atom_masks_to_states(remaining & target & ~proven & all_atoms, atom_state)
    # three equal bearings: collinear for every range assignment, no open state (exact)
    ray = jnp.all(bearings == bearings[:, :1], -1)[:, None]
    return jnp.where(ray, jnp.uint32(0), sets), jnp.where(ray, jnp.uint32(0), und)


def measure_triples(
    bearings: jax.Array,
    calc: Calculus | str | QRMSpec = "edc",
    target: jax.Array | None = None,
    *,
    pool: int = 16,
    depth: int = 12,
    exact: bool = True,
) -> TripleMeasurement:
    """Feasible states of the three cyclic relations of each triple (M§IV), batched.

    Args:
        bearings: [T, 3] bearings of each triple's landmarks in *range order* (nearest first;
            ties allowed).
        calc: the calculus (object, name or prepared spec).
        target: [T, 3] uint32 state masks restricting the work to states still open in the
            map (the others are returned as possible, unchecked); default all states.
        pool: boxes per triple in the branch-and-bound.
        depth: refinement rounds.

    Returns:
        A :class:`TripleMeasurement`: state masks of ``01:2, 12:0, 20:1`` (slots 0 = near,
        1 = mid, 2 = far) and the states left undecided; sound (docs/qrm.md §camera).

    Raises:
        ValueError: for an empty batch (T = 0), bearings of the wrong shape or with NaN/inf,
            a ``target`` of the wrong shape, ``pool < 4`` or ``depth < 1``.

    ``exact=True`` (concrete input only): the kernel is seeded with the witnesses of the
    arrangement sweep (:mod:`pqrm_jax.qrm.exact_camera`), and the states it still leaves
    undecided are settled by z3 on the exact polynomial systems
    (:func:`pqrm_jax.qrm.camera_oracle.settle_undecided`), so the sets are exactly the
    feasible sets; ``exact_decisions`` counts them. ``exact=False`` returns the kernel's
    sound sets (undecided states kept and reported).

    Bearings all equal (three landmarks on one ray): the points are collinear for every
    range assignment, which no (open) EDC state admits — ``ValueError`` (in a traced call
    the row's sets are empty, which the map update reports as inconsistent). Two equal
    bearings and ties in the ranges are ordinary input (the cone is closed; ties add no
    state, see :mod:`pqrm_jax.qrm.exact_camera`). A camera on a landmark: that landmark's
    range is 0 and its bearing arbitrary; ``d_near = 0`` lies in the closed cone, so the sets
    still contain the true states (they are the sets of the reported bearing).

    >>> import numpy as np
    >>> from pqrm_jax.qrm.spec import states_of
    >>> P = np.array([[2.0, 0.5], [1.0, 3.0], [-4.0, 1.5]])   # near, mid, far; truth: 1
    >>> m = measure_triples(np.arctan2(P[:, 1], P[:, 0])[None].astype(np.float32))
    >>> states_of("edc", int(m.sets[0, 0]))                    # 20 states → 3 (exact)
    ['1', '5', '11']
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    bearings = jnp.asarray(bearings)
    if jnp.issubdtype(bearings.dtype, jnp.complexfloating):
        raise TypeError(f"bearings are complex ({bearings.dtype}); bearings must be real")
    if bearings.ndim != 2 or bearings.shape[-1] != 3:
        raise ValueError(f"bearings must have shape (T, 3), got {bearings.shape}")
    if bearings.shape[0] == 0:
        raise ValueError("measure_triples: bearings holds no triple (shape (0, 3)); an image "
                         "with fewer than three landmarks has nothing to measure")
    if not jnp.issubdtype(bearings.dtype, jnp.floating):
        bearings = bearings.astype(jnp.float32)
    if not isinstance(bearings, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(bearings))):
        raise ValueError("bearings contain NaN or inf values")
    if target is None:
        target = jnp.full(bearings.shape[:1] + (3,), spec.full, jnp.uint32)
    target = jnp.asarray(target, jnp.uint32)
    if target.shape != bearings.shape[:1] + (3,):
        raise ValueError(f"target must have shape {bearings.shape[:1] + (3,)}, got {target.shape}")
    if pool < 4 or depth < 1:
        raise ValueError(f"pool must be >= 4 and depth >= 1, got pool={pool}, depth={depth}")
    concrete = not any(isinstance(x, jax.core.Tracer) for x in (bearings, target))
    if concrete:
        b = np.asarray(bearings, np.float64)
        same = (np.remainder(b - b[:, :1] + np.pi, 2 * np.pi) - np.pi == 0).all(-1)
        if same.any():
            raise ValueError(f"bearings of triple(s) {np.flatnonzero(same).tolist()} are all "
                             "equal: three landmarks on one ray are collinear, no open EDC "
                             "state fits")
    sets, und = _kernel(spec, bearings, target, pool=pool, depth=depth, sweep=exact)
    if exact and concrete:
        from .camera_oracle import settle_undecided

        sets, n = settle_undecided(spec, bearings, sets, und)
        return TripleMeasurement(jnp.asarray(sets), jnp.zeros_like(und), n)
    return TripleMeasurement(sets, und)


# --------------------------------------------------------------------------------------
# images
# --------------------------------------------------------------------------------------
@cache
def slot_triples(n_slots: int) -> np.ndarray:
    """(C(S, 3), 3) int32 slot triples s0 < s1 < s2 (range order: s0 nearest)."""
    if n_slots < 3:
        return np.zeros((0, 3), np.int32)
    return np.asarray(list(itertools.combinations(range(n_slots), 3)), np.int32)


def select_nearest(range_rank: jax.Array, visible: jax.Array, n: int) -> jax.Array:
    """(n,) landmark ids of the ``n`` nearest visible landmarks, nearest first (−1 = none)."""
    N = range_rank.shape[0]
    key = jnp.where(visible & (range_rank >= 0), range_rank, N + jnp.arange(N))
    order = jnp.argsort(key)[:n]
    ok = jnp.take(visible & (range_rank >= 0), order)
    ids = jnp.where(ok, order, -1).astype(jnp.int32)
    if n > N:
        ids = jnp.concatenate([ids, jnp.full((n - N,), -1, jnp.int32)])
    return ids


def _check_observation(bearings, range_rank, visible):
    bearings = np.asarray(bearings)
    rank = np.asarray(range_rank)
    vis = np.asarray(visible, bool)
    if bearings.ndim != 1 or rank.shape != bearings.shape or vis.shape != bearings.shape:
        raise ValueError("bearings, range_rank and visible must be 1-D arrays of equal length, "
                         f"got {bearings.shape}, {rank.shape}, {vis.shape}")
    if not np.all(np.isfinite(bearings[vis])):
        raise ValueError("non-finite bearing for a visible landmark: "
                         f"ids {np.flatnonzero(vis & ~np.isfinite(bearings)).tolist()}")
    r = rank[vis]
    if np.any(r < 0):
        raise ValueError("a visible landmark has no range rank (−1)")
    if len(np.unique(r)) != len(r):
        raise ValueError("ties in the range ordering: range_rank must give distinct ranks to "
                         "visible landmarks (break ties first; a tie is a valid configuration "
                         "on the boundary of both orders, so either order is sound)")
    if vis.sum() < 3:
        raise ValueError(f"fewer than three visible landmarks ({int(vis.sum())}): no triple "
                         "to measure")


@partial(jax.jit, static_argnames=("spec", "n", "pool", "depth"))
def _measure_image(spec, bearings, range_rank, visible, target_map, *, n, pool, depth):
    ids = select_nearest(range_rank, visible, n)
    tri = jnp.asarray(slot_triples(n))
    lid = ids[tri]  # (T, 3)
    valid = jnp.all(lid >= 0, -1)
    safe = jnp.maximum(lid, 0)
    b = bearings[safe]
    if target_map is None:
        target = jnp.full(lid.shape, spec.full, jnp.uint32)
    else:
        target = jnp.stack([target_map[safe[:, X], safe[:, Y], safe[:, Z]]
                            for X, Y, Z in CYCLIC], -1)
    sets, und = _kernel(spec, b, target, pool=pool, depth=depth)
    full = jnp.uint32(spec.full)
    sets = jnp.where(valid[:, None], sets, full)
    und = jnp.where(valid[:, None], und, jnp.uint32(0))
    return ImageMeasurement(ids, lid, sets, valid, und)


#: The raw jit-compiled image measurement (no host-side checks), for callers that trace it.
measure_image_kernel = _measure_image


def measure_image(
    bearings: jax.Array,
    range_rank: jax.Array,
    visible: jax.Array,
    n: int,
    calc: Calculus | str | QRMSpec = "edc",
    target_map: jax.Array | None = None,
    *,
    pool: int = 16,
    depth: int = 12,
    check: bool = True,
) -> ImageMeasurement:
    """Measure every triple of the ``n`` nearest visible landmarks of one image (M§IV).

    Args:
        bearings: [N] bearings of a :class:`~pqrm_jax.sim.sensors.CameraObservation`.
        range_rank: [N] its range ranks.
        visible: [N] its visibility.
        n: landmarks used per image (an int ≥ 3).
        calc: the calculus (object, name or prepared spec).
        target_map: [N, N, N] uint32, the current map relations (only their open states are
            tested).
        pool: boxes per triple in the branch-and-bound.
        depth: refinement rounds.
        check: check the observation when it is concrete.

    Returns:
        The :class:`ImageMeasurement` of the image.

    Raises:
        ValueError: for ``n < 3``, and (when concrete, ``check=True``) arrays of unequal
            length, non-finite bearings of visible landmarks, a visible landmark without a
            rank, repeated ranks or fewer than three visible landmarks.

    >>> import jax
    >>> from pqrm_jax import sim
    >>> lm = sim.uniform_landmarks(jax.random.key(0), 6)
    >>> cam = sim.camera(jax.numpy.array([50.0, 50.0, 0.0]), lm, sim.SensorParams(200.0))
    >>> m = measure_image(cam.bearings, cam.range_rank, cam.visible, n=6)
    >>> m.sets.shape, bool(m.valid.all())
    ((20, 3), True)
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    if not isinstance(n, int) or n < 3:
        raise ValueError(f"n (landmarks per image) must be an int >= 3, got {n!r}")
    if check and not any(isinstance(x, jax.core.Tracer) for x in (bearings, range_rank, visible)):
        _check_observation(bearings, range_rank, visible)
    return _measure_image(spec, jnp.asarray(bearings), jnp.asarray(range_rank),
                          jnp.asarray(visible), target_map, n=n, pool=pool, depth=depth)
