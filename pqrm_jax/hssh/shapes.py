"""Corridor shapes other than the + with their expected local topology (B §5.1, §5.3.2, §6.3.3).

B §6.3.3 measures the anchor gateways on + intersections only. This module draws the other
shapes a robot meets -- a T, an L, a straight corridor and a dead end -- the way the + corpus
draws its + (:func:`pqrm_jax.sim.corridors.intersection_rectangles`, area-sampled after
rotation about the junction point, free iff grey >= 128, then each free cell turns occupied
with the noise probability), with the robot placed off the centre, and states what the local
topology must be:

========== ========== ======= ============ ==============================================
shape      gateways   paths   kind         star (clockwise from "up", unrotated)
========== ========== ======= ============ ==============================================
T          3          2       place        ``<a-,0> <b+,1> <a+,1> <b-,1>`` (stem south)
L          2          2       place        ``<a+,1> <b+,1> <a-,0> <b-,0>`` (arms N, E)
straight   2          1       path         ``<a+,1> <a-,1>``
dead_end   1          1       dead_end     ``<a+,1> <a-,0>``
========== ========== ======= ============ ==============================================

(``<p d, t>``: path, direction, traversable; any rotation of the list is the same star,
:func:`~pqrm_jax.hssh.star.star_isomorphisms`.)

Robot positions (in corridor widths ``w``, in the shape's own frame): inside the junction
square (``|offset| <= w / 4`` on both axes) for T and L; anywhere within ``w`` of the centre
along a straight corridor (``w / 4`` across); between ``w / 4`` and ``w`` from a dead end's
end wall (``w / 4`` across), where the control level reads a dead end's view (issue 26).
The robot's own cell is never noise (a robot does not see itself as an obstacle).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pqrm_jax.hssh.star import star_isomorphisms

__all__ = ["SHAPES", "EXPECTED", "ShapeCase", "shape_image", "shape_cases", "shape_check"]

SHAPES = ("T", "L", "straight", "dead_end")

EXPECTED: dict[str, tuple[int, tuple[tuple[int, int, bool], ...], str]] = {
    "T": (3, ((0, -1, False), (1, 1, True), (0, 1, True), (1, -1, True)), "place"),
    "L": (2, ((0, 1, True), (1, 1, True), (0, -1, False), (1, -1, False)), "place"),
    "straight": (2, ((0, 1, True), (0, -1, True)), "path"),
    "dead_end": (1, ((0, 1, True), (0, -1, False)), "dead_end"),
}
"""Per shape: (number of gateways, star, place kind) of the correct local topology."""

# (along, across) offset ranges of the robot, in corridor widths, in the shape frame
_OFFSETS = {"T": ((-0.25, 0.25), (-0.25, 0.25)), "L": ((-0.25, 0.25), (-0.25, 0.25)),
            "straight": ((-1.0, 1.0), (-0.25, 0.25)), "dead_end": ((-0.25, 0.5), (-0.25, 0.25))}
# the axis "along" (degrees, counter-clockwise from east, before rotation) per shape
_ALONG = {"T": 270.0, "L": 90.0, "straight": 90.0, "dead_end": 270.0}


class ShapeCase(NamedTuple):
    """One image of the shape family.

    kind: one of :data:`SHAPES`.
    side: cells per side.
    rotation: degrees (counter-clockwise) about the junction point.
    noise: probability that a free cell turns occupied.
    width: corridor width as a fraction of the side.
    along, across: robot offset from the junction point in corridor widths (shape frame;
        ``along`` runs along the stem / the arm / the corridor, see the module docstring).
    seed: noise seed.
    """

    kind: str
    side: int
    rotation: float
    noise: float
    width: float = 1 / 3
    along: float = 0.0
    across: float = 0.0
    seed: int = 0


def _check(case: ShapeCase) -> None:
    if case.kind not in SHAPES:
        raise ValueError(f"kind must be one of {SHAPES}, got {case.kind!r}")
    if not isinstance(case.side, int | np.integer) or case.side < 9:
        raise ValueError(f"side must be an int >= 9, got {case.side!r}")
    if not (math.isfinite(case.rotation) and math.isfinite(case.width)
            and 0.0 < case.width < 0.5):
        raise ValueError(f"rotation must be finite and width in (0, 0.5), got "
                         f"{case.rotation!r}, {case.width!r}")
    if not 0.0 <= case.noise <= 1.0:
        raise ValueError(f"noise must be in [0, 1], got {case.noise!r}")
    (a0, a1), (c0, c1) = _OFFSETS[case.kind]
    if not (a0 <= case.along <= a1 and c0 <= case.across <= c1):
        raise ValueError(f"robot offset ({case.along}, {case.across}) widths is outside the "
                         f"{case.kind}'s place region along {a0}..{a1}, across {c0}..{c1}")


def shape_image(case: ShapeCase, supersample: int = 4) -> tuple[np.ndarray, tuple[int, int]]:
    """The occupancy grid ``[side, side]`` (bool, True = occupied) and the robot cell.

    Args:
        case: the :class:`ShapeCase` (checked: ``ValueError`` names a bad field).
        supersample: area samples per cell and axis of the drawing.

    Returns:
        ``(occupied [side, side] bool, (row, col) robot cell)``.

    >>> occ, rc = shape_image(ShapeCase("T", 39, 0.0, 0.0))
    >>> occ.shape, rc, bool(occ[rc])
    ((39, 39), (19, 19), False)
    """
    from pqrm_jax.sim.corridors import (
        INTERSECTIONS,
        intersection_rectangles,
        render_free_rectangles,
    )

    _check(case)
    side = int(case.side)
    grey = np.asarray(render_free_rectangles(side, intersection_rectangles(
        INTERSECTIONS[case.kind], case.width, case.rotation), supersample))
    occ = grey < 128
    a = math.radians(_ALONG[case.kind] + case.rotation)
    u = np.array([math.cos(a), math.sin(a)])     # along (x right, y up)
    n = np.array([-u[1], u[0]])                  # across
    xy = np.array([0.5, 0.5]) + case.width * (case.along * u + case.across * n)
    rc = (min(max(int(math.floor((1.0 - xy[1]) * side)), 0), side - 1),
          min(max(int(math.floor(xy[0] * side)), 0), side - 1))
    if occ[rc]:
        raise ValueError(f"robot cell {rc} of {case} is not free in the drawing")
    rng = np.random.default_rng([int(case.seed), side, SHAPES.index(case.kind),
                                 int(round(case.rotation * 1000)),
                                 int(round(case.noise * 1000))])
    flip = (rng.random(occ.shape) < case.noise) & ~occ
    flip[rc] = False
    return occ | flip, rc


def shape_cases(n: int, seed: int = 0, sizes: tuple[int, int] = (39, 299),
                rotations: tuple[float, float] = (0.0, 45.0),
                noise: tuple[float, float] = (0.0, 0.10),
                widths: tuple[float, float] = (0.22, 0.36),
                kinds: tuple[str, ...] = SHAPES) -> list[ShapeCase]:
    """``n`` random cases per shape: side, rotation (whole degrees), noise (whole percent),
    corridor width and robot offset drawn uniformly from the given ranges (issue 26's family:
    sizes 39--299, rotations 0--45°, noise 0--10 %).

    Args:
        n: cases per shape.
        seed: seed of the draw.
        sizes, rotations, noise, widths: ``(low, high)`` ranges (cells, degrees, probability,
            fraction of the side).
        kinds: the shapes to draw (of :data:`SHAPES`).

    Returns:
        ``n * len(kinds)`` :class:`ShapeCase`, one of each kind in turn.

    >>> [c.kind for c in shape_cases(1)]
    ['T', 'L', 'straight', 'dead_end']
    """
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(int(n)):
        for kind in kinds:
            (a0, a1), (c0, c1) = _OFFSETS[kind]
            out.append(ShapeCase(
                kind, int(rng.integers(sizes[0], sizes[1] + 1)),
                float(rng.integers(int(rotations[0]), int(rotations[1]) + 1)),
                round(float(rng.integers(int(round(noise[0] * 100)),
                                         int(round(noise[1] * 100)) + 1)) / 100, 2),
                round(float(rng.uniform(*widths)), 4), round(float(rng.uniform(a0, a1)), 3),
                round(float(rng.uniform(c0, c1)), 3), int(rng.integers(0, 2**31 - 1))))
    return out


def shape_check(lt, kind: str) -> str:
    """``""`` when a :class:`~pqrm_jax.hssh.topology.LocalTopology` is the correct one for
    ``kind``, else the reason (gateway count, star or kind).

    Args:
        lt: the local topology of a :func:`shape_image`.
        kind: the shape drawn.

    Returns:
        ``""`` or the reason of the failure.

    >>> from pqrm_jax.hssh import local_topology
    >>> occ, rc = shape_image(ShapeCase("L", 63, 0.0, 0.0, width=21 / 63))
    >>> shape_check(local_topology(occ, rc), "L")
    ''
    """
    n_gw, star, want = EXPECTED[kind]
    if len(lt.gateways) != n_gw:
        return f"{len(lt.gateways)} gateways ({lt.kind})"
    if not star_isomorphisms(lt.star, star):
        return f"{n_gw} gateways, star {list(lt.star)} not the {kind} star"
    if lt.kind != want:
        return f"kind {lt.kind}"
    return ""
