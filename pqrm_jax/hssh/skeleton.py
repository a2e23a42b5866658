"""Frontier-based pruning of the EVG skeleton to a tree (B §6.1.1, Fig. 6.3--6.4), on the host.

The pruned skeleton is a :class:`networkx.Graph` whose nodes are ``(row, col)`` cells and
whose edges join 8-neighbours (weight 1 or sqrt 2). Graph crawling and spanning trees are
irregular, data-dependent work over a few hundred to a few thousand skeleton cells, so they
run on the host with networkx (a graph users can inspect) rather than as fixed-shape JAX.

Steps (B §6.1.1): drop skeleton cells over unknown space; keep cells reachable from the robot
through free space; ``c`` = the skeleton cell closest to the robot; crawl from ``c``, stopping
at *exits* (skeleton cells on the grid border or next to unknown cells); keep the minimum
spanning tree of the crawled cells and strip every leaf that is not an exit (with at most one
way out, ``c`` is kept as a terminal too: the dead-end case; exits through one opening of the
border or into one unknown region are one way out); recompute ``c`` on the tree.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import networkx as nx
import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

__all__ = ["PrunedSkeleton", "skeleton_graph", "prune_skeleton"]

_STEPS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2.0)), (1, -1, math.sqrt(2.0)))


class PrunedSkeleton(NamedTuple):
    """A pruned skeleton (B §6.1.1).

    tree: networkx tree over ``(row, col)`` nodes (edge attribute ``weight``); may be empty.
    closest: ``c``, the tree node closest to the robot (None when the tree is empty).
    exits: the exits kept in the tree (list of nodes).
    forks: tree nodes where the paths from ``c`` to several exits through one border opening
        parted before all but one of those exits were dropped (issue 26); branches stop there
        as at a junction (:func:`~pqrm_jax.hssh.gateways.search_spaces`), but they are no
        junctions of the core.
    """

    tree: nx.Graph
    closest: tuple[int, int] | None
    exits: list[tuple[int, int]]
    forks: tuple[tuple[int, int], ...] = ()


def skeleton_graph(skeleton: np.ndarray) -> nx.Graph:
    """8-neighbour graph of a bool skeleton image ``[H, W]`` (nodes ``(row, col)``).

    Args:
        skeleton: ``[H, W]`` bool.

    Returns:
        ``networkx.Graph`` with edge ``weight`` 1 (4-neighbours) or √2 (diagonals) (B §6.1.1).

    >>> g = skeleton_graph(np.eye(3, dtype=bool))
    >>> sorted(g.edges(data="weight"))[0][2] == math.sqrt(2)
    True
    """
    sk = np.asarray(skeleton, bool)
    h, w = sk.shape
    g = nx.Graph()
    rows, cols = np.nonzero(sk)
    g.add_nodes_from(zip(rows.tolist(), cols.tolist(), strict=True))
    for di, dj, wt in _STEPS:
        r2, c2 = rows + di, cols + dj
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        ok[ok] = sk[r2[ok], c2[ok]]
        g.add_weighted_edges_from(
            ((int(a), int(b)), (int(c), int(d)), wt)
            for a, b, c, d in zip(rows[ok], cols[ok], r2[ok], c2[ok], strict=True))
    return g


OPENING_STUB = 0.25
"""Two runs of open cells along the grid border are one opening (one way out) when the obstacle
between them is a *stub*: no longer along the border than ``OPENING_STUB`` times the opening
width ``W`` (the two runs, or the openings already joined, and the stub together), and open
cells connect the two runs within ``OPENING_STUB * W`` of the stub (8-connected, the skeleton's
and the reachability's connectivity), so the stub reaches no deeper into the grid than that.

Noise cells on the border row of a corridor's opening are kept by island removal (they touch
the border), so they split the opening. The skeleton then forks around them into two exits
about half a corridor width before the border. Counted as two ways out, the dead end's own
branch was stripped and a dead end read as a two-gateway place; kept as two terminals, the
fork's junction entered the core of a robot near the border (issue 26: 10 of the 12 failures
of the shape family). A noise stub reaches 1--3 cells into the grid, around it the runs join
within a few cells; a wall between two corridors that leave the grid reaches in about a
corridor length or more. Both measures are relative to the opening width (scale-free)."""


def _ring(h: int, w: int) -> list[tuple[int, int]]:
    """The border cells of an ``h x w`` grid in cyclic order (clockwise from (0, 0))."""
    return ([(0, j) for j in range(w)] + [(i, w - 1) for i in range(1, h)]
            + [(h - 1, j) for j in range(w - 2, -1, -1)] + [(i, 0) for i in range(h - 2, 0, -1)])


def _joined_near(open_: np.ndarray, pa, pb, gap: list, depth: float) -> bool:
    """Whether open cells join ``pa`` and ``pb`` inside the box of ``gap + [pa, pb]`` grown
    by ``depth`` cells (8-connected)."""
    cells = np.array([pa, pb, *gap])
    d = int(math.floor(depth))
    r0, c0 = np.maximum(cells.min(axis=0) - d, 0)
    r1, c1 = np.minimum(cells.max(axis=0) + d + 1, open_.shape)
    lab, _ = ndimage.label(open_[r0:r1, c0:c1], structure=np.ones((3, 3), int))
    la, lb = lab[pa[0] - r0, pa[1] - c0], lab[pb[0] - r0, pb[1] - c0]
    return bool(la) and la == lb


def _opening_runs(open_: np.ndarray, stub: float = OPENING_STUB) -> dict:
    """Opening label of every open border cell: runs of ``open_`` cells along the border ring
    (closed through the corners), runs joined across border stubs (:data:`OPENING_STUB`).

    >>> open_ = np.zeros((9, 9), bool); open_[2:, 1:8] = True     # a corridor leaving at the bottom
    >>> open_[8, 4] = False                                       # one noise cell on the border
    >>> len(set(_opening_runs(open_).values())), len(set(_opening_runs(open_, 0.0).values()))
    (1, 2)
    """
    h, w = open_.shape
    ring = _ring(h, w)
    vals = [bool(open_[c]) for c in ring]
    if all(vals):
        return dict.fromkeys(ring, 0)
    n = len(ring)
    # start at a closed cell after an open one, so the runs alternate open / closed cyclically
    start = next((k for k in range(n) if not vals[k] and vals[k - 1]), 0)
    runs: list[tuple[bool, list[int]]] = []
    for k in range(n):
        idx = (start + k) % n
        if not runs or runs[-1][0] != vals[idx]:
            runs.append((vals[idx], []))
        runs[-1][1].append(idx)
    opens = [i for i, (o, _) in enumerate(runs) if o]
    parent = {i: i for i in opens}
    width = {i: len(runs[i][1]) for i in opens}   # of each joined opening (at its root)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    m = len(runs)
    changed = len(opens) > 1 and stub > 0
    while changed:   # join across stubs until stable (widths grow as openings join)
        changed = False
        for g, (is_open, cells) in enumerate(runs):
            if is_open:
                continue
            a, b = find((g - 1) % m), find((g + 1) % m)
            if a == b:
                continue
            wd = width[a] + width[b] + len(cells)
            if len(cells) > stub * wd:
                continue
            pa, pb = ring[runs[(g - 1) % m][1][-1]], ring[runs[(g + 1) % m][1][0]]
            if _joined_near(open_, pa, pb, [ring[i] for i in cells], stub * wd):
                parent[b] = a
                width[a] = wd
                changed = True
    out = {}
    for i in opens:
        for idx in runs[i][1]:
            out[ring[idx]] = find(i)
    return out


def _exit_groups(exits: list[tuple[int, int]], open_: np.ndarray,
                 unknown: np.ndarray) -> tuple[list[int], list[int]]:
    """Per exit: its way out (exits through one border opening, :func:`_opening_runs`, or next
    to one 8-connected unknown region share one) and its border opening (-1 for an exit off
    the border)."""
    runs = _opening_runs(open_) if exits else {}
    unk_lab, _ = ndimage.label(unknown, structure=np.ones((3, 3), int))
    parent = list(range(len(exits)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    first: dict = {}
    opening = []
    for k, (r, c) in enumerate(exits):
        keys = [("border", runs[(r, c)])] if (r, c) in runs else []
        opening.append(runs.get((r, c), -1))
        win = unk_lab[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
        keys.extend(("unknown", int(x)) for x in np.unique(win[win > 0]))
        for key in keys:
            if key in first:
                parent[find(k)] = find(first[key])
            else:
                first[key] = k
    return [find(k) for k in range(len(exits))], opening


def _ways_out(exits: list[tuple[int, int]], open_: np.ndarray, unknown: np.ndarray) -> int:
    """Number of distinct ways out among ``exits``: exits on one opening of the border ring
    (a run of ``open_`` cells, closed through the corners; runs split only by a border stub,
    :data:`OPENING_STUB`, are one opening) or next to one 8-connected unknown region count
    once. A wide corridor that leaves the grid at a corner meets the border in two exits (on
    two sides, or in two adjacent cells); counted as two, a dead end's own branch was stripped
    as a non-terminal leaf and the place read as enclosed (issue 26).

    >>> open_ = np.zeros((5, 5), bool); open_[3:, 3:] = True      # an opening at a corner
    >>> _ways_out([(4, 3), (3, 4)], open_, np.zeros((5, 5), bool))
    1
    """
    if len(exits) <= 1:
        return len(exits)
    return len(set(_exit_groups(exits, open_, unknown)[0]))


def _terminal_subtree(mst, terminals: list[int], rows: np.ndarray,
                      cols: np.ndarray) -> tuple[nx.Graph, set[int]]:
    """The smallest subtree of ``mst`` holding ``terminals`` (as a networkx tree over
    ``(row, col)`` nodes) and its node indices."""
    # stripping every non-terminal leaf until none is left leaves the smallest subtree that
    # holds the terminals: with the tree rooted at a terminal, the union of the terminals'
    # paths to the root (one walk up the BFS predecessors, each node visited once)
    root = terminals[0]
    _, pred = csgraph.breadth_first_order(mst, root, directed=False, return_predecessors=True)
    pred = pred.tolist()
    kept: set[int] = set()
    for t in terminals:
        while t >= 0 and t not in kept:
            kept.add(t)
            t = pred[t] if t != root else -1
    keep_idx = sorted(kept)
    rl, cl = rows.tolist(), cols.tolist()
    tree = nx.Graph()
    tree.add_nodes_from((rl[a], cl[a]) for a in keep_idx)
    tree.add_weighted_edges_from(
        ((rl[a], cl[a]), (rl[b], cl[b]), math.hypot(rl[a] - rl[b], cl[a] - cl[b]))
        for a, b in sorted((min(a, pred[a]), max(a, pred[a])) for a in keep_idx if a != root))
    return tree, kept


def _one_exit_per_opening(mst, ci: int, rows: np.ndarray, cols: np.ndarray,
                          exit_idx: list[int], opening: list[int], dist2, border: np.ndarray
                          ) -> tuple[list[int], list[tuple[int, int]]]:
    """Of the exits through one border opening keep one (the widest way from ``c``, then the
    nearest); also return the forks where the dropped exits' paths parted (issue 26)."""
    n = len(rows)
    forks: list[tuple[int, int]] = []
    dist = csgraph.dijkstra(mst, directed=False, indices=ci)
    # the widest way: the largest least clearance on the tree path from c (cells on the
    # border ring, where the noise stubs lie, not counted), then the shortest
    clr = (np.ones(n) if dist2 is None else
           np.asarray(dist2, float)[rows, cols]).astype(float)
    clr[border[rows, cols]] = np.inf
    order, pred_c = csgraph.breadth_first_order(mst, ci, directed=False,
                                                return_predecessors=True)
    neck = np.full(n, np.inf)
    neck[ci] = clr[ci]
    for v in order[1:].tolist():
        neck[v] = min(neck[pred_c[v]], clr[v])
    best: dict = {}
    for k, o in zip(exit_idx, opening, strict=True):
        key = (-neck[k], dist[k], int(rows[k]), int(cols[k]))
        if o >= 0 and (o not in best or key < best[o][0]):
            best[o] = (key, k)
    pred_l = pred_c.tolist()

    def up(v):  # the tree path from v to c
        out = []
        while v >= 0:
            out.append(v)
            v = pred_l[v] if v != ci else -1
        return out

    for o, (_, keep) in best.items():
        others = [k for k, oo in zip(exit_idx, opening, strict=True) if oo == o and k != keep]
        if others:   # where the kept exit's path parts from the dropped ones
            common = set.intersection(*(set(up(k)) for k in others))
            fork = next(v for v in up(keep) if v in common)
            if fork != ci:
                forks.append((int(rows[fork]), int(cols[fork])))
    exit_idx = sorted(k for k, o in zip(exit_idx, opening, strict=True)
                      if o < 0 or best[o][1] == k)
    return exit_idx, forks


