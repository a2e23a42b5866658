"""The SERGE potential ψ = ψ1 · ψ2 · ψ3 in log space (Padgett eqs. 3.4–3.7).

* ψ1 (eq. 3.5): a normal-shaped prior on the number of regions |R| with mean μ and spread σ,
  normalised by β = Σ_{k=1..K} N(k; μ, σ): ``log ψ1 = −(|R|−μ)²/2σ² − log Σ_k e^{−(k−μ)²/2σ²}``
  (the 1/√(2πσ²) of eq. 3.5 cancels against β).
* ψ2 (eq. 3.6): 1 when every region is one connected component, 0 otherwise. The merge
  search keeps ψ2 = 1 by construction; :func:`direct_log_potential` checks it.
* ψ3 (eq. 3.7): the map saliency ``∏_k ∫_{R_{L^B_k}} B_k``; ``log ψ3 = Σ_k log S_k``.

Decisions: σ = 0 ("exactly μ regions", P§3.2.3) is evaluated as σ = ``SIGMA_MIN`` = 1e-3,
which makes any |R| ≠ μ lose by ≥ 5·10⁵ nats — every search then ends at |R| = μ.
Saliencies are floored at ``SAL_FLOOR`` = 1e-30 before the log so that a belief with no mass
in its region costs −69 nats instead of producing −inf/NaN in float32 comparisons.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .grid import components_per_label

SAL_FLOOR = 1e-30
SIGMA_MIN = 1e-3


def check_params(mu, sigma, k_max: int, n_cells: int | None = None) -> None:
    """Check the SERGE prior parameters (P §3.2.2).

    Args:
        mu: μ, the preferred number of regions.
        sigma: σ, the width of the prior over the number of regions.
        k_max: K, the number of beliefs.
        n_cells: N, the number of grid cells (when known).

    Raises:
        ValueError: unless μ is an integer in ``1..min(K, N)`` and σ is finite and ≥ 0.
    """
    upper = k_max if n_cells is None else min(k_max, n_cells)
    if not float(mu).is_integer() or not 1 <= int(mu) <= upper:
        raise ValueError(f"SERGE: mu must be an integer in 1..min(K, N) = 1..{upper}, got {mu}")
    if not np.isfinite(sigma) or sigma < 0:
        raise ValueError(f"SERGE: sigma must be a finite number ≥ 0, got {sigma}")


def log_psi1(n_regions, mu, sigma, k_max, k_static: int) -> jax.Array:
    """log ψ1(|R|; μ, σ), the prior on the number of regions (P eq. 3.5), normalised.

    Args:
        n_regions: ``|R|`` (scalar or array).
        mu: μ.
        sigma: σ (floored at ``SIGMA_MIN``).
        k_max: the largest ``|R|`` of the normaliser (may be traced, ``≤ k_static``).
        k_static: a static bound on ``k_max``.

    Returns:
        float32 of the shape of ``n_regions``.
    """
    s = jnp.maximum(jnp.asarray(sigma, jnp.float32), SIGMA_MIN)
    ks = jnp.arange(1, k_static + 1, dtype=jnp.float32)
    terms = jnp.where(ks <= k_max, -((ks - mu) ** 2) / (2 * s**2), -jnp.inf)
    log_beta = jax.nn.logsumexp(terms)
    c = jnp.asarray(n_regions, jnp.float32)
    return -((c - mu) ** 2) / (2 * s**2) - log_beta


def log_saliency(region_mass: jax.Array, assign: jax.Array) -> jax.Array:
    """[K] log S_k = log ∫_{R_{L_k}} B_k from [K, R] region masses and assignments [K]."""
    s = jnp.take_along_axis(region_mass, assign[:, None], axis=1)[:, 0]
    return jnp.log(jnp.maximum(s, SAL_FLOOR))


def log_psi3(region_mass: jax.Array, assign: jax.Array, belief_mask=None) -> jax.Array:
    """log ψ3 (eq. 3.7) = Σ_k log S_k over the beliefs in ``belief_mask``."""
    ls = log_saliency(region_mass, assign)
    if belief_mask is not None:
        ls = jnp.where(belief_mask, ls, 0.0)
    return jnp.sum(ls)


def direct_log_potential(cell_mass, cell_labels, belief_labels, mu, sigma, shape,
                         k_max: int | None = None) -> float:
    """Reference: log of ψ1·ψ2·ψ3 evaluated directly in float64 from the fine cells.

    Args:
        cell_mass: [K, N] fine cell masses of the beliefs.
        cell_labels: [N] region of every fine cell.
        belief_labels: [K] region of every belief.
        mu: the count prior's mean.
        sigma: the count prior's standard deviation.
        shape: the grid shape (for connectivity).
        k_max: largest region count of the normalisation (default K).

    Returns:
        log ψ; −inf when any region is disconnected (ψ2 counts connected components, Ω of
        eq. 3.6).
    """
    pm = np.asarray(cell_mass, np.float64)
    lab = np.asarray(cell_labels)
    bl = np.asarray(belief_labels)
    k = pm.shape[0] if k_max is None else k_max
    regions = np.unique(lab)
    s = max(float(sigma), SIGMA_MIN)
    norm = np.exp(-((np.arange(1, k + 1) - mu) ** 2) / (2 * s**2)) / np.sqrt(2 * np.pi * s**2)
    beta = norm.sum()
    psi1 = np.exp(-((len(regions) - mu) ** 2) / (2 * s**2)) / (beta * np.sqrt(2 * np.pi * s**2))
    omega = components_per_label(lab, shape)
    psi2 = 1.0 if all(v == 1 for v in omega.values()) else 0.0
    sal = np.array([pm[i, lab == bl[i]].sum() for i in range(pm.shape[0])])
    psi3 = np.prod(np.maximum(sal, SAL_FLOOR))
    with np.errstate(divide="ignore"):
        return float(np.log(psi1) + np.log(psi2) + np.log(psi3))
