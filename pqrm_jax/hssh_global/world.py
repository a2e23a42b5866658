"""Abstract corridor worlds and exploration experiences (B §3.2.2, §8.1, §8.4).

A :class:`CorridorWorld` is the ground truth the HSSH global levels are tested against: places
embedded in the plane, each with its star (:class:`~pqrm_jax.hssh_global.star.Star`) and the
corridors between their gateways. Worlds are built on a square lattice (spacing ``scale``):
corridors run along lattice edges, lattice nodes where a corridor merely passes straight through
are path interior (the local levels report them as on-path, B §5.3.2), every other node is a
place (intersections, L corners, dead-ends). Stars list the compass directions clockwise from
north; the north-south axis is local path 0, east-west local path 1.

:func:`explore` walks a rover through a world by turn-then-travel actions and returns the
:class:`Experience` of B §8.4: the views ``⟨S_p, arrival entry⟩`` at each place (each star listed
from a random entry, because local labels are arbitrary), the turn of each action (clockwise
steps from the arrival entry to the exit entry: a turn is fully described by the star, B §8.1),
the entry bearings in the rover frame (the metrical annotation of the local map ``m_p``) and the
noisy odometry displacements ``λ_i`` (SE(2), rover pose at place ``i`` in the frame of the rover
pose at place ``i-1``). The same record can later be produced by the local levels from the
simulator: one row per confirmed place, the star from the gateways, the arrival gateway, the
exit gateway chosen and the odometry between the two dividing poses.

>>> w = grid_world(3, 3, seed=0)
>>> e = explore(w, 6, seed=1)
>>> len(e.views), e.turns.shape, e.odometry.shape
(7, (6,), (6, 3))
"""

from __future__ import annotations

from typing import NamedTuple

import networkx as nx
import numpy as np

from pqrm_jax.hssh.cellular import check_positive_finite

from .star import Star

_DIRS = ((0, 1), (1, 0), (0, -1), (-1, 0))  # N, E, S, W: clockwise
_BEARING = (np.pi / 2, 0.0, -np.pi / 2, np.pi)


class CorridorWorld(NamedTuple):
    """A ground-truth corridor world.

    Attributes:
        positions: ``[m, 2]`` place positions.
        stars: ``m`` stars, entries clockwise.
        bearings: ``m`` tuples, world heading of each star entry.
        edges: ``{(p, e): (p', e', length)}`` for every traversable entry (symmetric).
    """

    positions: np.ndarray
    stars: tuple
    bearings: tuple
    edges: dict

    @property
    def n_places(self) -> int:
        return len(self.stars)

    def graph(self) -> nx.MultiGraph:
        """The place graph (networkx), edge attribute ``length``."""
        g = nx.MultiGraph()
        g.add_nodes_from(range(self.n_places))
        for (p, e), (q, f, d) in self.edges.items():
            if (p, e) < (q, f):
                g.add_edge(p, q, length=d, gates=((p, e), (q, f)))
        return g


class Experience(NamedTuple):
    """An exploration experience ``v0 a1 v1 … an vn`` between places (B §8.4).

    Attributes:
        views: ``n+1`` views ``(star, arrival entry)`` as observed (star listed in rover order).
        bearings: ``n+1`` tuples, bearing of each observed entry in the rover frame at arrival.
        turns: ``[n]`` clockwise steps from the arrival entry to the exit entry before travel i.
        odometry: ``[n, 3]`` noisy displacement λ_i (x, y, θ) between consecutive arrivals.
        true_places: ``[n+1]`` ground-truth place of each view (for evaluation only).
        true_odometry: ``[n, 3]`` noise-free displacements (for evaluation only).
        true_arrivals: ``[n+1]`` arrival entry of each view in the world's star numbering.
    """

    views: tuple
    bearings: tuple
    turns: np.ndarray
    odometry: np.ndarray
    true_places: np.ndarray
    true_odometry: np.ndarray
    true_arrivals: np.ndarray


def _check_scale(scale) -> float:
    return check_positive_finite("scale", scale)


