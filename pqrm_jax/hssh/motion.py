"""The 21-parameter turn--travel--turn action model for LPM localization (B §4.3.1, Table 4.1).

An odometry increment from pose ``(x, y, theta)`` to ``(x', y', theta')`` is decomposed into a
turn ``alpha``, a travel ``rho`` and a turn ``beta`` (:func:`decompose`; Rekleitis 2003), with
the reverse option ``(alpha + pi, -rho, beta + pi)`` when it has smaller total turning. The
action model then samples (the second argument of N is a variance)::

    s     ~ N(a c0  + r c1  + b c2,  c3  + a^2 c4  + r^2 c5  + b^2 c6)    travel
    delta ~ N(a c7  + r c8  + b c9,  c10 + a^2 c11 + r^2 c12 + b^2 c13)   drift normal to it
    phi   ~ N(a c14 + r c15 + b c16, c17 + a^2 c18 + r^2 c19 + b^2 c20)   rotation
    x' = x + s cos(theta + a) + delta cos(theta + a + pi/2), likewise y', theta' = theta + phi

with ``a, r, b = alpha, rho, beta``. :data:`ACTION_MODELS` holds Table 4.1's presets. Units
are metres and radians (inferred from B's KLD bin size (0.05, 0.05, 0.006)).

Decision: Table 4.1 prints the "large" drift row as ``0 1 0 1e-2 0 0 0`` (mean drift = rho,
a sideways slide as long as the travel) and the "small" drift row with 8 numbers; both look
like transcription errors, so both drift rows here have mean 0 (``c8 = 0``) like the fitted
model, with the printed variance constants (1e-2, 1e-6).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["ACTION_MODELS", "decompose", "sample_motion"]

ACTION_MODELS: dict[str, np.ndarray] = {
    "large": np.array([0, 1, 0, 1e-2, 0, 0, 0,
                       0, 0, 0, 1e-2, 0, 0, 0,
                       1, 0, 1, 3e-2, 0, 0, 0], np.float32),
    "small": np.array([0, 1, 0, 1e-6, 0, 0, 0,
                       0, 0, 0, 1e-6, 0, 0, 0,
                       1, 0, 1, 3e-6, 0, 0, 0], np.float32),
    "fitted": np.array([-0.012, 0.99, -0.012, 2.6e-05, 0, 0.0052, 0,
                        0.0014, -0.0016, 0.0019, 1.4e-05, 0, 0.0012, 0,
                        0.98, -0.0048, 0.98, 4.1e-05, 0, 0.0093, 0], np.float32),
}


def _wrap(a):
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def decompose(prev: jax.Array, pose: jax.Array) -> jax.Array:
    """Turn--travel--turn ``[alpha, rho, beta]`` of the odometry step ``prev -> pose`` (B §4.3.1).

    The difference ``pose - prev`` is taken before anything is rounded to float32: in float64
    on the host for concrete float64 poses (so a 0.1 m step at UTM-sized coordinates reads
    0.1 m), in the input precision when traced. Concrete non-finite poses raise ``ValueError``.

    Args:
        prev: ``[3]`` the odometry pose before the step.
        pose: ``[3]`` the odometry pose after it.

    Returns:
        ``[3]`` ``(alpha, rho, beta)``: first turn, travel, second turn.

    >>> [round(float(v), 4) for v in decompose(jnp.zeros(3), jnp.array([0.0, 1.0, 0.0]))]
    [1.5708, 1.0, -1.5708]
    >>> [round(float(v), 4) + 0.0 for v in decompose(jnp.zeros(3), jnp.array([-1.0, 0.0, 0.0]))]
    [0.0, -1.0, 0.0]
    >>> utm = np.array([5e5, 4.2e6, 0.0])
    >>> round(float(decompose(utm, utm + np.array([0.0, 0.1, 0.0]))[1]), 6)
    0.1
    """
    if isinstance(prev, jax.core.Tracer) or isinstance(pose, jax.core.Tracer):
        prev, pose = jnp.asarray(prev), jnp.asarray(pose)
        return _decompose_delta(pose - prev, prev[2])
    a, b = np.asarray(prev), np.asarray(pose)
    for name, v in (("prev", a), ("pose", b)):
        if v.shape != (3,):
            raise ValueError(f"{name} must be [3] (x, y, theta), got shape {v.shape}")
        if not np.all(np.isfinite(v.astype(np.float64))):
            raise ValueError(f"{name} must be finite, got {v.tolist()}")
    wide = np.result_type(a.dtype, b.dtype, np.float32)
    delta = b.astype(wide) - a.astype(wide)
    return _decompose_delta(jnp.asarray(delta, jnp.float32), jnp.float32(a[2]))


@jax.jit
def _decompose_delta(delta: jax.Array, theta_prev: jax.Array) -> jax.Array:
    """:func:`decompose` from the pose difference ``[3]`` and the previous heading."""
    delta = jnp.asarray(delta, jnp.float32)
    theta_prev = jnp.asarray(theta_prev, jnp.float32)
    dx, dy = delta[0], delta[1]
    dth = _wrap(delta[2])
    rho = jnp.hypot(dx, dy)
    alpha = jnp.where(rho > 0, _wrap(jnp.arctan2(dy, dx) - theta_prev), 0.0)
    beta = _wrap(dth - alpha)
    ra, rb = _wrap(alpha + jnp.pi), _wrap(beta + jnp.pi)
    rev = (rho > 0) & (jnp.abs(ra) + jnp.abs(rb) < jnp.abs(alpha) + jnp.abs(beta))
    return jnp.stack([jnp.where(rev, ra, alpha), jnp.where(rev, -rho, rho),
                      jnp.where(rev, rb, beta)])


@jax.jit
def sample_motion(key: jax.Array, particles: jax.Array, prev_odom: jax.Array,
                  odom: jax.Array, c: jax.Array, noise_scale: jax.Array = 1.0) -> jax.Array:
    """Move every particle ``[P, 3]`` by one sampled action (B §4.3.1).

    Args:
        key: PRNG key.
        particles: ``[P, 3]`` poses.
        prev_odom, odom: ``[3]`` odometry readings before and after the step.
        c: ``[21]`` action-model parameters (e.g. ``ACTION_MODELS["fitted"]``).
        noise_scale: multiplies every standard deviation (B's *grow*: x2 per stage).

    Returns:
        ``[P, 3]`` moved particles (headings wrapped to ``[-pi, pi)``).

    >>> p = jnp.zeros((2, 3))
    >>> out = sample_motion(jax.random.key(0), p, jnp.zeros(3), jnp.array([1.0, 0.0, 0.0]),
    ...                     jnp.asarray(ACTION_MODELS["small"]))
    >>> (np.round(np.asarray(out), 2) + 0.0).tolist()
    [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    """
    a, r, b = decompose(prev_odom, odom)
    c = jnp.asarray(c, jnp.float32)
    feats = jnp.stack([a, r, b])
    sq = jnp.stack([a * a, r * r, b * b])
    mean = jnp.stack([feats @ c[0:3], feats @ c[7:10], feats @ c[14:17]])
    var = jnp.stack([c[3] + sq @ c[4:7], c[10] + sq @ c[11:14], c[17] + sq @ c[18:21]])
    z = jax.random.normal(key, (particles.shape[0], 3), particles.dtype)
    s, d, phi = (mean + noise_scale * jnp.sqrt(jnp.maximum(var, 0.0)) * z).T
    th = particles[:, 2] + a
    x = particles[:, 0] + s * jnp.cos(th) + d * jnp.cos(th + jnp.pi / 2)
    y = particles[:, 1] + s * jnp.sin(th) + d * jnp.sin(th + jnp.pi / 2)
    return jnp.stack([x, y, _wrap(particles[:, 2] + phi)], axis=1)
