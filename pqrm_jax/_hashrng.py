"""A cheap counter-based uniform stream for hot loops (an integer hash; far faster to compile
and run on CPU than threefry when a loop draws a few thousand numbers per step)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def hash_uniform(seed: jax.Array, counter: jax.Array, n: int) -> jax.Array:
    """n float32 uniforms in [0, 1) (24-bit) from a uint32 ``seed`` and ``counter``."""
    x = seed ^ (counter * jnp.uint32(0x9E3779B9)) ^ (jnp.arange(n, dtype=jnp.uint32)
                                                     * jnp.uint32(0x85EBCA6B))
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    x = x ^ (x >> 16)
    return (x >> 8).astype(jnp.float32) * (1.0 / (1 << 24))


def hash_uniform_at(seed, *keys):
    """Uniforms in [0, 1) (float32, 24-bit) at integer coordinates ``keys`` (broadcast
    together): the value at a coordinate does not depend on what else is drawn, so a batched
    program and a one-at-a-time loop draw the same numbers. Works on NumPy and JAX arrays."""
    x = seed
    with np.errstate(over="ignore"):  # uint32 arithmetic wraps (NumPy scalars warn)
        for key, mult in zip(keys, _MULTS, strict=False):
            x = x ^ (key.astype(np.uint32) * mult)
            x = x ^ (x >> 16)
            x = x * np.uint32(0x7FEB352D)
            x = x ^ (x >> 15)
            x = x * np.uint32(0x846CA68B)
            x = x ^ (x >> 16)
    return (x >> 8).astype(np.float32) * np.float32(1.0 / (1 << 24))


_MULTS = tuple(np.uint32(m) for m in (0x9E3779B9, 0x85EBCA6B, 0xC2B2AE35, 0x27D4EB2F,
                                      0x165667B1))
