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

:class:`Star` is the one star type of the HSSH, local and global levels alike (the global
levels, :mod:`pqrm_jax.hssh_global`, use it for views and the tree of maps): the topology
``(path, dir, alpha)`` of the clockwise list, built from any entries with
:meth:`Star.from_entries` (``(path, direction, traversable)`` triples, or the
:class:`StarEntry` records of :func:`build_star`, which also carry the gateway and angle).
:func:`star_isomorphisms` is the one host isomorphism; it takes stars or entry lists, and
:func:`pqrm_jax.hssh_global.match_matrix` is its batched (``vmap``) twin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["Star", "StarEntry", "build_star", "path_continuity", "star_isomorphisms",
           "right_of", "left_of", "clockwise_angle"]


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


class Star(NamedTuple):
    """A local topology: the clockwise circular list of directed local paths (B §5.1).

    Entry ``i`` has a local path id ``path[i]``, a direction ``dir[i]`` (+1/-1 away from the
    place) and a traversability ``alpha[i]`` (1 when a corridor leads away in that
    direction); ``opp[i]`` is the entry of the same path in the other direction. Hashable
    and compared by value (the tree of maps keys views by it).

    Attributes:
        path: ``tuple[int]`` of length ``L``, the local path id of each entry.
        dir: ``tuple[int]`` of length ``L``, +1 or -1.
        alpha: ``tuple[int]`` of length ``L``, 0 or 1.

    >>> Star.from_entries([(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]).opp
    (2, 3, 0, 1)
    """

    path: tuple
    dir: tuple
    alpha: tuple

    @staticmethod
    def from_entries(entries) -> Star:
        """Build and validate a star from its clockwise entries (B §5.1).

        Args:
            entries: a [L] sequence of ``(path, direction, traversable, ...)`` (triples, or
                :class:`StarEntry` records whose extra fields are dropped).

        Returns:
            The :class:`Star` (``alpha`` as 0/1 integers).

        Raises:
            ValueError: for no entry, a direction other than ±1, a directed path listed twice,
                a path without its opposite direction, or a traversability other than 0/1.
        """
        entries = [(int(e[0]), int(e[1]), int(e[2])) for e in entries]
        if not entries:
            raise ValueError("a star needs at least one directed local-path")
        path, dirs, alpha = zip(*entries, strict=True)
        star = Star(tuple(path), tuple(dirs), tuple(alpha))
        seen = {}
        for i, (p, d) in enumerate(zip(path, dirs, strict=True)):
            if d not in (1, -1):
                raise ValueError(f"entry {i}: direction must be +1 or -1, got {d}")
            if (p, d) in seen:
                raise ValueError(f"entry {i}: directed local-path ({p}, {d}) appears twice")
            seen[(p, d)] = i
        for p, d in seen:
            if (p, -d) not in seen:
                raise ValueError(f"star not closed under opposite direction: path {p}")
        if any(a not in (0, 1) for a in alpha):
            raise ValueError("alpha must be 0 or 1")
        return star

    def __len__(self) -> int:  # number of entries L
        return len(self.path)

    @property
    def opp(self) -> tuple:
        """[L] index of the opposite direction of each entry."""
        index = {(p, d): i for i, (p, d) in enumerate(zip(self.path, self.dir, strict=True))}
        return tuple(index[(p, -d)] for p, d in zip(self.path, self.dir, strict=True))

    def rotate(self, s: int) -> Star:
        """The same star listed from entry ``s`` (entry ``s`` becomes entry 0)."""
        n = len(self)
        idx = [(i + s) % n for i in range(n)]
        return Star(tuple(self.path[i] for i in idx), tuple(self.dir[i] for i in idx),
                    tuple(self.alpha[i] for i in idx))


def clockwise_angle(vec: Sequence[float]) -> float:
    """Clockwise angle from "up" (degrees in [0, 360)) of a (row, col) vector (B §5.1).

    Args:
        vec: a [2] (row, col) vector; row grows downwards (the grid image).

    Returns:
        The angle in degrees, in [0, 360).

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
    """B §5.2.2 path-continuity test: are two gateways the two ends of one local path?

    A ray from each gateway's midpoint, normal to it and into the place, must hit the other
    segment. Scale-free (the same answer in every unit and origin).

    Args:
        ends_a: ``[2, 2]`` segment end points (row, col) of gateway a.
        out_a: ``[2]`` outward normal of gateway a (normalised here).
        ends_b: ``[2, 2]`` segment end points of gateway b.
        out_b: ``[2]`` outward normal of gateway b.

    Returns:
        True when each inward ray hits the other gateway.

    Raises:
        ValueError: for non-finite or degenerate segments or normals.

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
        The clockwise list of :class:`StarEntry` (``Star.from_entries`` of it is the
        topology).

    Raises:
        ValueError: for wrong shapes, non-finite values, zero-length gateways, zero normals
            or a non-finite centre.

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
    if isinstance(star, Star):
        return [(p, d, bool(a)) for p, d, a in zip(star.path, star.dir, star.alpha, strict=True)]
    return [(int(e[0]), int(e[1]), bool(e[2])) for e in star]