def world_from_lattice(open_edges: set, scale: float = 1.0) -> CorridorWorld:
    """Builds a world from lattice corridors ``{((x, y), (x', y')), ...}`` (unit steps; B §8.4).

    Args:
        open_edges: the corridors, each a pair of adjacent lattice nodes.
        scale: the lattice spacing, finite and > 0.

    Returns:
        The :class:`CorridorWorld` whose places are the lattice nodes that are not plain
        corridor points.

    Raises:
        ValueError: for a bad ``scale``, a corridor that is not a unit step, no corridor, or a
            lattice without a place (a pure ring corridor).
    """
    _check_scale(scale)
    nbrs: dict = {}
    for a, b in open_edges:
        if abs(a[0] - b[0]) + abs(a[1] - b[1]) != 1:
            raise ValueError(f"lattice corridor {a}-{b} is not a unit step")
        nbrs.setdefault(a, set()).add(b)
        nbrs.setdefault(b, set()).add(a)
    if not nbrs:
        raise ValueError("a world needs at least one corridor")

    def open_dirs(n):
        return [any((n[0] + dx, n[1] + dy) == m for m in nbrs[n]) for dx, dy in _DIRS]

    def is_place(n):
        o = open_dirs(n)
        return o not in ([True, False, True, False], [False, True, False, True])

    places = sorted(n for n in nbrs if is_place(n))
    if not places:
        raise ValueError("the lattice has no place (a pure ring corridor)")
    pid = {n: i for i, n in enumerate(places)}
    stars, bearings, entry_of = [], [], []
    for n in places:
        o = open_dirs(n)
        axes = {0: o[0] or o[2], 1: o[1] or o[3]}
        ents, bs, eo = [], [], {}
        for k in range(4):
            ax = k % 2
            if axes[ax]:
                eo[k] = len(ents)
                ents.append((ax, 1 if k < 2 else -1, int(o[k])))
                bs.append(_BEARING[k])
        stars.append(Star.from_entries(ents))
        bearings.append(tuple(bs))
        entry_of.append(eo)
    edges = {}
    for n in places:
        for k, (dx, dy) in enumerate(_DIRS):
            if not open_dirs(n)[k]:
                continue
            cur, d = (n[0] + dx, n[1] + dy), 1
            while cur not in pid:
                cur, d = (cur[0] + dx, cur[1] + dy), d + 1
            back = (k + 2) % 4
            edges[(pid[n], entry_of[pid[n]][k])] = (pid[cur], entry_of[pid[cur]][back],
                                                    float(d * scale))
    pos = np.array(places, float) * scale
    return CorridorWorld(pos, tuple(stars), tuple(bearings), edges)


def grid_world(nx_: int, ny: int, loop_prob: float = 0.4, seed: int = 0,
               scale: float = 1.0) -> CorridorWorld:
    """A random connected corridor world on an ``nx_ × ny`` lattice (nested loops, aliasing).

    A random spanning tree of the lattice (random-weight minimum spanning tree) is kept, and each
    other lattice edge is opened with probability ``loop_prob`` (each one closes a loop).

    Args:
        nx_, ny: lattice size (≥ 2 each).
        loop_prob: probability of each extra corridor.
        seed: NumPy seed.
        scale: lattice spacing (results are scale-free).

    Returns:
        The :class:`CorridorWorld`.

    Raises:
        ValueError: for a lattice smaller than 2 × 2.
    """
    if nx_ < 2 or ny < 2:
        raise ValueError("grid_world needs at least a 2x2 lattice")
    _check_scale(scale)
    rng = np.random.default_rng(seed)
    lat = nx.grid_2d_graph(nx_, ny)
    for a, b in lat.edges:
        lat.edges[a, b]["w"] = rng.random()
    tree = nx.minimum_spanning_tree(lat, weight="w")
    edges = {tuple(sorted(e)) for e in tree.edges}
    for a, b in sorted(lat.edges):
        if tuple(sorted((a, b))) not in edges and rng.random() < loop_prob:
            edges.add(tuple(sorted((a, b))))
    return world_from_lattice(edges, scale)


def office_world(scale: float = 1.0) -> CorridorWorld:
    """A world built like the §8.3 office: 6 paths, 9 places, 4 distinct local topologies.

    Hallways ``y=0``, ``y=2`` (``x`` 0..2), ``x=0``, ``x=1``, ``x=2`` (``y`` 0..2) and ``y=1``
    from ``x=1`` to a dead-end at ``x=3`` (6 paths). Places: 4 L corners, 3 T (bottom, top and
    centre of ``x=1``), 1 + (``(2, 1)``) and 1 dead-end (``(3, 1)``) → 9 places, 4 distinct stars.
    The thesis's floor plan (Fig. 8.2) is not given as data; this is a stand-in with its counts.

    Args:
        scale: lattice spacing (results are scale-free).

    Returns:
        The :class:`CorridorWorld` (9 places).
    """
    e = set()
    for x in range(2):
        for y in (0, 2):
            e.add(((x, y), (x + 1, y)))
    for x in (0, 1, 2):
        for y in range(2):
            e.add(((x, y), (x, y + 1)))
    e.add(((1, 1), (2, 1)))
    e.add(((2, 1), (3, 1)))
    return world_from_lattice(e, scale)


