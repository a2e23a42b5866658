"""The Link Graph and batched planning over it (P §4.3.2, eq. 4.1).

"the Link Graph, G, is a graph G = {M, α, C} where M, the qualitative map elements, are the
nodes, α are the edges, and C are the edge costs. An edge α_{i,j} exists between M_i and M_j in
the Link Graph if |L_i ∩ L_j| ≥ β" (P §4.3.2). The overlap ``|L_i ∩ L_j|`` of every pair is one
matrix product of the landmark–element incidence. Edges are stored as a dense ``[E, E]`` cost
matrix (``inf`` = no edge) so the graph is directed: the −log-success cost depends on the
direction (P §4.3.3).

Planning (eq. 4.1, ``P* = argmin_P Σ C_ij``) is multi-source and multi-target (P §4.3.2: the
robot starts in any element whose references it sees and plans "to any map element containing
landmark L_D"). :func:`bfs_distances` (unit costs; frontier expansion as boolean matrix
products in one ``lax.while_loop``) and :func:`shortest_costs` (any non-negative costs;
Bellman–Ford min-plus relaxation, ``lax.map`` over sources) give the distances from every start
landmark's elements to every element at once; :func:`plan_pairs` then extracts the path of
every (start, goal) pair in one ``vmap``. ``|P|`` counts map elements (edges + 1): P §4.4.1,
"The paths for which |P| = 1 are paths where the goal is visible from the start".
:func:`to_networkx` returns the graph object users inspect and export.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np

from ..triplets import shared_landmarks
from .elements import MapElements, check_elements, incidence

__all__ = ["LinkGraph", "LinkPlan", "link_graph", "shared_counts", "bfs_distances",
           "shortest_costs", "plan_pairs", "to_networkx", "path_cost", "goal_distances",
           "plan_from", "neighbour_table"]


class LinkGraph(NamedTuple):
    """A Link Graph (P §4.3.2).

    cost: ``[E, E]`` float edge costs, ``inf`` where there is no edge (directed).
    shared: ``[E, E]`` int ``|L_i ∩ L_j|`` (0 on the diagonal).
    beta: the edge threshold β.
    """

    cost: np.ndarray
    shared: np.ndarray
    beta: int

    @property
    def adjacency(self) -> np.ndarray:
        """``[E, E]`` bool, an edge i → j."""
        return np.isfinite(self.cost)


class LinkPlan(NamedTuple):
    """Planned paths for B start/goal landmark pairs.

    reachable: ``[B]`` bool, a path exists.
    n_elements: ``[B]`` int32 ``|P|`` (map elements on the path), 0 when unreachable.
    path: ``[B, L]`` int32 element indices, ``-1`` padded.
    cost: ``[B]`` float path cost (``inf`` when unreachable).
    """

    reachable: jax.Array
    n_elements: jax.Array
    path: jax.Array
    cost: jax.Array


def _check_beta(beta) -> int:
    if isinstance(beta, bool) or not isinstance(beta, (int, np.integer)) or beta < 1:
        raise ValueError(f"beta must be an integer >= 1, got {beta!r}")
    if beta > 3:
        raise ValueError(f"beta must be <= 3 for triplet elements, got {beta}")
    return int(beta)


def shared_counts(elements: MapElements) -> np.ndarray:
    """``[E, E]`` int ``|L_i ∩ L_j|``, zero diagonal.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [3, 4, 5]]), jnp.zeros((3, 6, 4)), 6)
    >>> shared_counts(el).tolist()
    [[0, 2, 0], [2, 0, 1], [0, 1, 0]]
    """
    check_elements(elements)
    return shared_landmarks(np.asarray(elements.ids), elements.num_landmarks).astype(np.int16)


def link_graph(elements: MapElements, beta: int, cost: np.ndarray | None = None) -> LinkGraph:
    """Link Graph with edge rule ``|L_i ∩ L_j| >= beta`` (P §4.3.2).

    Args:
        elements: the map elements.
        beta: minimum number of shared (link) landmarks, ``>= 1``.
        cost: optional ``[E, E]`` edge costs (used where there is an edge; see
            :mod:`pqrm_jax.qlink.costs`); default unit cost ("unit cost to ensure a minimum
            Link Graph path length", P §4.4.1).

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [3, 4, 5]]), jnp.zeros((3, 6, 4)), 6)
    >>> link_graph(el, 2).adjacency.astype(int).tolist()
    [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    beta = _check_beta(beta)
    shared = shared_counts(elements)
    edge = shared >= beta
    base = np.ones(shared.shape, np.float64) if cost is None else np.asarray(cost, np.float64)
    if base.shape != shared.shape:
        raise ValueError(f"cost must have shape {shared.shape}, got {base.shape}")
    if np.any(base[edge] < 0) or np.any(np.isnan(base[edge])):
        raise ValueError("edge costs must be non-negative numbers")
    return LinkGraph(np.where(edge, base, np.inf), shared, beta)


def to_networkx(graph: LinkGraph, elements: MapElements | None = None) -> nx.DiGraph:
    """The Link Graph as a ``networkx.DiGraph`` (edge attributes ``weight``, ``shared``).

    Node attribute ``landmarks`` (the element's landmark ids) when ``elements`` is given.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3]]), jnp.zeros((2, 6, 4)), 4)
    >>> g = to_networkx(link_graph(el, 2), el)
    >>> sorted(g.edges(data="shared")), g.nodes[1]["landmarks"]
    ([(0, 1, 2), (1, 0, 2)], (1, 2, 3))
    """
    g = nx.DiGraph(beta=graph.beta)
    e = graph.cost.shape[0]
    ids = None if elements is None else np.asarray(elements.ids)
    for i in range(e):
        g.add_node(i, **({} if ids is None else {"landmarks": tuple(int(x) for x in ids[i])}))
    src, dst = np.nonzero(graph.adjacency)
    g.add_edges_from((int(i), int(j), {"weight": float(graph.cost[i, j]),
                                       "shared": int(graph.shared[i, j])})
                     for i, j in zip(src, dst, strict=True))
    return g


@jax.jit
def _bfs(adj, sources):
    adj_f = adj.astype(jnp.float32)
    dist0 = jnp.where(sources, 0, -1).astype(jnp.int32)

    def cond(c):
        _, frontier, _ = c
        return jnp.any(frontier)

    def body(c):
        dist, frontier, d = c
        reach = (frontier.astype(jnp.float32) @ adj_f) > 0
        new = reach & (dist < 0)
        return jnp.where(new, d + 1, dist), new, d + 1

    dist, _, _ = jax.lax.while_loop(cond, body, (dist0, sources, jnp.int32(0)))
    return dist


def bfs_distances(adjacency, sources) -> jax.Array:
    """Hop distances ``[S, E]`` from each source set ``sources [S, E]`` (``-1`` unreachable).

    >>> adj = jnp.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], bool)
    >>> bfs_distances(adj, jnp.array([[1, 0, 0], [0, 0, 1]], bool)).tolist()
    [[0, 1, 2], [2, 1, 0]]
    """
    return _bfs(jnp.asarray(adjacency, bool), jnp.asarray(sources, bool))


@jax.jit
def _bellman_ford(cost, sources):
    e = cost.shape[0]

    def one(src):
        d0 = jnp.where(src, 0.0, jnp.inf).astype(cost.dtype)

        def cond(c):
            _, changed, it = c
            return changed & (it < e)

        def body(c):
            d, _, it = c
            nd = jnp.minimum(d, jnp.min(d[:, None] + cost, axis=0))
            return nd, jnp.any(nd < d), it + 1

        d, _, _ = jax.lax.while_loop(cond, body, (d0, jnp.bool_(True), jnp.int32(0)))
        return d

    return jax.lax.map(one, sources)


def shortest_costs(cost, sources) -> jax.Array:
    """Least path costs ``[S, E]`` from each source set (non-negative costs; ``inf`` = none).

    Bellman–Ford min-plus relaxation (``d_v ← min(d_v, min_u d_u + C_uv)``) until no change.

    >>> c = jnp.array([[jnp.inf, 1., 5.], [1., jnp.inf, 1.], [5., 1., jnp.inf]])
    >>> shortest_costs(c, jnp.array([[1, 0, 0]], bool)).tolist()
    [[0.0, 1.0, 2.0]]
    """
    return _bellman_ford(jnp.asarray(cost), jnp.asarray(sources, bool))


@partial(jax.jit, static_argnames=("max_len",))
def _extract(dist_rows, cost, inc_start, inc_goal, *, max_len):
    """Backtrack one path per pair from its best goal element (vmapped by the caller)."""
    def one(d, src, tgt):
        dt = jnp.where(tgt, d, jnp.inf)
        t = jnp.argmin(dt)
        best = dt[t]
        ok = jnp.isfinite(best)

        def body(k, c):
            path, v, done = c
            path = path.at[k].set(jnp.where(done, -1, v))
            at_src = src[v] & (d[v] <= 0)
            cand = d + cost[:, v]
            u = jnp.argmin(jnp.where(jnp.arange(d.shape[0]) == v, jnp.inf, cand))
            return path, jnp.where(done | at_src, v, u), done | at_src

        path, _, _ = jax.lax.fori_loop(
            0, max_len, body, (jnp.full(max_len, -1, jnp.int32), t.astype(jnp.int32), ~ok))
        n = jnp.sum(path >= 0)
        # reverse the valid prefix so the path runs start -> goal
        idx = jnp.where(jnp.arange(max_len) < n, n - 1 - jnp.arange(max_len), 0)
        fwd = jnp.where(jnp.arange(max_len) < n, path[idx], -1)
        return ok, n.astype(jnp.int32), fwd, best

    return jax.vmap(one)(dist_rows, inc_start, inc_goal)


def plan_pairs(graph: LinkGraph, elements: MapElements, starts, goals) -> LinkPlan:
    """LinkPlan every (start landmark, goal landmark) pair in one batched program (eq. 4.1).

    Sources are all elements containing the start landmark, targets all elements containing
    the goal landmark. Unit-cost graphs use :func:`bfs_distances`, others
    :func:`shortest_costs`; distances are computed once per distinct start landmark.

    Raises:
        ValueError: a start or goal landmark is not in the map (in no element), or the
            arrays differ in length.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.zeros((3, 6, 4)), 5)
    >>> p = plan_pairs(link_graph(el, 2), el, [0, 4], [4, 4])
    >>> p.n_elements.tolist(), p.path.tolist()
    ([3, 1], [[0, 1, 2], [2, -1, -1]])
    """
    inc = incidence(elements)
    starts, goals = np.asarray(starts, np.int64).ravel(), np.asarray(goals, np.int64).ravel()
    if starts.shape != goals.shape:
        raise ValueError(f"starts and goals differ in length: {starts.shape} vs {goals.shape}")
    for name, lm in (("start", starts), ("goal", goals)):
        bad = (lm < 0) | (lm >= elements.num_landmarks)
        bad[~bad] = ~inc[lm[~bad]].any(axis=1)
        if bad.any():
            raise ValueError(f"{name} landmark {int(lm[bad][0])} is not in the map "
                             "(it belongs to no map element)")
    uniq, inv = np.unique(starts, return_inverse=True)
    src = jnp.asarray(inc[uniq])
    unit = bool(np.all(graph.cost[graph.adjacency] == 1.0))
    if unit:
        hops = np.asarray(bfs_distances(graph.adjacency, src))
        dist = np.where(hops < 0, np.inf, hops).astype(np.float32)
        cost = np.where(graph.adjacency, 1.0, np.inf).astype(np.float32)
    else:
        dist = np.asarray(shortest_costs(jnp.asarray(graph.cost, jnp.float32), src))
        cost = graph.cost.astype(np.float32)
    hop_bound = int(np.max(bfs_distances(graph.adjacency, src))) + 1
    max_len = max(1, hop_bound if unit else graph.cost.shape[0])
    ok, n, path, best = _extract(jnp.asarray(dist[inv]), jnp.asarray(cost),
                                 jnp.asarray(inc[starts]), jnp.asarray(inc[goals]),
                                 max_len=max_len)
    if not unit:  # trim padding to the longest path found
        width = max(1, int(np.max(np.asarray(n))))
        path = path[:, :width]
    return LinkPlan(ok, jnp.where(ok, n, 0), path, best)


def path_cost(graph: LinkGraph, path: np.ndarray) -> float:
    """Σ C_ij along one ``path`` (element indices, ``-1`` padded); ``inf`` if not a path."""
    p = [int(x) for x in np.asarray(path) if x >= 0]
    return float(sum(graph.cost[a, b] for a, b in zip(p[:-1], p[1:], strict=True)))


def goal_distances(graph: LinkGraph, elements: MapElements, goals) -> jax.Array:
    """Cost-to-go ``[G, E]`` from every element to the elements holding each goal landmark.

    Computed once per world and goal (reverse search on the transposed costs), so a robot can
    plan from whatever elements it has in view (P §4.3.2: "The robot defines its start as M_1
    since it has a set of reference landmarks from M_1 in view"). ``inf`` = unreachable.
    """
    inc = incidence(elements)
    goals = np.asarray(goals, np.int64)
    tgt = jnp.asarray(inc[goals])
    if bool(np.all(graph.cost[graph.adjacency] == 1.0)):
        hops = np.asarray(bfs_distances(graph.adjacency.T, tgt))
        return jnp.asarray(np.where(hops < 0, np.inf, hops), jnp.float32)
    return shortest_costs(jnp.asarray(graph.cost.T, jnp.float32), tgt)


def neighbour_table(graph: LinkGraph) -> tuple[jax.Array, jax.Array]:
    """The Link Graph as padded adjacency lists: ``(nbr [E, D] int32, cost [E, D] float32)``.

    Row u holds the heads of u's out-edges in increasing index order (``-1`` padded, cost
    ``inf``), ``D`` the largest out-degree rounded up to a multiple of 8. :func:`plan_from`
    walks it instead of the dense ``[E, E]`` matrix (the same argmin, ties to the smaller
    index); compute it once per graph and pass it to every call.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.zeros((3, 6, 4)), 5)
    >>> nbr, c = neighbour_table(link_graph(el, 2))
    >>> nbr[:, :2].tolist(), c[1, :2].tolist()
    ([[1, -1], [0, 2], [1, -1]], [1.0, 1.0])
    """
    adj = graph.adjacency
    deg = adj.sum(1)
    width = max(8, -(-int(deg.max(initial=0)) // 8) * 8)
    nbr = np.full((adj.shape[0], width), -1, np.int32)
    cost = np.full((adj.shape[0], width), np.inf, np.float32)
    src, dst = np.nonzero(adj)                     # row-major: heads ascending per row
    col = np.arange(len(src)) - np.concatenate([[0], np.cumsum(deg)[:-1]])[src]
    nbr[src, col] = dst
    cost[src, col] = graph.cost[src, dst].astype(np.float32)
    return jnp.asarray(nbr), jnp.asarray(cost)


@partial(jax.jit, static_argnames=("max_len",))
def _forward(to_go, nbr, ncost, rows, cands, *, max_len):
    def one(row, cand):
        d = to_go[row]
        ds = jnp.where(cand >= 0, d[jnp.maximum(cand, 0)], jnp.inf)
        u0 = jnp.maximum(cand[jnp.argmin(ds)], 0).astype(jnp.int32)
        best = jnp.min(ds)
        ok = jnp.isfinite(best)

        def body(k, c):
            path, u, done = c
            path = path.at[k].set(jnp.where(done, -1, u))
            at_goal = d[u] <= 0
            heads = nbr[u]
            cand_cost = jnp.where(heads >= 0, ncost[u] + d[jnp.maximum(heads, 0)], jnp.inf)
            v = jnp.maximum(heads[jnp.argmin(cand_cost)], 0)
            return path, jnp.where(done | at_goal, u, v).astype(jnp.int32), done | at_goal

        path, _, _ = jax.lax.fori_loop(0, max_len, body,
                                       (jnp.full(max_len, -1, jnp.int32), u0, ~ok))
        return ok, jnp.sum(path >= 0).astype(jnp.int32), path, best

    return jax.vmap(one)(rows, cands)


def plan_from(graph: LinkGraph, to_go, rows, candidates, max_len: int,
              neighbours: tuple[jax.Array, jax.Array] | None = None) -> LinkPlan:
    """Paths from per-trial candidate start elements down a cost-to-go table.

    Args:
        graph: the Link Graph.
        to_go: ``[G, E]`` rows of :func:`goal_distances`.
        rows: ``[B]`` row of ``to_go`` (the goal) of each trial.
        candidates: ``[B, C]`` element indices the robot may start from (``-1`` padded); the
            one with the least cost-to-go is ``M_1``.
        max_len: path array width (≥ the longest path).
        neighbours: :func:`neighbour_table` of ``graph`` (computed when not given; pass it
            when planning many batches on one graph).

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.zeros((3, 6, 4)), 5)
    >>> g = link_graph(el, 2)
    >>> p = plan_from(g, goal_distances(g, el, [4]), jnp.array([0]), jnp.array([[0, -1]]), 4)
    >>> p.n_elements.tolist(), p.path.tolist()
    ([3], [[0, 1, 2, -1]])
    """
    nbr, ncost = neighbour_table(graph) if neighbours is None else neighbours
    ok, n, path, best = _forward(jnp.asarray(to_go, jnp.float32), nbr, ncost,
                                 jnp.asarray(rows, jnp.int32), jnp.asarray(candidates, jnp.int32),
                                 max_len=int(max_len))
    return LinkPlan(ok, jnp.where(ok, n, 0), path, best)
