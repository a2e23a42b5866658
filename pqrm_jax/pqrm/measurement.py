"""The PQRM measurement model: ``p(R^n = q | Z^n)`` by sampling (P §2.2.2, eq. 2.9).

Offers the state probabilities of N triplets (``means`` ``[N, 3, 2]``, ``sigma`` ``[N, 3]``)
for one calculus or for several at once, the fused EDC sign kernel and its per-state counts,
and the aggregation of EDC counts into any calculus that merges the EDC. Eager calls raise
``ValueError`` for bad input; inside ``jit`` a row with no defined sample is all zeros.

One sampling pass for every representation, the fused kernel, common random numbers, bounded
memory and bad input: docs/pqrm.md §measurement.
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
from ..calculi.calculus import rescale_pow2

__all__ = [
    "EDC_NUM_STATES", "fine_counts", "state_counts", "state_probabilities",
    "multi_state_probabilities", "aggregation_matrix", "root_of", "edc_states_fused",
    "check_measurement_inputs", "normal_bank_rows", "sample_block", "working_set_bytes",
    "MAX_NUM_SAMPLES", "DEFAULT_MAX_BYTES", "KERNEL_COMPILER_OPTIONS",
]

EDC_NUM_STATES = 20
_FIELD_BITS = 8
_CHUNK_SAMPLES = (1 << _FIELD_BITS) - 1  # 255: a byte field never overflows
_WORDS = math.ceil(EDC_NUM_STATES * _FIELD_BITS / 32)  # 5 uint32 words
_REJECT_KEY = 2 * 10  # keys 0..19 are states; 20 = rejected sample (in no counted word)
MAX_NUM_SAMPLES = 2**31 - 1  # counts are int32
DEFAULT_MAX_BYTES = 8 << 30  # refuse a request whose estimated working set is above this
_BLOCK_PAIRS = 1 << 24  # sample–triplet pairs per streamed block (EDC kernel)
_BLOCK_SAMPLES_MAX = 1 << 18  # samples per streamed block at most (bank rows 6 MiB)
_GENERIC_BLOCK_PAIRS = 1 << 20  # the generic path materialises (B, S, Q) per block
#: XLA options of the programs that run the sampling kernel (``jax.jit(...,
#: compiler_options=KERNEL_COMPILER_OPTIONS)``): on a CPU with 512-bit vectors XLA otherwise
#: emits the kernel's loop 8 floats wide; at 16 the kernel on the sample-major bank ran
#: 1.2–1.5x the samples a second on the 2-core machine (one process, four A/Bs), same counts
#: (docs/benchmarks.md §bench_pqrm). Per program, not process-wide: other
#: programs' float reductions keep their order. A CPU without 512-bit vectors, or another
#: backend, ignores it.
KERNEL_COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512}

# Realisable (inside A-circle, inside B-circle) pairs per band, behind A .. in front of B; the
# key uses c = cA + cB, which identifies the pair within a band (P Fig. 2.5,
# docs/decisions.md §2.1).
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
    """The 0/1 matrix that merges counts of the root calculus into counts of ``calc`` (P §2.2.1).

    One sampling pass of the root calculus (the EDC for Padgett's six) serves every merge of
    it: ``counts_calc = counts_root @ aggregation_matrix(calc)``.

    Args:
        calc: a calculus (a merge chain ends at its root, ``root_of(calc)``).

    Returns:
        ``[Q_root, Q]`` float32, one 1 per row.
    """
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
    a, b, c = jnp.broadcast_arrays(a, b, c)
    d, e = b - a, c - a
    big = jnp.maximum(jnp.max(jnp.abs(d), axis=-1), jnp.max(jnp.abs(e), axis=-1))
    d, e = rescale_pow2(big[..., None], d, e)
    zero = jnp.zeros_like(d[..., 0])
    key = _edc_keys(*_uvmn(zero, zero, d[..., 0], d[..., 1], e[..., 0], e[..., 1]))
    table = jnp.asarray(np.append(key_to_edc_state(), -1).astype(np.int32))
    return table[key.astype(jnp.int32)]


def _variadic_sum(ops, axis):
    init = tuple(jnp.uint32(0) for _ in ops)

    def add(x, y):
        return tuple(p + q for p, q in zip(x, y, strict=True))

    return jax.lax.reduce(tuple(ops), init, add, (axis,))


def edc_block_counts(mT, sT, zc):
    """Counts in key order for one block: mT [6, B], sT [3, B] → [B, 20] int32.

    ``zc`` is the sample bank sample-major (``sample_bank(..., sample_major=True)``), [c, 6, C]
    shared by the B triplets, or [c, 6, C, B] with one bank per triplet
    (``Mapper.update_batch``); the per-sample arithmetic is the same either way. XLA
    vectorises the kernel along the C samples of a chunk: read from [c, C, 6], the six values
    of a sample took more shuffles than the arithmetic.
    """
    return _unpack_counts(_edc_packed(mT, sT, zc))


def _unpack_counts(packed):
    """[..., c, B, W] packed byte fields (:func:`_edc_packed`) → [..., B, 20] int32 counts."""
    shifts = jnp.arange(4, dtype=jnp.uint32) * _FIELD_BITS
    fields = (packed[..., None] >> shifts) & jnp.uint32((1 << _FIELD_BITS) - 1)  # (.., W, 4)
    counts = jnp.sum(fields.astype(jnp.int32), axis=-4)  # (..., B, W, 4)
    return counts.reshape(*counts.shape[:-2], _WORDS * 4)[..., :EDC_NUM_STATES]


def _edc_packed(mT, sT, zc):
    """[c, B, W] uint32: the counts of each chunk of ≤ 255 samples in key order, four byte
    fields a word (:func:`edc_block_counts`)."""
    def col(x):
        return x[None, None, :]

    def zz(j):
        return zc[:, j, :, None] if zc.ndim == 3 else zc[:, j]

    # translate each triplet to A and rescale it (means and sigmas) by a power of two: exact,
    # so the per-sample arithmetic below is the unscaled one times 2^-k (no over/underflow)
    md = jnp.stack([mT[2] - mT[0], mT[3] - mT[1], mT[4] - mT[0], mT[5] - mT[1]])
    big = jnp.maximum(jnp.max(jnp.abs(md), axis=0), jnp.max(sT, axis=0))
    md, sT = rescale_pow2(big, md, sT)
    zero = jnp.zeros_like(md[0])
    mT = jnp.stack([zero, zero, md[0], md[1], md[2], md[3]])
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
    return jnp.stack(packed, axis=-1)  # (c, B, words)


def sample_bank(key, num_samples: int, dtype, *, sample_major: bool = False):
    """Standard-normal bank [c, C, 6], padded with NaN (rejected) up to c·C ≥ num_samples.

    The values of ``jax.random.normal(key, (num_samples, 6), dtype)`` in chunks of C ≤ 255
    samples, drawn by an unrolled threefry (bit-identical) for a partitionable threefry key.
    ``sample_major=True`` gives the same values as [c, 6, C], the layout of the kernel
    (:func:`edc_block_counts`), generated in that order (a program whose innermost axis is 6
    long is not vectorised by XLA:CPU).
    """
    nchunks = -(-num_samples // _CHUNK_SAMPLES)
    size = -(-num_samples // nchunks)
    if _is_threefry(key) and jnp.dtype(dtype).itemsize in (4, 8):
        z = _bank_chunks(key, 0, nchunks, size, num_samples, dtype)  # [c, 6, C]
        return z if sample_major else jnp.swapaxes(z, 1, 2)
    z = jax.random.normal(key, (num_samples, 6), dtype)
    pad = nchunks * size - num_samples
    if pad:
        z = jnp.concatenate([z, jnp.full((pad, 6), jnp.nan, dtype)])
    z = z.reshape(nchunks, size, 6)
    return jnp.swapaxes(z, 1, 2) if sample_major else z


def _is_threefry(key) -> bool:
    """Whether ``key`` is a threefry key under ``jax_threefry_partitionable`` (no array op)."""
    if not jax.config.jax_threefry_partitionable:
        return False
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return "threefry" in str(jax.random.key_impl(key))
    return jax.config.jax_default_prng_impl == "threefry2x32" and key.shape == (2,)


def _threefry_key_data(key):
    """(k1, k2) uint32 words of a threefry key, or None for another PRNG implementation."""
    if not _is_threefry(key):
        return None
    data = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    data = data.astype(jnp.uint32)
    return data[0], data[1]


def _row_counters(rows: jax.Array, j: jax.Array | None = None):
    """Threefry counters (hi, lo) of the six elements of each row of an (S, 6) array, or of
    the elements (``rows[i]``, ``j[i]``) when ``j`` is given."""
    if j is None:
        r = rows.astype(jnp.uint32)[:, None]
        j = jnp.arange(6, dtype=jnp.uint32)[None, :]
    else:
        r = rows.astype(jnp.uint32)
    # 6 r + j < 3 · 2^32 for r < 2^31: split r = h·2^30 + l and form the 64-bit sum in words
    h = r >> 30
    x = 3 * (r & jnp.uint32((1 << 30) - 1))  # < 2^32
    lo0 = x << 1
    lo1 = lo0 + j
    hi = (x >> 31) + (lo1 < lo0).astype(jnp.uint32)
    lo = lo1 + h * jnp.uint32(1 << 31)
    hi = hi + h + ((h > 0) & (lo < lo1)).astype(jnp.uint32)
    return hi, lo


def normal_bank_rows(key: jax.Array, start, num_rows: int, dtype=jnp.float32) -> jax.Array:
    """Rows ``[start, start + num_rows)`` of ``jax.random.normal(key, (S, 6), dtype)``.

    The same bits for any S ≥ start + num_rows (partitionable threefry: element (s, j) draws
    from counter 6·s + j), without forming the other rows — the streamed bank of
    :func:`state_probabilities`. ``start`` may be traced. Raises ``ValueError`` for a key of
    another PRNG implementation.

    >>> import jax, jax.numpy as jnp
    >>> k = jax.random.key(3)
    >>> bool(jnp.array_equal(normal_bank_rows(k, 5, 4), jax.random.normal(k, (12, 6))[5:9]))
    True
    """
    if not _is_threefry(key):
        raise ValueError("normal_bank_rows needs a threefry key with jax_threefry_partitionable")
    return _bank_rows_jit(key, start, num_rows=int(num_rows), dtype=jnp.dtype(dtype))


@partial(jax.jit, static_argnames=("num_rows", "dtype"))
def _bank_rows_jit(key, start, *, num_rows: int, dtype):
    return _bank_rows(key, start, num_rows, dtype)


_THREEFRY_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def threefry2x32(k1, k2, x1, x2):
    """The threefry-2x32 hash of JAX's ``threefry2x32_p``, unrolled, in plain ``uint32`` ops.

    Bit-identical to ``jax.extend.random.threefry2x32_p.bind`` (a test checks it); on the CPU
    JAX lowers that primitive as a rolled five-iteration loop whose carried arrays XLA copies
    every iteration, about 4x slower than these twenty rounds fused into one loop.
    """
    k1, k2, x1, x2 = (jnp.asarray(v, jnp.uint32) for v in (k1, k2, x1, x2))
    ks = (k1, k2, k1 ^ k2 ^ jnp.uint32(0x1BD11BDA))
    x = [x1 + ks[0], x2 + ks[1]]
    for i in range(5):
        for r in _THREEFRY_ROTATIONS[i % 2]:
            x[0] = x[0] + x[1]
            x[1] = (x[1] << jnp.uint32(r)) | (x[1] >> jnp.uint32(32 - r))
            x[1] = x[0] ^ x[1]
        x[0] = x[0] + ks[(i + 1) % 3]
        x[1] = x[1] + ks[(i + 2) % 3] + jnp.uint32(i + 1)
    return x[0], x[1]


def _bank_rows(key, start, num_rows: int, dtype):
    """Rows ``[start, start + num_rows)`` of the normal bank, [num_rows, 6]."""
    # one flat array of the 6·num_rows elements (row-major): vectorises along its only axis
    flat = np.arange(6 * num_rows)
    rows = jnp.asarray(start, jnp.int32) + jnp.asarray(flat // 6, jnp.int32)
    return _normals(key, rows, jnp.asarray(flat % 6, jnp.uint32), dtype).reshape(num_rows, 6)


def _bank_chunks(key, start, nchunks: int, size: int, num_valid, dtype):
    """[nchunks, 6, size] sample-major chunks: element (i, j, s) is column j of row
    ``start + i·size + s`` of the normal bank, NaN for rows ≥ ``num_valid``."""
    shape = (nchunks, 6, size)
    rows = (jnp.asarray(start, jnp.int32) + jax.lax.broadcasted_iota(jnp.int32, shape, 0) * size
            + jax.lax.broadcasted_iota(jnp.int32, shape, 2))
    z = _normals(key, rows, jax.lax.broadcasted_iota(jnp.uint32, shape, 1), dtype)
    return jnp.where(rows < num_valid, z, jnp.nan)


def _normals(key, rows, cols, dtype):
    """Element (row, col) of ``jax.random.normal(key, (S, 6), dtype)`` for index arrays of one
    shape (partitionable threefry: element (s, j) draws from counter 6·s + j)."""
    words = _threefry_key_data(key)
    hi, lo = _row_counters(rows, cols)
    b1, b2 = threefry2x32(words[0], words[1], hi, lo)
    dtype = jnp.dtype(dtype)
    finfo = jnp.finfo(dtype)
    if finfo.bits == 64:
        bits = (b1.astype(jnp.uint64) << jnp.uint64(32)) | b2.astype(jnp.uint64)
        utype = jnp.uint64
    elif finfo.bits == 32:
        bits = b1 ^ b2
        utype = jnp.uint32
    else:
        raise ValueError(f"normal_bank_rows supports float32 and float64, not {dtype}")
    # jax.random.uniform(lo=nextafter(-1, 0), hi=1) then sqrt(2)·erfinv, as jax.random.normal
    lo_v = np.nextafter(np.array(-1.0, dtype), np.array(0.0, dtype), dtype=dtype)
    hi_v = np.array(1.0, dtype)
    fbits = jax.lax.shift_right_logical(bits, jnp.asarray(finfo.bits - finfo.nmant, utype))
    fbits = fbits | jnp.asarray(np.array(1.0, dtype).view(utype), utype)
    floats = jax.lax.bitcast_convert_type(fbits, dtype) - jnp.asarray(1.0, dtype)
    u = jax.lax.max(jnp.asarray(lo_v, dtype), floats * (hi_v - lo_v) + lo_v)
    return jax.lax.mul(jnp.asarray(np.sqrt(2), dtype), jax.scipy.special.erfinv(u))


def sample_block(chunk_triplets: int, num_triplets: int | None = None) -> int:
    """Samples per streamed block of the EDC kernel (a multiple of 255).

    About 2^24 sample–triplet pairs per block and at most 2^18 samples; a request with
    S ≤ this block is computed in one piece (no scan).

    >>> sample_block(4096), sample_block(4096, num_triplets=10)
    (4080, 262140)
    """
    blk = max(1, min(int(chunk_triplets), num_triplets or int(chunk_triplets)))
    groups = max(1, min(_BLOCK_PAIRS // (_CHUNK_SAMPLES * blk),
                        _BLOCK_SAMPLES_MAX // _CHUNK_SAMPLES))
    return groups * _CHUNK_SAMPLES


def _generic_block(chunk: int, num_triplets: int) -> int:
    blk = max(1, min(chunk, num_triplets))
    return max(1, min(_GENERIC_BLOCK_PAIRS // blk, _BLOCK_SAMPLES_MAX))


def working_set_bytes(num_triplets: int, num_samples: int, root_states: int = EDC_NUM_STATES,
                      *, chunk_triplets: int = 4096, generic: bool = False) -> int:
    """Estimated peak working set (bytes) of one :func:`fine_counts` call.

    The (N, Q) output and inputs (~ N · (36 + 12 Q) B) plus one streamed block:
    ~400 B per (255-sample chunk × triplet) and ~64 B per sample of the EDC kernel, or
    ~(40 + Q) B per sample–triplet pair of the generic path. Independent of S once S exceeds
    one block.

    >>> working_set_bytes(10, 10**8) < 200 * 2**20
    True
    """
    n = max(1, int(num_triplets))
    fixed = n * (36 + 12 * root_states)
    if generic:
        blk = max(1, min(max(1, int(chunk_triplets) // 16), n))
        sb = min(int(num_samples), _generic_block(blk, n))
        return fixed + blk * sb * (40 + root_states) + 24 * sb
    blk = max(1, min(int(chunk_triplets), n))
    sb = min(int(num_samples), sample_block(chunk_triplets, n))
    chunks = -(-sb // _CHUNK_SAMPLES)
    return fixed + 400 * chunks * blk + 64 * sb


def _balanced_block(n: int, chunk: int) -> int:
    """Triplets per block: at most ``chunk``, as even as the block count allows (N = 7 200 at
    ``chunk`` 4 096: two blocks of 3 600, not 4 096 + 3 104 padded to 8 192). The counts do not
    depend on the blocking (each row's arithmetic is the same).

    >>> _balanced_block(7200, 4096), _balanced_block(100, 4096), _balanced_block(5, 2)
    (3600, 100, 2)
    """
    blk = max(1, min(int(chunk), int(n)))
    nblk = -(-int(n) // blk)
    return -(-int(n) // nblk) if n else blk


def _pad_triplets(mT, sT, blk: int, dtype):
    n = mT.shape[1]
    nblk = -(-n // blk)
    pad = nblk * blk - n
    if pad:
        mT = jnp.concatenate([mT, jnp.full((6, pad), jnp.nan, dtype)], axis=1)
        sT = jnp.concatenate([sT, jnp.zeros((3, pad), dtype)], axis=1)
    return mT, sT, nblk


def _counts_all_blocks(mT, sT, z, nblk: int, blk: int):
    """Key-order counts (nblk·blk, 20) of every triplet block against one bank ``z``."""
    if nblk == 1:
        return edc_block_counts(mT, sT, z)
    mB = mT.reshape(6, nblk, blk).transpose(1, 0, 2)
    sB = sT.reshape(3, nblk, blk).transpose(1, 0, 2)
    # the blocks' packed fields, unpacked after the loop in one vectorised pass
    packed = jax.lax.map(lambda ms: _edc_packed(ms[0], ms[1], z), (mB, sB))
    return _unpack_counts(packed).reshape(nblk * blk, EDC_NUM_STATES)


def _streamed_bank(key, num_samples: int, block: int, dtype, *, sample_major: bool = False):
    """A function b ↦ bank block b, [block, 6] rows (or [block/255, 6, 255] sample-major
    chunks), NaN past ``num_samples``."""
    threefry = _is_threefry(key)

    def bank(b):
        if threefry and sample_major:
            return _bank_chunks(key, b * block, block // _CHUNK_SAMPLES, _CHUNK_SAMPLES,
                                num_samples, dtype)
        if threefry:
            z = _bank_rows(key, b * block, block, dtype)
        else:  # another PRNG: one folded key per block
            z = jax.random.normal(jax.random.fold_in(key, b), (block, 6), dtype)
        idx = b * block + jnp.arange(block)
        z = jnp.where((idx < num_samples)[:, None], z, jnp.nan)
        if sample_major:
            z = jnp.swapaxes(z.reshape(block // _CHUNK_SAMPLES, _CHUNK_SAMPLES, 6), 1, 2)
        return z

    return bank


def _fine_counts_edc(key, means, sigma, num_samples: int, chunk_triplets: int):
    n = means.shape[0]
    dtype = means.dtype
    mT = means.reshape(n, 6).T  # (6, N): ax, ay, bx, by, cx, cy
    sT = sigma.T  # (3, N)
    blk = _balanced_block(n, chunk_triplets)
    mT, sT, nblk = _pad_triplets(mT, sT, blk, dtype)
    block = sample_block(chunk_triplets, n)
    if num_samples <= block:
        z = sample_bank(key, num_samples, dtype, sample_major=True)
        counts = _counts_all_blocks(mT, sT, z, nblk, blk)
    else:
        bank = _streamed_bank(key, num_samples, block, dtype, sample_major=True)

        def step(acc, b):
            return acc + _counts_all_blocks(mT, sT, bank(b), nblk, blk), None

        zero = jnp.zeros((nblk * blk, EDC_NUM_STATES), jnp.int32)
        counts, _ = jax.lax.scan(step, zero, jnp.arange(-(-num_samples // block)))
    counts = counts[:n]
    # key order → EDC state order
    inv = np.argsort(key_to_edc_state())
    return counts[:, inv]


@partial(jax.jit, static_argnames=("num_samples", "block", "dtype"))
def _bank_block(key, b, *, num_samples: int, block: int, dtype):
    return _streamed_bank(key, num_samples, block, dtype, sample_major=True)(b)


@partial(jax.jit, static_argnames=("chunk_triplets",))
def _prepare_edc(means, sigma, *, chunk_triplets: int):
    n = means.shape[0]
    sigma = _broadcast_sigma(sigma, n, means.dtype)
    blk = _balanced_block(n, chunk_triplets)
    return _pad_triplets(means.reshape(n, 6).T, sigma.T, blk, means.dtype)[:2]


@partial(jax.jit, static_argnames=("nblk", "blk"), donate_argnums=(0,),
         compiler_options=KERNEL_COMPILER_OPTIONS)
def _accumulate_block(acc, mT, sT, z, *, nblk: int, blk: int):
    return acc + _counts_all_blocks(mT, sT, z, nblk, blk)


def _fine_counts_edc_eager(key, means, sigma, num_samples: int, chunk_triplets: int):
    """The streamed EDC counts as a host loop over sample blocks (eager calls only).

    Same blocks, bank rows and kernel as the ``lax.scan`` of :func:`_fine_counts_edc`, so the
    same counts; XLA compiles the kernel ~2-3x faster as its own program than inside a loop
    body that also generates the bank, so eager calls take this path.
    """
    n = means.shape[0]
    blk = _balanced_block(n, chunk_triplets)
    nblk = -(-n // blk)
    block = sample_block(chunk_triplets, n)
    mT, sT = _prepare_edc(means, sigma, chunk_triplets=chunk_triplets)
    acc = jnp.zeros((nblk * blk, EDC_NUM_STATES), jnp.int32)
    for b in range(-(-num_samples // block)):
        z = _bank_block(key, jnp.int32(b), num_samples=num_samples, block=block,
                        dtype=means.dtype)
        acc = _accumulate_block(acc, mT, sT, z, nblk=nblk, blk=blk)
    inv = np.argsort(key_to_edc_state())
    return acc[:n][:, inv]


def _fine_counts_generic(key, root: Calculus, means, sigma, num_samples: int, chunk: int):
    q = root.num_states
    n = means.shape[0]
    blk = max(1, min(chunk, n))
    nblk = -(-n // blk)
    pad = nblk * blk - n
    mp = jnp.concatenate([means, jnp.full((pad, 3, 2), jnp.nan, means.dtype)])
    sp = jnp.concatenate([sigma, jnp.zeros((pad, 3), sigma.dtype)])
    mp, sp = mp.reshape(nblk, blk, 3, 2), sp.reshape(nblk, blk, 3)

    def block_counts(z):
        def one_block(args):
            mb, sb = args  # (B,3,2), (B,3)
            pts = mb[:, None] + sb[:, None, :, None] * z[None]  # (B,S,3,2)
            st = root.classify(pts[..., 0, :], pts[..., 1, :], pts[..., 2, :])
            return jnp.sum(st[..., None] == jnp.arange(q), axis=1, dtype=jnp.int32)

        return jax.lax.map(one_block, (mp, sp)).reshape(nblk * blk, q)

    block = _generic_block(blk, n)
    if num_samples <= block:
        counts = block_counts(jax.random.normal(key, (num_samples, 3, 2), means.dtype))
    else:
        bank = _streamed_bank(key, num_samples, block, means.dtype)

        def step(acc, b):
            return acc + block_counts(bank(b).reshape(block, 3, 2)), None

        counts, _ = jax.lax.scan(step, jnp.zeros((nblk * blk, q), jnp.int32),
                                 jnp.arange(-(-num_samples // block)))
    return counts[:n]


def _broadcast_sigma(sigma, n: int, dtype):
    sigma = jnp.asarray(sigma, dtype)
    if sigma.ndim == 1:
        sigma = sigma[:, None]
    return jnp.broadcast_to(sigma, (n, 3))


def _root_counts(key, means, sigma, *, root: Calculus, num_samples: int, chunk_triplets: int):
    sigma = _broadcast_sigma(sigma, means.shape[0], means.dtype)
    if is_edc(root):
        return _fine_counts_edc(key, means, sigma, num_samples, chunk_triplets)
    return _fine_counts_generic(key, root, means, sigma, num_samples, max(1, chunk_triplets // 16))


def _staged() -> bool:
    """Whether this call is being traced into an outer ``jit`` (where JAX refuses a nested
    program with compiler options): there a constant through a primitive is a tracer, and
    outside it stays a host value (no program dispatched; a fresh array was an eager call)."""
    return isinstance(jax.lax.stop_gradient(np.float32(0)), jax.core.Tracer)


_STATIC = ("root", "num_samples", "chunk_triplets")
#: [N, Q_root] counts of ``root``'s states; callable inside ``jit``/``vmap``.
root_counts = jax.jit(_root_counts, static_argnames=_STATIC)
# the same as its own top-level program, with the kernel's XLA options (which JAX accepts on
# a top-level jit only): what an eager :func:`fine_counts` runs
_root_counts_top = jax.jit(_root_counts, static_argnames=_STATIC,
                           compiler_options=KERNEL_COMPILER_OPTIONS)


def _as_real_array(x, name: str):
    """``x`` as an array (nested lists welcome); complex or non-numeric raises TypeError."""
    if not isinstance(x, jax.Array | np.ndarray):
        try:
            x = np.asarray(x)
        except (TypeError, ValueError) as err:
            raise TypeError(f"{name} must be an array of real numbers") from err
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{name} is complex ({x.dtype}); positions and sigmas must be real")
    if jnp.issubdtype(x.dtype, jnp.bool_) or not (jnp.issubdtype(x.dtype, jnp.integer)
                               or jnp.issubdtype(x.dtype, jnp.floating)):
        raise TypeError(f"{name} has dtype {x.dtype}; expected real numbers")
    return x


def check_measurement_inputs(means, sigma, num_samples: int | None = None) -> None:
    """Raise ``ValueError`` for a malformed measurement (shapes always, values when concrete).

    ``TypeError`` for complex or non-numeric ``means``/``sigma``.
    """
    means = _as_real_array(means, "means")
    sigma = _as_real_array(sigma, "sigma")
    shape = np.shape(means)
    if len(shape) != 3 or shape[1:] != (3, 2):
        raise ValueError(f"means must have shape (N, 3, 2) (landmarks A, B, C of N triplets), "
                         f"got {tuple(shape)}")
    sshape = np.shape(sigma)
    if sshape not in ((), (shape[0],), (shape[0], 1), (shape[0], 3), (1,), (1, 1), (1, 3)):
        raise ValueError(f"sigma must be a scalar, (N,) or (N, 3); got shape {sshape} for "
                         f"N = {shape[0]}")
    if num_samples is not None and (not isinstance(num_samples, int | np.integer)
                                    or isinstance(num_samples, bool | np.bool_)
                                    or num_samples < 1):
        raise ValueError(f"num_samples must be a positive integer, got {num_samples!r}")
    if num_samples is not None and num_samples > MAX_NUM_SAMPLES:
        raise ValueError(f"num_samples = {num_samples} exceeds {MAX_NUM_SAMPLES} (2**31 - 1; "
                         "counts are int32): draw several batches with different keys and "
                         "add their state_counts")
    if not isinstance(means, jax.core.Tracer):
        _check_means_values(np.asarray(means))
    if not isinstance(sigma, jax.core.Tracer):
        s = np.asarray(sigma, dtype=float)
        lo, hi = (s.min(), s.max()) if s.size else (0.0, 0.0)  # NaN propagates through both
        if np.isnan(lo):
            raise ValueError("sigma must be a non-negative number, got NaN")
        if lo < 0:
            raise ValueError(f"sigma must be non-negative, got {lo}")
        if np.isinf(hi):
            raise ValueError("sigma must be finite")


def _check_means_values(m: np.ndarray) -> None:
    """Finite means whose coordinate differences within a triplet do not overflow.

    By the extremes first (two passes; NaN propagates through min and max): when ``max − min``
    is finite in the working dtype, so is every difference (rounding is monotonic), and only
    otherwise are the differences formed. The element-wise checks took 0.3–0.6 ms of an eager
    ``fine_counts`` call of ≈ 7 ms (N = 7 200, S = 1 024; docs/benchmarks.md §bench_pqrm).
    """
    if not m.size or not jnp.issubdtype(m.dtype, jnp.floating):
        return  # integers are finite; their differences are formed in floating point later
    dt = np.result_type(m.dtype, np.float32)
    lo, hi = np.asarray(m.min(), dt), np.asarray(m.max(), dt)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError("means contain NaN or infinite measurements")
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(hi - lo):
            return
        mm = m.astype(dt)
        diff = mm[:, 1:] - mm[:, :1]
    if not np.all(np.isfinite(diff)):
        raise ValueError(f"coordinate differences within a triplet overflow {dt} "
                         f"(|means| up to {np.abs(m).max():.3g}); translate or "
                         "rescale the positions")


def _check_working_set(calc: Calculus, n: int, num_samples: int, chunk_triplets: int,
                       max_bytes: int | None) -> None:
    if not isinstance(chunk_triplets, int | np.integer) or isinstance(chunk_triplets, bool) \
            or chunk_triplets < 1:
        raise ValueError(f"chunk_triplets must be a positive integer, got {chunk_triplets!r}")
    if max_bytes is None:
        return
    root = root_of(calc)
    generic = not is_edc(root)
    need = working_set_bytes(n, num_samples, root.num_states, chunk_triplets=chunk_triplets,
                             generic=generic)
    if need > max_bytes:
        raise ValueError(
            f"estimated working set {need / 2**30:.2f} GiB for N = {n} triplets, S = "
            f"{num_samples} samples, chunk_triplets = {chunk_triplets} exceeds max_bytes = "
            f"{max_bytes / 2**30:.2f} GiB: lower chunk_triplets, split the triplets into "
            "several calls, or raise max_bytes")


def fine_counts(
    key: jax.Array, calculus: Calculus | str, means: jax.Array, sigma, num_samples: int,
    *, chunk_triplets: int = 4096, max_bytes: int | None = DEFAULT_MAX_BYTES,
) -> jax.Array:
    """Sample counts [N, Q_root] of ``root_of(calculus)`` states (eq. 2.9 before normalising).

    Args:
        key: PRNG key (one bank of draws shared by the rows).
        calculus: a :class:`~pqrm_jax.calculi.Calculus` or a registered name.
        means: [N, 3, 2] measured positions of landmarks A, B, C of each triplet.
        sigma: noise std, scalar, [N] or [N, 3].
        num_samples: S, samples per triplet.
        chunk_triplets: triplets per block (bounds the working set).
        max_bytes: bound on the estimated working set (:func:`working_set_bytes`); ``None``
            disables the check.

    Returns:
        [N, Q_root] int32 counts; rows sum to the number of defined samples (≤ ``num_samples``;
        rejected samples — a zero constraint or a non-finite value — are in no state).

    Raises:
        ValueError: for bad input when called eagerly (see :func:`check_measurement_inputs`).
    """
    calc = calculi.get(calculus)
    check_measurement_inputs(means, sigma, num_samples)
    means = _as_real_array(means, "means")
    sigma = _as_real_array(sigma, "sigma")
    _check_working_set(calc, int(np.shape(means)[0]), int(num_samples), chunk_triplets,
                       max_bytes)
    dtype = jnp.result_type(means, jnp.float32)
    if not (isinstance(means, jax.Array) and means.dtype == dtype):  # (a no-op dispatched)
        means = jnp.asarray(means, dtype)
    root = root_of(calc)
    traced = any(isinstance(x, jax.core.Tracer) for x in (key, means, sigma))
    if (not traced and is_edc(root) and _is_threefry(key)
            and int(num_samples) > sample_block(int(chunk_triplets), means.shape[0])):
        return _fine_counts_edc_eager(key, means, sigma, int(num_samples), int(chunk_triplets))
    counts = root_counts if _staged() else _root_counts_top
    return counts(key, means, sigma, root=root, num_samples=int(num_samples),
                        chunk_triplets=int(chunk_triplets))


def counts_to_probabilities(counts: jax.Array) -> jax.Array:
    """Normalise counts per row; a row with no defined sample stays all zeros (never NaN)."""
    counts = counts.astype(jnp.float32)
    total = jnp.sum(counts, axis=-1, keepdims=True)
    return counts / jnp.maximum(total, 1.0)


def state_counts(key, calculus, means, sigma, num_samples: int, *, chunk_triplets: int = 4096,
                 max_bytes: int | None = DEFAULT_MAX_BYTES):
    """Sample counts of ``calculus`` states for N triplets (P eq. 2.9, before normalising).

    Aggregated from one pass of the root calculus; exact int32.

    Args:
        key: PRNG key (one bank of draws shared by the rows).
        calculus: a :class:`~pqrm_jax.calculi.Calculus` or a registered name.
        means: ``[N, 3, 2]`` measured positions of A, B, C of each triplet.
        sigma: noise std, scalar, ``[N]`` or ``[N, 3]``.
        num_samples: S, samples per triplet.
        chunk_triplets: triplets per sampling block.
        max_bytes: refuse a working set above this many bytes (``None``: no check).

    Returns:
        ``[N, Q]`` int32 counts (rows sum to S minus the undefined samples).

    Raises:
        ValueError: for an estimated working set above ``max_bytes`` and the input checks of
            :func:`fine_counts`.
    """
    calc = calculi.get(calculus)
    fine = fine_counts(key, calc, means, sigma, num_samples, chunk_triplets=chunk_triplets,
                       max_bytes=max_bytes)
    return jnp.dot(fine, jnp.asarray(aggregation_matrix(calc), jnp.int32),
                   preferred_element_type=jnp.int32)


def state_probabilities(
    key: jax.Array, calculus: Calculus | str, means: jax.Array, sigma, num_samples: int,
    *, chunk_triplets: int = 4096, max_bytes: int | None = DEFAULT_MAX_BYTES,
) -> jax.Array:
    """``p(AB:C = q | Z)`` for N triplets by sampling the Gaussian inverse sensor model (eq. 2.9).

    Args:
        key: PRNG key (one bank of draws shared by the rows; use a fresh key per call).
        calculus: a :class:`~pqrm_jax.calculi.Calculus` or a registered name.
        means: [N, 3, 2] measured positions of landmarks A, B, C of each triplet (robot frame).
        sigma: noise std, scalar, [N] or [N, 3] (per landmark), isotropic.
        num_samples: S, samples per triplet.
        chunk_triplets: triplets per block (bounds the working set, with the streamed
            sample blocks; results do not depend on it).
        max_bytes: refuse (``ValueError``) a request whose estimated working set
            (:func:`working_set_bytes`) exceeds this; ``None`` disables the check.

    Returns:
        [N, Q] float32 probabilities; each row sums to 1, or is all zeros when no sample had a
        defined state (see docs/pqrm.md §measurement).

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
        state_counts(key, calculus, means, sigma, num_samples, chunk_triplets=chunk_triplets,
                     max_bytes=max_bytes))


def multi_state_probabilities(
    key: jax.Array, calculi_: Sequence[Calculus | str], means: jax.Array, sigma,
    num_samples: int, *, chunk_triplets: int = 4096,
    max_bytes: int | None = DEFAULT_MAX_BYTES,
) -> dict[str, jax.Array]:
    """``state_probabilities`` for several merges of one root calculus from one sampling pass.

    Args:
        key: PRNG key (one bank of draws shared by the rows).
        calculi_: the calculi (objects or registered names), all merges of one root calculus.
        means: [N, 3, 2] measured positions of landmarks A, B, C of each triplet.
        sigma: noise std, scalar, [N] or [N, 3].
        num_samples: S, samples per triplet.
        chunk_triplets: triplets per block (bounds the working set).

    Returns:
        A dict from calculus name to its [N, Q] float32 probabilities.

    Raises:
        ValueError: for calculi without a common root calculus, or bad input when eager.

    >>> import jax, jax.numpy as jnp
    >>> means = jnp.array([[[0., 0.], [0., 10.], [5., 4.]]])
    >>> ps = multi_state_probabilities(jax.random.key(0), ["edc", "lr"], means, 0.5, 500)
    >>> sorted(ps), ps["lr"].tolist()
    (['edc', 'lr'], [[0.0, 1.0]])
    """
    if isinstance(calculi_, str | Calculus):
        calculi_ = [calculi_]
    cals = [calculi.get(c) for c in calculi_]
    if not cals:
        raise ValueError("multi_state_probabilities needs at least one calculus")
    roots = {root_identity(c) for c in cals}
    if len(roots) != 1:
        raise ValueError("multi_state_probabilities needs calculi that share one root calculus")
    fine = fine_counts(key, cals[0], means, sigma, num_samples, chunk_triplets=chunk_triplets,
                       max_bytes=max_bytes)
    f = fine.astype(jnp.float32)
    return {c.name: counts_to_probabilities(f @ aggregation_matrix(c)) for c in cals}