def _se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[2]), np.sin(a[2])
    d = b[:2] - a[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1],
                     (b[2] - a[2] + np.pi) % (2 * np.pi) - np.pi])


def explore(world: CorridorWorld, n_travels: int, seed: int = 0, sigma_xy: float = 0.02,
            sigma_theta: float = 0.01, start: int | None = None) -> Experience:
    """Walks the rover through ``world`` by turn-then-travel actions (B §8.1, §8.4).

    The policy prefers a gateway of the current place not traversed yet (exploration), else a
    random traversable gateway (no U-turn unless at a dead-end). Odometry noise per travel of
    length ``d``: Gaussian with sd ``sigma_xy · d`` on x, y and ``sigma_theta · d / scale`` on θ
    (``scale`` = shortest corridor), so results do not change with units.

    Args:
        world: ground truth.
        n_travels: number of travel actions (``≥ 0``).
        seed: NumPy seed (exploration policy, listing rotations, noise).
        sigma_xy, sigma_theta: odometry noise.
        start: start place (random when ``None``).

    Returns:
        The :class:`Experience` (``n_travels + 1`` views, turns, odometry ``[n, 3]`` and the
        ground truth for evaluation).

    Raises:
        ValueError: for ``n_travels < 0`` or a ``start`` not in the world.
    """
    if n_travels < 0:
        raise ValueError(f"n_travels must be >= 0, got {n_travels}")
    rng = np.random.default_rng(seed)
    unit = min(d for (_, _, d) in world.edges.values())
    p = int(rng.integers(world.n_places)) if start is None else int(start)
    if not 0 <= p < world.n_places:
        raise ValueError(f"start place {start} not in the world")
    gates = [e for e in range(len(world.stars[p])) if world.stars[p].alpha[e]]
    arr = world.stars[p].opp[int(rng.choice(gates))]  # initial action a0 arrived through it
    visited: set = set()
    arrivals = [arr]
    views, bears, turns, odo, todo, places = [], [], [], [], [], [p]

    def observe(p, arr):
        star = world.stars[p]
        s = int(rng.integers(len(star)))
        heading = world.bearings[p][arr]
        b = tuple(float((world.bearings[p][(i + s) % len(star)] - heading + np.pi)
                        % (2 * np.pi) - np.pi) for i in range(len(star)))
        views.append((star.rotate(s), (arr - s) % len(star)))
        bears.append(b)

    def pose(p, arr):
        return np.array([*world.positions[p], world.bearings[p][arr]])

    observe(p, arr)
    for _ in range(n_travels):
        star = world.stars[p]
        gates = [e for e in range(len(star)) if star.alpha[e]]
        fresh = [e for e in gates if (p, e) not in visited]
        if fresh:
            ex = int(rng.choice(fresh))
        else:
            back = star.opp[arr]
            ch = [e for e in gates if e != back] or gates
            ex = int(rng.choice(ch))
        q, f, d = world.edges[(p, ex)]
        visited.update({(p, ex), (q, f)})
        new_arr = world.stars[q].opp[f]
        true = _se2_between(pose(p, arr), pose(q, new_arr))
        noise = rng.normal(size=3) * np.array([sigma_xy * d, sigma_xy * d, sigma_theta * d / unit])
        turns.append((ex - arr) % len(star))
        todo.append(true)
        odo.append(true + noise)
        p, arr = q, new_arr
        places.append(p)
        arrivals.append(arr)
        observe(p, arr)
    return Experience(tuple(views), tuple(bears), np.array(turns, np.int32),
                      np.array(odo, float).reshape(-1, 3), np.array(places, np.int32),
                      np.array(todo, float).reshape(-1, 3),
                      np.array(arrivals, np.int32))


def global_paths(world: CorridorWorld) -> list[list[int]]:
    """The global paths of a world: chains of local paths joined by corridors (B §3.2.3).

    Returns:
        One list of places per path, in order along the path.

    Args:
        world: the corridor world.
    """
    seen, out = set(), []
    for p, star in enumerate(world.stars):
        for e in range(len(star)):
            node = (p, star.path[e])
            if node in seen:
                continue
            chain = [p]
            seen.add(node)
            for first, prepend in ((e, False), (star.opp[e], True)):
                cp, ce = p, first
                while (cp, ce) in world.edges:
                    q, f, _ = world.edges[(cp, ce)]
                    if (q, world.stars[q].path[f]) in seen:
                        break
                    seen.add((q, world.stars[q].path[f]))
                    chain = [q, *chain] if prepend else [*chain, q]
                    cp, ce = q, world.stars[q].opp[f]
            out.append(chain)
    return out
