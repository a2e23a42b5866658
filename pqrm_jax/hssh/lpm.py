"""The local perceptual map: a scrolling log-odds occupancy grid (B §3.3, §4.1).

A bounded robot-centred grid ``[N, N]`` of occupancy log-odds (0 = unknown, the 0.5 prior).
Each update first *scrolls* the map by whole cells so the robot sits in the central cell
``(N // 2, N // 2)`` -- no rotation or partial-cell shift, which would blur it; cells that scroll
off are dropped, cells that scroll in are unknown -- then adds one lidar scan: cells a beam
crosses before its hit get ``l_free``, the hit cell ``l_occ`` (each cell at most once per scan),
clipped to ``[l_min, l_max]``. Cells are classified occupied / free / unknown by two
thresholds. Constant cost per update; pure functions over :class:`LPMState`, so ``jax.vmap``
batches runs.

Grid convention as :mod:`pqrm_jax.sim.lidar`: row ``i`` along y, column ``j`` along x, cell
``(i, j)`` covers ``[x0 + j r, x0 + (j + 1) r) x [y0 + i r, y0 + (i + 1) r)`` for ``origin =
(x0, y0)``. For :func:`pqrm_jax.hssh.local_topology`, whose stars run clockwise on the
image with row 0 at the top, pass ``occupied[::-1]`` to get world-clockwise stars.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.sim.lidar import LidarScan

__all__ = ["LPMParams", "DEFAULT", "LPMState", "lpm_init", "lpm_update", "lpm_classify"]


class LPMParams(NamedTuple):
    """LPM parameters (B's implementation: 300 x 300 cells of 5 cm).

    size: cells per side (static).
    resolution: cell size (world units).
    l_occ, l_free: log-odds added to a hit cell / a traversed cell.
    l_min, l_max: clipping range.
    occ_threshold, free_threshold: log-odds above which a cell is occupied / below which
        it is free (in between: unknown).
    """

    size: int = 300
    resolution: float = 0.05
    l_occ: float = 0.85
    l_free: float = -0.4
    l_min: float = -4.0
    l_max: float = 4.0
    occ_threshold: float = 0.4
    free_threshold: float = -0.2


DEFAULT = LPMParams()


class LPMState(NamedTuple):
    """logodds: ``[N, N]``; origin: ``[2]`` world (x, y) of cell (0, 0)'s corner (float32);
    origin_lo: ``[2]`` the part of the origin float32 cannot hold (``origin + origin_lo`` is
    the origin to float64 precision, zero unless the LPM was started from a float64 pose).

    At world coordinates of a UTM size (5e5, 4.2e6 m) float32 holds positions only to
    0.03--0.5 m; the LPM then keeps every position as this two-float sum and takes differences
    of the large parts first (exact when they are close, Sterbenz), so a 5 cm grid at such
    coordinates equals the one at the origin. Pass float64 poses (NumPy) to get this.
    """

    logodds: jax.Array
    origin: jax.Array
    origin_lo: jax.Array = np.zeros(2, np.float32)


def _split(pose, name: str = "pose"):
    """``(hi, lo)`` float32 ``[3]`` parts of a pose: ``hi + lo`` is a float64 pose to ~1e-14
    relative precision; a traced or float32 pose gives ``lo = 0`` (unchanged behaviour).
    Raises ``ValueError`` for a concrete non-finite pose."""
    if isinstance(pose, jax.core.Tracer):
        p = jnp.asarray(pose, jnp.float32)
        return p, jnp.zeros_like(p)
    a = np.asarray(pose)
    if a.shape != (3,):
        raise ValueError(f"{name} must be [3] (x, y, theta), got shape {a.shape}")
    if not np.all(np.isfinite(a.astype(np.float64))):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    if a.dtype != np.float64:
        p = jnp.asarray(a, jnp.float32)
        return p, jnp.zeros_like(p)
    hi = a.astype(np.float32)
    lo = (a - hi.astype(np.float64)).astype(np.float32)
    return jnp.asarray(hi), jnp.asarray(lo)


def lpm_init(pose: jax.Array, params: LPMParams = DEFAULT) -> LPMState:
    """An all-unknown LPM with the robot (``pose`` = x, y, theta) in the central cell.

    A float64 ``pose`` (NumPy) keeps its full precision in ``origin + origin_lo`` (see
    :class:`LPMState`); a non-finite pose raises ``ValueError``.

    Args:
        pose: ``[3]`` the robot's pose (the LPM's frame, B §4.1).
        params: the LPM parameters (``size`` cells of ``resolution``).

    Returns:
        :class:`LPMState` with ``logodds [N, N]`` zeros and ``origin [2]``
        (and ``origin_lo [2]``).

    >>> s = lpm_init(jnp.array([1.0, 2.0, 0.0]), LPMParams(size=5, resolution=1.0))
    >>> s.origin.tolist(), float(s.logodds.sum())
    ([-1.0, 0.0], 0.0)
    """
    n, r = params.size, params.resolution
    hi, lo = _split(pose)
    if isinstance(pose, jax.core.Tracer) or np.asarray(pose).dtype != np.float64:
        cell = jnp.floor(hi[:2] / r)
        origin = (cell - n // 2) * r
        return LPMState(jnp.zeros((n, n), jnp.float32), origin.reshape(1, 2)[0],
                        jnp.zeros(2, jnp.float32))
    p = np.asarray(pose, np.float64)
    origin = (np.floor(p[:2] / np.float64(np.float32(r))) - n // 2) * np.float64(np.float32(r))
    o_hi = origin.astype(np.float32)
    o_lo = (origin - o_hi.astype(np.float64)).astype(np.float32)
    return LPMState(jnp.zeros((n, n), jnp.float32), jnp.asarray(o_hi), jnp.asarray(o_lo))


def lpm_update(state: LPMState, pose: jax.Array, scan: LidarScan,
               params: LPMParams = DEFAULT) -> LPMState:
    """Scroll the LPM to keep the robot central, then add one scan (B §4.1).

    Positions are differences taken before rounding to float32: ``pose - origin`` is
    ``(pose_hi - origin) + (pose_lo - origin_lo)`` with a float64 pose split into two float32
    parts (see :class:`LPMState`), so the map does not depend on where the world origin is.

    Args:
        state: the current :class:`LPMState`.
        pose: ``[3]`` robot (x, y, theta) in the world frame at the scan (float64 NumPy keeps
            UTM-sized coordinates exact; a concrete non-finite pose raises ``ValueError``).
        scan: a :class:`~pqrm_jax.sim.lidar.LidarScan` (angles in the robot frame).
        params: static :class:`LPMParams`.

    Returns:
        the updated :class:`LPMState`.

    >>> from pqrm_jax.sim.lidar import LidarScan
    >>> p = LPMParams(size=7, resolution=1.0)
    >>> s = lpm_init(jnp.array([3.5, 3.5, 0.0]), p)
    >>> scan = LidarScan(jnp.array([0.0]), jnp.array([2.2]), jnp.array([True]))
    >>> s = lpm_update(s, jnp.array([3.5, 3.5, 0.0]), scan, p)
    >>> (jnp.sign(s.logodds[3]).astype(int)).tolist()
    [0, 0, 0, -1, -1, 1, 0]
    """
    hi, lo = _split(pose)
    return _lpm_update(state, hi, lo, scan, params)


@partial(jax.jit, static_argnames="params")
def _lpm_update(state: LPMState, pose: jax.Array, pose_lo: jax.Array, scan: LidarScan,
                params: LPMParams) -> LPMState:
    """:func:`lpm_update` on a pose split into float32 ``pose + pose_lo`` parts."""
    n, r = params.size, params.resolution
    pose = jnp.asarray(pose, jnp.float32)
    o_hi = jnp.asarray(state.origin, jnp.float32)
    o_lo = jnp.asarray(state.origin_lo, jnp.float32)
    # scroll by whole cells so the robot is in cell (n // 2, n // 2); differences of the large
    # parts first (exact when close), then of the small parts
    rel = (pose[:2] - o_hi) + (pose_lo[:2] - o_lo)
    rc = jnp.floor(rel / r).astype(jnp.int32)  # (col, row) = (x, y)
    k = jnp.clip(rc - n // 2, -n, n)
    padded = jnp.pad(state.logodds, n)
    lo = jax.lax.dynamic_slice(padded, (n + k[1], n + k[0]), (n, n))
    step = k.astype(jnp.float32) * r
    new_hi = o_hi + step   # two-sum: new_hi + err is o_hi + step exactly
    back = new_hi - o_hi
    err = (o_hi - (new_hi - back)) + (step - back)
    new_lo = o_lo + err
    rel = (pose[:2] - new_hi) + (pose_lo[:2] - new_lo)  # robot in the new LPM frame
    # ray update: sample each beam every r / 2 up to its range
    m = 2 * n + 2
    t = (jnp.arange(m, dtype=jnp.float32) + 0.5) * (r / 2)
    ang = pose[2] + scan.angles
    rng = scan.ranges
    px = rel[0] + t[None, :] * jnp.cos(ang)[:, None]
    py = rel[1] + t[None, :] * jnp.sin(ang)[:, None]
    j = jnp.floor(px / r).astype(jnp.int32)
    i = jnp.floor(py / r).astype(jnp.int32)
    inside = (i >= 0) & (i < n) & (j >= 0) & (j < n) & jnp.isfinite(rng)[:, None]
    hx = rel[0] + rng * jnp.cos(ang)
    hy = rel[1] + rng * jnp.sin(ang)
    hj = jnp.floor(hx / r).astype(jnp.int32)
    hi = jnp.floor(hy / r).astype(jnp.int32)
    hit_ok = scan.hit & (hi >= 0) & (hi < n) & (hj >= 0) & (hj < n) & jnp.isfinite(rng)
    before = t[None, :] < rng[:, None]
    not_hit_cell = ~((i == hi[:, None]) & (j == hj[:, None]) & scan.hit[:, None])
    free_s = inside & before & not_hit_cell
    ic, jc = jnp.clip(i, 0, n - 1), jnp.clip(j, 0, n - 1)
    free = jnp.zeros((n, n), bool).at[ic, jc].max(free_s)
    occ = jnp.zeros((n, n), bool).at[jnp.clip(hi, 0, n - 1), jnp.clip(hj, 0, n - 1)].max(hit_ok)
    lo = lo + jnp.where(occ, params.l_occ, jnp.where(free, params.l_free, 0.0))
    return LPMState(jnp.clip(lo, params.l_min, params.l_max), new_hi, new_lo)


def lpm_classify(state: LPMState,
                 params: LPMParams = DEFAULT) -> tuple[jax.Array, jax.Array]:
    """``(occupied, unknown)`` bool ``[N, N]`` masks of an LPM (the rest is free).

    Args:
        state: the LPM.
        params: its thresholds (B §4.1).

    Returns:
        ``(occupied [N, N], unknown [N, N])`` bool.

    >>> s = LPMState(jnp.array([[1.0, 0.0, -1.0]]), jnp.zeros(2))
    >>> [m.astype(int).tolist() for m in lpm_classify(s)]
    [[[1, 0, 0]], [[0, 1, 0]]]
    """
    occ = state.logodds > params.occ_threshold
    free = state.logodds < params.free_threshold
    return occ, ~occ & ~free
