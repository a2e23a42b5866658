"""A cheap counter-based uniform stream for hot loops (an integer hash).

It is far faster to compile and run on CPU than threefry when a loop draws a few thousand
numbers per step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def mix32(x):
    """The hash's finaliser on uint32 arrays, NumPy or JAX (uint32 arithmetic wraps).

    An avalanche of xor-shifts and odd multiplies.
    """
    with np.errstate(over="ignore"):  # NumPy scalars warn on the wrap
        x = x ^ (x >> 16)
        x = x * np.uint32(0x7FEB352D)
        x = x ^ (x >> 15)
        x = x * np.uint32(0x846CA68B)
        return x ^ (x >> 16)


def to_unit(x):
    """uint32 hashes → float32 uniforms in [0, 1) (their top 24 bits)."""
    return (x >> 8).astype(np.float32) * np.float32(1.0 / (1 << 24))


def hash_uniform(seed: jax.Array, counter: jax.Array, n: int) -> jax.Array:
    """n float32 uniforms in [0, 1) (24-bit) from a uint32 ``seed`` and ``counter``."""
    x = seed ^ (counter * jnp.uint32(0x9E3779B9)) ^ (jnp.arange(n, dtype=jnp.uint32)
                                                     * jnp.uint32(0x85EBCA6B))
    return to_unit(mix32(x))


def hash_uniform_at(seed, *keys):
    """Uniforms in [0, 1) (float32, 24-bit) at integer coordinates ``keys`` (broadcast together).

    The value at a coordinate does not depend on what else is drawn, so a batched program and a
    one-at-a-time loop draw the same numbers. Works on NumPy and JAX arrays.
    """
    x = seed
    with np.errstate(over="ignore"):  # uint32 arithmetic wraps (NumPy scalars warn)
        for key, mult in zip(keys, _MULTS, strict=False):
            x = mix32(x ^ (key.astype(np.uint32) * mult))
    return to_unit(x)


_MULTS = tuple(np.uint32(m) for m in (0x9E3779B9, 0x85EBCA6B, 0xC2B2AE35, 0x27D4EB2F,
                                      0x165667B1))
