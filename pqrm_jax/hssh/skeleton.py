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
    """

    tree: nx.Graph
    closest: tuple[int, int] | None
    exits: list[tuple[int, int]]


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


def _ways_out(exits: list[tuple[int, int]], open_: np.ndarray, unknown: np.ndarray) -> int:
    """Number of distinct ways out among ``exits``: exits on one run of ``open_`` cells along
    the border ring (the ring is closed through the corners) or next to one 8-connected
    unknown region count once. A wide corridor that leaves the grid at a corner meets the
    border in two exits (on two sides, or in two adjacent cells); counted as two, a dead end's
    own branch was stripped as a non-terminal leaf and the place read as enclosed (issue 26).

    >>> open_ = np.zeros((5, 5), bool); open_[3:, 3:] = True      # an opening at a corner
    >>> _ways_out([(4, 3), (3, 4)], open_, np.zeros((5, 5), bool))
    1
    """
    if len(exits) <= 1:
        return len(exits)
    h, w = open_.shape
    ring = ([(0, j) for j in range(w)] + [(i, w - 1) for i in range(1, h)]
            + [(h - 1, j) for j in range(w - 2, -1, -1)] + [(i, 0) for i in range(h - 2, 0, -1)])
    vals = [bool(open_[c]) for c in ring]
    run: dict = {}
    if all(vals):
        run = dict.fromkeys(ring, 0)
    else:
        start, label = vals.index(False), -1
        for k in range(len(ring)):
            idx = (start + k) % len(ring)
            if vals[idx]:
                if not vals[idx - 1]:
                    label += 1
                run[ring[idx]] = label
    unk_lab, _ = ndimage.label(unknown, structure=np.ones((3, 3), int))
    parent = list(range(len(exits)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    first: dict = {}
    for k, (r, c) in enumerate(exits):
        keys = [("border", run[(r, c)])] if (r, c) in run else []
        win = unk_lab[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
        keys.extend(("unknown", int(x)) for x in np.unique(win[win > 0]))
        for key in keys:
            if key in first:
                parent[find(k)] = find(first[key])
            else:
                first[key] = k
    return len({find(k) for k in range(len(exits))})


def prune_skeleton(skeleton: np.ndarray, free_space: np.ndarray, unknown: np.ndarray,
                   robot_cell: tuple[int, int]) -> PrunedSkeleton:
    """Prune an EVG skeleton to the spanning tree of its exits (B §6.1.1).

    Args:
        skeleton: bool ``[H, W]`` (from :func:`pqrm_jax.hssh.cellular.evg_skeleton`).
        free_space: bool ``[H, W]`` free cells after island removal (reachability).
        unknown: bool ``[H, W]`` unknown cells (frontiers).
        robot_cell: ``(row, col)``; must lie in ``free_space`` (checked by the caller).

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
    n_ways = _ways_out(list(zip(rows[exit_idx].tolist(), cols[exit_idx].tolist(), strict=True)),
                       np.asarray(free_space, bool) | np.asarray(unknown, bool),
                       np.asarray(unknown, bool))  # exits counted as ways out (issue 26)
    terminals = exit_idx if n_ways > 1 else sorted(set(exit_idx) | {ci})
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
    exits = sorted((rl[a], cl[a]) for a in exit_idx if a in kept)
    nodes = np.array(sorted(tree.nodes), int).reshape(-1, 2)
    d2 = (nodes[:, 0] - robot_cell[0]) ** 2 + (nodes[:, 1] - robot_cell[1]) ** 2
    c = tuple(int(x) for x in nodes[int(np.argmin(d2))])
    return PrunedSkeleton(tree, c, [e for e in exits if e in tree])