def _as_star(star) -> Star:
    return star if isinstance(star, Star) else Star.from_entries(star)


def star_isomorphisms(a: Star | Sequence, b: Star | Sequence) -> list[int]:
    """The rotations ``s`` such that ``φ(i) = (i + s) mod L`` is a star isomorphism a → b (B §5.1).

    An isomorphism ``φ: S → S'`` is a bijection with ``next(φ(x)) = φ(next(x))`` that preserves
    traversability and maps the two directions of a path to the two directions of one path:
    for stars, a rotation of the circular list preserving ``alpha`` and the pairing ``opp``.
    The one host implementation, for the local levels (shape checks) and the global levels
    (view matching, the tree of maps); :func:`pqrm_jax.hssh_global.match_matrix` is its
    batched twin.

    Args:
        a: the source star, a :class:`Star` or its [L] clockwise entries
            ``(path, direction, traversable, ...)``.
        b: the target star, likewise.

    Returns:
        The valid shifts in increasing order (empty when the stars are not isomorphic, or
        either has no entry).

    Raises:
        ValueError: for entries that are not a star (:meth:`Star.from_entries`).

    >>> plus = [(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]
    >>> star_isomorphisms(plus, plus)
    [0, 1, 2, 3]
    >>> tee = [(0, -1, False), (1, 1, True), (0, 1, True), (1, -1, True)]
    >>> star_isomorphisms(tee, tee)
    [0]
    """
    if len(a) == 0 or len(b) == 0:
        return []
    a, b = _as_star(a), _as_star(b)
    n = len(a)
    if len(b) != n:
        return []
    oa, ob = a.opp, b.opp
    out = []
    for s in range(n):
        if all(b.alpha[(i + s) % n] == a.alpha[i] and ob[(i + s) % n] == (oa[i] + s) % n
               for i in range(n)):
            out.append(s)
    return out


def _between(star, start, stop):
    s = _triples(star)
    n = len(s)
    i0 = next((i for i, e in enumerate(s) if e[:2] == start), None)
    if i0 is None:
        raise ValueError(f"directed path {start} is not in the star")
    out = []
    for k in range(1, n):
        e = s[(i0 + k) % n]
        if e[:2] == stop:
            return out
        out.append(e[:2])
    raise ValueError(f"directed path {stop} is not in the star")


def right_of(star: Star | Sequence, path: int, direction: int) -> list[tuple[int, int]]:
    """The directed paths to the right when leaving along ``(path, direction)`` (B §5.1).

    They are the entries strictly clockwise between ``(path, direction)`` and its opposite.

    Args:
        star: a :class:`Star` or its [L] clockwise entries ``(path, direction, traversable)``.
        path: the local path id.
        direction: +1 or -1.

    Returns:
        The ``(path, direction)`` pairs in clockwise order.

    Raises:
        ValueError: when ``(path, direction)`` or its opposite is not in the star.

    >>> plus = [(0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True)]
    >>> right_of(plus, 0, 1), left_of(plus, 0, 1)
    ([(1, 1)], [(1, -1)])
    """
    return _between(star, (path, direction), (path, -direction))


def left_of(star: Star | Sequence, path: int, direction: int) -> list[tuple[int, int]]:
    """The directed paths to the left when leaving along ``(path, direction)`` (B §5.1).

    They are the entries strictly clockwise between the opposite ``(path, -direction)`` and
    ``(path, direction)``.

    Args:
        star: a :class:`Star` or its [L] clockwise entries ``(path, direction, traversable)``.
        path: the local path id.
        direction: +1 or -1.

    Returns:
        The ``(path, direction)`` pairs in clockwise order.

    Raises:
        ValueError: when ``(path, direction)`` or its opposite is not in the star.
    """
    return _between(star, (path, -direction), (path, direction))
