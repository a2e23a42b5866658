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
products in one ``lax.while_loop``) and :func:`shortest_tree` (any non-negative costs;
Bellman–Ford min-plus relaxation, ``lax.map`` over sources, recording the predecessor on every
strict improvement) give the distances from every start landmark's elements to every element
at once; :func:`plan_pairs` then follows the predecessors of every (start, goal) pair in one
``vmap`` — simple optimal paths even with zero-cost edges, sized by hop counts
(docs/qlink.md §linkgraph). Costs are scaled by :func:`work_costs`, never silently cast.
``|P|`` counts map elements (edges + 1): P §4.4.1,
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
from .checks import validate
from .elements import MapElements, check_elements, incidence

__all__ = ["LinkGraph", "LinkPlan", "GoalTable", "link_graph", "shared_counts", "bfs_distances",
           "shortest_costs", "shortest_tree", "plan_pairs", "to_networkx", "path_cost",
           "goal_distances", "plan_from", "neighbour_table", "work_costs"]


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


class GoalTable(NamedTuple):
    """Cost-to-go from every element to the elements holding each goal landmark.

    cost: ``[G, E]`` float64 least cost to the goal's elements (``inf`` = unreachable).
    next: ``[G, E]`` int32 successor of each element on an optimal path, recorded during the
        relaxation (``-1`` at the goal's elements and where unreachable).
    hops: ``[G, E]`` int32 edges to the goal along ``next`` (``-1`` = unreachable); a path
        from element u holds ``hops[g, u] + 1`` elements.
    """

    cost: np.ndarray
    next: jax.Array
    hops: np.ndarray


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

    Returns:
        :class:`LinkGraph`: ``cost [E, E]`` (``inf`` where there is no edge), ``shared
        [E, E]`` ``|L_i ∩ L_j|``, ``beta``.

    Raises:
        ValueError: malformed elements, β not an integer in 1..3, ``cost`` not ``[E, E]``
            or NaN/negative on an edge.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [3, 4, 5]]), jnp.zeros((3, 6, 4)), 6)
    >>> link_graph(el, 2).adjacency.astype(int).tolist()
    [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    validate(elements=elements, probs_used=False, beta=beta)
    beta = int(beta)
    shared = shared_counts(elements)
    edge = shared >= beta
    base = np.ones(shared.shape, np.float64) if cost is None else np.asarray(cost, np.float64)
    if base.shape != shared.shape:
        raise ValueError(f"cost must have shape {shared.shape}, got {base.shape}")
    bad = edge & ~(base >= 0)                   # NaN and negative costs (inf: no edge)
    if bad.any():
        i, j = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(f"cost[{i}, {j}] = {base[i, j]!r}: an edge cost must be a number "
                         ">= 0 (inf = no edge)")
    return LinkGraph(np.where(edge, base, np.inf), shared, beta)


def to_networkx(graph: LinkGraph, elements: MapElements | None = None) -> nx.DiGraph:
    """The Link Graph as a ``networkx.DiGraph`` (P §4.3.2), for host-side analysis and re-planning.

    Args:
        graph: the Link Graph (``E`` elements).
        elements: optional map elements: each node then carries the attribute ``landmarks``
            (its landmark ids).

    Returns:
        ``networkx.DiGraph`` with nodes ``0..E-1`` and one edge per finite cost, attributes
        ``weight`` (the cost) and ``shared`` (``|L_i ∩ L_j|``).

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


def work_costs(graph: LinkGraph) -> tuple[np.ndarray, float, bool]:
    """``(costs [E, E], scale, unit)``: the edge costs in the working float dtype (float32,
    float64 under ``jax_enable_x64``) divided by their largest finite positive value.

    Plans are invariant to a positive scale, so costs at 1e±40 (beyond float32) plan exactly
    as at 1; ``unit`` is True when every edge has the same cost (breadth-first search then).

    Raises:
        ValueError: a NaN or negative cost, or positive costs spanning more than the working
            dtype resolves (the smallest would become 0): the message names ``graph.cost``.

    >>> g = LinkGraph(np.array([[np.inf, 3e40], [6e40, np.inf]]), np.zeros((2, 2), int), 1)
    >>> w, scale, unit = work_costs(g)
    >>> w.tolist(), scale, unit
    ([[inf, 0.5], [1.0, inf]], 6e+40, False)
    """
    c = np.asarray(graph.cost, np.float64)
    if c.ndim != 2 or c.shape[0] != c.shape[1]:
        raise ValueError(f"graph.cost must be a square (E, E) matrix, got {c.shape}")
    bad = ~(c >= 0)
    if bad.any():
        i, j = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(f"graph.cost[{i}, {j}] = {c[i, j]!r}: edge costs must be >= 0")
    edge = np.isfinite(c)
    pos = c[edge & (c > 0)]
    scale = float(pos.max()) if pos.size else 1.0
    dt = np.dtype(jnp.zeros(()).dtype)
    if pos.size and float(pos.min()) / scale < np.finfo(dt).tiny:
        raise ValueError(f"graph.cost spans {float(pos.min()):.3g} to {scale:.3g}: the "
                         f"smallest positive cost would be 0 in {dt}; enable float64 "
                         "(jax_enable_x64) or plan with fewer orders of magnitude")
    w = np.where(edge, c / scale, np.inf).astype(dt)
    return w, scale, bool(np.all(w[edge] == 1.0))


def _hops(pred, reach):
    """``[E]`` edges from each node to its root along ``pred`` (pointer jumping), −1 where
    not ``reach``."""
    e = pred.shape[0]
    root = pred < 0
    anc = jnp.where(root, jnp.arange(e), pred)
    h = jnp.where(root, 0, 1).astype(jnp.int32)

    def body(_, c):
        h, anc = c
        return h + h[anc], anc[anc]

    h, _ = jax.lax.fori_loop(0, max(1, (e - 1).bit_length()) + 1, body, (h, anc))
    return jnp.where(reach, h, -1).astype(jnp.int32)


@jax.jit
def _tree(cost, sources):
    e = cost.shape[0]
    cols = jnp.arange(e)

    def one(src):
        d0 = jnp.where(src, 0.0, jnp.inf).astype(cost.dtype)

        def cond(c):
            _, _, changed, it = c
            return changed & (it < e)

        def body(c):
            d, p, _, it = c
            cand = d[:, None] + cost                        # [u, v]
            u = jnp.argmin(cand, axis=0).astype(jnp.int32)  # ties: the smallest u
            best = cand[u, cols]
            better = best < d                               # strict: p stays a forest
            return jnp.where(better, best, d), jnp.where(better, u, p), jnp.any(better), it + 1

        d, p, _, _ = jax.lax.while_loop(
            cond, body, (d0, jnp.full(e, -1, jnp.int32), jnp.bool_(True), jnp.int32(0)))
        return d, p, _hops(p, jnp.isfinite(d))

    return jax.lax.map(one, sources)


def shortest_tree(cost, sources) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Least costs, predecessors and hop counts ``([S, E], [S, E], [S, E])`` from each source
    set ``sources [S, E]`` (costs ``[E, E]`` ≥ 0, ``inf`` = no edge).

    Bellman–Ford min-plus relaxation (``d_v ← min(d_v, min_u d_u + C_uv)``) that records the
    predecessor ``u`` whenever ``d_v`` strictly decreases. With costs ≥ 0 the predecessors
    form a forest rooted at the sources even with zero-cost edges and under rounding (along
    a predecessor edge ``d`` never increases, and the edge that would close a cycle needs a
    strict decrease), so following them gives a simple optimal path; ``hops`` (pointer
    jumping over the forest) sizes the path buffer. ``-1`` = source / unreachable.

    >>> c = jnp.array([[jnp.inf, 0., 5.], [0., jnp.inf, 0.], [5., 0., jnp.inf]])
    >>> d, p, h = shortest_tree(c, jnp.array([[1, 0, 0]], bool))
    >>> d.tolist(), p.tolist(), h.tolist()
    ([[0.0, 0.0, 0.0]], [[-1, 0, 1]], [[0, 1, 2]])
    """
    return _tree(jnp.asarray(cost), jnp.asarray(sources, bool))


def shortest_costs(cost, sources) -> jax.Array:
    """Least path costs ``[S, E]`` from each source set (non-negative costs; ``inf`` = none).

    The distances of :func:`shortest_tree`.

    >>> c = jnp.array([[jnp.inf, 1., 5.], [1., jnp.inf, 1.], [5., 1., jnp.inf]])
    >>> shortest_costs(c, jnp.array([[1, 0, 0]], bool)).tolist()
    [[0.0, 1.0, 2.0]]
    """
    return shortest_tree(cost, sources)[0]


@partial(jax.jit, static_argnames=("max_len",))
def _extract(dist_rows, cost, inc_start, inc_goal, *, max_len):
    """Unit costs: backtrack one path per pair from its best goal element (d strictly
    decreases by one along the way, so the argmin is a predecessor)."""
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
        return ok, n.astype(jnp.int32), _reverse(path, n), best

    return jax.vmap(one)(dist_rows, inc_start, inc_goal)


def _reverse(path, n):
    """The first ``n`` entries of ``path`` reversed (start -> goal), ``-1`` padded."""
    m = path.shape[0]
    idx = jnp.where(jnp.arange(m) < n, n - 1 - jnp.arange(m), 0)
    return jnp.where(jnp.arange(m) < n, path[idx], -1)


@partial(jax.jit, static_argnames=("max_len",))
def _follow(ptr, rows, u0, ok, *, max_len):
    """From ``u0`` follow ``ptr[row]`` until ``-1``: ``[B, max_len]`` paths (``-1`` padded)."""
    def one(r, u, ok):
        def body(k, c):
            path, u, done = c
            path = path.at[k].set(jnp.where(done, -1, u))
            v = ptr[r, u]
            end = done | (v < 0)
            return path, jnp.where(end, u, v), end

        path, _, _ = jax.lax.fori_loop(
            0, max_len, body, (jnp.full(max_len, -1, jnp.int32), u.astype(jnp.int32), ~ok))
        return path

    return jax.vmap(one)(rows, u0, ok)


def _graph_matches(graph: LinkGraph, elements: MapElements) -> None:
    e = np.asarray(elements.ids).shape[0]
    if np.shape(graph.cost) != (e, e):
        raise ValueError(f"graph.cost has shape {np.shape(graph.cost)} but elements has {e} "
                         "map elements")


def _path_costs(graph: LinkGraph, path: np.ndarray) -> np.ndarray:
    """``[B]`` float64 Σ C_ij along each ``path [B, L]`` (``-1`` padded)."""
    path = np.asarray(path)
    if path.shape[1] < 2:
        return np.zeros(path.shape[0])
    a, b = path[:, :-1], path[:, 1:]
    ok = (a >= 0) & (b >= 0)
    c = np.asarray(graph.cost, np.float64)[np.maximum(a, 0), np.maximum(b, 0)]
    return np.where(ok, c, 0.0).sum(1)


def plan_pairs(graph: LinkGraph, elements: MapElements, starts, goals) -> LinkPlan:
    """Least-cost Link Graph paths for B (start, goal) landmark pairs, batched (P §4.3.2, eq. 4.1).

    Sources are all elements containing the start landmark, targets all elements containing
    the goal landmark. Equal edge costs use :func:`bfs_distances`, others
    :func:`shortest_tree` (predecessors recorded during the relaxation, so zero-cost edges
    give simple optimal paths) on :func:`work_costs` (scaled, never silently cast);
    distances are computed once per distinct start landmark. Paths are sized by hop counts.
    ``cost`` is Σ C_ij along the returned path in float64 (hops × the cost for equal costs).

    Args:
        graph: the Link Graph of ``elements`` (any costs ≥ 0; ``inf`` = no edge).
        elements: the map elements (``E`` of them).
        starts: ``[B]`` start landmark ids; goals: ``[B]`` goal landmark ids.

    Returns:
        :class:`LinkPlan`: ``reachable [B]``, ``n_elements [B]`` ``|P|`` (0 when
        unreachable), ``path [B, L]`` element indices (``-1`` padded, ``L`` the longest
        path), ``cost [B]`` (``inf`` when unreachable).

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) empty, non-integer, negative
            or out-of-range ids, a start or goal landmark in no element, malformed elements,
            a graph of another map, costs that cannot be planned, or lengths that differ.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.ones((3, 6, 4)), 5)
    >>> p = plan_pairs(link_graph(el, 2), el, [0, 4], [4, 4])
    >>> p.n_elements.tolist(), p.path.tolist()
    ([3, 1], [[0, 1, 2], [2, -1, -1]])
    """
    got = validate(elements=elements, landmark_ids={"starts": starts, "goals": goals},
                   probs_used=False)
    starts, goals = got["starts"].ravel(), got["goals"].ravel()
    if starts.shape != goals.shape:
        raise ValueError(f"starts and goals differ in length: {starts.shape} vs {goals.shape}")
    _graph_matches(graph, elements)
    inc = incidence(elements)
    w, scale, unit = work_costs(graph)
    uniq, inv = np.unique(starts, return_inverse=True)
    src = jnp.asarray(inc[uniq])
    if unit:
        hops = np.asarray(bfs_distances(graph.adjacency, src))
        dist = np.where(hops < 0, np.inf, hops).astype(np.float32)
        cost = np.where(graph.adjacency, 1.0, np.inf).astype(np.float32)
        ok, n, path, best = _extract(jnp.asarray(dist[inv]), jnp.asarray(cost),
                                     jnp.asarray(inc[starts]), jnp.asarray(inc[goals]),
                                     max_len=max(1, int(np.max(hops)) + 1))
        return LinkPlan(ok, jnp.where(ok, n, 0), path, best if scale == 1.0 else
                    np.asarray(best, np.float64) * scale)    # equal costs: hops × the cost
    d, pred, hops = (np.asarray(x) for x in shortest_tree(w, src))
    dt = np.where(inc[goals], d[inv], np.inf)
    t = np.argmin(dt, axis=1)
    rows = np.arange(len(goals))
    ok = np.isfinite(dt[rows, t])
    n = np.where(ok, hops[inv, t] + 1, 0)
    back = _follow(jnp.asarray(pred), jnp.asarray(inv, jnp.int32), jnp.asarray(t, jnp.int32),
                   jnp.asarray(ok), max_len=max(1, int(n.max(initial=1))))
    path = np.asarray(jax.vmap(_reverse)(back, jnp.asarray(n, jnp.int32)))
    cost = np.where(ok, _path_costs(graph, path), np.inf)
    return LinkPlan(jnp.asarray(ok), jnp.asarray(n, jnp.int32), jnp.asarray(path), cost)


def path_cost(graph: LinkGraph, path: np.ndarray) -> float:
    """Σ C_ij along one ``path`` (element indices, ``-1`` padded); ``inf`` if not a path."""
    p = [int(x) for x in np.asarray(path) if x >= 0]
    return float(sum(graph.cost[a, b] for a, b in zip(p[:-1], p[1:], strict=True)))


@jax.jit
def _bfs_next(hops, nbr):
    """``[G, E]`` the first out-neighbour one hop closer to the goal (−1 at the goal)."""
    def one(h):
        hn = jnp.where(nbr >= 0, h[jnp.maximum(nbr, 0)], -2)          # [E, D]
        ok = (hn >= 0) & (hn == h[:, None] - 1)
        j = jnp.argmax(ok, axis=1)
        return jnp.where(ok.any(1), nbr[jnp.arange(nbr.shape[0]), j], -1).astype(jnp.int32)

    return jax.lax.map(one, hops)


def goal_distances(graph: LinkGraph, elements: MapElements, goals) -> GoalTable:
    """Cost-to-go, successor and hop tables to the elements holding each goal (P §4.3.2).

    Computed once per world and goal (reverse search on the transposed costs: the
    predecessor in the reversed graph is the successor towards the goal), so a robot can
    plan from whatever elements it has in view (P §4.3.2: "The robot defines its start as
    M_1 since it has a set of reference landmarks from M_1 in view"). Equal costs: breadth-
    first search, successor = the first out-neighbour one hop closer. ``inf`` = unreachable.

    Args:
        graph: the Link Graph of ``elements`` (``E`` elements, any costs ≥ 0).
        elements: the map elements.
        goals: ``[G]`` goal landmark ids.

    Returns:
        :class:`GoalTable` of ``[G, E]`` tables: ``cost`` (float64), ``next`` (int32
        successor, ``-1`` at the goal and where unreachable), ``hops`` (int32, ``-1`` =
        unreachable).

    Raises:
        ValueError: as :func:`plan_pairs` for ``goals``.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.ones((3, 6, 4)), 5)
    >>> t = goal_distances(link_graph(el, 2), el, [4])
    >>> t.cost.tolist(), t.next.tolist(), t.hops.tolist()
    ([[2.0, 1.0, 0.0]], [[1, 2, -1]], [[2, 1, 0]])
    """
    goals = validate(elements=elements, landmark_ids={"goals": goals},
                     probs_used=False)["goals"].ravel()
    _graph_matches(graph, elements)
    inc = incidence(elements)
    tgt = jnp.asarray(inc[goals])
    w, scale, unit = work_costs(graph)
    if unit:
        hops = np.asarray(bfs_distances(graph.adjacency.T, tgt))
        nxt = _bfs_next(jnp.asarray(hops), neighbour_table(graph)[0])
        cost = np.where(hops < 0, np.inf, hops * scale)
        return GoalTable(cost, nxt, hops.astype(np.int32))
    d, nxt, hops = shortest_tree(jnp.asarray(w.T), tgt)
    return GoalTable(np.asarray(d, np.float64) * scale, nxt, np.asarray(hops))


def neighbour_table(graph: LinkGraph) -> tuple[jax.Array, jax.Array]:
    """The Link Graph as padded adjacency lists (P §4.3.2), for walks without the dense matrix.

    Row u holds the heads of u's out-edges in increasing index order (``-1`` padded, cost
    ``inf``), ``D`` the largest out-degree rounded up to a multiple of 8.
    :func:`goal_distances` takes the equal-cost successors from it (ties to the smaller
    index).

    Args:
        graph: the Link Graph (``E`` elements).

    Returns:
        ``(nbr [E, D] int32, cost [E, D] float32)``.

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


def plan_from(graph: LinkGraph, to_go: GoalTable, rows, candidates,
              max_len: int | None = None) -> LinkPlan:
    """Paths from per-trial candidate start elements down a :class:`GoalTable` (P §4.3.2).

    The candidate with the least cost-to-go (ties: the first) is ``M_1``; the path follows
    the recorded successors to the goal, so it is simple and optimal for any costs ≥ 0.

    Args:
        graph: the Link Graph (the table's).
        to_go: :func:`goal_distances` of ``graph``.
        rows: ``[B]`` row of ``to_go`` (the goal) of each trial.
        candidates: ``[B, C]`` element indices the robot may start from (``-1`` padded).
        max_len: path array width, at least the longest path (hops + 1); default the
            longest of this batch.

    Returns:
        :class:`LinkPlan`: ``reachable [B]``, ``n_elements [B]`` (0 when unreachable),
        ``path [B, max_len]`` (``-1`` padded), ``cost [B]`` the chosen candidate's
        cost-to-go (``inf`` when unreachable).

    Raises:
        ValueError: ``to_go`` of another graph, ``max_len`` shorter than the longest path.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]), jnp.ones((3, 6, 4)), 5)
    >>> g = link_graph(el, 2)
    >>> p = plan_from(g, goal_distances(g, el, [4]), jnp.array([0]), jnp.array([[0, -1]]), 4)
    >>> p.n_elements.tolist(), p.path.tolist()
    ([3], [[0, 1, 2, -1]])
    """
    cost, hops = np.asarray(to_go.cost), np.asarray(to_go.hops)
    if cost.shape[1] != np.shape(graph.cost)[0]:
        raise ValueError(f"to_go has {cost.shape[1]} elements, graph {np.shape(graph.cost)[0]}")
    rows, cands = np.asarray(rows, np.int64), np.asarray(candidates, np.int64)
    ds = np.where(cands >= 0, cost[rows[:, None], np.maximum(cands, 0)], np.inf)
    j = np.argmin(ds, axis=1) if ds.shape[1] else np.zeros(len(rows), np.int64)
    ar = np.arange(len(rows))
    best = ds[ar, j] if ds.shape[1] else np.full(len(rows), np.inf)
    ok = np.isfinite(best)
    u0 = np.where(ok, cands[ar, j] if ds.shape[1] else 0, 0)
    n = np.where(ok, hops[rows, u0] + 1, 0).astype(np.int32)
    need = int(n.max(initial=1))
    max_len = need if max_len is None else int(max_len)
    if max_len < need:
        raise ValueError(f"max_len = {max_len} is shorter than the longest path ({need})")
    path = _follow(to_go.next, jnp.asarray(rows, jnp.int32), jnp.asarray(u0, jnp.int32),
                   jnp.asarray(ok), max_len=max(1, max_len))
    return LinkPlan(jnp.asarray(ok), jnp.asarray(n), path, best)
