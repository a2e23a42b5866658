"""The small-scale star: directed local paths around a place (B §5.1--5.2.2).

A star is a circular, clockwise list of :class:`StarEntry` (path id, direction ``+1``/``-1``,
traversable). It is built from gateways (:func:`build_star`): each gateway's outward side is a
traversable directed local path; two gateways that pass the *path-continuity test* (a ray from
each midpoint, normal to the gateway and into the place, hits the other segment; B §5.2.2)
are the two directions of one path; an unpaired gateway's path gets a non-traversable
opposite direction placed where its inward ray leaves the place.

Clockwise is as seen on the grid image (row 0 at the top); the list starts at the entry
nearest clockwise from "up". :func:`star_isomorphisms` finds the rotations that preserve
traversability and direction pairing (two + stars: exactly 4); :func:`right_of` /
:func:`left_of` give the qualitative sides of a directed path (B §5.1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["StarEntry", "build_star", "path_continuity", "star_isomorphisms", "right_of",
           "left_of", "clockwise_angle"]


class StarEntry(NamedTuple):
    """One directed local path of a star.

    path: path id (0, 1, ... in order of first appearance).
    direction: +1 or -1 (the two directions of the path leaving the place).
    traversable: B's ``alpha``.
    gateway: index of the gateway it leaves through (-1 for a non-traversable entry).
    angle: clockwise angle from "up" (degrees) of its position around the place.
    """

    path: int
    direction: int
    traversable: bool
    gateway: int
    angle: float


def clockwise_angle(vec: Sequence[float]) -> float:
    """Clockwise angle from "up" (degrees in [0, 360)) of a (row, col) vector.

    >>> clockwise_angle((-1, 0)), clockwise_angle((0, 1)), clockwise_angle((1, 0))
    (0.0, 90.0, 180.0)
    """
    dr, dc = float(vec[0]), float(vec[1])
    return math.degrees(math.atan2(dc, -dr)) % 360.0


_PARALLEL = 1e-12
"""Ray and segment count as parallel when ``|sin|`` of their angle is below this
(dimensionless: the test is the same in every unit)."""

_ON_SEGMENT = 1e-9
"""Relative slack of the segment parameter ``s`` in [0, 1] (a fraction of the segment)."""


def _ray_hits(origin, direction, a, b) -> bool:
    """Does the ray ``origin + t direction`` (t >= 0) meet segment a-b?

    Scale-free: the parallel test compares ``|d x e|`` with ``|d| |e|`` and the end slack
    is a fraction of the segment, so multiplying every length by any factor (or moving the
    origin) gives the same answer."""
    d = np.asarray(direction, float)
    a = np.asarray(a, float)
    e = np.asarray(b, float) - a
    w = a - np.asarray(origin, float)
    den = d[0] * (-e[1]) - d[1] * (-e[0])
    norm = math.hypot(*d) * math.hypot(*e)
    if not norm > 0 or abs(den) <= _PARALLEL * norm:
        return False
    t = (w[0] * (-e[1]) - w[1] * (-e[0])) / den
    s = (d[0] * w[1] - d[1] * w[0]) / den
    return bool(t >= 0 and -_ON_SEGMENT <= s <= 1 + _ON_SEGMENT)


def _check_gateways(ends, outward, centre=None):
    """Validated float arrays ``[G, 2, 2]``, ``[G, 2]`` (unit) and ``[2]``; ``ValueError`` names
    the argument for a wrong shape, a non-finite value, a zero-length gateway or a zero
    normal."""
    e = np.asarray(ends, float)
    o = np.asarray(outward, float)
    if e.size % 4 or o.size % 2:
        raise ValueError(f"ends must be [G, 2, 2] and outward [G, 2], got shapes {e.shape}, "
                         f"{o.shape}")
    e, o = e.reshape(-1, 2, 2), o.reshape(-1, 2)
    if len(e) != len(o):
        raise ValueError(f"ends ({len(e)} gateways) and outward ({len(o)}) differ in length")
    if not np.all(np.isfinite(e)):
        raise ValueError(f"ends must be finite, got non-finite segment ends in gateways "
                         f"{np.nonzero(~np.isfinite(e).all(axis=(1, 2)))[0].tolist()}")
    if not np.all(np.isfinite(o)):
        raise ValueError(f"outward must be finite, got non-finite normals in gateways "
                         f"{np.nonzero(~np.isfinite(o).all(axis=1))[0].tolist()}")
    n = np.hypot(o[:, 0], o[:, 1])
    if np.any(n == 0):
        raise ValueError(f"outward normals must be nonzero, got zero normals in gateways "
                         f"{np.nonzero(n == 0)[0].tolist()}")
    length = np.hypot(*(e[:, 1] - e[:, 0]).T)
    if np.any(length == 0):
        raise ValueError(f"ends must span a segment, got zero-length gateways "
                         f"{np.nonzero(length == 0)[0].tolist()}")
    o = o / n[:, None]
    if centre is None:
        return e, o, None
    c = np.asarray(centre, float)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"centre must be a finite [2] point, got {c.tolist()}")
    return e, o, c


def path_continuity(ends_a, out_a, ends_b, out_b) -> bool:
    """B §5.2.2 path-continuity test between two gateways.

    Args:
        ends_a, ends_b: ``[2, 2]`` segment end points (row, col).
        out_a, out_b: ``[2]`` outward unit normals.

    >>> a = np.array([[0.0, 0.0], [0.0, 2.0]]); b = np.array([[5.0, 0.0], [5.0, 2.0]])
    >>> path_continuity(a, np.array([-1.0, 0.0]), b, np.array([1.0, 0.0]))
    True
    """
    ends, outs, _ = _check_gateways(np.stack([np.asarray(ends_a, float),
                                              np.asarray(ends_b, float)]),
                                    np.stack([np.asarray(out_a, float),
                                              np.asarray(out_b, float)]))
    return _continuity(ends[0], outs[0], ends[1], outs[1])


def _continuity(ends_a, out_a, ends_b, out_b) -> bool:
    ref = ends_a[0]  # differences first: coordinates relative to one gateway end
    ea, eb = ends_a - ref, ends_b - ref
    ma, mb = ea.mean(axis=0), eb.mean(axis=0)
    return bool(_ray_hits(ma, -out_a, eb[0], eb[1]) and _ray_hits(mb, -out_b, ea[0], ea[1]))


def build_star(ends: np.ndarray, outward: np.ndarray, centre: np.ndarray) -> list[StarEntry]:
    """The small-scale star of a place from its gateways (B §5.2.2).

    Args:
        ends: float ``[G, 2, 2]`` gateway end points (row, col).
        outward: float ``[G, 2]`` outward unit normals.
        centre: float ``[2]`` the place centre (angles are measured around it).

    Returns:
        the clockwise list of :class:`StarEntry`.

    >>> up = ([[0.0, 4.0], [0.0, 6.0]], [-1.0, 0.0]); dn = ([[9.0, 4.0], [9.0, 6.0]], [1.0, 0.0])
    >>> s = build_star(np.array([up[0], dn[0]]), np.array([up[1], dn[1]]), np.array([5.0, 5.0]))
    >>> [(e.path, e.direction, e.traversable) for e in s]
    [(0, 1, True), (0, -1, True)]
    """
    ends, outward, centre = _check_gateways(ends, outward, centre)
    ends = ends - centre  # differences first: every position relative to the place centre
    centre = np.zeros(2)
    g = len(ends)
    mids = ends.mean(axis=1)
    halves = 0.5 * np.hypot(*(ends[:, 1] - ends[:, 0]).T)
    cands = []
    for i in range(g):
        for j in range(i + 1, g):
            if _continuity(ends[i], outward[i], ends[j], outward[j]):
                cands.append((float(np.dot(outward[i], outward[j])), i, j))
    partner = [-1] * g
    for _, i, j in sorted(cands):
        if partner[i] < 0 and partner[j] < 0:
            partner[i], partner[j] = j, i
    raw = []  # (angle, traversable, gateway, group)
    for i in range(g):
        rel = mids[i] - centre
        # a midpoint within 1e-9 gateway half-lengths of the centre has no direction of its
        # own: use the outward normal (scale-free)
        ang = clockwise_angle(rel if np.hypot(*rel) > 1e-9 * halves[i] else outward[i])
        raw.append((ang, True, i, min(i, partner[i]) if partner[i] >= 0 else i))
        if partner[i] < 0:
            reach = max(float(np.hypot(*rel)), float(halves[i]))
            far = mids[i] - 2.0 * reach * outward[i]
            raw.append((clockwise_angle(far - centre), False, -1, i))
    raw.sort(key=lambda t: (round(t[0], 9), not t[1]))
    ids: dict[int, int] = {}
    seen: set[int] = set()
    star = []
    for ang, trav, gw, grp in raw:
        if grp not in ids:
            ids[grp] = len(ids)
        paired = partner[grp] >= 0
        if paired:
            direction = -1 if grp in seen else 1
        else:
            direction = 1 if trav else -1
        seen.add(grp)
        star.append(StarEntry(ids[grp], direction, trav, gw, ang))
    return star


def _triples(star):
    return [(int(e[0]), int(e[1]), bool(e[2])) for e in star]


def star_isomorphisms(a: Sequence, b: Sequence) -> list[int]:
    """Rotations ``k`` with ``phi(a[i]) = b[(i + k) % L]`` that are star isomorphisms (B §5.1).

    ``phi`` must preserve traversability and map the two directions of a path to the two
    directions of one path.

    >>> plus = [(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]
    >>> star_isomorphisms(plus, plus)
    [0, 1, 2, 3]
    >>> tee = [(0, -1, False), (1, 1, True), (0, 1, True), (1, -1, True)]
    >>> star_isomorphisms(tee, tee)
    [0]
    """
    a, b = _triples(a), _triples(b)
    n = len(a)
    if n != len(b):
        return []
    out = []
    for k in range(n):
        fwd: dict[int, int] = {}
        bwd: dict[int, int] = {}
        ok = True
        for i in range(n):
            x, y = a[i], b[(i + k) % n]
            if x[2] != y[2] or fwd.setdefault(x[0], y[0]) != y[0] \
                    or bwd.setdefault(y[0], x[0]) != x[0]:
                ok = False
                break
        if ok:
            out.append(k)
    return out


def _between(star, start, stop):
    s = _triples(star)
    n = len(s)
    i0 = next(i for i, e in enumerate(s) if e[:2] == start)
    out = []
    for k in range(1, n):
        e = s[(i0 + k) % n]
        if e[:2] == stop:
            return out
        out.append(e[:2])
    raise ValueError(f"directed path {stop} is not in the star")


def right_of(star: Sequence, path: int, direction: int) -> list[tuple[int, int]]:
    """Directed paths strictly clockwise between ``(path, direction)`` and its opposite:
    the ones to the right when leaving along ``(path, direction)`` (B §5.1).

    >>> plus = [(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]
    >>> right_of(plus, 0, 1), left_of(plus, 0, 1)
    ([(1, 1)], [(1, -1)])
    """
    return _between(star, (path, direction), (path, -direction))


def left_of(star: Sequence, path: int, direction: int) -> list[tuple[int, int]]:
    """Directed paths to the left when leaving along ``(path, direction)`` (B §5.1)."""
    return _between(star, (path, -direction), (path, direction))
