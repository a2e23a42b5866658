"""Lidar ray casting into an occupancy grid (docs/decisions.md §9).

A 2D occupancy grid is a boolean array ``grid[i, j]`` (row ``i`` along y, column ``j`` along
x); cell ``(i, j)`` covers ``[x0 + j r, x0 + (j + 1) r) x [y0 + i r, y0 + (i + 1) r)`` for
``origin = (x0, y0)`` and resolution ``r``. Cells outside the grid are free.

:func:`lidar_scan` casts ``n_beams`` beams evenly over the field of view by marching along
each beam in steps of ``resolution / oversample`` (static shapes, no loops over beams): the
returned range is the first sample inside an occupied cell, so it is within one march step of
the exact distance to the cell boundary. :func:`rasterize_discs` turns landmarks of a given
radius into such a grid (e.g. to give :mod:`sim.world` worlds a lidar view).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from pqrm_jax.sim._validate import (
    as_float,
    check_count,
    check_finite,
    check_nonneg,
    check_positive,
    check_shape,
)

__all__ = ["LidarParams", "LidarScan", "lidar_scan", "rasterize_discs"]


class LidarParams(NamedTuple):
    """Lidar parameters. ``n_beams`` is static; the others may be traced.

    Attributes:
        n_beams: number of beams, spread evenly over ``fov`` (centred on the heading; for
            ``fov >= 2 pi`` they cover the full circle without repeating the first beam).
        max_range: beams that hit nothing report ``max_range``.
        fov: field of view in radians.
        sigma: std of Gaussian noise added to the ranges of beams that hit (then clipped at 0).
    """

    n_beams: int = 180
    max_range: float = 30.0
    fov: float = 2 * math.pi
    sigma: float = 0.0


class LidarScan(NamedTuple):
    """Result of :func:`lidar_scan`.

    ``angles`` [B] beam angles in the robot frame, ``ranges`` [B] measured ranges, ``hit`` [B]
    bool, True where the beam hit an occupied cell within ``max_range``.
    """

    angles: jax.Array
    ranges: jax.Array
    hit: jax.Array


@partial(jax.jit, static_argnames=("n_beams", "n_samples"))
def _scan(key, pose, grid, resolution, origin, n_beams, n_samples, max_range, fov, sigma):
    dtype = pose.dtype
    full = fov >= 2 * jnp.pi
    k = jnp.arange(n_beams, dtype=dtype)
    spacing = jnp.where(full, 2 * jnp.pi / n_beams, fov / jnp.maximum(n_beams - 1, 1))
    start = jnp.where(full, -jnp.pi, jnp.where(n_beams > 1, -0.5 * fov, 0.0))
    angles = start + spacing * k
    step = max_range / n_samples
    s = step * jnp.arange(1, n_samples + 1, dtype=dtype)
    world = pose[2] + angles
    px = pose[0] + s[None, :] * jnp.cos(world)[:, None]
    py = pose[1] + s[None, :] * jnp.sin(world)[:, None]
    j = jnp.floor((px - origin[0]) / resolution).astype(jnp.int32)
    i = jnp.floor((py - origin[1]) / resolution).astype(jnp.int32)
    inside = (i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])
    occ = inside & grid[jnp.clip(i, 0, grid.shape[0] - 1), jnp.clip(j, 0, grid.shape[1] - 1)]
    hit = occ.any(axis=1)
    first = jnp.argmax(occ, axis=1)
    ranges = jnp.where(hit, s[first], max_range)
    noise = sigma * jax.random.normal(key, ranges.shape, dtype=dtype)
    ranges = jnp.where(hit, jnp.maximum(ranges + noise, 0.0), ranges)
    return LidarScan(angles, ranges, hit)


def lidar_scan(
    key: jax.Array,
    pose: jax.Array,
    grid: jax.Array,
    resolution: float,
    origin: Sequence[float] = (0.0, 0.0),
    params: LidarParams | None = None,
    oversample: int = 4,
) -> LidarScan:
    """Cast ``params.n_beams`` beams from ``pose`` into the occupancy ``grid``.

    Args:
        key: PRNG key of the range noise.
        pose: ``[3]`` sensor pose ``(x, y, theta)``.
        grid: [rows, cols] bool occupancy grid (rows along y, columns along x).
        resolution: cell size (positive).
        origin: world position of the grid's corner ``(x, y)``.
        params: lidar parameters; ``params.max_range`` must be concrete (it fixes the number of
            march samples, ``ceil(oversample * max_range / resolution)``).
        oversample: march samples per cell (at least 1).

    Returns:
        A :class:`LidarScan` (beam angles, ranges, hits).

    Raises:
        ValueError: for a bad pose, grid, origin, resolution or parameters.

    >>> grid = jnp.zeros((10, 10), bool).at[:, 7].set(True)     # a wall at x in [7, 8)
    >>> scan = lidar_scan(jax.random.key(0), jnp.array([2.0, 5.0, 0.0]), grid, 1.0,
    ...                   params=LidarParams(n_beams=4, max_range=20.0))
    >>> [round(math.degrees(a)) for a in scan.angles.tolist()]
    [-180, -90, 0, 90]
    >>> scan.ranges.tolist(), scan.hit.tolist()
    ([20.0, 20.0, 5.0, 20.0], [False, False, True, False])
    """
    params = LidarParams() if params is None else params
    pose, grid = as_float(pose), jnp.asarray(grid)
    check_shape("pose", pose, 1, 3)
    check_finite("pose", pose)
    if grid.ndim != 2:
        raise ValueError(f"grid must be a 2-D occupancy array, got shape {grid.shape}")
    origin = as_float(origin)
    check_shape("origin", origin, 1, 2)
    check_finite("origin", origin)
    check_positive("resolution", resolution)
    n_beams = check_count("LidarParams.n_beams", params.n_beams, minimum=1)
    oversample = check_count("oversample", oversample, minimum=1)
    check_positive("LidarParams.max_range", params.max_range)
    check_nonneg("LidarParams.fov", params.fov)
    check_nonneg("LidarParams.sigma", params.sigma)
    n_samples = max(1, math.ceil(oversample * float(params.max_range) / float(resolution)))
    dtype = pose.dtype
    return _scan(key, pose, grid.astype(bool), jnp.asarray(resolution, dtype),
                 origin.astype(dtype), n_beams, n_samples,
                 jnp.asarray(params.max_range, dtype), jnp.asarray(params.fov, dtype),
                 jnp.asarray(params.sigma, dtype))


@partial(jax.jit, static_argnames="shape")
def _raster(landmarks, radius, shape, resolution, origin):
    ys = origin[1] + (jnp.arange(shape[0], dtype=landmarks.dtype) + 0.5) * resolution
    xs = origin[0] + (jnp.arange(shape[1], dtype=landmarks.dtype) + 0.5) * resolution
    dx = xs[None, None, :] - landmarks[:, 0, None, None]
    dy = ys[None, :, None] - landmarks[:, 1, None, None]
    return jnp.any(dx**2 + dy**2 <= radius**2, axis=0)


def rasterize_discs(
    landmarks: jax.Array,
    radius: float,
    shape: tuple[int, int],
    resolution: float,
    origin: Sequence[float] = (0.0, 0.0),
) -> jax.Array:
    """Occupancy grid of ``shape`` (rows along y, columns along x) from disc landmarks.

    A cell is occupied when its centre lies within ``radius`` of a landmark centre.

    Args:
        landmarks: [N, 2] disc centres.
        radius: disc radius (non-negative).
        shape: ``(rows, cols)`` of the grid.
        resolution: cell size (positive).
        origin: world position of the grid's corner ``(x, y)``.

    Returns:
        [rows, cols] bool occupancy grid.

    Raises:
        ValueError: for bad landmarks, radius, resolution or shape.

    >>> g = rasterize_discs(jnp.array([[2.5, 1.5]]), 0.6, (3, 4), 1.0)
    >>> g.astype(int).tolist()
    [[0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 0]]
    """
    landmarks = as_float(landmarks)
    check_shape("landmarks", landmarks, 2, 2)
    check_finite("landmarks", landmarks)
    check_nonneg("radius", radius)
    check_positive("resolution", resolution)
    if len(shape) != 2 or not all(isinstance(s, int) and s >= 1 for s in shape):
        raise ValueError(f"shape must be a pair of positive ints (rows, cols), got {shape}")
    shape = (int(shape[0]), int(shape[1]))
    return _raster(landmarks, radius, shape, resolution, as_float(origin).astype(landmarks.dtype))
