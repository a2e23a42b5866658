"""Corridor-network occupancy worlds rendered as grey images (B §6.3.3, docs/decisions.md §9).

A world is a union of free rectangles in the unit square (x to the right, y up); everything
else is wall. :func:`render_free_rectangles` rasterises it into a ``side x side`` grey image
(uint8, 255 = free) by area sampling (``supersample**2`` points per cell), the way a
high-resolution drawing is reduced to a coarse grid. Cell ``(row, col)`` has its centre at
``x = (col + 0.5) / side``, ``y = 1 - (row + 0.5) / side`` (row 0 at the top).

:func:`intersection_rectangles` builds corridor intersections from arms leaving a centre
(+, T, L, Y, dead ends, non-rectangular ones) and :func:`plus_image` is the +-intersection of
Beeson's robustness corpus: four arms of width 1/3 (13 cells of a 39-cell image, B §6.3.3),
drawn once with arms long enough to leave the image at every rotation, rotated about the
image centre. :func:`room_doorway_rectangles` adds a room behind a doorway off a corridor.

Thresholding the grey image at 127 (free iff grey >= 128) gives the occupancy grid the
gateway pipeline reads (:mod:`pqrm_jax.hssh`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "render_free_rectangles",
    "intersection_rectangles",
    "room_doorway_rectangles",
    "plus_image",
    "network_rectangles",
    "NETWORK_PLACES",
    "INTERSECTIONS",
]

# arm directions (degrees, counter-clockwise from east) and lengths (None = leaves the image)
INTERSECTIONS: dict[str, tuple[tuple[float, float | None], ...]] = {
    "plus": ((0, None), (90, None), (180, None), (270, None)),
    "T": ((0, None), (180, None), (270, None)),
    "L": ((90, None), (0, None)),
    "Y": ((90, None), (210, None), (330, None)),
    "dead_end": ((270, None),),
    "straight": ((90, None), (270, None)),
    "K": ((90, None), (270, None), (30, None), (330, None)),
}


@partial(jax.jit, static_argnames=("side", "supersample"))
def _render(rects, side, supersample):
    k = supersample
    sub = (jnp.arange(k) + 0.5) / k
    idx = jnp.arange(side)
    xs = (idx[:, None] + sub[None, :]).reshape(-1) / side          # [side*k] along columns
    ys = 1.0 - (idx[:, None] + sub[None, :]).reshape(-1) / side    # [side*k] along rows
    x = xs[None, :]
    y = ys[:, None]
    free = jnp.zeros((side * k, side * k), bool)
    for r in range(rects.shape[0]):
        cx, cy, half_len, half_wid, ang = (rects[r, i] for i in range(5))
        c, s = jnp.cos(ang), jnp.sin(ang)
        u = (x - cx) * c + (y - cy) * s
        v = -(x - cx) * s + (y - cy) * c
        free = free | ((jnp.abs(u) <= half_len) & (jnp.abs(v) <= half_wid))
    frac = free.reshape(side, k, side, k).mean(axis=(1, 3))
    return jnp.round(255.0 * frac).astype(jnp.uint8)


def render_free_rectangles(side: int, rects: Sequence[Sequence[float]],
                           supersample: int = 4) -> jax.Array:
    """Rasterise a union of free rectangles into a grey image ``[side, side]`` uint8.

    Args:
        side: cells per side (>= 3).
        rects: ``[R, 5]`` rows ``(cx, cy, length, width, angle_rad)`` in unit-square
            coordinates (x right, y up; angle counter-clockwise from +x).
        supersample: area samples per cell and axis (>= 1).

    Returns:
        uint8 ``[side, side]``: 255 free, 0 wall, grey where a cell is partly free.

    >>> img = render_free_rectangles(5, [(0.5, 0.5, 1.0, 0.2, 0.0)], supersample=1)
    >>> img[:, 0].tolist()
    [0, 0, 255, 0, 0]
    """
    if not isinstance(side, int | np.integer) or side < 3:
        raise ValueError(f"side must be an int >= 3, got {side!r}")
    if not isinstance(supersample, int | np.integer) or supersample < 1:
        raise ValueError(f"supersample must be an int >= 1, got {supersample!r}")
    r = np.asarray(rects, np.float64)
    if r.ndim != 2 or r.shape[1] != 5 or r.shape[0] == 0:
        raise ValueError(f"rects must have shape [R, 5] with R >= 1, got {r.shape}")
    if not np.all(np.isfinite(r)) or np.any(r[:, 2:4] <= 0):
        raise ValueError("rects must be finite with positive length and width")
    arr = np.stack([r[:, 0], r[:, 1], r[:, 2] / 2, r[:, 3] / 2, r[:, 4]], axis=1)
    return _render(jnp.asarray(arr, jnp.float32), int(side), int(supersample))


def intersection_rectangles(arms: Sequence[tuple[float, float | None]], width: float = 1 / 3,
                            rotation_deg: float = 0.0,
                            centre: tuple[float, float] = (0.5, 0.5)) -> list[tuple]:
    """Free rectangles of corridor arms leaving ``centre`` (an intersection, B §5.1).

    Args:
        arms: ``(direction_deg, length)`` per arm, direction counter-clockwise from east,
            length in unit-square units from the centre (None: the arm leaves the image).
        width: corridor width (fraction of the side).
        rotation_deg: rotation of the whole intersection about ``centre``.
        centre: the junction point.

    Returns:
        list of ``(cx, cy, length, width, angle)`` rectangles; each arm starts ``width / 2``
        behind the centre so the junction is filled.

    >>> len(intersection_rectangles(INTERSECTIONS["T"]))
    3
    """
    out = []
    for deg, length in arms:
        a = math.radians(deg + rotation_deg)
        far = 2.0 if length is None else float(length)
        near = -width / 2
        mid = 0.5 * (far + near)
        out.append((centre[0] + mid * math.cos(a), centre[1] + mid * math.sin(a),
                    far - near, width, a))
    return out


def room_doorway_rectangles(width: float = 0.2, room: float = 0.6,
                            door: float = 0.12) -> list[tuple]:
    """A vertical corridor through the image with a room off its right side.

    The corridor (width ``width``) runs bottom to top at ``x = 0.3``; the room (height
    ``room``) extends from a wall of thickness 0.06 past the right border -- a room larger
    than the LPM, as B Fig. 6.12 -- joined to the corridor by a doorway of width ``door`` at
    mid height. A room wholly inside the grid would have no frontier exit, and B's pruning
    (§6.1.1) rightly drops its branch.

    Args:
        width: corridor width (fraction of the image side).
        room: room height.
        door: doorway width.

    Returns:
        ``list`` of free rectangles ``(cx, cy, length, width, angle_rad)`` in unit-square
        coordinates (:func:`render_free_rectangles`).

    >>> len(room_doorway_rectangles())
    3
    """
    cx = 0.3
    wall = cx + width / 2 + 0.06
    return [
        (cx, 0.5, 2.5, width, math.pi / 2),
        (wall + 0.5, 0.5, 1.0, room, 0.0),
        (cx + width / 2 + 0.03, 0.5, 0.08, door, 0.0),
    ]


def plus_image(side: int, rotation_deg: float = 0.0, supersample: int = 4) -> jax.Array:
    """The +-intersection of B §6.3.3 as a grey image ``[side, side]`` (uint8, 255 free).

    Four arms of width ``1/3`` of the side meet at the centre; the drawing is the same for
    every size (only the resolution changes) and is rotated about the image centre.

    Args:
        side: image size in pixels.
        rotation_deg: rotation about the centre.
        supersample: samples per pixel side (anti-aliasing).

    Returns:
        ``[side, side]`` uint8.

    >>> img = plus_image(9)
    >>> (img >= 128).astype(int)[4].tolist(), (img >= 128).astype(int)[0].tolist()
    ([1, 1, 1, 1, 1, 1, 1, 1, 1], [0, 0, 0, 1, 1, 1, 0, 0, 0])
    """
    return render_free_rectangles(side, intersection_rectangles(
        INTERSECTIONS["plus"], 1 / 3, rotation_deg), supersample)


# junction points of :func:`network_rectangles` (unit square, x right, y up), by kind
NETWORK_PLACES: dict[str, tuple[float, float]] = {
    "plus": (0.35, 0.65), "L": (0.75, 0.65), "T": (0.35, 0.25), "plus_2": (0.75, 0.25),
    "dead_end": (0.75, 0.1), "path": (0.55, 0.65),
}


def network_rectangles(width: float = 0.06) -> list[tuple]:
    """A corridor network in the unit square: two + crossings, a T, an L and a dead end.

    Corridors (width ``width``): horizontal at ``y = 0.65`` from the left border to
    ``x = 0.75``; vertical at ``x = 0.35`` from ``y = 0.25`` to the top border; horizontal at
    ``y = 0.25`` across the whole square; vertical at ``x = 0.75`` from ``y = 0.1`` (a dead end)
    up to the first corridor (an L). Junction points: :data:`NETWORK_PLACES`.

    >>> len(network_rectangles())
    4
    """
    h = width / 2
    return [
        ((0.75 + h - 0.5) / 2, 0.65, 0.75 + h + 0.5, width, 0.0),
        (0.35, (0.25 - h + 1.5) / 2, 1.5 - (0.25 - h), width, math.pi / 2),
        (0.5, 0.25, 2.0, width, 0.0),
        (0.75, (0.1 + 0.65 + h) / 2, 0.65 + h - 0.1, width, math.pi / 2),
    ]
