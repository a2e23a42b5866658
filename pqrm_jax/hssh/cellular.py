"""Cellular stages of gateway detection as batched JAX programs (B §6.1.1, §6.3.1).

Every function here works on a stack of equal-size grids ``[B, H, W]`` with static shapes and
``lax.while_loop`` / ``lax.fori_loop`` iterations (no Python loop over images or cells):

* :func:`remove_islands` -- flood fill over non-free cells from the grid border; every
  non-free component that does not touch the border becomes free (B §6.1.1). 4-connectivity
  between non-free cells: with it uniform free-cell noise stays a set of finite clusters up to
  the site-percolation threshold (~59 %), which is what lets the +-corpus survive 50 % noise.
* :func:`squared_distance_transform` -- exact squared Euclidean distance from each cell to the
  nearest occupied cell (the Voronoi radius ``r_p``, B Alg. 6.1), two separable passes; an
  optional cap ``K`` keeps only distances ``<= K`` exact (the rest are reported ``> K``).
* :func:`zhang_suen_thin` -- parallel Zhang--Suen thinning (Zhang & Suen 1984; B §6.1.1) by
  a 256-entry look-up table, with cells that may never be deleted (``protect``) and a choice
  of what lies beyond the grid border (``pad``).
* :func:`evg_skeleton` -- the thinning approximation of the extended Voronoi graph capped at
  ``M`` (B §6.3.1): cells at distance ``>= M`` stop the wavefront; the remaining blob is cut
  to its iso-distance-``M`` rim and thinned again.
* :func:`cellular_stages` -- the whole cellular pipeline (island removal, obstacle bleeding
  by the robot radius, distance transform, EVG skeleton) for a stack of grids.

Grid convention: ``occupied`` and ``unknown`` are bool ``[B, H, W]``; a cell is free when it is
neither. Beyond the border the skeleton continues (``pad=True`` in the EVG), so skeleton
branches reach the border where the frontier-based pruning finds its *exits* (B Fig. 6.3).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "CellularMaps",
    "zhang_suen_lut",
    "remove_islands",
    "squared_distance_transform",
    "zhang_suen_thin",
    "evg_skeleton",
    "cellular_stages",
]


class CellularMaps(NamedTuple):
    """Output of :func:`cellular_stages`, every field ``[B, H, W]``.

    occupied: obstacles after island removal and bleeding (the obstacles gateways end on).
    unknown: unknown cells kept after island removal (they count as free for the skeleton).
    free_space: cells that are neither ``occupied`` nor ``unknown`` after island removal but
        before bleeding (robot reachability is computed in it).
    dist2: squared Euclidean distance to the nearest ``occupied`` cell (int32; cells farther
        than the cap hold ``cap**2 + 1`` or more).
    skeleton: the EVG skeleton (bool), before frontier pruning.
    """

    occupied: jax.Array
    unknown: jax.Array
    free_space: jax.Array
    dist2: jax.Array
    skeleton: jax.Array


def zhang_suen_lut() -> np.ndarray:
    """The Zhang--Suen deletion table ``[256]`` (uint8): bit 0 = deletable in sub-iteration 1,
    bit 1 = deletable in sub-iteration 2.

    A neighbourhood code sums ``2**k`` over the set neighbours, ``k`` running clockwise from
    north-west (NW, N, NE, E, SE, S, SW, W). Zhang & Suen's rules with ``P2 = N`` … ``P9 = NW``:
    ``2 <= B(P) <= 6`` set neighbours, exactly one 0→1 transition around P, and
    ``P2 P4 P6 = P4 P6 P8 = 0`` (first) or ``P2 P4 P8 = P2 P6 P8 = 0`` (second).

    >>> lut = zhang_suen_lut()
    >>> int(lut[0]), int(lut[2 + 4 + 8]), int(lut[2 + 8]), int(lut[255])
    (0, 3, 0, 0)

    (isolated cell; N+NE+E corner, deletable in both; N+E without NE, two 0→1 transitions;
    interior.) scikit-image's ``skeletonize(method='zhang')`` uses a different hand-made
    table (e.g. it deletes the N+E pattern; scikit-image issue #6175 notes its table cannot
    be derived from the paper), so its skeletons are close but not identical.
    """
    lut = np.zeros(256, np.uint8)
    for code in range(256):
        nw, n, ne, e, se, s, sw, w = ((code >> k) & 1 for k in range(8))
        ring = [n, ne, e, se, s, sw, w, nw]  # P2..P9
        b = sum(ring)
        a = sum(1 for k in range(8) if ring[k] == 0 and ring[(k + 1) % 8] == 1)
        if not (2 <= b <= 6 and a == 1):
            continue
        if n * e * s == 0 and e * s * w == 0:
            lut[code] |= 1
        if n * e * w == 0 and n * s * w == 0:
            lut[code] |= 2
    return lut


def _shift(x: jax.Array, di: int, dj: int, fill) -> jax.Array:
    """``y[..., i, j] = x[..., i + di, j + dj]`` with ``fill`` beyond the border."""
    h, w = x.shape[-2:]
    pad = [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)]
    xp = jnp.pad(x, pad, constant_values=fill)
    return xp[..., 1 + di:1 + di + h, 1 + dj:1 + dj + w]


def _dilate4(x: jax.Array) -> jax.Array:
    return (x | _shift(x, -1, 0, False) | _shift(x, 1, 0, False)
            | _shift(x, 0, -1, False) | _shift(x, 0, 1, False))


@jax.jit
def remove_islands(occupied: jax.Array, unknown: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Free every non-free component that does not touch the border (B §6.1.1).

    Args:
        occupied: bool ``[B, H, W]``.
        unknown: bool ``[B, H, W]``.

    Returns:
        ``(occupied, unknown)`` with the islands cleared (bool ``[B, H, W]`` each).

    >>> occ = jnp.zeros((1, 5, 5), bool).at[0, 2, 2].set(True).at[0, 0, :].set(True)
    >>> o, u = remove_islands(occ, jnp.zeros_like(occ))
    >>> int(o.sum()), bool(o[0, 2, 2])
    (5, False)
    """
    nonfree = occupied | unknown
    h, w = nonfree.shape[-2:]
    border = jnp.zeros((h, w), bool).at[0, :].set(True).at[-1, :].set(True)
    border = border.at[:, 0].set(True).at[:, -1].set(True)
    seed = nonfree & border

    def body(state):
        reached, _ = state
        new = reached
        for _ in range(4):  # several fronts per loop trip: fewer loop-condition round trips
            new = nonfree & _dilate4(new)
        return new, jnp.any(new != reached)

    reached, _ = jax.lax.while_loop(lambda s: s[1], body, (seed, jnp.array(True)))
    return occupied & reached, unknown & reached


