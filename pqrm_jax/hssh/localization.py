"""Adaptive particle proposals for localization in a grid map (B §4.3.2).

One localization step starts from a prior pose, moves ``K`` blocks of ``B`` particles with the
21-parameter action model (:mod:`pqrm_jax.hssh.motion`) and scores them with a scan likelihood
against an occupancy grid; the result is the best particle and its likelihood (B's metric,
Table 4.2). Fixed shapes: every block is always computed and blocks past a filter's stopping
point are masked out (no Python loop over particles or stages).

* ``"raw"`` -- the odometry pose (the action model's mean), no sampling.
* ``"pf"`` -- all ``K B`` particles from the action-model proposal.
* ``"shrink"`` -- one block from the proposal, a Gaussian fitted to it with likelihood
  weights, the other ``K - 1`` blocks from that Gaussian (after Grisetti et al. 2005).
* ``"grow"`` -- block ``k`` from the proposal with standard deviations ``x 2**k`` (covariance
  x4 per stage, B Fig. 4.9), stopping at the first block whose best likelihood reaches the
  threshold, annealed by ``anneal`` per stage.
* ``"shrink_and_grow"`` -- grow until a stage holds a good particle, then shrink that stage:
  the particle budget left (``(K - 1 - k) B`` after stage ``k``) is drawn from the Gaussian
  fitted to it (B: "run shrink on the original proposal; if no good particle is found, grow
  the original proposal, then shrink the grown one").

Scan likelihood (:func:`scan_likelihood`): the likelihood-field model, the mean over hit
beams of ``exp(-d**2 / (2 sigma**2))`` with ``d`` the distance from the beam end to the nearest
occupied cell (in ``(0, 1]``; 0 without a usable beam). B used Konolige's likelihood; the
likelihood field is this library's choice.

KLD-sampling (Fox 2003, as B §4.3.2 uses it in every filter; :class:`KLDParams`, off by
default): each proposal is drawn as a full block and only its first ``n`` particles are kept,
``n`` the first count at which Fox's bound is met, ``n >= max(n_min, n_chi(k_n))`` with
``k_n`` the number of occupied pose bins among the first ``n`` particles and
``n_chi(k) = (k - 1) / (2 eps) (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1))) z)**3``
(``z`` the standard normal ``confidence`` quantile) -- a mask on the fixed block
(:func:`kld_mask`), so a small proposal uses few particles and a wide one up to the block.
B's budget: at most 100 per stage x 5 stages = 500; confidence 0.95, error 0.5, bins
(0.05, 0.05, 0.006) (m, m, rad).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.hssh.motion import sample_motion
from pqrm_jax.sim.lidar import LidarScan

__all__ = ["METHODS", "KLDParams", "LocalizeParams", "DEFAULT_PARAMS", "kld_bound", "kld_mask",
           "scan_likelihood", "localize", "localize_with_count"]

METHODS = ("raw", "pf", "shrink", "grow", "shrink_and_grow")


class KLDParams(NamedTuple):
    """KLD-sampling settings (Fox 2003; B §4.3.2's values): bound error ``epsilon``,
    ``confidence`` (1 - delta), pose ``bin_size`` (x, y, theta) and the least count ``n_min``
    (Fox's lower bound; not given by B -- this library's choice)."""

    epsilon: float = 0.5
    confidence: float = 0.95
    bin_size: tuple[float, float, float] = (0.05, 0.05, 0.006)
    n_min: int = 10


class LocalizeParams(NamedTuple):
    """blocks x block particles; likelihood-field sigma (world units); stopping threshold and
    its per-stage annealing factor (grow, shrink-and-grow); ``kld``: :class:`KLDParams` to
    size every proposal by KLD-sampling, or None for full blocks."""

    blocks: int = 5
    block: int = 100
    sigma: float = 0.1
    threshold: float = 0.8
    anneal: float = 0.9
    kld: KLDParams | None = None


DEFAULT_PARAMS = LocalizeParams()


def scan_likelihood(poses: jax.Array, scan: LidarScan, dist2: jax.Array, origin: jax.Array,
                    resolution: float, sigma: float) -> jax.Array:
    """Likelihood-field scan likelihood ``[P]`` of poses ``[P, 3]``.

    Args:
        poses: ``[P, 3]`` (x, y, theta).
        scan: the scan (angles in the robot frame).
        dist2: ``[H, W]`` squared distance (cells) to the nearest occupied cell, rows along y.
        origin: ``[2]`` world (x, y) of cell (0, 0)'s corner.
        resolution: cell size.
        sigma: likelihood-field standard deviation (world units).

    Returns:
        ``[P]`` float in ``[0, 1]``: the mean over the beams that hit of the likelihood field
        ``exp(−d²/2σ²)`` at the beam end (0 outside the map; B §4.3.2). Beam ends are taken
        relative to the map origin, ``(pose - origin) + range * direction``, with the
        difference first (in float64 on the host for float64 NumPy ``poses`` or ``origin``), so
        the result does not depend on where the world origin is (issue 26).

    >>> d2 = jnp.zeros((4, 4), jnp.int32)
    >>> z = LidarScan(jnp.array([0.0]), jnp.array([1.0]), jnp.array([True]))
    >>> float(scan_likelihood(jnp.array([[1.0, 1.0, 0.0]]), z, d2, jnp.zeros(2), 1.0, 0.5)[0])
    1.0
    """
    h, w = dist2.shape
    rel = _relative(poses, origin)   # pose minus map origin, taken before any float32 rounding
    poses = jnp.asarray(poses)
    ang = poses[:, 2, None] + scan.angles[None, :]
    ex = rel[:, 0, None] + scan.ranges[None, :] * jnp.cos(ang)
    ey = rel[:, 1, None] + scan.ranges[None, :] * jnp.sin(ang)
    j = jnp.floor(ex / resolution).astype(jnp.int32)
    i = jnp.floor(ey / resolution).astype(jnp.int32)
    ok = (scan.hit & jnp.isfinite(scan.ranges))[None, :]
    inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    d2 = dist2[jnp.clip(i, 0, h - 1), jnp.clip(j, 0, w - 1)].astype(jnp.float32)
    lik = jnp.where(inside, jnp.exp(-d2 * resolution**2 / (2 * sigma**2)), 0.0)
    n = jnp.maximum(ok.sum(), 1)
    return jnp.where(ok, lik, 0.0).sum(axis=1) / n


def _concrete64(*xs) -> bool:
    """True when no argument is traced and one of them is a float64 NumPy array: the host
    float64 paths (local frame) of :func:`scan_likelihood` and :func:`localize_with_count`."""
    if any(isinstance(x, jax.core.Tracer) for x in xs):
        return False
    return any(isinstance(x, np.ndarray) and x.dtype == np.float64 for x in xs)


def _relative(poses, origin) -> jax.Array:
    """``poses[:, :2] - origin`` ``[P, 2]`` float32: in float64 on the host for concrete
    float64 input (UTM-sized coordinates keep their 0.1 m), else in the input precision."""
    if _concrete64(poses, origin):
        return jnp.asarray(np.asarray(poses, np.float64)[:, :2]
                           - np.asarray(origin, np.float64), jnp.float32)
    return jnp.asarray(poses)[:, :2] - jnp.asarray(origin)


def kld_bound(k: jax.Array, epsilon: float, confidence: float) -> jax.Array:
    """Fox's (2003) sample count ``n_chi(k)`` for ``k`` occupied bins (0 for ``k <= 1``).

    Args:
        k: occupied bins (any shape).
        epsilon: the bound on the KL divergence.
        confidence: ``1 − δ``.

    Returns:
        float32 ``n_chi(k)``, the shape of ``k`` (B §4.3.2).

    >>> [round(float(kld_bound(jnp.array(k), 0.5, 0.95)), 1) for k in (1, 2, 10, 100)]
    [0.0, 3.7, 16.9, 123.2]
    """
    from jax.scipy.special import ndtri

    z = ndtri(confidence)
    km1 = jnp.maximum(jnp.asarray(k, jnp.float32) - 1.0, 1.0)
    a = 2.0 / (9.0 * km1)
    n = km1 / (2.0 * epsilon) * (1.0 - a + jnp.sqrt(a) * z) ** 3
    return jnp.where(k > 1, n, 0.0)


def kld_mask(poses: jax.Array, params: KLDParams | None = None) -> tuple[jax.Array, jax.Array]:
    """KLD-sampling on a drawn block: keep the first ``n`` particles of ``poses`` ``[N, 3]``.

    ``n`` is the first count with ``n >= max(n_min, n_chi(k_n))``, ``k_n`` the number of
    distinct pose bins among the first ``n`` particles (``N`` if the bound is never met).
    Distinct-bin counts of all prefixes come from one sort (first occurrence of each bin).

    Args:
        poses: ``[N, 3]`` drawn particles.
        params: :class:`KLDParams` (default ``KLDParams()``).

    Returns:
        ``(mask [N] bool, n)``.

    >>> tight = jnp.zeros((100, 3))                      # one bin: n_min particles
    >>> wide = jnp.arange(300.0).reshape(100, 3)          # every particle its own bin
    >>> int(kld_mask(tight)[1]), int(kld_mask(wide)[1])
    (10, 100)
    """
    params = KLDParams() if params is None else params
    n_all = poses.shape[0]
    b = jnp.floor(poses / jnp.asarray(params.bin_size, poses.dtype)).astype(jnp.int32)
    idx = jnp.arange(n_all)
    order = jnp.lexsort((idx, b[:, 2], b[:, 1], b[:, 0]))
    sb = b[order]
    first = jnp.concatenate([jnp.ones(1, bool), jnp.any(sb[1:] != sb[:-1], axis=1)])
    new = jnp.zeros(n_all, bool).at[order].set(first)
    k = jnp.cumsum(new)
    n = idx + 1
    need = jnp.maximum(kld_bound(k, params.epsilon, params.confidence), params.n_min)
    done = n >= need
    stop = jnp.where(done.any(), jnp.argmax(done) + 1, n_all)
    return idx < stop, stop


def _fit(x, wts, prior):
    """Weighted Gaussian of poses ``[N, 3]`` (headings relative to the prior's)."""
    rel = x.at[:, 2].set((x[:, 2] - prior[2] + jnp.pi) % (2 * jnp.pi) - jnp.pi)
    tot = wts.sum()
    ww = jnp.where(tot > 0, wts / jnp.maximum(tot, 1e-30), 1.0 / x.shape[0])
    mu = ww @ rel
    dev = rel - mu
    cov = (ww[:, None] * dev).T @ dev + 1e-8 * jnp.eye(3)
    return mu, cov


def _draw(key, mu, cov, n, prior):
    chol = jnp.linalg.cholesky(cov)
    z = jax.random.normal(key, (n, 3)) @ chol.T + mu
    return z.at[:, 2].set(z[:, 2] + prior[2])


def localize(key: jax.Array, prior: jax.Array, prev_odom: jax.Array, odom: jax.Array,
             scan: LidarScan, dist2: jax.Array, origin: jax.Array, resolution: float,
             c: jax.Array, method: str = "shrink_and_grow",
             params: LocalizeParams = DEFAULT_PARAMS) -> tuple[jax.Array, jax.Array]:
    """One localization step: ``(best pose [3], its likelihood)`` (B §4.3.2).

    Args:
        key: PRNG key.
        prior: ``[3]`` pose before the step.
        prev_odom, odom: ``[3]`` odometry readings before and after.
        scan: the scan at the new pose.
        dist2, origin, resolution: the map (see :func:`scan_likelihood`).
        c: ``[21]`` action model.
        method: one of :data:`METHODS`.
        params: static :class:`LocalizeParams`.

    Returns:
        ``(pose [3], likelihood)``: the best-scoring particle and its scan likelihood.

    Raises:
        ValueError: for an unknown ``method``.
    """
    pose, lik, _ = localize_with_count(key, prior, prev_odom, odom, scan, dist2, origin,
                                       resolution, c, method=method, params=params)
    return pose, lik


def localize_with_count(key: jax.Array, prior: jax.Array, prev_odom: jax.Array,
                        odom: jax.Array, scan: LidarScan, dist2: jax.Array, origin: jax.Array,
                        resolution: float, c: jax.Array, method: str = "shrink_and_grow",
                        params: LocalizeParams = DEFAULT_PARAMS,
                        budget: jax.Array | None = None
                        ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """:func:`localize` that also returns the number of particles scored (int32 scalar).

    Without ``params.kld`` the count is the fixed budget the method used (all blocks for
    PF and shrink, the stages up to the stopping one for grow, ...); with it, each proposal
    is cut by :func:`kld_mask`. ``budget`` (an int scalar, traced) keeps at most that many of
    the particles the method would score, the first in draw order (proposal blocks first,
    then refit draws): methods compared at an equal particle budget (issue 26). A refit
    (shrink, shrink-and-grow) fits its Gaussian to the budgeted particles only.

    World coordinates: with concrete float64 NumPy ``prior``, odometry or ``origin`` the step
    runs in a local frame at the prior's position, taken in float64 on the host (the map
    origin and the odometry step are differences taken before rounding to float32), and the
    pose comes back as float64 NumPy. So at UTM-sized coordinates (5e5, 4.2e6 m) the result
    equals the one at the origin, shifted (issue 26). Traced or float32 input takes the
    float32 path: inside one's own ``jit``, use local coordinates.

    Args:
        key, prior, prev_odom, odom, scan, dist2, origin, resolution, c, method, params: as
            :func:`localize`.
        budget: optional int scalar, the most particles scored (see above).

    Returns:
        ``(pose [3], likelihood, particles)``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not _concrete64(prior, prev_odom, odom, origin):
        return _localize_jit(key, prior, prev_odom, odom, scan, dist2, origin, resolution, c,
                             method=method, params=params, budget=budget)
    pr, po, od, org = (np.asarray(x, np.float64) for x in (prior, prev_odom, odom, origin))
    ref = pr[:2].copy()
    local = np.array([0.0, 0.0, pr[2]])
    step = np.concatenate([od[:2] - po[:2], od[2:]])
    pose, lik, n = _localize_jit(key, jnp.asarray(local, jnp.float32),
                                 jnp.asarray([0.0, 0.0, po[2]], jnp.float32),
                                 jnp.asarray(step, jnp.float32), scan, dist2,
                                 jnp.asarray(org - ref, jnp.float32), resolution, c,
                                 method=method, params=params, budget=budget)
    out = np.asarray(pose, np.float64)
    out[:2] += ref
    return out, lik, n


@partial(jax.jit, static_argnames=("method", "params"))
def _localize_jit(key: jax.Array, prior: jax.Array, prev_odom: jax.Array,
                        odom: jax.Array, scan: LidarScan, dist2: jax.Array, origin: jax.Array,
                        resolution: float, c: jax.Array, method: str = "shrink_and_grow",
                        params: LocalizeParams = DEFAULT_PARAMS,
                        budget: jax.Array | None = None
                        ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """:func:`localize_with_count` on float32 (or traced) input."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    kb, b = params.blocks, params.block
    keys = jax.random.split(key, 2 * kb)
    seed = jnp.tile(prior[None, :], (b, 1))

    def lik(p):
        return scan_likelihood(p, scan, dist2, origin, resolution, params.sigma)

    def kmask(p):
        if params.kld is None:
            return jnp.ones(p.shape[0], bool)
        return kld_mask(p, params.kld)[0]

    def cap(mask):  # the first ``budget`` particles of a mask in draw order
        if budget is None:
            return mask
        return mask & (jnp.cumsum(mask) <= jnp.maximum(jnp.asarray(budget, jnp.int32), 1))

    def best(p, lk, mask):
        mask = cap(mask)
        lk = jnp.where(mask, lk, -1.0)
        k = jnp.argmax(lk)
        return p[k], lk[k], mask.sum().astype(jnp.int32)

    if method == "raw":
        p = sample_motion(keys[0], prior[None, :], prev_odom, odom, c, 0.0)
        return p[0], lik(p)[0], jnp.int32(1)
    if method == "pf":
        p = jnp.concatenate([sample_motion(keys[k], seed, prev_odom, odom, c)
                             for k in range(kb)])
        return best(p, lik(p), kmask(p))
    if method == "shrink":
        p0 = sample_motion(keys[0], seed, prev_odom, odom, c)
        l0, m0 = lik(p0), cap(kmask(p0))
        mu, cov = _fit(p0, l0 if params.kld is None and budget is None else l0 * m0, prior)
        p1 = _draw(keys[1], mu, cov, (kb - 1) * b, prior)
        p = jnp.concatenate([p0, p1])
        lk = jnp.concatenate([l0, lik(p1)])
        return best(p, lk, jnp.concatenate([m0, kmask(p1)]))
    blocks = [sample_motion(keys[k], seed, prev_odom, odom, c, 2.0**k) for k in range(kb)]
    bmask = jnp.stack([kmask(p) for p in blocks])          # [K, B] KLD cut of each stage
    lk = jnp.stack([lik(p) for p in blocks])               # [K, B] grown proposals
    stage_best = jnp.where(bmask, lk, -1.0).max(axis=1)
    good = stage_best >= params.threshold * params.anneal ** jnp.arange(kb)
    first = jnp.where(good.any(), jnp.argmax(good), kb - 1)
    used = (jnp.arange(kb) <= first)[:, None] & bmask
    props = jnp.concatenate(blocks)
    if method == "grow":
        return best(props, lk.reshape(-1), used.reshape(-1))
    # shrink-and-grow: the stage that found a good particle is shrunk with the budget left
    stage = jnp.stack(blocks)[first]
    seen = cap(used.reshape(-1)).reshape(kb, b)      # the budget's share of the stages
    wts = lk[first] if params.kld is None and budget is None else lk[first] * seen[first]
    mu, cov = _fit(stage, wts, prior)
    extra = _draw(keys[kb], mu, cov, (kb - 1) * b, prior)
    left = jnp.arange((kb - 1) * b) < (kb - 1 - first) * b
    if params.kld is not None:
        left = left & kmask(extra)
    p = jnp.concatenate([props, extra])
    mask = jnp.concatenate([used.reshape(-1), left & good.any()])
    return best(p, jnp.concatenate([lk.reshape(-1), lik(extra)]), mask)
