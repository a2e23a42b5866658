"""The PQRM measurement model: ``p(R^n = q | Z^n)`` by sampling (P §2.2.2, eq. 2.9).

For each landmark triplet n the three measured positions ``means[n] = (A, B, C)`` (robot frame)
are the centres of an isotropic Gaussian inverse sensor model ``p(L^n | Z^n)`` with standard
deviation ``sigma[n, i]`` per landmark. Eq. 2.9 is estimated by drawing S landmark
configurations, evaluating the k constraint signs of each and counting the samples per state:
``p̂(q) = #{s : state(s) = q} / #{s : state(s) is defined}``.

**One sampling pass for every representation.** All of Padgett's representations (P Fig. 2.2)
are merges of the 20-state EDC, so the kernel counts EDC states once and every coarser
calculus is an exact aggregation of those counts (``calc.parent_map``): the six
representations of the Monte Carlo study cost one pass. A calculus that is not a merge of the
EDC takes a generic (slower) path through ``Calculus.classify``.

**The fused EDC kernel.** Per sample the kernel computes ``u = e×d``, ``v = e·d``, ``m = |e|²``,
``n = |d|²`` (d = B−A, e = C−A), the six homogenised EDC constraints and from their strict signs
an arithmetic state key (side × band × circle count) — no table lookup, no division. It equals
``edc.classify`` on every sample whose constraint values are all non-zero and finite (a test
checks this); a sample with a zero constraint (C exactly on a boundary, A = B) or a non-finite
value is *rejected* (counted in no state), which is what ``classify`` does for EDC boundaries.
Because every representation is aggregated from EDC counts, a sample on an EDC boundary is
rejected for a coarser calculus too, even where that boundary is internal to a coarse state
(e.g. β = ½ for LR); with σ > 0 this has probability zero, with σ = 0 it affects only inputs
exactly on an EDC boundary.
The counts are accumulated with a single variadic XLA reduction into byte fields packed four
per uint32 word (chunks of at most 255 samples, so a field never overflows) — a histogram
without scatter and without a one-hot tensor.

**Common random numbers.** One bank of S standard-normal draws (S, 3, 2) is shared by all
triplets of a call and scaled by each triplet's means and sigmas. Every row is therefore
exactly the S-sample Monte Carlo estimator of eq. 2.9 (same distribution as with independent
draws); only the errors of different rows are correlated. Use a fresh key per call.

**Bounded memory.** The sample axis is reduced inside the fusion (chunks of ≤ 255 samples) and
the triplet axis is processed in blocks of ``chunk_triplets`` with ``lax.map``, so the working
set is O(chunk_triplets · 255) regardless of N·S; the output is (N, Q).

**Bad input.** ``means`` must be (N, 3, 2); eager calls raise ``ValueError`` for NaN/inf
means, negative or NaN sigma and non-positive ``num_samples``. Inside ``jit``/``vmap`` values
are not inspected: a row whose samples are all rejected (non-finite input, σ = 0 with C exactly
on a boundary or A = B) is all zeros — never NaN — and ``valid`` reports 0 samples for it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache, partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from ..calculi import Calculus

__all__ = [
    "EDC_NUM_STATES", "fine_counts", "state_counts", "state_probabilities",
    "multi_state_probabilities", "aggregation_matrix", "root_of", "edc_states_fused",
    "check_measurement_inputs",
]

EDC_NUM_STATES = 20
_FIELD_BITS = 8
_CHUNK_SAMPLES = (1 << _FIELD_BITS) - 1  # 255: a byte field never overflows
_WORDS = math.ceil(EDC_NUM_STATES * _FIELD_BITS / 32)  # 5 uint32 words
_REJECT_KEY = 2 * 10  # keys 0..19 are states; 20 = rejected sample (in no counted word)

# Realisable (inside A-circle, inside B-circle) pairs per band, behind A .. in front of B; the
# key uses c = cA + cB, which identifies the pair within a band (P Fig. 2.5, SPEC §2.1).
_BAND_CIRCLES = (
    ((0, 0), (1, 0)),
    ((0, 0), (1, 0), (1, 1)),
    ((0, 0), (0, 1), (1, 1)),
    ((0, 0), (0, 1)),
)
_BAND_OFFSET = (0, 2, 5, 8)


def root_of(calc: Calculus) -> Calculus:
    """The finest calculus that ``calc`` is a (chain of) merge(s) of (no ``parent``: itself)."""
    while getattr(calc, "parent", None) is not None:
        calc = calc.parent
    return calc


def root_identity(calc: Calculus) -> str | int:
    """What makes two calculi share one root: its ``definition_hash``, else the object itself."""
    root = root_of(calc)
    return getattr(root, "definition_hash", None) or id(root)


def is_edc(calc: Calculus) -> bool:
    """Whether ``calc`` is the EDC itself (it gets the fused sampling kernel)."""
    return getattr(calc, "definition_hash", None) == calculi.get("edc").definition_hash


@cache
def key_to_edc_state() -> np.ndarray:
    """Permutation key (0..19) → EDC state index, derived from ``edc.sign_table``."""
    edc = calculi.get("edc")
    out = np.full(EDC_NUM_STATES, -1, np.int32)
    for side in (0, 1):
        for band, pairs in enumerate(_BAND_CIRCLES):
            for ca, cb in pairs:
                # signs of (-α, -β, 1-β, 1-2β, 1-ρ, 2β-ρ); side 1 = right (α > 0)
                signs = (-1 if side else 1, -1 if band >= 1 else 1, -1 if band >= 3 else 1,
                         -1 if band >= 2 else 1, 1 if ca else -1, 1 if cb else -1)
                idx = sum((s + 1) * 3**a for a, s in enumerate(signs))
                key = side * 10 + _BAND_OFFSET[band] + ca + cb
                out[key] = edc.sign_table[idx]
    if sorted(out.tolist()) != list(range(EDC_NUM_STATES)):
        raise AssertionError("EDC key layout does not match edc.sign_table")
    return out


def aggregation_matrix(calc: Calculus) -> np.ndarray:
    """(Q_root, Q) 0/1 matrix mapping counts of ``root_of(calc)`` to counts of ``calc``."""
    fine_to = np.arange(calc.num_states)
    c = calc
    while getattr(c, "parent", None) is not None:
        fine_to = fine_to[np.asarray(c.parent_map)]
        c = c.parent
    mat = np.zeros((c.num_states, calc.num_states), np.float32)
    mat[np.arange(c.num_states), fine_to] = 1.0
    return mat


def _edc_keys(u, v, m, n):
    """Arithmetic EDC key (0..19) from homogenised quantities, ``_REJECT_KEY`` if undefined."""
    side = (u > 0).astype(jnp.uint32)  # −α < 0: C right of AB
    b1 = v > 0
    b2 = 2 * v > n
    b3 = v > n
    band = b1.astype(jnp.uint32) + b2.astype(jnp.uint32) + b3.astype(jnp.uint32)
    ca = m < n
    cb = m < 2 * v
    c = ca.astype(jnp.uint32) + cb.astype(jnp.uint32)
    offset = 3 * band - jnp.minimum(band, 1)
    key = side * 10 + offset + c
    # realisable (band, circles) combinations; others only arise from rounding (classify: −1)
    realisable = jnp.where(
        band == 0, ~cb, jnp.where(band == 1, ca | ~cb, jnp.where(band == 2, cb | ~ca, ~ca))
    )
    nonzero = (u != 0) & (v != 0) & (n != v) & (n != 2 * v) & (n != m) & (m != 2 * v)
    ok = nonzero & realisable & jnp.isfinite(u + v + m + n)
    return jnp.where(ok, key, jnp.uint32(_REJECT_KEY))


def _uvmn(ax, ay, bx, by, cx, cy):
    dx, dy, ex, ey = bx - ax, by - ay, cx - ax, cy - ay
    return ex * dy - ey * dx, ex * dx + ey * dy, ex * ex + ey * ey, dx * dx + dy * dy


def edc_states_fused(a: jax.Array, b: jax.Array, c: jax.Array) -> jax.Array:
    """EDC state index of ``AB:C`` by the fused kernel's arithmetic (−1 where rejected).

    Exposed so tests can check it against ``calculi.get("edc").classify``.
    """
    a, b, c = (jnp.asarray(x, jnp.result_type(x, jnp.float32)) for x in (a, b, c))
    key = _edc_keys(*_uvmn(a[..., 0], a[..., 1], b[..., 0], b[..., 1], c[..., 0], c[..., 1]))
    table = jnp.asarray(np.append(key_to_edc_state(), -1).astype(np.int32))
    return table[key.astype(jnp.int32)]


def _variadic_sum(ops, axis):
    init = tuple(jnp.uint32(0) for _ in ops)

    def add(x, y):
        return tuple(p + q for p, q in zip(x, y, strict=True))

    return jax.lax.reduce(tuple(ops), init, add, (axis,))


def edc_block_counts(mT, sT, zc):
    """Counts in key order for one block: mT (6, B), sT (3, B) → (B, 20) int32.

    ``zc`` is the sample bank, (c, C, 6) shared by the B triplets, or (c, C, 6, B) with one bank
    per triplet (``Mapper.update_batch``); the per-sample arithmetic is the same either way.
    """
    def col(x):
        return x[None, None, :]

    def zz(j):
        return zc[:, :, j, None] if zc.ndim == 3 else zc[:, :, j, :]

    # d = B − A and e = C − A per sample: mean difference + the two scaled noise terms
    dx = col(mT[2] - mT[0]) + col(sT[1]) * zz(2) - col(sT[0]) * zz(0)
    dy = col(mT[3] - mT[1]) + col(sT[1]) * zz(3) - col(sT[0]) * zz(1)
    ex = col(mT[4] - mT[0]) + col(sT[2]) * zz(4) - col(sT[0]) * zz(0)
    ey = col(mT[5] - mT[1]) + col(sT[2]) * zz(5) - col(sT[0]) * zz(1)
    key = _edc_keys(ex * dy - ey * dx, ex * dx + ey * dy, ex * ex + ey * ey, dx * dx + dy * dy)
    word = key >> 2
    val = jnp.left_shift(jnp.uint32(1), (key & 3) * _FIELD_BITS)
    zero = jnp.uint32(0)
    packed = _variadic_sum([jnp.where(word == w, val, zero) for w in range(_WORDS)], 1)
    packed = jnp.stack(packed, axis=-1)  # (c, B, words)
    shifts = jnp.arange(4, dtype=jnp.uint32) * _FIELD_BITS
    fields = (packed[..., None] >> shifts) & jnp.uint32((1 << _FIELD_BITS) - 1)  # (c,B,W,4)
    counts = jnp.sum(fields.astype(jnp.int32), axis=0)  # (B, W, 4)
    return counts.reshape(counts.shape[0], _WORDS * 4)[:, :EDC_NUM_STATES]


def sample_bank(key, num_samples: int, dtype):
    """Standard-normal bank (c, C, 6), padded with NaN (rejected) up to c·C ≥ num_samples."""
    nchunks = -(-num_samples // _CHUNK_SAMPLES)
    size = -(-num_samples // nchunks)
    z = jax.random.normal(key, (num_samples, 6), dtype)
    pad = nchunks * size - num_samples
    if pad:
        z = jnp.concatenate([z, jnp.full((pad, 6), jnp.nan, dtype)])
    return z.reshape(nchunks, size, 6)


def _fine_counts_edc(key, means, sigma, num_samples: int, chunk_triplets: int):
    n = means.shape[0]
    dtype = means.dtype
    z = sample_bank(key, num_samples, dtype)
    mT = means.reshape(n, 6).T  # (6, N): ax, ay, bx, by, cx, cy
    sT = sigma.T  # (3, N)
    blk = max(1, min(chunk_triplets, n))
    nblk = -(-n // blk)
    pad = nblk * blk - n
    if pad:
        mT = jnp.concatenate([mT, jnp.full((6, pad), jnp.nan, dtype)], axis=1)
        sT = jnp.concatenate([sT, jnp.zeros((3, pad), dtype)], axis=1)
    if nblk == 1:
        counts = edc_block_counts(mT, sT, z)
    else:
        mB = mT.reshape(6, nblk, blk).transpose(1, 0, 2)
        sB = sT.reshape(3, nblk, blk).transpose(1, 0, 2)
        counts = jax.lax.map(lambda ms: edc_block_counts(ms[0], ms[1], z), (mB, sB))
        counts = counts.reshape(nblk * blk, EDC_NUM_STATES)
    counts = counts[:n]
    # key order → EDC state order
    inv = np.argsort(key_to_edc_state())
    return counts[:, inv]


def _fine_counts_generic(key, root: Calculus, means, sigma, num_samples: int, chunk: int):
    z = jax.random.normal(key, (num_samples, 3, 2), means.dtype)
    q = root.num_states

    def one_block(args):
        mb, sb = args  # (B,3,2), (B,3)
        pts = mb[:, None] + sb[:, None, :, None] * z[None]  # (B,S,3,2)
        st = root.classify(pts[..., 0, :], pts[..., 1, :], pts[..., 2, :])
        return jnp.sum(st[..., None] == jnp.arange(q), axis=1, dtype=jnp.int32)

    n = means.shape[0]
    blk = max(1, min(chunk, n))
    nblk = -(-n // blk)
    pad = nblk * blk - n
    mp = jnp.concatenate([means, jnp.full((pad, 3, 2), jnp.nan, means.dtype)])
    sp = jnp.concatenate([sigma, jnp.zeros((pad, 3), sigma.dtype)])
    counts = jax.lax.map(one_block, (mp.reshape(nblk, blk, 3, 2), sp.reshape(nblk, blk, 3)))
    return counts.reshape(nblk * blk, q)[:n]


def _broadcast_sigma(sigma, n: int, dtype):
    sigma = jnp.asarray(sigma, dtype)
    if sigma.ndim == 1:
        sigma = sigma[:, None]
    return jnp.broadcast_to(sigma, (n, 3))


@partial(jax.jit, static_argnames=("root", "num_samples", "chunk_triplets"))
def root_counts(key, means, sigma, *, root: Calculus, num_samples: int, chunk_triplets: int):
    sigma = _broadcast_sigma(sigma, means.shape[0], means.dtype)
    if is_edc(root):
        return _fine_counts_edc(key, means, sigma, num_samples, chunk_triplets)
    return _fine_counts_generic(key, root, means, sigma, num_samples, max(1, chunk_triplets // 16))


def check_measurement_inputs(means, sigma, num_samples: int | None = None) -> None:
    """Raise ``ValueError`` for a malformed measurement (shapes always, values when concrete)."""
    shape = np.shape(means)
    if len(shape) != 3 or shape[1:] != (3, 2):
        raise ValueError(f"means must have shape (N, 3, 2) (landmarks A, B, C of N triplets), "
                         f"got {tuple(shape)}")
    sshape = np.shape(sigma)
    if sshape not in ((), (shape[0],), (shape[0], 1), (shape[0], 3), (1,), (1, 1), (1, 3)):
        raise ValueError(f"sigma must be a scalar, (N,) or (N, 3); got shape {sshape} for "
                         f"N = {shape[0]}")
    if num_samples is not None and (not isinstance(num_samples, int | np.integer)
                                    or num_samples < 1):
        raise ValueError(f"num_samples must be a positive integer, got {num_samples!r}")
    if not isinstance(means, jax.core.Tracer):
        if not np.all(np.isfinite(np.asarray(means))):
            raise ValueError("means contain NaN or infinite measurements")
    if not isinstance(sigma, jax.core.Tracer):
        s = np.asarray(sigma, dtype=float)
        if np.any(np.isnan(s)):
            raise ValueError("sigma must be a non-negative number, got NaN")
        if np.any(s < 0):
            raise ValueError(f"sigma must be non-negative, got {s.min()}")
        if np.any(np.isinf(s)):
            raise ValueError("sigma must be finite")


def fine_counts(
    key: jax.Array, calculus: Calculus | str, means: jax.Array, sigma, num_samples: int,
    *, chunk_triplets: int = 4096,
) -> jax.Array:
    """Sample counts (N, Q_root) of ``root_of(calculus)`` states (eq. 2.9 before normalising).

    Rows sum to the number of defined samples (≤ ``num_samples``; rejected samples — a zero
    constraint or a non-finite value — are in no state).
    """
    calc = calculi.get(calculus)
    check_measurement_inputs(means, sigma, num_samples)
    means = jnp.asarray(means, jnp.result_type(means, jnp.float32))
    return root_counts(key, means, sigma, root=root_of(calc), num_samples=int(num_samples),
                        chunk_triplets=int(chunk_triplets))


def counts_to_probabilities(counts: jax.Array) -> jax.Array:
    """Normalise counts per row; a row with no defined sample stays all zeros (never NaN)."""
    counts = counts.astype(jnp.float32)
    total = jnp.sum(counts, axis=-1, keepdims=True)
    return counts / jnp.maximum(total, 1.0)


def state_counts(key, calculus, means, sigma, num_samples: int, *, chunk_triplets: int = 4096):
    """Sample counts (N, Q) of ``calculus`` states (aggregated from one EDC pass)."""
    calc = calculi.get(calculus)
    fine = fine_counts(key, calc, means, sigma, num_samples, chunk_triplets=chunk_triplets)
    return (fine.astype(jnp.float32) @ aggregation_matrix(calc)).astype(jnp.int32)


def state_probabilities(
    key: jax.Array, calculus: Calculus | str, means: jax.Array, sigma, num_samples: int,
    *, chunk_triplets: int = 4096,
) -> jax.Array:
    """``p(AB:C = q | Z)`` for N triplets by sampling the Gaussian inverse sensor model (eq. 2.9).

    Args:
        key: PRNG key (one bank of draws shared by the rows; use a fresh key per call).
        calculus: a :class:`~pqrm_jax.calculi.Calculus` or a registered name.
        means: (N, 3, 2) measured positions of landmarks A, B, C of each triplet (robot frame).
        sigma: noise std, scalar, (N,) or (N, 3) (per landmark), isotropic.
        num_samples: S, samples per triplet.
        chunk_triplets: triplets per block (bounds the working set).

    Returns:
        (N, Q) float32 probabilities; each row sums to 1, or is all zeros when no sample had a
        defined state (see the module docstring).

    >>> import jax, jax.numpy as jnp
    >>> means = jnp.array([[[0., 0.], [0., 10.], [5., 4.]]])      # C right of AB
    >>> p = state_probabilities(jax.random.key(0), "lr", means, 0.0, 100)
    >>> p.tolist()
    [[0.0, 1.0]]
    >>> p = state_probabilities(jax.random.key(0), "edc", means, 1.0, 4000)
    >>> p.shape, round(float(p.sum()), 5)
    ((1, 20), 1.0)
    """
    return counts_to_probabilities(
        state_counts(key, calculus, means, sigma, num_samples, chunk_triplets=chunk_triplets))


def multi_state_probabilities(
    key: jax.Array, calculi_: Sequence[Calculus | str], means: jax.Array, sigma,
    num_samples: int, *, chunk_triplets: int = 4096,
) -> dict[str, jax.Array]:
    """``state_probabilities`` for several merges of one root calculus from one sampling pass.

    >>> import jax, jax.numpy as jnp
    >>> means = jnp.array([[[0., 0.], [0., 10.], [5., 4.]]])
    >>> ps = multi_state_probabilities(jax.random.key(0), ["edc", "lr"], means, 0.5, 500)
    >>> sorted(ps), ps["lr"].tolist()
    (['edc', 'lr'], [[0.0, 1.0]])
    """
    cals = [calculi.get(c) for c in calculi_]
    roots = {root_identity(c) for c in cals}
    if len(roots) != 1:
        raise ValueError("multi_state_probabilities needs calculi that share one root calculus")
    fine = fine_counts(key, cals[0], means, sigma, num_samples, chunk_triplets=chunk_triplets)
    f = fine.astype(jnp.float32)
    return {c.name: counts_to_probabilities(f @ aggregation_matrix(c)) for c in cals}