@partial(jax.jit, static_argnames="cap")
def squared_distance_transform(occupied: jax.Array, cap: int | None = None) -> jax.Array:
    """Exact squared Euclidean distance to the nearest occupied cell, ``[B, H, W]`` int32.

    First pass: distance along each row to the nearest obstacle (running max/min of obstacle
    indices). Second pass: ``d2[i, j] = min_k g[i + k, j]**2 + k**2`` over row offsets
    ``|k| <= cap`` (all offsets when ``cap`` is None). Distances ``<= cap`` are exact; cells
    farther than ``cap`` hold a value ``> cap**2``. Without obstacles every cell holds a
    large sentinel (``> (H + W)**2``). Cells outside the grid are not obstacles (as in
    ``scipy.ndimage.distance_transform_edt`` of the free mask).

    >>> occ = jnp.zeros((1, 3, 4), bool).at[0, 0, 0].set(True)
    >>> squared_distance_transform(occ)[0].tolist()
    [[0, 1, 4, 9], [1, 2, 5, 10], [4, 5, 8, 13]]
    """
    h, w = occupied.shape[-2:]
    big = 2 * (h + w) + 2
    j = jnp.arange(w, dtype=jnp.int32)
    left = jax.lax.cummax(jnp.where(occupied, j, -big), axis=occupied.ndim - 1)
    right = jax.lax.cummin(jnp.where(occupied, j, 2 * big), axis=occupied.ndim - 1,
                           reverse=True)
    g = jnp.minimum(j - left, right - j)
    g = jnp.minimum(g, big)
    g2 = g * g
    k_max = h - 1 if cap is None else min(int(cap) + 1, h - 1)
    pad = [(0, 0)] * (g2.ndim - 2) + [(k_max, k_max), (0, 0)]
    gp = jnp.pad(g2, pad, constant_values=big * big)

    def body(k, best):
        sl = jax.lax.dynamic_slice_in_dim(gp, k, h, axis=g2.ndim - 2)
        off = k - k_max
        return jnp.minimum(best, sl + off * off)

    return jax.lax.fori_loop(0, 2 * k_max + 1, body, g2)


def _ring(x: jax.Array, pad: bool) -> list[jax.Array]:
    """The 8 neighbours P2..P9 (N, NE, E, SE, S, SW, W, NW) of every cell, one pad."""
    h, w = x.shape[-2:]
    xp = jnp.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)], constant_values=pad)
    order = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))
    return [xp[..., 1 + di:1 + di + h, 1 + dj:1 + dj + w] for di, dj in order]


