"""Landmark worlds for the rover simulator (docs/decisions.md §9).

Every generator is a pure function of an explicit PRNG key and static sizes, returns an
``[n, 2]`` float array of landmark centres (metres, world frame) and can be ``vmap``-ed over
keys to draw a batch of worlds::

    keys = jax.random.split(jax.random.key(0), 1000)
    worlds = jax.vmap(lambda k: uniform_landmarks(k, 30))(keys)   # (1000, 30, 2)

Padgett's Monte Carlo setup (P §2.3.1) draws landmarks uniformly over a 100 m x 100 m square:
``uniform_landmarks(key, n)`` with the default ``size``.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.sim._validate import check_count, check_nonneg, check_positive

__all__ = [
    "uniform_landmarks",
    "clustered_landmarks",
    "hallway_landmarks",
    "corridor_grid_landmarks",
]

Size = Sequence[float] | jax.Array


def _float() -> jnp.dtype:
    return jnp.result_type(float)


def _check_size(size: Size) -> None:
    if np.shape(size) != (2,):
        raise ValueError(f"size must be a pair (width, height), got shape {np.shape(size)}")
    check_positive("size", size)


@partial(jax.jit, static_argnames="n")
def _uniform(key, n, size):
    u = jax.random.uniform(key, (n, 2), dtype=_float())
    return u * jnp.asarray(size, _float())


def uniform_landmarks(key: jax.Array, n: int, size: Size = (100.0, 100.0)) -> jax.Array:
    """``n`` landmarks uniform over the box ``[0, size[0]] x [0, size[1]]``.

    Args:
        key: PRNG key.
        n: number of landmarks.
        size: box side lengths (metres).

    Returns:
        [n, 2] landmark positions.

    Raises:
        ValueError: for a negative or non-integer ``n`` or a bad ``size``.

    >>> lm = uniform_landmarks(jax.random.key(0), 30)
    >>> lm.shape, bool((lm >= 0).all() & (lm <= 100).all())
    ((30, 2), True)
    """
    n = check_count("n", n)
    _check_size(size)
    return _uniform(key, n, size)


@partial(jax.jit, static_argnames=("n", "n_clusters"))
def _clustered(key, n, n_clusters, size, spread):
    k_c, k_a, k_o = jax.random.split(key, 3)
    size = jnp.asarray(size, _float())
    centres = jax.random.uniform(k_c, (n_clusters, 2), dtype=_float()) * size
    which = jax.random.randint(k_a, (n,), 0, n_clusters)
    offsets = jax.random.normal(k_o, (n, 2), dtype=_float()) * spread
    return jnp.clip(centres[which] + offsets, 0.0, size)


def clustered_landmarks(
    key: jax.Array,
    n: int,
    n_clusters: int,
    size: Size = (100.0, 100.0),
    spread: float = 5.0,
) -> jax.Array:
    """``n`` landmarks in ``n_clusters`` Gaussian clusters (std ``spread``) inside the box.

    Cluster centres are uniform over the box, each landmark picks a cluster uniformly at
    random, and positions are clipped to the box.

    Args:
        key: PRNG key.
        n: number of landmarks.
        n_clusters: number of clusters (at least 1).
        size: box side lengths (metres).
        spread: standard deviation of each cluster (metres, non-negative).

    Returns:
        [n, 2] landmark positions.

    Raises:
        ValueError: for bad counts, a bad ``size`` or a negative ``spread``.

    >>> lm = clustered_landmarks(jax.random.key(0), 40, n_clusters=4, spread=3.0)
    >>> lm.shape
    (40, 2)
    """
    n = check_count("n", n)
    n_clusters = check_count("n_clusters", n_clusters, minimum=1)
    _check_size(size)
    check_nonneg("spread", spread)
    return _clustered(key, n, n_clusters, size, spread)


@partial(jax.jit, static_argnames="n")
def _hallway(key, n, length, width, jitter, origin):
    k_x, k_j = jax.random.split(key)
    x = jax.random.uniform(k_x, (n,), dtype=_float()) * length
    side = jnp.where(jnp.arange(n) % 2 == 0, 0.5, -0.5).astype(_float())
    pts = jnp.stack([x, side * width], axis=-1)
    pts = pts + jitter * jax.random.normal(k_j, (n, 2), dtype=_float())
    return pts + jnp.asarray(origin, _float())


def hallway_landmarks(
    key: jax.Array,
    n: int,
    length: float = 100.0,
    width: float = 4.0,
    jitter: float = 0.1,
    origin: Sequence[float] = (0.0, 0.0),
) -> jax.Array:
    """``n`` landmarks on the two walls of a straight hallway along the x axis.

    The hallway runs from ``origin`` to ``origin + (length, 0)``; its walls are the lines
    ``y = origin[1] +- width / 2``. Even-indexed landmarks lie on the left wall (+y), odd ones
    on the right wall, at x positions uniform along the hallway, each displaced by isotropic
    Gaussian noise of std ``jitter``.

    Args:
        key: PRNG key.
        n: number of landmarks.
        length, width: the hallway's size (world units).
        jitter: std of the isotropic displacement.
        origin: ``(x, y)`` of the hallway's start.

    Returns:
        ``[n, 2]`` float32 positions.

    >>> lm = hallway_landmarks(jax.random.key(0), 200, length=20.0, width=2.0, jitter=0.0)
    >>> sorted(set(lm[:, 1].tolist()))
    [-1.0, 1.0]
    """
    n = check_count("n", n)
    check_positive("length", length)
    check_nonneg("width", width)
    check_nonneg("jitter", jitter)
    return _hallway(key, n, length, width, jitter, origin)


def _corridor_template(n_x: int, n_y: int, spacing: float, width: float, per_side: int):
    """Noise-free landmark template of a corridor grid (plain NumPy, static)."""
    frac = (np.arange(per_side) + 0.5) / per_side
    # Keep landmarks clear of the intersections: spread over the block edge between corridors.
    along = width / 2 + frac * (spacing - width)
    pts = []
    for j in range(n_y + 1):  # horizontal corridors y = j * spacing
        for i in range(n_x):
            for s in (-0.5, 0.5):
                wall = np.full(per_side, j * spacing + s * width)
                pts.append(np.stack([i * spacing + along, wall], -1))
    for i in range(n_x + 1):  # vertical corridors x = i * spacing
        for j in range(n_y):
            for s in (-0.5, 0.5):
                wall = np.full(per_side, i * spacing + s * width)
                pts.append(np.stack([wall, j * spacing + along], -1))
    return np.concatenate(pts, axis=0)


def corridor_grid_landmarks(
    key: jax.Array,
    n_x: int = 3,
    n_y: int = 3,
    spacing: float = 20.0,
    width: float = 4.0,
    per_side: int = 3,
    jitter: float = 0.1,
) -> jax.Array:
    """Landmarks lining the walls of a grid of corridors (a city-block / office layout).

    Corridors of the given ``width`` run along the lines ``x = i * spacing`` (``i = 0..n_x``)
    and ``y = j * spacing`` (``j = 0..n_y``). Each corridor segment between two intersections
    gets ``per_side`` evenly spaced landmarks on each of its two walls, displaced by Gaussian
    noise of std ``jitter``. The number of landmarks is
    ``2 * per_side * (n_x * (n_y + 1) + n_y * (n_x + 1))``.

    Args:
        key: PRNG key.
        n_x, n_y: corridors along y and along x (``n_x + 1`` and ``n_y + 1`` lines).
        spacing: distance between parallel corridors.
        width: corridor width.
        per_side: landmarks per wall of each segment.
        jitter: std of the isotropic displacement.

    Returns:
        ``[2·per_side·(n_x(n_y + 1) + n_y(n_x + 1)), 2]`` float32 positions.

    >>> corridor_grid_landmarks(jax.random.key(0), n_x=2, n_y=1, per_side=2).shape
    (28, 2)
    """
    n_x = check_count("n_x", n_x, minimum=1)
    n_y = check_count("n_y", n_y, minimum=1)
    per_side = check_count("per_side", per_side, minimum=1)
    check_positive("spacing", spacing)
    check_nonneg("width", width)
    check_nonneg("jitter", jitter)
    if float(width) >= float(spacing):  # geometry is static: spacing/width must be concrete
        raise ValueError(f"width ({width}) must be smaller than spacing ({spacing})")
    template = jnp.asarray(_corridor_template(n_x, n_y, float(spacing), float(width), per_side),
                           _float())
    return template + jitter * jax.random.normal(key, template.shape, dtype=_float())
