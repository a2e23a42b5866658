"""Frontier-based pruning of the EVG skeleton to a tree (B §6.1.1, Fig. 6.3--6.4), on the host.

The pruned skeleton is a :class:`networkx.Graph` whose nodes are ``(row, col)`` cells and
whose edges join 8-neighbours (weight 1 or sqrt 2). Graph crawling and spanning trees are
irregular, data-dependent work over a few hundred to a few thousand skeleton cells, so they
run on the host with networkx (a graph users can inspect) rather than as fixed-shape JAX.

Steps (B §6.1.1): drop skeleton cells over unknown space; keep cells reachable from the robot
through free space; ``c`` = the skeleton cell closest to the robot; crawl from ``c``, stopping
at *exits* (skeleton cells on the grid border or next to unknown cells); keep the minimum
spanning tree of the crawled cells and strip every leaf that is not an exit (with at most one
exit, ``c`` is kept as a terminal too: the dead-end case); recompute ``c`` on the tree.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import networkx as nx
import numpy as np
from scipy import ndimage

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
    d2 = (rows - robot_cell[0]) ** 2 + (cols - robot_cell[1]) ** 2
    order = np.lexsort((cols, rows, d2))
    c = (int(rows[order[0]]), int(cols[order[0]]))
    g = skeleton_graph(sk)
    # crawl from c, not expanding beyond exits
    seen = {c}
    stack = [c]
    while stack:
        u = stack.pop()
        if exit_mask[u] and u != c:
            continue
        for v in g.neighbors(u):
            if v not in seen:
                seen.add(v)
                stack.append(v)
    exits = sorted(v for v in seen if exit_mask[v])
    tree = nx.minimum_spanning_tree(g.subgraph(seen))
    terminals = set(exits)
    if len(exits) <= 1:
        terminals.add(c)
    leaves = [v for v in tree.nodes if tree.degree(v) <= 1 and v not in terminals]
    while leaves:
        v = leaves.pop()
        if v not in tree:
            continue
        nbrs = list(tree.neighbors(v))
        tree.remove_node(v)
        for u in nbrs:
            if tree.degree(u) <= 1 and u not in terminals:
                leaves.append(u)
    nodes = np.array(sorted(tree.nodes), int).reshape(-1, 2)
    d2 = (nodes[:, 0] - robot_cell[0]) ** 2 + (nodes[:, 1] - robot_cell[1]) ** 2
    c = tuple(int(x) for x in nodes[int(np.argmin(d2))])
    return PrunedSkeleton(tree, c, [e for e in exits if e in tree])
