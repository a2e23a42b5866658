"""Probabilistic composition (Z eq. 2.4 / 4.28) and its propagation over a PQRM map.

Offers the composition of two distributions through a ``[Q, Q, Q]`` tensor, the fusion rule
that combines several composition paths (and optionally the measurement), and the batched
propagation over a dense ``[L, L, L, Q]`` map with an ``[L, L, L]`` ``observed`` mask, with
converters from and to PQRM rows. Bad input raises ``ValueError``.

Map layout, the composition sum, the fusion rule (a smoothed, tempered product of experts)
and its defaults: docs/compositions.md §propagation.

>>> import numpy as np
>>> T = np.zeros((2, 2, 2), np.float32); T[0, 0, 0] = T[1, 1, 0] = 1; T[0, 1, 1] = T[1, 0, 1] = 1
>>> print(np.asarray(compose(np.array([0.9, 0.1]), np.array([0.8, 0.2]), T)).round(3))
[0.74 0.26]
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..triplets import dense_to_rows, distinct_mask, ordered_triplets, rows_to_dense

__all__ = ["PropagationResult", "compose", "fuse", "propagate", "propagate_loop", "from_pqrm",
           "to_pqrm_rows",
           "check_tensor", "check_map", "DEFAULT_EPS", "DEFAULT_PATH_WEIGHT"]

DEFAULT_EPS = 0.05
DEFAULT_PATH_WEIGHT = 0.5


# -------------------------------------------------------------------------------- checks
def check_tensor(tensor, atol: float = 1e-3) -> jax.Array:
    """Validate a ``[Q, Q, Q]`` probabilistic composition tensor; rows sum to 1 (or 0).

    A row ``T[a, b, :]`` summing to 0 marks a jointly impossible pair of source states.
    """
    t = np.asarray(tensor, dtype=np.float64)
    if t.ndim != 3 or not (t.shape[0] == t.shape[1] == t.shape[2]):
        raise ValueError(f"composition tensor must have shape (Q, Q, Q), got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError("composition tensor has negative or non-finite entries")
    s = t.sum(-1)
    bad = ~(np.isclose(s, 1.0, atol=atol) | (s == 0))
    if bad.any():
        a, b = np.argwhere(bad)[0]
        raise ValueError(f"composition tensor row T[{a}, {b}, :] sums to {s[a, b]:.4g}, "
                         f"not 1 (or 0 for an impossible pair)")
    return jnp.asarray(t, dtype=jnp.float32)


def check_map(probs, observed, atol: float = 1e-3, renormalize: bool = False):
    """Validate the ``[L, L, L, Q]`` map and ``[L, L, L]`` mask; returns float32 arrays.

    Unobserved rows are zeroed (they may hold anything, including NaN).
    """
    p = np.asarray(probs, dtype=np.float64)
    m = np.asarray(observed)
    if p.ndim != 4 or p.shape[0] != p.shape[1] or p.shape[1] != p.shape[2]:
        raise ValueError(f"probs must have shape (L, L, L, Q), got {p.shape}")
    if m.shape != p.shape[:3]:
        raise ValueError(f"observed must have shape {p.shape[:3]}, got {m.shape}")
    if m.dtype != bool:
        if not np.isin(m, (0, 1)).all():
            raise ValueError("observed must be a boolean mask")
        m = m.astype(bool)
    rep = m & ~distinct_mask(p.shape[0])
    if rep.any():
        i, j, k = np.argwhere(rep)[0]
        raise ValueError(f"observed triplet ({i}, {j}, {k}) repeats a landmark; triplets need "
                         f"three distinct landmarks")
    rows = p[m]
    if not np.all(np.isfinite(rows)):
        raise ValueError("observed probability rows contain NaN or inf")
    if np.any(rows < 0):
        idx = np.argwhere(m)[np.argwhere((rows < 0).any(-1))[0, 0]]
        raise ValueError(f"observed probability row {tuple(idx)} has negative entries")
    s = rows.sum(-1)
    if renormalize:
        if np.any(s <= 0):
            raise ValueError("observed probability rows with zero total mass cannot be "
                             "renormalised")
        rows = rows / s[:, None]
    elif not np.allclose(s, 1.0, atol=atol):
        idx = np.argwhere(m)[np.argmax(np.abs(s - 1.0))]
        raise ValueError(f"observed probability row {tuple(idx)} sums to "
                         f"{s[np.argmax(np.abs(s - 1.0))]:.4g}, not 1 (pass renormalize=True "
                         f"to rescale)")
    out = np.zeros(p.shape, np.float32)
    out[m] = rows
    return jnp.asarray(out), jnp.asarray(m)


# ------------------------------------------------------------------------ primitives
def _log(x):
    """log clipped at 1e-30: finite even for eps = 0, so softmax never sees all -inf."""
    return jnp.log(jnp.maximum(x, 1e-30))


def compose(p1, p2, tensor) -> jax.Array:
    """Z eq. 2.4: ``P(AB:D)`` from ``P(AB:C)`` and ``P(BC:D)``.

    Args:
        p1: [..., Q] distribution of ``AB:C``.
        p2: [..., Q] distribution of ``BC:D`` (broadcast against ``p1``).
        tensor: [Q, Q, Q] probabilistic composition tensor, ``T[a, b, c] = P(AB:D = c | a, b)``.

    Returns:
        [..., Q] renormalised distribution of ``AB:D``; all zeros for an impossible pair (zero
        mass).
    """
    t = jnp.asarray(tensor, jnp.float32)
    r = jnp.einsum("...a,...b,abc->...c", jnp.asarray(p1, jnp.float32),
                   jnp.asarray(p2, jnp.float32), t)
    s = r.sum(-1, keepdims=True)
    return jnp.where(s > 0, r / jnp.where(s > 0, s, 1.0), 0.0)


def fuse(dists, weights=None, eps: float = DEFAULT_EPS, axis: int = 0) -> jax.Array:
    """Smoothed tempered product of experts over ``axis`` of ``dists``.

    Assumes the sources are conditionally independent given the state; the rule is described
    in docs/compositions.md §propagation.

    Args:
        dists: the source distributions, [..., Q] with the sources along ``axis``.
        weights: the exponents ``w_s``, broadcast against ``dists`` without its last axis; a
            weight of 0 removes a source. Default 1 each.
        eps: smoothing of every source towards uniform, ``(1 − ε)·p + ε/Q``.
        axis: the axis of the sources.

    Returns:
        The fused distribution (a proper distribution: no NaN, no negative entries).

    >>> print(np.asarray(fuse(np.array([[0.7, 0.3], [0.6, 0.4]]), eps=0.0)).round(3))
    [0.778 0.222]
    """
    d = jnp.asarray(dists, jnp.float32)
    q = d.shape[-1]
    w = jnp.ones(d.shape[:-1], jnp.float32) if weights is None else jnp.broadcast_to(
        jnp.asarray(weights, jnp.float32), d.shape[:-1])
    logp = _log((1.0 - eps) * d + eps / q)
    ax = axis % d.ndim
    s = jnp.sum(w[..., None] * logp, axis=ax)
    return jax.nn.softmax(s, axis=-1)


# ---------------------------------------------------------------------------- batched
@dataclass(frozen=True)
class PropagationResult:
    """Output of :func:`propagate`.

    ``probs`` [L, L, L, Q] the updated map; ``n_paths`` [L, L, L] int32 number of composition
    paths that contributed to each ordered triplet; ``filled`` [L, L, L] bool — unobserved
    triplets that received a composed distribution; ``known`` = observed | filled.
    """

    probs: jax.Array
    n_paths: jax.Array
    filled: jax.Array
    known: jax.Array


def _paths_for_j(pj, pij, aj, aij, tensor, eps, prior_log, j):
    """All paths ``(ij:k, jk:d) → ij:d`` through one middle landmark ``j``.

    ``pj = P(jk:d)`` [k, d, Q], ``pij = P(ij:k)`` [i, k, Q], ``aj``/``aij`` their availability.
    Returns the summed log-evidence [i, d, Q] and the path counts [i, d].
    """
    n, q = pij.shape[0], pij.shape[-1]
    # N[k, d, a, c] = Σ_b P(jk:d = b) T[a, b, c]   (independent of i)
    nkd = jnp.einsum("kdb,abc->kdac", pj, tensor)
    # R[k, i, d, c] = Σ_a P(ij:k = a) N[k, d, a, c]: one (L×Q)·(Q×L·Q) matmul per k
    r = jnp.einsum("ika,kdac->kidc", pij, nkd)
    mass = r.sum(-1)
    ar = jnp.arange(n)
    valid = (aij.T[:, :, None] & aj[:, None, :] & (mass > 1e-12)
             & (ar[:, None] != ar[None, :])[None])                   # (k, i, d), i ≠ d
    r = r / jnp.where(mass > 1e-12, mass, 1.0)[..., None]
    logp = _log((1.0 - eps) * r + eps / q) - prior_log
    ev = jnp.einsum("kid,kidc->idc", valid.astype(logp.dtype), logp)
    cnt = valid.sum(0).astype(jnp.int32)                          # (i, d)
    return ev, cnt


@partial(jax.jit, static_argnames=("batch_size",))
def _propagate_core(probs, avail, tensor, eps, prior_log, batch_size):
    n = probs.shape[0]

    def body(args):
        pj, pij, aj, aij, j = args
        return _paths_for_j(pj, pij, aj, aij, tensor, eps, prior_log, j)

    ev, cnt = jax.lax.map(body, (probs, jnp.swapaxes(probs, 0, 1), avail,
                                 jnp.swapaxes(avail, 0, 1), jnp.arange(n)),
                          batch_size=batch_size)
    # (j, i, d, ...) → (i, j, d, ...)
    return jnp.swapaxes(ev, 0, 1), jnp.swapaxes(cnt, 0, 1)


@jax.jit
def _combine(ev, cnt, probs, observed, targets, prior_log, eps, path_weight, meas_weight):
    """Fuse the path evidence of ``targets`` (with the measurement where observed)."""
    q = probs.shape[-1]
    meas_log = _log((1.0 - eps) * probs + eps / q) - prior_log
    has = (cnt > 0) & targets
    score = prior_log + path_weight * ev * has[..., None] \
        + jnp.where(observed[..., None], meas_weight * meas_log, 0.0)
    post = jax.nn.softmax(score, axis=-1)
    prior = jnp.broadcast_to(jnp.exp(prior_log), probs.shape)
    out = jnp.where((observed & ~has)[..., None], probs,
                    jnp.where(has[..., None], post, prior))
    return out, has


def propagate(probs, observed, tensor, *, mode: str = "fill", rounds: int = 1,
              eps: float = DEFAULT_EPS, path_weight: float = DEFAULT_PATH_WEIGHT,
              measurement_weight: float = 1.0, prior=None, batch_size: int | None = None,
              renormalize: bool = False, validate: bool = True) -> PropagationResult:
    """Fill in / sharpen a PQRM map by probabilistic composition (Z eq. 2.4, 4.28).

    Args:
        probs: ``[L, L, L, Q]`` map, ``probs[i, j, k] = P(ij:k)``; layout in
            docs/compositions.md §propagation.
        observed: ``[L, L, L]`` bool, the measured triplets; other rows are ignored.
        tensor: ``[Q, Q, Q]`` probabilistic composition tensor
            (``calc.tables.prob_compose``).
        mode: ``"fill"`` — only unobserved triplets are inferred, observed rows are returned
            as given; ``"fuse"`` — observed rows are also fused with their composition paths.
        rounds: round ``r > 1`` also uses triplets filled in earlier rounds as path operands,
            for targets still without a path (reaches triplets that need deeper composition
            trees).
        eps: smoothing of every source towards uniform in the fusion rule.
        path_weight: tempering exponent of each composition path in the fusion rule.
        measurement_weight: tempering exponent of the measurement (``mode="fuse"``).
        prior: ``[Q]`` prior over states; defaults to uniform.
        batch_size: how many middle landmarks ``j`` are processed at once (``None``: one at
            a time; memory ``≈ batch_size·L³·Q`` floats).
        renormalize: rescale observed rows that merely do not sum to 1 instead of raising.
        validate: check the map and the tensor first (see Raises).

    Returns:
        A :class:`PropagationResult`. Unobserved triplets with no path get ``prior``;
        triplets with a repeated landmark get ``prior`` and are never marked known.

    Raises:
        ValueError: for an unknown ``mode``, ``eps`` outside [0, 1], negative weights,
            ``rounds < 1``, and (with ``validate``) a malformed map or tensor.

    >>> import numpy as np
    >>> from pqrm_jax.compositions.propagation import propagate
    >>> T = np.eye(2, dtype=np.float32)[np.arange(2)[:, None] ^ np.arange(2)]  # c = a xor b
    >>> P = np.full((4, 4, 4, 2), 0.5, np.float32); obs = np.zeros((4, 4, 4), bool)
    >>> P[0, 1, 2] = [1, 0]; P[1, 2, 3] = [0, 1]; obs[0, 1, 2] = obs[1, 2, 3] = True
    >>> res = propagate(P, obs, T, eps=0.0)
    >>> print(np.asarray(res.probs[0, 1, 3]).round(3), bool(res.filled[0, 1, 3]),
    ...       int(res.n_paths[0, 1, 3]))
    [0. 1.] True 1
    """
    if mode not in ("fill", "fuse"):
        raise ValueError(f"mode must be 'fill' or 'fuse', got {mode!r}")
    if not (0.0 <= eps <= 1.0):  # also refuses NaN
        raise ValueError(f"eps must be in [0, 1], got {eps}")
    for wname, w in (("path_weight", path_weight), ("measurement_weight", measurement_weight)):
        if not (0.0 <= float(w) < float("inf")):  # NaN and inf fail too
            raise ValueError(f"{wname} must be finite and ≥ 0, got {w}")
    if rounds < 1:
        raise ValueError(f"rounds must be ≥ 1, got {rounds}")
    if validate:
        t = check_tensor(tensor)
        p, obs = check_map(probs, observed, renormalize=renormalize)
    else:
        t = jnp.asarray(tensor, jnp.float32)
        p, obs = jnp.asarray(probs, jnp.float32), jnp.asarray(observed, bool)
        p = jnp.where(obs[..., None], p, 0.0)
    n, q = p.shape[0], p.shape[-1]
    if t.shape[0] != q:
        raise ValueError(f"tensor has {t.shape[0]} states but the map has {q}")
    if prior is None:
        prior_log = jnp.full((q,), -np.log(q), jnp.float32)
    else:
        pr = np.asarray(prior, np.float64)
        if pr.shape != (q,) or np.any(pr <= 0) or not np.isclose(pr.sum(), 1, atol=1e-3):
            raise ValueError("prior must be a strictly positive (Q,) distribution")
        prior_log = jnp.log(jnp.asarray(pr / pr.sum(), jnp.float32))
    distinct = jnp.asarray(distinct_mask(n))
    eps_ = jnp.float32(eps)
    targets0 = distinct if mode == "fuse" else distinct & ~obs
    known, cur = obs, p
    filled = jnp.zeros((n, n, n), bool)
    for r in range(rounds):
        ev, cnt = _propagate_core(cur, known, t, eps_, prior_log, batch_size)
        targets = targets0 if r == 0 else distinct & ~known
        out_r, has = _combine(ev, cnt, p, obs, targets, prior_log, eps_,
                              jnp.float32(path_weight), jnp.float32(measurement_weight))
        if r == 0:
            out, n_paths = out_r, jnp.where(has, cnt, 0)
        else:
            if not bool(has.any()):
                break
            out = jnp.where(has[..., None], out_r, out)
            n_paths = jnp.where(has, cnt, n_paths)
        filled = filled | (has & ~obs)
        known = obs | filled
        cur = jnp.where(known[..., None], out, 0.0)
    return PropagationResult(out, n_paths, filled, known)


# ---------------------------------------------------------------- per-triplet reference
@jax.jit
def _one_target(pij, pjd, valid_k, meas, use_meas, tensor, eps, prior_log, path_weight,
                meas_weight):
    """One target ``ij:d`` from its ``L`` candidate paths (reference for the benchmark)."""
    q = pij.shape[-1]
    r = jnp.einsum("ka,kb,abc->kc", pij, pjd, tensor)
    mass = r.sum(-1)
    valid = valid_k & (mass > 1e-12)
    r = r / jnp.where(mass > 1e-12, mass, 1.0)[:, None]
    logp = _log((1.0 - eps) * r + eps / q) - prior_log
    score = prior_log + path_weight * jnp.einsum("k,kc->c", valid.astype(logp.dtype), logp)
    score = score + use_meas * meas_weight * (_log((1.0 - eps) * meas + eps / q) - prior_log)
    return jax.nn.softmax(score), valid.sum()


def propagate_loop(probs, observed, tensor, *, mode: str = "fill", eps: float = DEFAULT_EPS,
                   path_weight: float = DEFAULT_PATH_WEIGHT, measurement_weight: float = 1.0,
                   backend: str = "numpy"):
    """Per-triplet reference of :func:`propagate` (one round, uniform prior).

    Loops in Python over every target ordered triplet; ``backend="numpy"`` is a plain NumPy
    implementation, ``backend="jax"`` calls one jitted per-target kernel. Returns
    ``(probs, n_paths)`` as NumPy arrays. Slow by design: it is the benchmark's baseline and
    the test oracle for :func:`propagate`.
    """
    if backend not in ("numpy", "jax"):
        raise ValueError(f"backend must be 'numpy' or 'jax', got {backend!r}")
    p, obs = check_map(probs, observed)
    p, obs = np.asarray(p), np.asarray(obs)
    t = np.asarray(check_tensor(tensor))
    n, q = p.shape[0], p.shape[-1]
    out = np.where(obs[..., None], p, 1.0 / q).astype(np.float32)
    cnt = np.zeros((n, n, n), np.int32)
    prior_log = np.full(q, -np.log(q), np.float32)
    ks = np.arange(n)
    fuse_obs = mode == "fuse"
    for i in range(n):
        for j in range(n):
            if j == i:
                continue
            for d in range(n):
                if d in (i, j) or (obs[i, j, d] and not fuse_obs):
                    continue
                vk = obs[i, j] & obs[j, :, d] & (ks != i) & (ks != j) & (ks != d)
                if not vk.any():
                    continue
                if backend == "jax":
                    post, c = _one_target(p[i, j], p[j, :, d], vk, p[i, j, d],
                                          np.float32(obs[i, j, d]), t, eps, prior_log,
                                          path_weight, measurement_weight)
                    if int(c):
                        out[i, j, d] = np.asarray(post)
                        cnt[i, j, d] = int(c)
                    continue
                a, b = p[i, j, vk], p[j, vk, d]
                r = np.einsum("ka,kb,abc->kc", a, b, t)
                mass = r.sum(-1)
                ok = mass > 1e-12
                if not ok.any():
                    continue
                r = r[ok] / mass[ok, None]
                score = prior_log + path_weight * (np.log(
                    np.maximum((1 - eps) * r + eps / q, 1e-30)) - prior_log).sum(0)
                if obs[i, j, d]:
                    score = score + measurement_weight * (np.log(np.maximum(
                        (1 - eps) * p[i, j, d] + eps / q, 1e-30)) - prior_log)
                score = score - score.max()
                e = np.exp(score)
                out[i, j, d] = e / e.sum()
                cnt[i, j, d] = int(ok.sum())
    return out, cnt


# ------------------------------------------------------------------------ PQRM adapter
def from_pqrm(state, num_landmarks: int, representation: str = "edc"):
    """``(probs, observed)`` arrays of this module from a :class:`pqrm_jax.pqrm.MapState`.

    Rows of ``state.probs[representation]`` follow ``pqrm.ordered_triplets(num_landmarks)``;
    ``observed`` is ``state.mapped``. Mapped rows are renormalised by :func:`propagate`'s
    checks only if you pass ``renormalize=True``.

    Args:
        state: a dense PQRM map state.
        num_landmarks: ``L``.
        representation: the calculus name of the rows to take.

    Returns:
        ``(probs [L, L, L, Q] float32, observed [L, L, L] bool)`` (the dense layout of
        :mod:`pqrm_jax.triplets`).

    Raises:
        ValueError: for a missing representation or a row count that is not ``L(L−1)(L−2)``.
    """
    trip = ordered_triplets(num_landmarks)
    if representation not in state.probs:
        raise ValueError(f"map has no representation {representation!r}; it has "
                         f"{sorted(state.probs)}")
    rows = np.asarray(state.probs[representation], np.float32)
    if rows.shape[0] != len(trip):
        raise ValueError(f"map has {rows.shape[0]} rows, {num_landmarks} landmarks need "
                         f"{len(trip)}")
    probs = rows_to_dense(rows, num_landmarks, fill=0.0)
    observed = rows_to_dense(np.asarray(state.mapped, bool), num_landmarks, fill=False)
    return probs, observed


def to_pqrm_rows(probs, num_landmarks: int) -> np.ndarray:
    """Dense ``[L, L, L, Q]`` → PQRM rows ``[T, Q]`` in ``pqrm.ordered_triplets`` order.

    Args:
        probs: ``[L, L, L, Q]``.
        num_landmarks: ``L``.

    Returns:
        ``[L(L−1)(L−2), Q]`` NumPy rows.

    Raises:
        ValueError: when the leading shape is not ``(L, L, L)``.
    """
    return dense_to_rows(np.asarray(probs), num_landmarks)
