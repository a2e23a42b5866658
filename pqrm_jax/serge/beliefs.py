"""Beliefs ``B_k = p(X_k | Z_k)`` over a 2-D domain (Padgett eq. 3.1, §3.4.1).

Offers Gaussian beliefs and sample-set beliefs, each giving the ``[K, N]`` cell masses on a
grid and the ``[K, N]`` score used to pick the highest-saliency belief per cell. Bad input
raises ``ValueError`` naming the belief.

How cell masses are computed and how singular covariances are handled: docs/serge.md §beliefs.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .grid import Grid


def _histogram(grid: Grid, samples: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """[K, S, 2] samples → [K, N] normalised cell masses (clipped to the border)."""
    k, s = samples.shape[:2]
    idx = grid.cell_of(samples)                                       # (K, S)
    w = jnp.ones((k, s), jnp.float32) if weights is None else weights
    flat = idx + grid.n_cells * jnp.arange(k)[:, None]
    h = jnp.zeros(k * grid.n_cells, jnp.float32).at[flat.ravel()].add(w.ravel())
    h = h.reshape(k, grid.n_cells)
    return h / jnp.sum(h, axis=1, keepdims=True)


@dataclass(frozen=True)
class GaussianBeliefs:
    """K Gaussian beliefs with means [K, 2] and covariances [K, 2, 2].

    >>> b = GaussianBeliefs(np.array([[0., 0.], [5., 0.]]), np.tile(np.eye(2) * .1, (2, 1, 1)))
    >>> b.k
    2
    """

    means: np.ndarray
    covs: np.ndarray

    def __post_init__(self):
        m = np.asarray(self.means, dtype=np.float64)
        c = np.asarray(self.covs, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != 2 or m.shape[0] == 0:
            raise ValueError(f"GaussianBeliefs: means must have shape (K>0, 2), got {m.shape}")
        if c.shape != (m.shape[0], 2, 2):
            raise ValueError(f"GaussianBeliefs: covs must have shape ({m.shape[0]}, 2, 2), "
                             f"got {c.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(m), axis=1) | ~np.all(np.isfinite(c), axis=(1, 2)))
        if len(bad):
            raise ValueError(f"GaussianBeliefs: beliefs {bad.tolist()} have NaN/inf parameters")
        asym = np.flatnonzero(np.abs(c[:, 0, 1] - c[:, 1, 0]) > 1e-9 * (1 + np.abs(c).max()))
        if len(asym):
            raise ValueError(f"GaussianBeliefs: covariances of beliefs {asym.tolist()} are not "
                             "symmetric")
        ev = np.linalg.eigvalsh(c)
        scale = max(1.0, float(np.abs(c).max()))
        neg = np.flatnonzero(ev[:, 0] < -1e-9 * scale)
        if len(neg):
            raise ValueError(f"GaussianBeliefs: covariances of beliefs {neg.tolist()} are not "
                             "positive semidefinite")
        c = c + np.eye(2) * 1e-12 * scale
        object.__setattr__(self, "means", m)
        object.__setattr__(self, "covs", c)

    @property
    def k(self) -> int:
        return self.means.shape[0]

    @classmethod
    def fit(cls, points: list[np.ndarray] | np.ndarray, min_var: float = 0.0) -> GaussianBeliefs:
        """Fit ``N(α_k, Σ_k)`` to the measurements of each belief (P§3.4.1).

        ``points``: a list of [S_k, 2] arrays (or one [K, S, 2] array). Needs S_k ≥ 2;
        ``min_var`` is added to the diagonal (e.g. a sensor-noise floor).
        """
        means, covs = [], []
        for k, p in enumerate(points):
            p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
            if len(p) < 2:
                raise ValueError(f"GaussianBeliefs.fit: belief {k} has {len(p)} points (need ≥ 2)")
            if not np.all(np.isfinite(p)):
                raise ValueError(f"GaussianBeliefs.fit: belief {k} has NaN/inf points")
            means.append(p.mean(axis=0))
            covs.append(np.cov(p.T) + np.eye(2) * min_var)
        return cls(np.array(means), np.array(covs))

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        """[K, n, 2] samples."""
        chol = np.linalg.cholesky(self.covs)
        z = jax.random.normal(key, (self.k, n, 2), jnp.float32)
        return jnp.asarray(self.means, jnp.float32)[:, None, :] + jnp.einsum(
            "kij,knj->kni", jnp.asarray(chol, jnp.float32), z)

    def cell_masses(self, grid: Grid, key: jax.Array | None = None, n_mc: int = 20000) -> jax.Array:
        """[K, N] cell masses ``∫_{C_n} B_k`` from ``n_mc`` samples per belief (key 0 default)."""
        key = jax.random.PRNGKey(0) if key is None else key
        return _histogram(grid, self.sample(key, n_mc))

    def cell_scores(self, grid: Grid) -> np.ndarray:
        """[K, N] log densities at cell centres: the smooth 'highest-saliency' score."""
        x = grid.centers()[None, :, :] - self.means[:, None, :]
        inv = np.linalg.inv(self.covs)
        maha = np.einsum("kni,kij,knj->kn", x, inv, x)
        logdet = np.log(np.linalg.det(self.covs))
        return -0.5 * (maha + logdet[:, None])


@dataclass(frozen=True)
class SampleBeliefs:
    """K beliefs as sample sets, [K, S, 2] (all sets the same size S ≥ 1).

    >>> b = SampleBeliefs(np.zeros((3, 10, 2)) + np.arange(3)[:, None, None])
    >>> b.k, b.samples.shape
    (3, (3, 10, 2))
    """

    samples: np.ndarray

    def __post_init__(self):
        s = np.asarray(self.samples, dtype=np.float32)
        if s.ndim != 3 or s.shape[2] != 2:
            raise ValueError(f"SampleBeliefs: samples must have shape (K, S, 2), got {s.shape}")
        if s.shape[0] == 0 or s.shape[1] == 0:
            raise ValueError(f"SampleBeliefs: empty beliefs (shape {s.shape})")
        bad = np.flatnonzero(~np.all(np.isfinite(s), axis=(1, 2)))
        if len(bad):
            raise ValueError(f"SampleBeliefs: beliefs {bad.tolist()} contain NaN/inf samples")
        object.__setattr__(self, "samples", s)

    @property
    def k(self) -> int:
        return self.samples.shape[0]

    def cell_masses(self, grid: Grid, key: jax.Array | None = None, n_mc: int = 0) -> jax.Array:
        """[K, N] fraction of each belief's samples in each cell (``key``/``n_mc`` unused)."""
        return _histogram(grid, jnp.asarray(self.samples))

    def cell_scores(self, grid: Grid, blur_cells: float = 1.0) -> np.ndarray:
        """[K, N] log of the histogram blurred by a Gaussian of ``blur_cells`` cells.

        The score is −inf where a belief has no mass nearby.
        """
        h = np.asarray(self.cell_masses(grid), np.float64).reshape(self.k, *grid.shape)
        if blur_cells > 0:
            r = int(np.ceil(3 * blur_cells))
            ker = np.exp(-0.5 * (np.arange(-r, r + 1) / blur_cells) ** 2)
            ker /= ker.sum()
            h = np.apply_along_axis(lambda v: np.convolve(v, ker, mode="same"), 1, h)
            h = np.apply_along_axis(lambda v: np.convolve(v, ker, mode="same"), 2, h)
        with np.errstate(divide="ignore"):
            return np.log(h.reshape(self.k, -1))

    def points(self) -> np.ndarray:
        return self.samples


Beliefs = GaussianBeliefs | SampleBeliefs
