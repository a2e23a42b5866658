"""The 21-parameter turn-travel-turn action model (B §4.3.1, Table 4.1)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.hssh.motion import ACTION_MODELS, decompose, sample_motion


def test_decomposition_reconstructs_the_odometry_step():
    rng = np.random.default_rng(0)
    for _ in range(50):
        prev = rng.uniform([-5, -5, -np.pi], [5, 5, np.pi])
        pose = prev + rng.normal(0, [0.5, 0.5, 0.8])
        a, r, b = np.asarray(decompose(jnp.asarray(prev), jnp.asarray(pose)), float)
        x = prev[0] + r * np.cos(prev[2] + a)
        y = prev[1] + r * np.sin(prev[2] + a)
        th = prev[2] + a + b
        np.testing.assert_allclose([x, y], pose[:2], atol=1e-4)
        assert abs((th - pose[2] + np.pi) % (2 * np.pi) - np.pi) < 1e-4
        assert abs(a) + abs(b) <= np.pi + 1e-5          # the reverse option keeps turns short


def test_pure_rotation_and_reverse():
    a, r, b = np.asarray(decompose(jnp.zeros(3), jnp.array([0.0, 0.0, 0.7])))
    assert (a, r) == (0.0, 0.0) and abs(b - 0.7) < 1e-6
    a, r, b = np.asarray(decompose(jnp.array([0.0, 0.0, 0.3]),
                                   jnp.array([-np.cos(0.3), -np.sin(0.3), 0.3])))
    assert r < 0 and abs(a) < 1e-5 and abs(b) < 1e-5


def test_sampled_moments_follow_the_model():
    c = jnp.asarray(ACTION_MODELS["large"])
    p = jnp.zeros((40000, 3))
    out = np.asarray(sample_motion(jax.random.key(1), p, jnp.zeros(3),
                                   jnp.array([1.0, 0.0, 0.2]), c))
    # alpha = 0, rho = 1, beta = 0.2: s ~ N(1, 1e-2), delta ~ N(0, 1e-2), phi ~ N(0.2, 3e-2)
    assert abs(out[:, 0].mean() - 1.0) < 0.005 and abs(out[:, 0].var() - 1e-2) < 1e-3
    assert abs(out[:, 1].mean()) < 0.005 and abs(out[:, 1].var() - 1e-2) < 1e-3
    assert abs(out[:, 2].mean() - 0.2) < 0.01 and abs(out[:, 2].var() - 3e-2) < 3e-3
    small = np.asarray(sample_motion(jax.random.key(2), p[:100], jnp.zeros(3),
                                     jnp.array([1.0, 0.0, 0.2]), ACTION_MODELS["small"]))
    assert np.abs(small - [1.0, 0.0, 0.2]).max() < 0.01
    fitted = ACTION_MODELS["fitted"]
    assert fitted.shape == (21,) and abs(float(fitted[1]) - 0.99) < 1e-6
