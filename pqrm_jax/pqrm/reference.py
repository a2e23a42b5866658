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

__all__ = ["numpy_state_probabilities", "numpy_counts", "numpy_fused_counts"]


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


def numpy_fused_counts(means: np.ndarray, sigma, z: np.ndarray) -> np.ndarray:
    """[N, 20] EDC counts by the fused kernel's arithmetic, vectorised over [N, S] in NumPy.

    The benchmark's second baseline (docs/benchmarks.md §bench_pqrm): the same per-sample
    arithmetic as ``measurement.edc_block_counts`` — d = B − A and e = C − A from the shared
    bank ``z`` [S, 3, 2], the homogenised quantities u = e×d, v = e·d, m = |e|², n = |d|²,
    the arithmetic state key (side, band, circles) and a realisability check — counted with
    ``np.bincount``, in float32 without the power-of-two rescaling (the same counts at ordinary
    scales). Written from docs/decisions.md §2.1 (the key layout is the kernel's
    ``key_to_edc_state``), not from the JAX code.

    Args:
        means: [N, 3, 2] measured positions of A, B, C.
        sigma: noise std, scalar, [N] or [N, 3].
        z: [S, 3, 2] standard-normal bank shared by the rows.

    Returns:
        [N, 20] int64 counts of the EDC states (rejected samples in none).
    """
    from .measurement import key_to_edc_state

    means = np.asarray(means, np.float32)
    nrows = means.shape[0]
    sig = np.broadcast_to(np.asarray(sigma, np.float32).reshape(
        (-1, 1) if np.ndim(sigma) == 1 else np.shape(sigma)), (nrows, 3))
    z = np.asarray(z, np.float32)
    s = sig[:, None, :]  # [N, 1, 3]
    md = means[:, 1] - means[:, 0]
    me = means[:, 2] - means[:, 0]
    dx = md[:, None, 0] + s[..., 1] * z[None, :, 1, 0] - s[..., 0] * z[None, :, 0, 0]
    dy = md[:, None, 1] + s[..., 1] * z[None, :, 1, 1] - s[..., 0] * z[None, :, 0, 1]
    ex = me[:, None, 0] + s[..., 2] * z[None, :, 2, 0] - s[..., 0] * z[None, :, 0, 0]
    ey = me[:, None, 1] + s[..., 2] * z[None, :, 2, 1] - s[..., 0] * z[None, :, 0, 1]
    u, v = ex * dy - ey * dx, ex * dx + ey * dy
    m, n = ex * ex + ey * ey, dx * dx + dy * dy
    band = (v > 0).astype(np.int64) + (2 * v > n) + (v > n)
    ca, cb = m < n, m < 2 * v
    key = (u > 0) * 10 + 3 * band - np.minimum(band, 1) + ca + cb
    realisable = np.where(band == 0, ~cb, np.where(band == 1, ca | ~cb,
                                                   np.where(band == 2, cb | ~ca, ~ca)))
    with np.errstate(invalid="ignore", over="ignore"):
        ok = ((u != 0) & (v != 0) & (n != v) & (n != 2 * v) & (n != m) & (m != 2 * v)
              & realisable & np.isfinite(u + v + m + n))
    state = key_to_edc_state()[np.where(ok, key, 0)]
    flat = np.where(ok, np.arange(nrows)[:, None] * 20 + state, -1).ravel()
    flat = flat[flat >= 0]
    return np.bincount(flat, minlength=nrows * 20).reshape(nrows, 20)
