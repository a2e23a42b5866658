"""Landmark sensors for the rover simulator (docs/decisions.md §9).

Offers two measurement models over a fixed-size landmark array with boolean masks: noisy
relative landmark positions (the range sensor of P §2.3.1) and the camera measurement of
M §IV (bearings plus range ordering). Shapes are always checked; values are checked when
concrete.

Visibility, occlusion and the handling of bad input: docs/sim.md §sensors.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.sim._validate import as_float, check_finite, check_nonneg, check_shape

__all__ = ["SensorParams", "Observation", "CameraObservation", "observe", "camera",
           "relative_positions", "visibility"]


class _SensorParamsFields(NamedTuple):
    max_range: float = 60.0
    fov: float = 2 * jnp.pi
    landmark_radius: float = 0.0
    sigma: float = 0.0


FINITE_SENSOR_FIELDS = ("landmark_radius", "sigma")  # max_range, fov may be inf (unbounded)


class SensorParams(_SensorParamsFields):
    """Sensor parameters (a pytree; fields may be traced).

    max_range: detection range in metres (Padgett's study uses 60 m); ``inf`` = unbounded.
    fov: field of view in radians, centred on the heading; ``>= 2*pi`` is omnidirectional.
    landmark_radius: physical radius of a landmark, used for occlusion (0 disables occlusion).
    sigma: std of isotropic Gaussian noise added to each relative position (metres).

    Plain numbers are checked when the tuple is built: NaN anywhere, a negative value, or an
    infinite ``sigma``/``landmark_radius`` raises ``ValueError`` (an infinite σ would make
    :func:`observe` return ±inf positions). Arrays are checked by :func:`observe`.

    >>> SensorParams(sigma=float("inf"))
    Traceback (most recent call last):
    ...
    ValueError: SensorParams.sigma must be finite, got inf
    """

    __slots__ = ()

    def __new__(cls, max_range=60.0, fov=2 * jnp.pi, landmark_radius=0.0, sigma=0.0):
        for name, v in (("max_range", max_range), ("fov", fov),
                        ("landmark_radius", landmark_radius), ("sigma", sigma)):
            if isinstance(v, (int, float, np.number)) and not isinstance(v, bool):
                _check_param(name, v)
        return super().__new__(cls, max_range, fov, landmark_radius, sigma)


def _check_param(name: str, v) -> None:
    a = np.asarray(v, dtype=float)
    if np.any(np.isnan(a)):
        raise ValueError(f"SensorParams.{name} must be a non-negative number, got NaN")
    if np.any(a < 0):
        raise ValueError(f"SensorParams.{name} must be non-negative, got {a.tolist()}")
    if name in FINITE_SENSOR_FIELDS and not np.all(np.isfinite(a)):
        raise ValueError(f"SensorParams.{name} must be finite, got {a.tolist()}")


class Observation(NamedTuple):
    """Result of :func:`observe`.

    Attributes:
        rel: [N, 2] noisy landmark positions in the robot frame (noise is drawn for every landmark;
            entries of invisible landmarks are meaningless, use ``visible``).
        true_rel: [N, 2] noise-free positions in the robot frame.
        visible: [N] bool, in range and field of view and not occluded.
    """

    rel: jax.Array
    true_rel: jax.Array
    visible: jax.Array


class CameraObservation(NamedTuple):
    """Result of :func:`camera`.

    Attributes:
        bearings: [N] angle of each landmark centre in the robot frame, in ``(-pi, pi]``,
            counter-clockwise from the heading (computed for every landmark; meaningful where
            ``visible``).
        range_rank: [N] int32, 0 for the nearest visible landmark, 1 for the next, ...;
            -1 where not visible. Ties are broken by landmark index.
        visible: [N] bool, as in :class:`Observation`.
    """

    bearings: jax.Array
    range_rank: jax.Array
    visible: jax.Array


def _check_inputs(pose, landmarks, params: SensorParams) -> None:
    check_shape("pose", pose, 1, 3)
    check_shape("landmarks", landmarks, 2, 2)
    check_finite("pose", pose)
    check_finite("landmarks", landmarks)
    if not isinstance(params, SensorParams):
        raise ValueError(f"params must be a SensorParams, got {type(params).__name__}")
    for name in SensorParams._fields:
        value = getattr(params, name)
        if np.ndim(value) != 0:
            raise ValueError(f"SensorParams.{name} must be a scalar, got shape {np.shape(value)}")
        check_nonneg(f"SensorParams.{name}", value)
        if name in FINITE_SENSOR_FIELDS:
            check_finite(f"SensorParams.{name}", value)


def _relative(pose, landmarks):
    d = landmarks - pose[:2]
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    return jnp.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)


def _visibility(rel, params: SensorParams):
    dist2 = jnp.sum(rel**2, axis=-1)
    dist = jnp.sqrt(dist2)
    in_range = dist <= params.max_range
    bearing = jnp.arctan2(rel[:, 1], rel[:, 0])
    in_fov = (jnp.abs(bearing) <= 0.5 * params.fov) | (params.fov >= 2 * jnp.pi)
    # occluded[j] = any k nearer than j whose centre is within radius of the segment 0 -> rel[j].
    pj = rel[:, None, :]  # target j on axis 0
    pk = rel[None, :, :]  # candidate occluder k on axis 1
    t = jnp.sum(pk * pj, axis=-1) / jnp.where(dist2[:, None] > 0, dist2[:, None], 1.0)
    t = jnp.clip(t, 0.0, 1.0)
    seg_d2 = jnp.sum((pk - t[..., None] * pj) ** 2, axis=-1)
    nearer = dist2[None, :] < dist2[:, None]
    occluded = jnp.any(nearer & (seg_d2 < params.landmark_radius**2), axis=1)
    return in_range & in_fov & ~occluded


_relative_jit = jax.jit(_relative)


@jax.jit
def _visibility_jit(pose, landmarks, params):
    return _visibility(_relative(pose, landmarks), params)


@jax.jit
def _observe(key, pose, landmarks, params):
    true_rel = _relative(pose, landmarks)
    visible = _visibility(true_rel, params)
    noise = jax.random.normal(key, true_rel.shape, dtype=true_rel.dtype)
    return Observation(true_rel + params.sigma * noise, true_rel, visible)


@jax.jit
def camera_kernel(pose, landmarks, params):
    rel = _relative(pose, landmarks)
    visible = _visibility(rel, params)
    bearings = jnp.arctan2(rel[:, 1], rel[:, 0])
    dist2 = jnp.where(visible, jnp.sum(rel**2, axis=-1), jnp.inf)
    order = jnp.argsort(dist2, stable=True)
    n = rel.shape[0]
    rank = jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32))
    return CameraObservation(bearings, jnp.where(visible, rank, -1), visible)


def _prepare(pose, landmarks, params):
    params = SensorParams() if params is None else params
    pose, landmarks = as_float(pose), as_float(landmarks)
    _check_inputs(pose, landmarks, params)
    dtype = jnp.result_type(pose, landmarks)
    params = SensorParams(*(jnp.asarray(v, dtype) for v in params))
    return pose.astype(dtype), landmarks.astype(dtype), params


def relative_positions(pose: jax.Array, landmarks: jax.Array) -> jax.Array:
    """Landmark positions ``[N, 2]`` in the robot frame (x forward, y left), noise-free.

    Args:
        pose: ``[3]`` ``(x, y, theta)``.
        landmarks: ``[N, 2]`` world positions.

    Returns:
        ``[N, 2]``.

    >>> relative_positions(jnp.array([1.0, 0.0, jnp.pi / 2]), jnp.array([[1.0, 2.0]])).round(4)
    Array([[ 2., -0.]], dtype=float32)
    """
    pose, landmarks, _ = _prepare(pose, landmarks, SensorParams())
    return _relative_jit(pose, landmarks)


def visibility(pose: jax.Array, landmarks: jax.Array, params: SensorParams) -> jax.Array:
    """Boolean ``[N]`` visibility mask: range & field of view & occlusion.

    Range, field of view and occlusion of P §2.3.1 (docs/sim.md).

    Args:
        pose: ``[3]`` ``(x, y, theta)``.
        landmarks: ``[N, 2]`` world positions.
        params: the sensor.

    Returns:
        ``[N]`` bool.
    """
    pose, landmarks, params = _prepare(pose, landmarks, params)
    return _visibility_jit(pose, landmarks, params)


def observe(
    key: jax.Array, pose: jax.Array, landmarks: jax.Array, params: SensorParams | None = None
) -> Observation:
    """Noisy relative-position measurement of all landmarks from ``pose`` = (x, y, theta).

    ``vmap`` over runs: ``jax.vmap(observe, (0, 0, None, None))(keys, poses, lm, params)``.

    Args:
        key: PRNG key of the position noise.
        pose: ``[3]`` robot pose ``(x, y, theta)``.
        landmarks: [N, 2] landmark positions.
        params: sensor parameters (defaults to ``SensorParams()``).

    Returns:
        An :class:`Observation`: noisy and true positions in the robot frame and visibility
        (range, field of view, occlusion; docs/sim.md §sensors).

    Raises:
        ValueError: for inputs of the wrong shape, and (when concrete) NaN/inf values or
            negative parameters.

    >>> lm = jnp.array([[10.0, 0.0], [0.0, 100.0]])
    >>> obs = observe(jax.random.key(0), jnp.zeros(3), lm, SensorParams(max_range=60.0))
    >>> obs.visible.tolist(), obs.true_rel[0].tolist()
    ([True, False], [10.0, 0.0])
    """
    pose, landmarks, params = _prepare(pose, landmarks, params)
    return _observe(key, pose, landmarks, params)


def camera(
    pose: jax.Array, landmarks: jax.Array, params: SensorParams | None = None
) -> CameraObservation:
    """Camera measurement (M §IV): bearings of landmarks and range ordering of the visible ones.

    Bearings and ordering are exact, as assumed in M §IV, so ``params.sigma`` is not used.

    Args:
        pose: ``[3]`` camera pose ``(x, y, theta)``.
        landmarks: [N, 2] landmark positions.
        params: sensor parameters (range, field of view, occlusion radius).

    Returns:
        A :class:`CameraObservation` (bearings in the camera frame, range rank of each visible
        landmark, ``-1`` for the others).

    Raises:
        ValueError: for inputs of the wrong shape, and (when concrete) NaN/inf values or
            negative parameters.

    >>> lm = jnp.array([[0.0, 5.0], [2.0, 0.0], [90.0, 0.0]])
    >>> cam = camera(jnp.zeros(3), lm, SensorParams(max_range=60.0))
    >>> cam.range_rank.tolist(), round(float(cam.bearings[0]), 4)
    ([1, 0, -1], 1.5708)
    """
    pose, landmarks, params = _prepare(pose, landmarks, params)
    return camera_kernel(pose, landmarks, params)