def _deletable(x: jax.Array, pad: bool, first: bool) -> jax.Array:
    """Zhang--Suen deletion test (the rules of :func:`zhang_suen_lut`) as fused array ops."""
    p = _ring(x, pad)
    b = sum(q.astype(jnp.int8) for q in p)
    a = sum((~p[k] & p[(k + 1) % 8]).astype(jnp.int8) for k in range(8))
    n, e, s, w = p[0], p[2], p[4], p[6]
    if first:
        c = ~(n & e & s) & ~(e & s & w)
    else:
        c = ~(n & e & w) & ~(n & s & w)
    return x & (b >= 2) & (b <= 6) & (a == 1) & c


@partial(jax.jit, static_argnames="pad")
def zhang_suen_thin(fg: jax.Array, protect: jax.Array | None = None,
                    pad: bool = False) -> jax.Array:
    """Zhang--Suen thinning of a stack of binary images ``[B, H, W]`` to convergence.

    Both sub-iterations are parallel: each reads the image left by the previous one (Zhang &
    Suen 1984, the rules of :func:`zhang_suen_lut`). ``protect`` (bool ``[B, H, W]``) marks
    cells never deleted; ``pad`` is the value assumed beyond the border.

    >>> img = jnp.zeros((1, 5, 9), bool).at[0, 1:4, 1:8].set(True)
    >>> zhang_suen_thin(img)[0].astype(int).tolist()[2]
    [0, 0, 1, 1, 1, 1, 0, 0, 0]
    """
    keep = jnp.zeros(fg.shape, bool) if protect is None else protect

    def sub(x, first):
        return x & ~(_deletable(x, pad, first) & ~keep)

    def body(state):
        x, _ = state
        y = sub(sub(x, True), False)
        return y, jnp.any(y != x)

    out, _ = jax.lax.while_loop(lambda s: s[1], body, (fg, jnp.array(True)))
    return out


@partial(jax.jit, static_argnames="m_cap")
def evg_skeleton(free: jax.Array, dist2: jax.Array, m_cap: float) -> jax.Array:
    """Thinning approximation of the extended Voronoi graph capped at ``m_cap`` (B §6.3.1).

    Cells of ``free`` at distance ``>= m_cap`` from every obstacle never burn, so the wavefront
    stops there (B Fig. 6.14); the unburnt blob is then cut to its rim (distance
    ``< m_cap + 1.5``) and thinned again, which leaves the iso-distance-``M`` curve joined to the
    Voronoi branches. Beyond the border the image continues as foreground, so branches run
    into the border (the frontier exits of B §6.1.1).

    Args:
        free: bool ``[B, H, W]`` cells the skeleton may use (free or unknown).
        dist2: squared distances ``[B, H, W]`` from :func:`squared_distance_transform`.
        m_cap: the cap ``M`` in cells (B: ``side / 5``).

    Returns:
        bool ``[B, H, W]`` skeleton.
    """
    far = free & (dist2 >= m_cap * m_cap)
    first = zhang_suen_thin(free, far, pad=True)
    rim = first & (dist2 < (m_cap + 1.5) ** 2)
    return zhang_suen_thin(rim, None, pad=True)


def _bleed_and_distance(occupied, radius, cap):
    dist2 = squared_distance_transform(occupied, cap=cap)
    if radius > 0:
        occupied = occupied | (dist2 <= radius * radius)
        dist2 = squared_distance_transform(occupied, cap=cap)
    return occupied, dist2


def cellular_stages(occupied: jax.Array, unknown: jax.Array, *, robot_radius: float = 0.0,
                    m_cap: float | None = None) -> CellularMaps:
    """Run island removal, bleeding, the distance transform and the EVG skeleton on a stack.

    Args:
        occupied: bool ``[B, H, W]``.
        unknown: bool ``[B, H, W]``.
        robot_radius: bleed obstacles by this many cells (B §6.1.1; 0 = none).
        m_cap: EVG cap ``M`` in cells; default ``min(H, W) / 5`` (B §6.3.1, ``c = 5``).

    Returns:
        :class:`CellularMaps` (a horizontal corridor through the grid thins to its midline
        row, reaching both borders; see ``tests/test_hssh.py``).
    """
    occupied = jnp.asarray(occupied, bool)
    unknown = jnp.asarray(unknown, bool)
    h, w = occupied.shape[-2:]
    m = float(min(h, w) / 5.0 if m_cap is None else m_cap)
    cap = int(np.ceil(m + 2.0 + robot_radius))
    return _cellular(occupied, unknown, float(robot_radius), m, cap)


@partial(jax.jit, static_argnames=("radius", "m", "cap"))
def _cellular(occupied, unknown, radius, m, cap):
    occ, unk = remove_islands(occupied, unknown)
    free_space = ~(occ | unk)
    occ_b, dist2 = _bleed_and_distance(occ, radius, cap)
    skel = evg_skeleton(~occ_b, dist2, m)
    return CellularMaps(occ_b, unk & ~occ_b, free_space, dist2, skel)
