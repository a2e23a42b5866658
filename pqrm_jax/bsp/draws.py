"""The planner's random draws: ``jax.random``'s threefry bits as one fused expression.

A plan draws four uniforms per tree branch from keys derived by ``fold_in`` and ``split``
(:func:`~pqrm_jax.bsp.planner.plan`). ``jax.random`` lowers each threefry-2x32 hash on CPU
as a rolled loop (an XLA ``while`` of five steps), one loop per derivation: in a batched plan
those loops took about a sixth of the time (docs/bsp.md §benchmark). Here the hash is
unrolled (20 rounds of add, rotate, xor on uint32 words) so that XLA fuses a branch's eleven
hashes into elementwise code. The bits are ``jax.random``'s for threefry keys with
``jax_threefry_partitionable`` (JAX's default): :func:`fold_in`, :func:`split` and
:func:`uniform` equal ``jax.random.fold_in``, ``jax.random.split(key, n)[i]`` and
``jax.random.uniform(key)`` bit for bit (``tests/test_bsp_planner.py``), so plans keep their
draws.

Keys here are their two uint32 words, ``[..., 2]`` (:func:`key_words`).

>>> import jax
>>> k = jax.random.key(3)
>>> w = key_words(k)
>>> bool(uniform(fold_in(w, 7)) == jax.random.uniform(jax.random.fold_in(k, 7)))
True
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def key_words(key: jax.Array) -> jax.Array:
    """[..., 2] uint32 words of threefry keys (typed ``jax.random.key`` or raw uint32 data).

    Raises:
        ValueError: naming ``key`` for a typed key of another PRNG implementation.
    """
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        impl = str(jax.random.key_impl(key))
        if "threefry2x32" not in impl:
            raise ValueError(f"key: the planner's draws need threefry2x32 keys, got {impl}")
        return jax.random.key_data(key)
    if key.dtype != jnp.uint32 or key.shape[-1:] != (2,):
        raise ValueError(f"key: expected a PRNG key or [..., 2] uint32 words, got {key.dtype} "
                         f"{key.shape}")
    return key


def threefry2x32(k0, k1, x0, x1) -> tuple[jax.Array, jax.Array]:
    """The Threefry-2x32 hash (20 rounds) of the counter words ``(x0, x1)`` under the key
    words ``(k0, k1)``, unrolled; all uint32, broadcast together."""
    ks = (k0, k1, k0 ^ k1 ^ np.uint32(0x1BD11BDA))
    x0, x1 = x0 + ks[0], x1 + ks[1]
    for r in range(5):
        for s in _ROTATIONS[r % 2]:
            x0 = x0 + x1
            x1 = (x1 << np.uint32(s)) | (x1 >> np.uint32(32 - s))
            x1 = x0 ^ x1
        x0 = x0 + ks[(r + 1) % 3]
        x1 = x1 + ks[(r + 2) % 3] + np.uint32(r + 1)
    return x0, x1


def _hash(words, count) -> jax.Array:
    """The key words hashed with the counter ``(0, count)``: [..., 2]."""
    c = jnp.asarray(count, jnp.uint32)
    y0, y1 = threefry2x32(words[..., 0], words[..., 1], jnp.zeros_like(c), c)
    return jnp.stack([y0, y1], -1)


def fold_in(words, data) -> jax.Array:
    """``jax.random.fold_in`` on key words [..., 2] with int ``data`` (broadcast)."""
    return _hash(words, data)


def split(words, i) -> jax.Array:
    """``jax.random.split(key, n)[i]`` on key words [..., 2] (any ``n > i``)."""
    return _hash(words, i)


def uniform(words) -> jax.Array:
    """``jax.random.uniform(key)`` (float32 in [0, 1)) on key words [..., 2]."""
    y = _hash(words, 0)
    bits = y[..., 0] ^ y[..., 1]
    one = np.array(1.0, np.float32).view(np.uint32)
    return jax.lax.bitcast_convert_type((bits >> np.uint32(9)) | one, jnp.float32) - 1.0
