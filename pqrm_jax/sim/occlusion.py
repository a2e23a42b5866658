"""Partial occlusion by disc-shaped landmarks, and wall segments as extended landmarks.

Padgett's occlusion trials (P §4.4.1): "a landmark, L_A, is only recognized if no portions of
another landmark, L_B, occlude or partially occlude L_A". Landmarks are discs of radius ``r``
(the study's "size" is the diameter). Seen from the robot at p, the disc of landmark k at
distance ``d_k`` covers the bearings within ``asin(r / d_k)`` of its centre bearing. Target t is
hidden when a strictly nearer landmark k has an angular separation (between the bearings of t
and k) smaller than ``asin(r / d_t) + asin(r / d_k)``: the two silhouettes overlap. With
``r = 0`` nothing is hidden. This is stricter than :func:`pqrm_jax.sim.visibility`'s
centre-ray rule, which hides t only when the ray to t's centre crosses k's disc.

A landmark within ``r`` of the robot subtends the whole half-plane (``asin`` clipped at 1).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["disc_visibility", "target_visibility", "occluder_table", "local_target_visibility",
           "segment_distance", "segment_visibility"]


def _half_width(d, r):
    ratio = jnp.where(d > r, r / jnp.maximum(d, 1e-30), 1.0)
    return jnp.arcsin(jnp.clip(ratio, 0.0, 1.0))


def target_visibility(pos: jax.Array, landmarks: jax.Array, targets: jax.Array,
                      max_range, radius) -> jax.Array:
    """Visibility ``[K]`` of the landmarks ``targets`` from ``pos`` (range + partial occlusion).

    Args:
        pos: ``[2]`` sensor position.
        landmarks: ``[N, 2]`` all landmark centres (every one may occlude).
        targets: ``[K]`` int indices of the landmarks to test (``-1`` = padding, never visible).
        max_range: sensing range (a centre at distance ``<= max_range`` is in range).
        radius: disc radius of every landmark (0 disables occlusion).

    Returns:
        ``[K]`` bool.

    >>> lm = jnp.array([[10., 0.], [5., 0.2], [0., 8.]])
    >>> target_visibility(jnp.zeros(2), lm, jnp.array([0, 2, -1]), 20.0, 0.3).tolist()
    [False, True, False]
    >>> target_visibility(jnp.zeros(2), lm, jnp.array([0, 2, -1]), 20.0, 0.0).tolist()
    [True, True, False]
    """
    rel = landmarks - pos
    d = jnp.linalg.norm(rel, axis=-1)                       # [N]
    t = jnp.maximum(targets, 0)
    rt, dt = rel[t], d[t]                                   # [K, 2], [K]
    cross = rt[:, None, 0] * rel[None, :, 1] - rt[:, None, 1] * rel[None, :, 0]
    dot = rt[:, None, 0] * rel[None, :, 0] + rt[:, None, 1] * rel[None, :, 1]
    sep = jnp.arctan2(jnp.abs(cross), dot)                  # [K, N]
    overlap = sep < _half_width(dt, radius)[:, None] + _half_width(d, radius)[None, :]
    nearer = d[None, :] < dt[:, None]
    hidden = jnp.any(overlap & nearer & (radius > 0), axis=1)
    return (targets >= 0) & (dt <= max_range) & ~hidden


def occluder_table(landmarks, max_range: float, radius: float | None = None) -> np.ndarray:
    """``[N, M]`` for every landmark the ids of the others that can ever hide it (``-1`` padded).

    A hidden target t is in range (``d_t ≤ max_range``) and its occluder k is strictly nearer
    (``d_k < d_t``), so ``|k − t| < d_k + d_t < 2·max_range``. With the disc ``radius`` r known
    the bound is tighter: if the bearings of t and k differ by θ ≤ 60° then
    ``|k − t|² = d_k² + d_t² − 2 d_k d_t cos θ ≤ d_t²``; a larger θ needs
    ``asin(r/d_t) + asin(r/d_k) > 60°``, so ``d_k < 2r`` (``|k − t| < max_range + 2r``) or
    ``d_t < 2r`` (``|k − t| < 4r``). The landmarks within that reach of t (1e-5 relative margin)
    are the only candidates, and :func:`local_target_visibility` over this table equals
    :func:`target_visibility` over all landmarks. Built on the host (``O(N²)``); ``M`` is
    padded to a multiple of 8 so that nearby settings share one compiled width.

    Args:
        landmarks: ``[N, 2]``.
        max_range: the sensing range.
        radius: the disc radius (``None``: the looser ``2·max_range`` bound).

    Returns:
        ``[N, M]`` int32 occluder ids, ``-1`` padded.

    >>> lm = np.array([[0., 0.], [3., 0.], [10., 0.]])
    >>> tab = occluder_table(lm, 2.0)
    >>> tab.shape, tab[:, :2].tolist()
    ((3, 8), [[1, -1], [0, -1], [-1, -1]])
    >>> occluder_table(lm, 2.0, radius=0.1)[:, 0].tolist()     # reach 2.2 < 3
    [-1, -1, -1]
    """
    lm = np.asarray(landmarks, np.float64)
    if lm.ndim != 2 or lm.shape[-1] != 2:
        raise ValueError(f"landmarks must be [N, 2], got shape {lm.shape}")
    if not (np.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be positive and finite, got {max_range}")
    if radius is not None and not (np.isfinite(radius) and radius >= 0):
        raise ValueError(f"radius must be non-negative and finite, got {radius}")
    reach = 2.0 * max_range if radius is None else min(2.0 * max_range,
                                                       max(max_range + 2 * radius, 4 * radius))
    d = np.linalg.norm(lm[:, None] - lm[None], axis=-1)
    near = (d <= reach * (1 + 1e-5)) & ~np.eye(len(lm), dtype=bool)
    width = max(8, -(-int(near.sum(1).max(initial=0)) // 8) * 8)
    out = np.full((len(lm), width), -1, np.int32)
    for i, row in enumerate(near):
        ids = np.flatnonzero(row)
        out[i, :len(ids)] = ids
    return out


def local_target_visibility(pos: jax.Array, landmarks: jax.Array, targets: jax.Array,
                            occluders: jax.Array, max_range, radius) -> jax.Array:
    """:func:`target_visibility` with the candidate occluders of each target given.

    Args:
        pos: ``[2]`` sensor position. landmarks: ``[N, 2]``.
        targets: ``[K]`` landmark ids (``-1`` = padding, never visible).
        occluders: ``[K, M]`` the ids that may hide each target (``-1`` padded), e.g. the rows
            of :func:`occluder_table` for ``targets``; exact when they hold every landmark
            that can hide the target (see there). Cost ``K·M`` instead of ``K·N``.
        max_range: sensing range. radius: disc radius of every landmark (0 = no occlusion).

    Returns:
        ``[K]`` bool.

    >>> lm = jnp.array([[10., 0.], [5., 0.2], [0., 8.]])
    >>> occ = jnp.asarray(occluder_table(lm, 20.0))
    >>> t = jnp.array([0, 2, -1])
    >>> local_target_visibility(jnp.zeros(2), lm, t, occ[jnp.maximum(t, 0)], 20.0, 0.3).tolist()
    [False, True, False]
    """
    t = jnp.maximum(targets, 0)
    rt = landmarks[t] - pos                                 # [K, 2]
    dt = jnp.linalg.norm(rt, axis=-1)                       # [K]
    valid = occluders >= 0
    rel = landmarks[jnp.maximum(occluders, 0)] - pos        # [K, M, 2]
    d = jnp.linalg.norm(rel, axis=-1)                       # [K, M]
    cross = rt[:, None, 0] * rel[..., 1] - rt[:, None, 1] * rel[..., 0]
    dot = rt[:, None, 0] * rel[..., 0] + rt[:, None, 1] * rel[..., 1]
    sep = jnp.arctan2(jnp.abs(cross), dot)
    overlap = sep < _half_width(dt, radius)[:, None] + _half_width(d, radius)
    nearer = d < dt[:, None]
    hidden = jnp.any(overlap & nearer & valid & (radius > 0), axis=1)
    return (targets >= 0) & (dt <= max_range) & ~hidden


def disc_visibility(pos: jax.Array, landmarks: jax.Array, max_range, radius) -> jax.Array:
    """Visibility ``[N]`` of every landmark from ``pos`` under the partial-disc rule.

    Landmarks are discs of ``radius``; one is hidden when nearer discs cover its whole
    angular extent (P §4.4.1).

    Args:
        pos: ``[2]`` the observer.
        landmarks: ``[N, 2]``.
        max_range: the sensing range.
        radius: the landmark disc radius.

    Returns:
        ``[N]`` bool.

    >>> lm = jnp.array([[10., 0.], [5., 0.2], [0., 30.]])
    >>> disc_visibility(jnp.zeros(2), lm, 20.0, 0.3).tolist()
    [False, True, False]
    """
    return target_visibility(pos, landmarks, jnp.arange(landmarks.shape[0]), max_range, radius)


def segment_distance(pos: jax.Array, segments: jax.Array) -> jax.Array:
    """Euclidean distance ``[S]`` from ``pos`` to each wall segment ``segments [S, 2, 2]``.

    Args:
        pos: ``[2]``.
        segments: ``[S, 2, 2]`` end points.

    Returns:
        ``[S]``.

    >>> segment_distance(jnp.array([1., 2.]), jnp.array([[[0., 0.], [4., 0.]]])).tolist()
    [2.0]
    """
    a, b = segments[:, 0], segments[:, 1]
    ab = b - a
    t = jnp.clip(jnp.sum((pos - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-30), 0, 1)
    return jnp.linalg.norm(a + t[:, None] * ab - pos, axis=-1)


def segment_visibility(pos: jax.Array, segments: jax.Array, max_range) -> jax.Array:
    """An extended (wall) landmark ``[S, 2, 2]`` is seen when any of its points is in range.

    Walls of P §4.4.1 are never occluded.

    Args:
        pos: ``[2]``.
        segments: ``[S, 2, 2]`` end points.
        max_range: the sensing range.

    Returns:
        ``[S]`` bool.

    >>> segment_visibility(jnp.array([1., 2.]), jnp.array([[[0., 0.], [4., 0.]]]), 1.5).tolist()
    [False]
    """
    return segment_distance(pos, segments) <= max_range


target_visibility = jax.jit(target_visibility)