def prune_skeleton(skeleton: np.ndarray, free_space: np.ndarray, unknown: np.ndarray,
                   robot_cell: tuple[int, int],
                   dist2: np.ndarray | None = None) -> PrunedSkeleton:
    """Prune an EVG skeleton to the spanning tree of its exits (B §6.1.1).

    Args:
        skeleton: bool ``[H, W]`` (from :func:`pqrm_jax.hssh.cellular.evg_skeleton`).
        free_space: bool ``[H, W]`` free cells after island removal (reachability).
        unknown: bool ``[H, W]`` unknown cells (frontiers).
        robot_cell: ``(row, col)``; must lie in ``free_space`` (checked by the caller).
        dist2: optional ``[H, W]`` squared distance transform: of several exits through one
            border opening the one reached from ``c`` with the largest least clearance is kept
            (without it, the nearest along the tree).

    Returns:
        :class:`PrunedSkeleton` (an empty tree when no skeleton cell is reachable).
    """
    sk = np.asarray(skeleton, bool) & ~np.asarray(unknown, bool)
    h, w = sk.shape
    labels, _ = ndimage.label(np.asarray(free_space, bool), structure=np.ones((3, 3), int))
    lab = labels[robot_cell]
    sk &= labels == lab
    empty = PrunedSkeleton(nx.Graph(), None, [])
    if not sk.any():
        return empty
    near_unknown = ndimage.binary_dilation(np.asarray(unknown, bool),
                                           structure=np.ones((3, 3), bool))
    border = np.zeros((h, w), bool)
    border[0, :] = border[-1, :] = border[:, 0] = border[:, -1] = True
    exit_mask = sk & (border | near_unknown)
    rows, cols = np.nonzero(sk)
    n = len(rows)
    d2 = (rows - robot_cell[0]) ** 2 + (cols - robot_cell[1]) ** 2
    order = np.lexsort((cols, rows, d2))
    ci = int(order[0])
    c = (int(rows[ci]), int(cols[ci]))
    # 8-neighbour edges as index arrays (sparse graph work in scipy: the skeleton of a noisy
    # 600 x 600 grid has ~10^4 cells, too slow for pure-Python graph code)
    index = np.full((h, w), -1)
    index[rows, cols] = np.arange(n)
    us, vs, ws = [], [], []
    for di, dj, wt in _STEPS:
        r2, c2 = rows + di, cols + dj
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        ok[ok] = sk[r2[ok], c2[ok]]
        us.append(np.nonzero(ok)[0])
        vs.append(index[r2[ok], c2[ok]])
        ws.append(np.full(int(ok.sum()), wt))
    u, v, wgt = np.concatenate(us), np.concatenate(vs), np.concatenate(ws)
    is_exit = exit_mask[rows, cols]
    # crawl from c without passing through exits: components of the non-exit graph
    inner = ~is_exit[u] & ~is_exit[v]
    adj = sparse.coo_matrix((np.ones(int(inner.sum())), (u[inner], v[inner])), shape=(n, n))
    _, lab = csgraph.connected_components(adj, directed=False)
    if is_exit[ci]:
        nb = np.concatenate([v[u == ci], u[v == ci]])
        seeds = {int(lab[k]) for k in nb if not is_exit[k]}
    else:
        seeds = {int(lab[ci])}
    core_nodes = np.isin(lab, list(seeds)) & ~is_exit
    touch = (core_nodes[u] & is_exit[v]) | (core_nodes[v] & is_exit[u])
    seen_mask = core_nodes.copy()
    seen_mask[u[touch]] = True
    seen_mask[v[touch]] = True
    seen_mask[ci] = True
    keep = seen_mask[u] & seen_mask[v]
    # a crawl never steps from one exit to another unless one of them is c
    keep &= ~(is_exit[u] & is_exit[v]) | (u == ci) | (v == ci)
    mst = csgraph.minimum_spanning_tree(
        sparse.coo_matrix((wgt[keep], (u[keep], v[keep])), shape=(n, n)).tocsr())
    # the part of the tree holding c; its terminals: the exits (and c itself when there is
    # at most one exit: the dead-end case)
    comp = csgraph.breadth_first_order(mst, ci, directed=False, return_predecessors=False)
    exit_idx = sorted(int(k) for k in comp[is_exit[comp]])
    # exits counted as ways out (issue 26); of the exits through one border opening only the
    # one nearest c along the tree stays a terminal, so no fork on border noise survives
    ways, opening = _exit_groups(
        list(zip(rows[exit_idx].tolist(), cols[exit_idx].tolist(), strict=True)),
        np.asarray(free_space, bool) | np.asarray(unknown, bool), np.asarray(unknown, bool))
    n_ways = len(set(ways))
    forks: list[tuple[int, int]] = []
    if len(set(o for o in opening if o >= 0)) < sum(o >= 0 for o in opening):
        exit_idx, forks = _one_exit_per_opening(mst, ci, rows, cols, exit_idx, opening,
                                                dist2, border)
    terminals = exit_idx if n_ways > 1 else sorted(set(exit_idx) | {ci})
    tree, kept = _terminal_subtree(mst, terminals, rows, cols)
    rl, cl = rows.tolist(), cols.tolist()
    exits = sorted((rl[a], cl[a]) for a in exit_idx if a in kept)
    nodes = np.array(sorted(tree.nodes), int).reshape(-1, 2)
    d2 = (nodes[:, 0] - robot_cell[0]) ** 2 + (nodes[:, 1] - robot_cell[1]) ** 2
    c = tuple(int(x) for x in nodes[int(np.argmin(d2))])
    return PrunedSkeleton(tree, c, [e for e in exits if e in tree],
                          tuple(sorted(f for f in forks if f in tree)))
