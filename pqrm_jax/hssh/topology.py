"""Local topology of an occupancy grid: gateways, star, place kind (B ch. 5--6).

:func:`local_topology` runs the whole pipeline on one grid and :func:`local_topology_batch`
on a stack of equal-size grids: the cellular stages (island removal, bleeding, distance
transform, EVG thinning) run as one batched JAX program (:mod:`pqrm_jax.hssh.cellular`), the
graph stages (pruning, core, search spaces, anchors, gateway segments, star) on the host
(:mod:`pqrm_jax.hssh.skeleton`, :mod:`pqrm_jax.hssh.gateways`, :mod:`pqrm_jax.hssh.star`).

Place detection (B §5.3.2): ``"path"`` iff exactly 2 gateways and 1 path; ``"dead_end"`` with
one gateway; ``"enclosed"`` with none; ``"place"`` otherwise.

Input grids: a 2-D ``uint8`` grey image (free iff value >= 128, B §6.3.3's threshold 127) or
a ``bool`` occupancy array (True = occupied); optional ``unknown`` mask (bool). Bad input
raises ``TypeError``/``ValueError`` naming the problem: wrong dtype or shape, a side below
:data:`MIN_SIDE`, a negative or non-finite robot radius, a robot cell out of the grid or not
in free space (after island removal), no free cell, or no obstacle at all (featureless open
space is not handled, B §3.3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from pqrm_jax.hssh.cellular import (
    CellularMaps,
    cellular_stages,
    check_m_cap,
    check_robot_radius,
)
from pqrm_jax.hssh.gateways import (
    SIDE_CONE,
    SIDE_SLACK,
    Core,
    Gateway,
    core,
    find_gateways,
    search_spaces,
)
from pqrm_jax.hssh.skeleton import PrunedSkeleton, prune_skeleton
from pqrm_jax.hssh.star import StarEntry, build_star

__all__ = ["LocalTopology", "MIN_SIDE", "local_topology", "local_topology_batch",
           "topology_from_maps", "place_kind", "occupancy_from_grid", "resolution_bound"]

MIN_SIDE = 9
"""Smallest grid side accepted (the smallest image of B's corpus). B §6.3.3 finds paths
narrower than ``13 + robot width`` cells unreliable; see :func:`resolution_bound`."""


class LocalTopology(NamedTuple):
    """Local topology of one grid (B §5.1--5.3).

    gateways: float ``[G, 2, 2]`` segment end points (row, col); ``[g, 0]`` is on the left
        looking out of the place.
    outward: float ``[G, 2]`` unit outward normals (row, col).
    num_paths: number of distinct local paths.
    star: the clockwise circular list of ``(path id, direction, traversable)``.
    kind: ``"path"``, ``"place"``, ``"dead_end"`` or ``"enclosed"``.
    entries: the star as :class:`StarEntry` (with gateway index and angle).
    skeleton: the pruned skeleton (tree, ``c``, exits).
    core: base points and core (:class:`Core`; None when the tree is empty).
    details: the :class:`Gateway` records (anchors, centres, radii).
    """

    gateways: np.ndarray
    outward: np.ndarray
    num_paths: int
    star: tuple[tuple[int, int, bool], ...]
    kind: str
    entries: tuple[StarEntry, ...]
    skeleton: PrunedSkeleton
    core: Core | None
    details: tuple[Gateway, ...]


def place_kind(num_gateways: int, num_paths: int) -> str:
    """B §5.3.2 place-detection rule.

    Args:
        num_gateways: gateways of the local topology.
        num_paths: paths through it.

    Returns:
        ``"path"``, ``"place"``, ``"dead_end"`` or ``"enclosed"``.

    >>> place_kind(2, 1), place_kind(4, 2), place_kind(1, 1), place_kind(0, 0)
    ('path', 'place', 'dead_end', 'enclosed')
    """
    if num_gateways == 0:
        return "enclosed"
    if num_gateways == 2 and num_paths == 1:
        return "path"
    if num_gateways == 1:
        return "dead_end"
    return "place"


def resolution_bound(max_path_width: float, robot_width: float,
                     min_path_cells: int = 13) -> tuple[float, int]:
    """Coarsest cell size and smallest LPM side for reliable gateways (B §6.3.3).

    The largest cell size ``x`` with ``max_path_width / x - ceil(robot_width / x) >= 13``, and
    the side ``ceil((max_path_width + robot_width) / x)``. Units cancel (scale-free).

    Args:
        max_path_width: the widest path to be recognised.
        robot_width: the robot's width (same units).
        min_path_cells: the least cells across a path (B's 13).

    Returns:
        ``(cell size, LPM side in cells)``.

    >>> resolution_bound(300.0, 30.0)      # B's worked example: 30 cm robot, 3 m path
    (20.0, 17)
    """
    if not (max_path_width > 0 and robot_width >= 0 and math.isfinite(max_path_width)
            and math.isfinite(robot_width)):
        raise ValueError("max_path_width must be > 0 and robot_width >= 0 (finite)")
    # max_path_width / x - ceil(robot_width / x) decreases in x; search the breakpoints
    best = None
    lo, hi = max_path_width / 1e6, max_path_width / min_path_cells
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if max_path_width / mid - math.ceil(robot_width / mid - 1e-12) >= min_path_cells:
            best, lo = mid, mid
        else:
            hi = mid
    x = float(round(best, 9))
    return x, int(math.ceil((max_path_width + robot_width) / x - 1e-9))


def occupancy_from_grid(grid) -> np.ndarray:
    """Occupied mask of a uint8 grey image (free iff >= 128) or a bool occupancy array.

    Args:
        grid: ``[H, W]`` uint8 grey image or bool occupancy.

    Returns:
        ``[H, W]`` bool, True where occupied.

    >>> occupancy_from_grid(np.array([[0, 127, 128, 255]], np.uint8)).tolist()
    [[True, True, False, False]]
    """
    g = np.asarray(grid)
    if g.dtype == np.uint8:
        return g < 128
    if g.dtype == np.bool_:
        return g.copy()
    raise TypeError(f"grid must be uint8 grey (free >= 128) or bool occupancy, got {g.dtype}")


def _check_stack(occ: np.ndarray) -> None:
    h, w = occ.shape[-2:]
    if min(h, w) < MIN_SIDE:
        raise ValueError(f"grid {h}x{w} is too small: sides must be >= {MIN_SIDE} cells "
                         "(B §6.3.3: paths need >= 13 + robot-width cells)")


def _check_robot(cell, shape) -> tuple[int, int]:
    try:
        r, c = (int(v) for v in cell)
        if not all(float(v) == int(v) for v in cell):
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f"robot_cell must be a (row, col) pair of ints, got {cell!r}") from None
    if not (0 <= r < shape[0] and 0 <= c < shape[1]):
        raise ValueError(f"robot_cell {(r, c)} lies outside the {shape[0]}x{shape[1]} grid")
    return r, c


def topology_from_maps(occupied: np.ndarray, unknown: np.ndarray, free_space: np.ndarray,
                       dist2: np.ndarray, skeleton: np.ndarray, robot_cell: tuple[int, int],
                       method: str = "anchor", side_slack: float = SIDE_SLACK,
                       side_cone: float = SIDE_CONE) -> LocalTopology:
    """Host graph stages for one grid's :class:`~pqrm_jax.hssh.cellular.CellularMaps` slice.

    Args:
        occupied, unknown, free_space: ``[H, W]`` bool masks of the grid.
        dist2: ``[H, W]`` squared distance transform (cells).
        skeleton: ``[H, W]`` bool thinned free space.
        robot_cell: ``(row, col)`` of the robot.
        method: ``"anchor"`` (B §6.3.2) or ``"constriction"`` (B §6.2).
        side_slack: slack of the gateway side test.

    Returns:
        :class:`LocalTopology` (B §5.3, ch. 6).

    Raises:
        ValueError: when the robot is not in free space after island removal or no obstacle is
            left (featureless open space, B §3.3).
    """
    occupied = np.asarray(occupied, bool)
    if not free_space[robot_cell]:
        raise ValueError(f"robot_cell {robot_cell} is not in free space (after island removal)")
    if not occupied.any():
        raise ValueError("no obstacle left after island removal: featureless open space is "
                         "not handled (B §3.3)")
    pr = prune_skeleton(skeleton, free_space, unknown, robot_cell, dist2)
    empty = np.zeros((0, 2, 2)), np.zeros((0, 2))
    if pr.closest is None or not pr.exits:
        return LocalTopology(*empty, 0, (), "enclosed", (), pr, None, ())
    cr = core(pr.tree, pr.closest, dist2)
    branches = search_spaces(pr.tree, pr.closest, cr, dist2, pr.forks)
    gws = find_gateways(branches, dist2, occupied, method=method, side_slack=side_slack,
                        side_cone=side_cone)
    ends = np.array([g.ends for g in gws], float).reshape(-1, 2, 2)
    outward = np.array([g.outward for g in gws], float).reshape(-1, 2)
    entries = build_star(ends, outward, cr.centre)
    star = tuple((e.path, e.direction, e.traversable) for e in entries)
    n_paths = len({e.path for e in entries})
    return LocalTopology(ends, outward, n_paths, star, place_kind(len(gws), n_paths),
                         tuple(entries), pr, cr, tuple(gws))


def _unstack(maps: CellularMaps, i: int) -> dict:
    return {k: np.asarray(getattr(maps, k)[i]) for k in
            ("occupied", "unknown", "free_space", "dist2", "skeleton")}


def local_topology_batch(grids, robot_cells: Sequence, *, robot_radius: float = 0.0,
                         unknown=None, method: str = "anchor", m_cap: float | None = None,
                         side_slack: float = SIDE_SLACK,
                         side_cone: float = SIDE_CONE) -> list[LocalTopology]:
    """Local topology of a stack of equal-size grids ``[B, H, W]`` (B ch. 5--6).

    The cellular stages run once, batched, in JAX; the graph stages per grid on the host.

    Args:
        grids: uint8 grey ``[B, H, W]`` (free >= 128) or bool occupancy (True = occupied).
        robot_cells: ``[B, 2]`` (row, col) per grid.
        robot_radius: obstacle bleeding radius in cells (>= 0).
        unknown: optional bool ``[B, H, W]`` unknown cells (count as free for the skeleton;
            skeleton cells next to them are exits).
        method: ``"anchor"`` (B §6.3.2) or ``"constriction"`` (B §6.2).
        m_cap: EVG cap ``M`` in cells (default ``min(H, W) / 5``, B §6.3.1).
        side_slack: side-obstacle search slack (:data:`~pqrm_jax.hssh.gateways.SIDE_SLACK`).
        side_cone: side-obstacle cone half-angle, degrees
            (:data:`~pqrm_jax.hssh.gateways.SIDE_CONE`; 90 = B's half-plane rule).

    Returns:
        list of :class:`LocalTopology`.
    """
    occ = occupancy_from_grid(grids)
    if occ.ndim != 3:
        raise ValueError(f"grids must be a stack [B, H, W], got shape {occ.shape}")
    _check_stack(occ)
    radius = check_robot_radius(robot_radius, occ.shape[1:])
    if m_cap is not None:
        check_m_cap(m_cap)
    unk = np.zeros_like(occ) if unknown is None else np.asarray(unknown)
    if unk.dtype != np.bool_ or unk.shape != occ.shape:
        raise ValueError(f"unknown must be bool with shape {occ.shape}, got "
                         f"{unk.dtype} {unk.shape}")
    cells = list(robot_cells)
    if len(cells) != occ.shape[0]:
        raise ValueError(f"need one robot cell per grid ({occ.shape[0]}), got {len(cells)}")
    cells = [_check_robot(c, occ.shape[1:]) for c in cells]
    free = ~(occ | unk)
    for i in range(occ.shape[0]):
        if not free[i].any():
            raise ValueError(f"grid {i} has no free cell")
        if not occ[i].any():
            raise ValueError(f"grid {i} has no occupied cell: featureless open space is not "
                             "handled (B §3.3)")
    maps = cellular_stages(jnp.asarray(occ), jnp.asarray(unk), robot_radius=radius,
                           m_cap=m_cap)
    out = []
    for i, rc in enumerate(cells):
        try:
            out.append(topology_from_maps(**_unstack(maps, i), robot_cell=rc, method=method,
                                          side_slack=side_slack, side_cone=side_cone))
        except ValueError as e:
            raise ValueError(f"grid {i}: {e}") from None
    return out


def local_topology(grid, robot_cell: Sequence[int], *, robot_radius: float = 0.0,
                   unknown=None, method: str = "anchor", m_cap: float | None = None,
                   side_slack: float = SIDE_SLACK,
                   side_cone: float = SIDE_CONE) -> LocalTopology:
    """Gateways, star and place kind of one grid (B ch. 5--6).

    Args:
        grid: 2-D uint8 grey image (free >= 128) or bool occupancy (True = occupied).
        robot_cell: ``(row, col)`` of the robot.
        robot_radius: obstacle bleeding radius in cells (>= 0).
        unknown: optional bool mask of unknown cells.
        method: ``"anchor"`` or ``"constriction"``.
        m_cap: EVG cap ``M`` in cells (default ``min(H, W) / 5``).
        side_slack: side-obstacle search slack (see :data:`~pqrm_jax.hssh.gateways.SIDE_SLACK`).
        side_cone: side-obstacle cone half-angle (see :data:`~pqrm_jax.hssh.gateways.SIDE_CONE`).

    Returns:
        :class:`LocalTopology`.

    >>> from pqrm_jax.sim.corridors import plus_image
    >>> lt = local_topology(plus_image(39), (19, 19))
    >>> lt.kind, lt.num_paths, lt.gateways.shape
    ('place', 2, (4, 2, 2))
    >>> lt.star
    ((0, 1, True), (1, 1, True), (0, -1, True), (1, -1, True))
    """
    g = np.asarray(grid)
    if g.ndim != 2:
        raise ValueError(f"grid must be 2-D, got shape {g.shape}")
    unk = None if unknown is None else np.asarray(unknown)[None]
    return local_topology_batch(g[None], [robot_cell], robot_radius=robot_radius,
                                unknown=unk, method=method, m_cap=m_cap,
                                side_slack=side_slack, side_cone=side_cone)[0]
