"""Compositions in planning: the augmented belief ``b^M`` (Z §4.2.6, eqs. 4.26–4.28).

Once per planning session the measured triplets ``M`` are the sources of the minimal composition
trees of Z Alg. 1 (``pqrm_jax.compositions.optimal_composition_graph`` with unit composition cost,
so the tree has the minimal number of leaves, eq. 4.27). Every triplet that is not measured but
composable is composed bottom-up along its tree; one step of eq. 4.28 is ``prob_compose`` applied to
the pattern ``(ij:k, jk:d) → ij:d`` (docs/decisions.md §2.3), and the other five orderings of the
result are filled with the sampled unary operators ``U`` (LEFT, RIGHT, INVERSE). Composed triplets
from shared sources are treated as independent (the thesis's product of marginals, eq. 4.27;
docs/bsp.md §Z-25).

The Link-Graph (Z Def. 2.3.1) — triplets as nodes, an edge when two share exactly two
landmarks — is :func:`triplet_link_graph` (its edges are
:func:`pqrm_jax.triplets.link_adjacency` with β = 2, Q-Link's Link Graph rule); Thm 4.1 says a
connected Link-Graph is composable, but not conversely (Fig. 4.3: ``{ABC, BCD, ADE}``).

>>> import networkx as nx
>>> nx.is_connected(triplet_link_graph(["ABC", "BCD", "ADE"]))
False
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import combinations

import networkx as nx
import numpy as np

from ..compositions import as_triplet_set, optimal_composition_graph
from ..triplets import link_adjacency

LEFT, RIGHT, INVERSE = 0, 1, 2


def triplet_link_graph(triplets: Iterable[Iterable]) -> nx.Graph:
    """The Link-Graph of Z Def. 2.3.1 as a networkx graph (nodes: triplets as frozensets).

    Two triplets are linked when they share two landmarks
    (:func:`pqrm_jax.triplets.link_adjacency` with β = 2).

    Args:
        triplets: the triplets, each an iterable of three landmark ids.

    Returns:
        The undirected graph; every triplet is a node, isolated ones included.
    """
    T = sorted(as_triplet_set(triplets), key=lambda t: sorted(map(str, t)))
    g = nx.Graph()
    g.add_nodes_from(T)
    if not T:
        return g
    labels = {x: i for i, x in enumerate(sorted({x for t in T for x in t}, key=str))}
    ids = np.array([sorted(labels[x] for x in t) for t in T], np.int32)
    i, j = np.nonzero(np.triu(link_adjacency(ids, 2, len(labels))))
    g.add_edges_from((T[a], T[b]) for a, b in zip(i.tolist(), j.tolist(), strict=True))
    return g


def orderings(p: np.ndarray, U: np.ndarray) -> dict[tuple[int, int, int], np.ndarray]:
    """The six orderings of ``AB:C = p`` as ``{(a, b, c) positions: distribution}``.

    Positions 0, 1, 2 stand for A, B, C: ``(1, 2, 0)`` is ``BC:A = LEFT``, ``(2, 0, 1)`` is
    ``CA:B = RIGHT``, ``(1, 0, 2)`` is ``BA:C = INVERSE`` and so on.
    """
    left, right = p @ U[LEFT], p @ U[RIGHT]
    return {(0, 1, 2): p, (1, 0, 2): p @ U[INVERSE], (1, 2, 0): left,
            (2, 1, 0): left @ U[INVERSE], (2, 0, 1): right, (0, 2, 1): right @ U[INVERSE]}


def compose_step(p1: np.ndarray, p2: np.ndarray, tensor: np.ndarray) -> np.ndarray:
    """Z eq. 4.28 in NumPy (the formula of ``compositions.propagation.compose``; host speed).

    Jointly impossible operands (zero mass) give the uniform distribution (no information).
    """
    r = np.einsum("a,b,abc->c", p1, p2, tensor)
    s = r.sum()
    return (r / s if s > 0 else np.full(r.shape, 1.0 / r.size)).astype(np.float32)


def augment(trip: np.ndarray, measured: np.ndarray, n: int, tensor: np.ndarray,
            U: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compose every composable, unmeasured triplet of landmarks ``0..n−1`` (host NumPy).

    Args:
        trip: (L, L, L, Q) triplet beliefs, all orderings (rows of measured triplets are used).
        measured: (L, L, L) bool, symmetric under permutations (measured triplets).
        n: number of real landmarks (the first ``n`` ids).
        tensor: (Q, Q, Q) ``prob_compose``.
        U: (3, Q, Q) probabilistic LEFT, RIGHT, INVERSE.

    Returns:
        ``(trip', src, ncomp)``: beliefs with composed rows filled, the source code per ordered
        triplet (0 unknown, 1 measured, 2 composed) and the number of compositions of the
        minimal tree of each composed triplet (0 elsewhere).
    """
    trip = np.array(trip, np.float32, copy=True)
    L = trip.shape[0]
    src = np.where(measured, 1, 0).astype(np.int8)
    ncomp = np.zeros((L, L, L), np.int8)
    nz = np.argwhere(measured)
    sources = {frozenset(map(int, t)) for t in nz if t[0] < t[1] < t[2]}
    if not sources:
        return trip, src, ncomp
    g = optimal_composition_graph(sources, landmarks=range(n))
    have = np.zeros(g.num_triplets, bool)  # graph node -> its row is measured or composed
    have[[g.triplet_id(t) for t in sources]] = True

    # every composable triplet along its minimal tree: the tree of Z Alg. 4 follows the parent
    # pointers of the graph, so a node's row is composed once, from its two parents' rows,
    # after them (an explicit stack; no tree object per target)
    for t in combinations(range(n), 3):
        root = g.triplet_id(t)
        if not np.isfinite(g.d[root]) or have[root]:
            continue
        stack = [root]
        while stack:
            v = stack[-1]
            if have[v]:
                stack.pop()
                continue
            pa, pb = (int(p) for p in g.parents[v])
            missing = [p for p in (pa, pb) if not have[p]]
            if missing:
                stack += missing
                continue
            stack.pop()
            head, tl, tr = g.triplet(v), g.triplet(pa), g.triplet(pb)
            shared = tl & tr
            (i,) = tl - shared
            (d,) = tr - shared
            (j,) = head & shared
            (k,) = shared - {j}
            p = compose_step(trip[i, j, k], trip[j, k, d], tensor)
            have[v] = True
            rows = orderings(p, U)  # the composed triplet's six orderings, filled at once
            a, b, c = np.asarray((i, j, d))[np.asarray(list(rows))].T  # [6] landmark ids each
            trip[a, b, c] = np.stack(list(rows.values()))
            src[a, b, c] = 2
            ncomp[a, b, c] = min(int(round(float(g.d[v]))), 127)
    return trip, src, ncomp
