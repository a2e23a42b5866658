"""Input checks shared by the simulator modules (docs/decisions.md §9).

Shape checks always run (shapes are static, also under ``jit``/``vmap``). Value checks
(NaN/inf, negative parameters) run only when the inputs are concrete arrays, i.e. when a
public function is called eagerly; inside ``jit`` or ``vmap`` values are tracers and are not
inspected, so bad values there propagate (NaN in, NaN out) instead of raising.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def is_concrete(x: Any) -> bool:
    """True when no leaf of ``x`` is a JAX tracer (so its values can be inspected)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def as_float(x: Any) -> jax.Array:
    """``x`` as a JAX array of the default float dtype (float32, or float64 under x64).

    Floating inputs keep their dtype (subject to the x64 setting); integer/bool inputs are
    promoted to the default float dtype.
    """
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def check_shape(name: str, x: Any, ndim: int, last: int | None = None) -> None:
    """Raise ``ValueError`` unless ``x`` has ``ndim`` dimensions and last axis ``last``."""
    shape = np.shape(x)
    if len(shape) != ndim or (last is not None and shape[-1] != last):
        want = {1: f"({last},)" if last is not None else "(N,)",
                2: f"(N, {last})" if last is not None else "(N, M)"}.get(ndim, f"{ndim}-d")
        raise ValueError(f"{name} must have shape {want}, got {tuple(shape)}")


def check_finite(name: str, x: Any) -> None:
    """Raise ``ValueError`` if a concrete ``x`` contains NaN or inf."""
    if is_concrete(x) and not np.all(np.isfinite(np.asarray(x))):
        raise ValueError(f"{name} contains NaN or inf values")


def check_nonneg(name: str, x: Any) -> None:
    """Raise ``ValueError`` if a concrete ``x`` is negative or NaN."""
    if is_concrete(x):
        a = np.asarray(x)
        if np.any(np.isnan(a)):
            raise ValueError(f"{name} must be a non-negative number, got NaN")
        if np.any(a < 0):
            raise ValueError(f"{name} must be non-negative, got {a.tolist()}")


def check_positive(name: str, x: Any) -> None:
    """Raise ``ValueError`` if a concrete ``x`` is not strictly positive."""
    if is_concrete(x):
        a = np.asarray(x)
        if not np.all(a > 0):  # also catches NaN
            raise ValueError(f"{name} must be positive, got {a.tolist()}")


def check_count(name: str, n: Any, minimum: int = 0) -> int:
    """Return ``n`` as a Python int, raising ``ValueError`` if it is not an int >= minimum."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise ValueError(f"{name} must be a Python int (a static size), got {n!r}")
    if n < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {n}")
    return int(n)


def wrap_angle(a: jax.Array) -> jax.Array:
    """Wrap angles to ``[-pi, pi)``.

    Args:
        a: angles (radians), any shape.

    Returns:
        The wrapped angles, same shape.
    """
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi
