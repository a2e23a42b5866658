"""Cellular stages of gateway detection as batched JAX programs (B §6.1.1, §6.3.1).

Every function here works on a stack of equal-size grids ``[B, H, W]`` with static shapes and
``lax.while_loop`` / ``lax.fori_loop`` iterations (no Python loop over images or cells):

* :func:`remove_islands` -- flood fill over bit-packed non-free cells from the grid border; every
  non-free component that does not touch the border becomes free (B §6.1.1). 4-connectivity
  between non-free cells: with it uniform free-cell noise stays a set of finite clusters up to
  the site-percolation threshold (~59 %), which is what lets the +-corpus survive 50 % noise.
* :func:`squared_distance_transform` -- exact squared Euclidean distance from each cell to the
  nearest occupied cell (the Voronoi radius ``r_p``, B Alg. 6.1), two separable passes; an
  optional cap ``K`` keeps only distances ``<= K`` exact (the rest are reported ``> K``).
* :func:`zhang_suen_thin` -- parallel Zhang--Suen thinning (Zhang & Suen 1984; B §6.1.1),
  the rules of :func:`zhang_suen_lut` as bitwise operations on bit-packed rows (32 cells per
  uint32 word), with cells that may never be deleted (``protect``) and a choice of what lies
  beyond the grid border (``pad``).
* :func:`evg_skeleton` -- the thinning approximation of the extended Voronoi graph capped at
  ``M`` (B §6.3.1): cells at distance ``>= M`` stop the wavefront; the remaining blob is cut
  to its iso-distance-``M`` rim and thinned again.
* :func:`cellular_stages` -- the whole cellular pipeline (island removal, obstacle bleeding
  by the robot radius, distance transform, EVG skeleton) for a stack of grids.

Speed: the flood fill and the thinning work on bit-packed rows (:func:`_pack`: uint32 words
of 32 columns inside a one-word frame holding the value beyond the border), so one bitwise
operation updates 32 cells and every neighbour is a static slice; both iterate with
``while_loop`` to the fixpoint (results are exactly those of the cell-by-cell rules, see
``tests/test_hssh.py``).

Grid convention: ``occupied`` and ``unknown`` are bool ``[B, H, W]``; a cell is free when it is
neither. Beyond the border the skeleton continues (``pad=True`` in the EVG), so skeleton
branches reach the border where the frontier-based pruning finds its *exits* (B Fig. 6.3).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "CHUNK_CELLS",
    "CellularMaps",
    "zhang_suen_lut",
    "remove_islands",
    "squared_distance_transform",
    "zhang_suen_thin",
    "evg_skeleton",
    "cellular_stages",
    "check_m_cap",
    "check_positive_finite",
    "check_robot_radius",
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


_WORD = 32  # cells per packed word (uint32)
_ALL = 0xFFFFFFFF
_EDT_CHUNK = 16  # row offsets per fused pass of the distance transform


def _pack(x: jax.Array, fill: bool) -> jax.Array:
    """Bit-pack a bool ``[..., H, W]`` along the columns into uint32 words ``[..., H + 2, NW + 2]``.

    Bit ``k`` of word ``q`` holds column ``32 q + k``; columns past ``W`` in the last word and
    the frame of one row / one word around the grid hold ``fill`` (the value assumed beyond the
    border), so every neighbour of a grid cell is a static slice of the packed array.
    """
    w = x.shape[-1]
    nw = -(-w // _WORD)
    lead = [(0, 0)] * (x.ndim - 1)
    xp = jnp.pad(x, lead + [(0, nw * _WORD - w)], constant_values=fill)
    xp = xp.reshape(x.shape[:-1] + (nw, _WORD)).astype(jnp.uint32)
    words = jnp.sum(xp << jnp.arange(_WORD, dtype=jnp.uint32), axis=-1, dtype=jnp.uint32)
    return jnp.pad(words, lead[:-1] + [(1, 1), (1, 1)],
                   constant_values=jnp.uint32(_ALL if fill else 0))


def _unpack(p: jax.Array, w: int) -> jax.Array:
    """Inverse of :func:`_pack`: the bool ``[..., H, W]`` grid inside the frame."""
    inner = p[..., 1:-1, 1:-1]
    bits = (inner[..., None] >> jnp.arange(_WORD, dtype=jnp.uint32)) & jnp.uint32(1)
    return bits.reshape(inner.shape[:-1] + (-1,))[..., :w].astype(bool)


def _neighbours(p: jax.Array) -> tuple[list[jax.Array], jax.Array]:
    """The 8 neighbour words P2..P9 (N, NE, E, SE, S, SW, W, NW) of every interior word of a
    framed packed array, and the interior itself (all ``[..., H, NW]``)."""
    h, nw = p.shape[-2] - 2, p.shape[-1] - 2

    def at(di, dq):
        return p[..., 1 + di:1 + di + h, 1 + dq:1 + dq + nw]

    def east(di):  # column j + 1: shift down one bit, the next word's bit 0 comes in on top
        return (at(di, 0) >> 1) | (at(di, 1) << (_WORD - 1))

    def west(di):  # column j - 1
        return (at(di, 0) << 1) | (at(di, -1) >> (_WORD - 1))

    return [at(-1, 0), east(-1), east(0), east(1), at(1, 0), west(1), west(0), west(-1)], at(0, 0)


def _at_least_two(words: list[jax.Array]) -> tuple[jax.Array, jax.Array]:
    """Bitwise (at least one, at least two) of a list of words."""
    one, two = words[0], jnp.zeros_like(words[0])
    for t in words[1:]:
        two = two | (one & t)
        one = one | t
    return one, two


def _framed(inner: jax.Array, fill: bool) -> jax.Array:
    """Put the one-row / one-word frame holding ``fill`` back around interior words
    ``[..., H, NW]`` (a pad fuses with the update; writing into the old array copies it)."""
    lead = [(0, 0)] * (inner.ndim - 2)
    return jnp.pad(inner, lead + [(1, 1), (1, 1)],
                   constant_values=jnp.uint32(_ALL if fill else 0))


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
    mask = _pack(nonfree, False)[..., 1:-1, 1:-1]
    seed = _pack(nonfree & border, False)

    def body(state):
        reached, _ = state
        new = reached
        for _ in range(4):  # several fronts per loop trip: fewer loop-condition round trips
            ring, mid = _neighbours(new)
            inner = mask & (mid | ring[0] | ring[2] | ring[4] | ring[6])
            # run fill toward higher bits (east) inside each word: adding the reached bits
            # to the mask carries through the rest of each reached run (inner is in mask)
            inner = (((mask + inner) ^ mask) & mask) | inner
            new = _framed(inner, False)
        return new, jnp.any(new != reached)

    reached, _ = jax.lax.while_loop(lambda s: s[1], body, (seed, jnp.array(True)))
    reached = _unpack(reached, w)
    return occupied & reached, unknown & reached


@partial(jax.jit, static_argnames="cap")
def squared_distance_transform(occupied: jax.Array, cap: int | None = None) -> jax.Array:
    """Exact squared Euclidean distance to the nearest occupied cell, ``[B, H, W]`` int32.

    First pass: distance along each row to the nearest obstacle (running max/min of obstacle
    indices). Second pass: ``d2[i, j] = min_k g[i + k, j]**2 + k**2`` over row offsets
    ``|k| <= cap + 1`` (all offsets when ``cap`` is None), 16 offsets per fused pass, in
    int16 when the capped sums fit. Distances ``<= cap`` are exact; cells farther than ``cap``
    hold a value ``> cap**2``. Without obstacles every cell holds a sentinel (``> (H + W)**2``
    uncapped, ``>= (cap + 2)**2`` capped). Cells outside the grid are not obstacles (as in
    ``scipy.ndimage.distance_transform_edt`` of the free mask).

    Args:
        occupied: ``[B, H, W]`` bool obstacle masks.
        cap: distances above ``cap`` cells need not be exact (``None``: all exact).

    Returns:
        ``[B, H, W]`` int32 squared distances in cells (B §6.1.1's distance transform).

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
    g = jnp.minimum(jnp.minimum(j - left, right - j), big)
    k_max = h - 1 if cap is None else max(min(int(cap) + 1, h - 1), 0)
    n_off = 2 * k_max + 1
    n_chunk = -(-n_off // _EDT_CHUNK)
    max_off = n_chunk * _EDT_CHUNK - 1 - k_max  # largest row offset the chunks visit
    if cap is None:
        dtype, sentinel = jnp.int32, big * big
    else:
        # row distances past the cap only have to stay past it: clip them, and use int16
        # when every sum g**2 + k**2 fits (twice the throughput of int32)
        g = jnp.minimum(g, k_max + 1)
        sentinel = (k_max + 1) ** 2
        dtype = jnp.int16 if sentinel + max_off ** 2 <= 32767 else jnp.int32
    g2 = (g * g).astype(dtype)
    lead = [(0, 0)] * (g2.ndim - 2)
    gp = jnp.pad(g2, lead + [(k_max, k_max + n_chunk * _EDT_CHUNK - n_off), (0, 0)],
                 constant_values=sentinel)

    def body(c, best):
        # _EDT_CHUNK row offsets per loop trip as static slices: one fused pass over memory
        k0 = c * _EDT_CHUNK
        win = jax.lax.dynamic_slice_in_dim(gp, k0, h + _EDT_CHUNK - 1, axis=g2.ndim - 2)
        for b in range(_EDT_CHUNK):
            off = (k0 + b - k_max).astype(dtype)
            best = jnp.minimum(best, win[..., b:b + h, :] + off * off)
        return best

    return jax.lax.fori_loop(0, n_chunk, body, g2).astype(jnp.int32)


def _zs_sub(p: jax.Array, deletable_mask: jax.Array, first: bool, fill: bool) -> jax.Array:
    """One parallel Zhang--Suen sub-iteration on a framed packed image (the rules of
    :func:`zhang_suen_lut` as bitwise word operations, 32 cells per operation).

    With exactly one 0→1 transition around P the set neighbours form one arc, so
    ``B(P) >= 2`` is "some two cyclically adjacent neighbours set" and ``B(P) <= 6`` is
    "some two adjacent neighbours clear" (fewer operations than counting; the equivalence
    over all 256 neighbourhoods is checked in ``tests/test_hssh.py``).
    """
    ring, x = _neighbours(p)
    pair_set = ring[0] & ring[1]    # some adjacent pair set
    pair_any = ring[0] | ring[1]    # every adjacent pair has one set (no adjacent pair clear)
    for k in range(1, 8):
        pair_set = pair_set | (ring[k] & ring[(k + 1) % 8])
        pair_any = pair_any & (ring[k] | ring[(k + 1) % 8])
    one, two = _at_least_two([~ring[k] & ring[(k + 1) % 8] for k in range(8)])  # 0->1
    n, e, s, w = ring[0], ring[2], ring[4], ring[6]
    if first:  # P2 P4 P6 = P4 P6 P8 = 0
        c = ~(e & s & (n | w))
    else:      # P2 P4 P8 = P2 P6 P8 = 0
        c = ~(n & w & (e | s))
    return _framed(x & ~(pair_set & ~pair_any & one & ~two & c & deletable_mask), fill)


@partial(jax.jit, static_argnames="pad")
def zhang_suen_thin(fg: jax.Array, protect: jax.Array | None = None,
                    pad: bool = False) -> jax.Array:
    """Zhang--Suen thinning of a stack of binary images ``[B, H, W]`` to convergence.

    Both sub-iterations are parallel: each reads the image left by the previous one (Zhang &
    Suen 1984, the rules of :func:`zhang_suen_lut`). ``protect`` (bool ``[B, H, W]``) marks
    cells never deleted; ``pad`` is the value assumed beyond the border.

    Args:
        fg: ``[B, H, W]`` bool foreground.
        protect: ``[B, H, W]`` bool cells never deleted (``None``: none).
        pad: the value assumed beyond the border.

    Returns:
        ``[B, H, W]`` bool skeletons (B §6.1.1).

    >>> img = jnp.zeros((1, 5, 9), bool).at[0, 1:4, 1:8].set(True)
    >>> zhang_suen_thin(img)[0].astype(int).tolist()[2]
    [0, 0, 1, 1, 1, 1, 0, 0, 0]
    """
    w = fg.shape[-1]
    x = _pack(fg, pad)
    inside = _pack(jnp.ones(fg.shape, bool), False)[..., 1:-1, 1:-1]
    if protect is not None:
        inside = inside & ~_pack(protect, False)[..., 1:-1, 1:-1]

    def body(state):
        p, _ = state
        q = _zs_sub(_zs_sub(p, inside, True, pad), inside, False, pad)
        return q, jnp.any(q != p)

    out, _ = jax.lax.while_loop(lambda s: s[1], body, (x, jnp.array(True)))
    return _unpack(out, w)


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


def check_positive_finite(name: str, value, unit: str = "") -> float:
    """``value`` as a float; ``ValueError`` naming ``name`` unless it is finite and > 0.

    Args:
        name: the argument's name, for the message.
        value: the host scalar to check.
        unit: its unit, for the message (e.g. ``"cells"``).

    Returns:
        ``float(value)``.

    Raises:
        ValueError: ``value`` is not a number, NaN, ±inf or ≤ 0.

    >>> check_positive_finite("scale", 2)
    2.0
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        of = f" of {unit}" if unit else ""
        raise ValueError(f"{name} must be a finite number{of} > 0, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0{' ' + unit if unit else ''}, "
                         f"got {value!r}")
    return v


def check_m_cap(m_cap) -> float:
    """``m_cap`` as a float; ``ValueError`` naming it unless finite and > 0 (cells).

    >>> check_m_cap(12)
    12.0
    """
    return check_positive_finite("m_cap", m_cap, "cells")


def check_robot_radius(robot_radius, shape) -> float:
    """``robot_radius`` as a float; ``ValueError`` naming it unless finite, ``>= 0`` and below
    half the shorter grid side (a robot that wide does not fit in the grid: bleeding by it
    would cover every cell).

    >>> check_robot_radius(2, (39, 39))
    2.0
    """
    try:
        r = float(robot_radius)
    except (TypeError, ValueError):
        raise ValueError(f"robot_radius must be a finite number >= 0, got {robot_radius!r}") \
            from None
    if not math.isfinite(r) or r < 0:
        raise ValueError(f"robot_radius must be finite and >= 0, got {robot_radius!r}")
    if r >= min(shape) / 2:
        raise ValueError(f"robot_radius {robot_radius!r} cells does not fit in a "
                         f"{shape[0]}x{shape[1]} grid (must be < {min(shape) / 2})")
    return r


def cellular_stages(occupied: jax.Array, unknown: jax.Array, *, robot_radius: float = 0.0,
                    m_cap: float | None = None, chunk_cells: int | None = None) -> CellularMaps:
    """Run island removal, bleeding, the distance transform and the EVG skeleton on a stack.

    Args:
        occupied: bool ``[B, H, W]``.
        unknown: bool ``[B, H, W]``.
        robot_radius: bleed obstacles by this many cells (B §6.1.1; 0 = none).
        m_cap: EVG cap ``M`` in cells; default ``min(H, W) / 5`` (B §6.3.1, ``c = 5``).
        chunk_cells: cells per chunk of the batch (the grids go through the stages chunk by
            chunk); default :data:`CHUNK_CELLS`. The outputs do not depend on it.

    Returns:
        :class:`CellularMaps` (a horizontal corridor through the grid thins to its midline
        row, reaching both borders; see ``tests/test_hssh.py``).
    """
    occupied = jnp.asarray(occupied, bool)
    unknown = jnp.asarray(unknown, bool)
    h, w = occupied.shape[-2:]
    m = float(min(h, w) / 5.0 if m_cap is None else check_m_cap(m_cap))
    radius = check_robot_radius(robot_radius, (h, w))
    cap = int(np.ceil(m + 2.0 + radius))
    cells = CHUNK_CELLS if chunk_cells is None else int(chunk_cells)
    if cells < 1:
        raise ValueError(f"chunk_cells must be positive, got {chunk_cells}")
    return _cellular(occupied, unknown, radius, m, cap, cells)


#: default cells per chunk of the batch: ~16 grids of 300 x 300 (CPU caches, see _chunking)
CHUNK_CELLS = 1_500_000


def _chunking(b: int, h: int, w: int, cells: int = CHUNK_CELLS) -> tuple[int, int]:
    """(number of chunks, grids per chunk) for a batch of ``b`` grids of ``h x w`` cells.

    The stages sweep their arrays tens of times; past a few MB (an int16 distance map of 16
    grids of 300 x 300 is 2.9 MB) the sweeps fall out of the per-core cache and the time per
    grid grows (measured on a loaded machine: 2.8 ms/grid at 16, 4.6 at 32, 5.0 at 64 before
    chunking). Chunks are as equal as possible; the last is padded with empty grids.
    """
    per = max(1, cells // max(h * w, 1))
    n = -(-b // per)
    return n, -(-b // n)


@partial(jax.jit, static_argnames=("radius", "m", "cap", "cells"))
def _cellular(occupied, unknown, radius, m, cap, cells):
    b, h, w = occupied.shape
    n, per = _chunking(b, h, w, cells)
    if n == 1:
        return _cellular_chunk(occupied, unknown, radius, m, cap)
    pad = [(0, n * per - b), (0, 0), (0, 0)]
    chunks = (jnp.pad(occupied, pad).reshape(n, per, h, w),
              jnp.pad(unknown, pad).reshape(n, per, h, w))
    out = jax.lax.map(lambda c: _cellular_chunk(*c, radius, m, cap), chunks)
    return CellularMaps(*(x.reshape((n * per, h, w))[:b] for x in out))


def _cellular_chunk(occupied, unknown, radius, m, cap):
    occ, unk = remove_islands(occupied, unknown)
    free_space = ~(occ | unk)
    occ_b, dist2 = _bleed_and_distance(occ, radius, cap)
    skel = evg_skeleton(~occ_b, dist2, m)
    return CellularMaps(occ_b, unk & ~occ_b, free_space, dist2, skel)
