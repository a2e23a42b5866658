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
occupied cell (in ``(0, 1]``; 0 without a usable beam). B used KLD-sampling with at most 500
particles (100 per stage x 5) and Konolige's likelihood; the fixed blocks and the likelihood
field are this library's choices.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from pqrm_jax.hssh.motion import sample_motion
from pqrm_jax.sim.lidar import LidarScan

__all__ = ["METHODS", "LocalizeParams", "DEFAULT_PARAMS", "scan_likelihood", "localize"]

METHODS = ("raw", "pf", "shrink", "grow", "shrink_and_grow")


class LocalizeParams(NamedTuple):
    """blocks x block particles; likelihood-field sigma (world units); stopping threshold and
    its per-stage annealing factor (grow, shrink-and-grow)."""

    blocks: int = 5
    block: int = 100
    sigma: float = 0.1
    threshold: float = 0.8
    anneal: float = 0.9


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

    >>> d2 = jnp.zeros((4, 4), jnp.int32)
    >>> z = LidarScan(jnp.array([0.0]), jnp.array([1.0]), jnp.array([True]))
    >>> float(scan_likelihood(jnp.array([[1.0, 1.0, 0.0]]), z, d2, jnp.zeros(2), 1.0, 0.5)[0])
    1.0
    """
    h, w = dist2.shape
    ang = poses[:, 2, None] + scan.angles[None, :]
    ex = poses[:, 0, None] + scan.ranges[None, :] * jnp.cos(ang)
    ey = poses[:, 1, None] + scan.ranges[None, :] * jnp.sin(ang)
    j = jnp.floor((ex - origin[0]) / resolution).astype(jnp.int32)
    i = jnp.floor((ey - origin[1]) / resolution).astype(jnp.int32)
    ok = (scan.hit & jnp.isfinite(scan.ranges))[None, :]
    inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    d2 = dist2[jnp.clip(i, 0, h - 1), jnp.clip(j, 0, w - 1)].astype(jnp.float32)
    lik = jnp.where(inside, jnp.exp(-d2 * resolution**2 / (2 * sigma**2)), 0.0)
    n = jnp.maximum(ok.sum(), 1)
    return jnp.where(ok, lik, 0.0).sum(axis=1) / n


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


@partial(jax.jit, static_argnames=("method", "params"))
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
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    kb, b = params.blocks, params.block
    keys = jax.random.split(key, 2 * kb)
    seed = jnp.tile(prior[None, :], (b, 1))

    def lik(p):
        return scan_likelihood(p, scan, dist2, origin, resolution, params.sigma)

    def best(p, lk, mask):
        lk = jnp.where(mask, lk, -1.0)
        k = jnp.argmax(lk)
        return p[k], lk[k]

    if method == "raw":
        p = sample_motion(keys[0], prior[None, :], prev_odom, odom, c, 0.0)
        return p[0], lik(p)[0]
    if method == "pf":
        p = jnp.concatenate([sample_motion(keys[k], seed, prev_odom, odom, c)
                             for k in range(kb)])
        lk = lik(p)
        return best(p, lk, jnp.ones_like(lk, bool))
    if method == "shrink":
        p0 = sample_motion(keys[0], seed, prev_odom, odom, c)
        l0 = lik(p0)
        mu, cov = _fit(p0, l0, prior)
        p1 = _draw(keys[1], mu, cov, (kb - 1) * b, prior)
        p = jnp.concatenate([p0, p1])
        lk = jnp.concatenate([l0, lik(p1)])
        return best(p, lk, jnp.ones_like(lk, bool))
    blocks = [sample_motion(keys[k], seed, prev_odom, odom, c, 2.0**k) for k in range(kb)]
    lk = jnp.stack([lik(p) for p in blocks])               # [K, B] grown proposals
    good = lk.max(axis=1) >= params.threshold * params.anneal ** jnp.arange(kb)
    first = jnp.where(good.any(), jnp.argmax(good), kb - 1)
    used = jnp.arange(kb) <= first
    props = jnp.concatenate(blocks)
    if method == "grow":
        return best(props, lk.reshape(-1), jnp.repeat(used, b))
    # shrink-and-grow: the stage that found a good particle is shrunk with the budget left
    stage = jnp.stack(blocks)[first]
    mu, cov = _fit(stage, lk[first], prior)
    extra = _draw(keys[kb], mu, cov, (kb - 1) * b, prior)
    left = jnp.arange((kb - 1) * b) < (kb - 1 - first) * b
    p = jnp.concatenate([props, extra])
    mask = jnp.concatenate([jnp.repeat(used, b), left & good.any()])
    return best(p, jnp.concatenate([lk.reshape(-1), lik(extra)]), mask)
