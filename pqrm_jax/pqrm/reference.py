"""A plain NumPy implementation of the eq. 2.9 estimator (P §2.2.2), independent of the kernel.

Used as the statistical oracle in the tests and as the baseline of ``benchmarks/bench_pqrm.py``.
It is written the straightforward way: draw Gaussian samples of the three landmarks, transform
C into the canonical AB frame by division (α, β, ρ), evaluate the calculus's constraint
polynomials, look the sign pattern up in the calculus's sign table and count with
``np.bincount``. It shares nothing with the JAX kernel but the calculus definition.
"""

from __future__ import annotations

import numpy as np

from .. import calculi
from ..calculi import Calculus

__all__ = ["numpy_state_probabilities", "numpy_counts"]


def _eval_poly(poly, alpha, beta, rho):
    out = np.zeros_like(alpha)
    for (ea, eb, er), coef in poly.terms.items():
        out = out + float(coef) * alpha**ea * beta**eb * rho**er
    return out


def numpy_counts(calc: Calculus | str, points: np.ndarray) -> np.ndarray:
    """Counts [N, Q] of the states of ``points`` [N, S, 3, 2] (boundary samples uncounted)."""
    calc = calculi.get(calc)
    a, b, c = points[..., 0, :], points[..., 1, :], points[..., 2, :]
    d = b - a
    e = c - a
    n = d[..., 0] ** 2 + d[..., 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = (e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]) / n
        beta = (e[..., 0] * d[..., 0] + e[..., 1] * d[..., 1]) / n
        rho = (e[..., 0] ** 2 + e[..., 1] ** 2) / n
        idx = np.zeros(alpha.shape, np.int64)
        for a_, poly in enumerate(calc.constraints):
            idx += (np.sign(_eval_poly(poly, alpha, beta, rho)).astype(np.int64) + 1) * 3**a_
    state = calc.sign_table[idx]
    state = np.where(np.isfinite(alpha) & np.isfinite(beta) & np.isfinite(rho), state, -1)
    q = calc.num_states
    rows = np.arange(state.shape[0])[:, None]
    flat = np.where(state >= 0, rows * q + state, -1).ravel()
    flat = flat[flat >= 0]
    return np.bincount(flat, minlength=state.shape[0] * q).reshape(state.shape[0], q)


def numpy_state_probabilities(
    rng: np.random.Generator, calc: Calculus | str, means: np.ndarray, sigma, num_samples: int,
    *, shared: bool = False, z: np.ndarray | None = None,
) -> np.ndarray:
    """[N, Q] eq. 2.9 probabilities with NumPy.

    ``shared=True`` draws one [S, 3, 2] standard-normal bank for all rows (the JAX kernel's
    scheme); otherwise every row gets its own draws. ``z`` [S, 3, 2] overrides the draws.
    """
    means = np.asarray(means, np.float32)
    nrows = means.shape[0]
    sig = np.broadcast_to(np.asarray(sigma, np.float32).reshape(
        (-1, 1) if np.ndim(sigma) == 1 else np.shape(sigma)), (nrows, 3))
    if z is None:
        shape = (num_samples, 3, 2) if shared else (nrows, num_samples, 3, 2)
        z = rng.standard_normal(shape, dtype=np.float32)
    if z.ndim == 3:
        z = z[None]
    points = means[:, None] + sig[:, None, :, None] * z
    counts = numpy_counts(calc, points).astype(np.float64)
    total = counts.sum(axis=1, keepdims=True)
    return counts / np.maximum(total, 1.0)
