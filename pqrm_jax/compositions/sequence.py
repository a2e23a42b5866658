"""Optimal composition sequence: composition graph, hypergraph Dijkstra, tree extraction.

Implements Z §3.2.2 (Alg. 1–4): the composition graph over a landmark space, its incremental
update by a generalised Dijkstra on the composition hypergraph, the extraction of the
optimal composition tree of a target, and Alg. 1 end to end. Costs are user-defined;
negative or non-finite costs raise ``ValueError``.

The graph representation, the costs and the decision on negative source costs:
docs/compositions.md §sequence.

>>> g = optimal_composition_graph(["ABC", "BCD", "ADE"])
>>> g.cost("ACE"), g.cost("BCE")
(2.0, 3.0)
>>> print(g.extract("ACE").pretty())
ACE  d=2
  ACD  d=1
    BCD [source]  d=0
    ABC [source]  d=0
  ADE [source]  d=0
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Hashable, Iterable, Mapping
from itertools import combinations

import numpy as np

from ..triplets import ORDERINGS
from .composable import CompositionTree, Triplet, as_triplet, as_triplet_set, fmt

__all__ = ["CompositionGraph", "optimal_composition_graph", "optimal_composition_tree",
           "unit_cost"]

CompCost = Callable[[Triplet, Triplet, Triplet], float]


def unit_cost(left: Triplet, right: Triplet, head: Triplet) -> float:
    """One unit per composition (the running example of Z §3.2.4).

    Args:
        left, right: the operands of the composition.
        head: the composed triplet.

    Returns:
        ``1.0``.
    """
    return 1.0


class CompositionGraph:
    """Composition graph over a landmark space with cumulative costs (Z Def. 3.2.6, Alg. 2).

    Args:
        landmarks: the landmark space ``L`` (distinct hashable items; at least 3).
        comp_cost: ``C_comp(τ_L, τ_R, τ) ≥ 0`` (callable) or a constant; default 1 per
            composition.

    Raises:
        ValueError: for repeated landmarks, fewer than 3, or a constant cost that is
            negative or not finite.
    """

    def __init__(self, landmarks: Iterable[Hashable], comp_cost: CompCost | float = 1.0):
        lms = tuple(landmarks)
        if isinstance(landmarks, str):
            lms = tuple(landmarks)
        if len(set(lms)) != len(lms):
            raise ValueError(f"landmark space has repeated landmarks: {lms!r}")
        if len(lms) < 3:
            raise ValueError(f"a landmark space needs at least 3 landmarks, got {len(lms)}")
        self.landmarks = lms
        self._pos = {x: i for i, x in enumerate(lms)}
        n = len(lms)
        self.n = n
        trip = np.array(list(combinations(range(n), 3)), dtype=np.int32)
        self._trip = trip
        idx = np.full((n, n, n), -1, dtype=np.int32)
        ids = np.arange(len(trip), dtype=np.int32)
        for p in ORDERINGS:
            idx[trip[:, p[0]], trip[:, p[1]], trip[:, p[2]]] = ids
        self._idx = idx
        self.d = np.full(len(trip), np.inf)           # cumulative cost d(v_τ)
        self.parents = np.full((len(trip), 2), -1, dtype=np.int64)
        self.source_cost = np.full(len(trip), np.inf)
        if callable(comp_cost):
            self._comp: CompCost = comp_cost
            self._const = None
        else:
            c = float(comp_cost)
            if not (math.isfinite(c) and c >= 0):
                raise ValueError(f"composition cost must be finite and ≥ 0, got {c}")
            self._const = c
            self._comp = lambda a, b, h: c
        self.pops = 0  # Dijkstra work counter (for the complexity notes)

    # ---------------------------------------------------------------------------- indexing
    @property
    def num_triplets(self) -> int:
        return len(self._trip)

    @property
    def num_quartets(self) -> int:
        return math.comb(self.n, 4)

    def triplet_id(self, t: Iterable[Hashable]) -> int:
        tau = as_triplet(t)
        try:
            a, b, c = (self._pos[x] for x in tau)
        except KeyError:
            bad = sorted(str(x) for x in tau if x not in self._pos)
            raise ValueError(f"triplet {fmt(tau)}: landmarks {bad} are outside the landmark "
                             f"space of this composition graph") from None
        return int(self._idx[a, b, c])

    def triplet(self, i: int) -> Triplet:
        return frozenset(self.landmarks[j] for j in self._trip[i])

    def cost(self, t: Iterable[Hashable]) -> float:
        """Cumulative cost ``d(v_τ)`` (``inf`` when ``τ`` cannot be composed yet)."""
        return float(self.d[self.triplet_id(t)])

    def finite(self) -> set[Triplet]:
        """Triplets with a finite cumulative cost."""
        return {self.triplet(i) for i in np.flatnonzero(np.isfinite(self.d))}

    # ------------------------------------------------------------------------------ Alg. 3
    def add_source(self, t: Iterable[Hashable], cost: float = 0.0) -> int:
        """``UPDATECOMPGRAPH`` (Z Alg. 3): offer ``t`` as a source of cost ``C_source(t)``.

        Propagates the improvement through the hypergraph with Dijkstra's ordering. Returns the
        number of triplet nodes whose cost improved (0 if ``cost`` does not beat ``d(t)``).
        """
        c = float(cost)
        if not math.isfinite(c) or c < 0:
            raise ValueError(f"source cost of {fmt(as_triplet(t))} must be finite and ≥ 0, "
                             f"got {cost!r} (see module doc)")
        v = self.triplet_id(t)
        self.source_cost[v] = min(self.source_cost[v], c)
        if not c < self.d[v]:
            return 0
        self.d[v] = c
        self.parents[v] = -1
        heap = [(c, v)]
        updated = {v}
        d, idx, trip, comp = self.d, self._idx, self._trip, self._comp
        n = self.n
        while heap:
            dv, v = heapq.heappop(heap)
            if dv > d[v]:
                continue  # stale entry
            self.pops += 1
            a, b, c3 = (int(x) for x in trip[v])
            tv = None
            for x in range(n):
                if x == a or x == b or x == c3:
                    continue
                # quartet {a,b,c3,x}: the other three triplets
                others = (int(idx[a, b, x]), int(idx[a, c3, x]), int(idx[b, c3, x]))
                for partner in others:
                    dp = d[partner]
                    if dp == math.inf:
                        continue
                    base = dv + dp
                    for head in others:
                        if head == partner or not base < d[head]:
                            continue
                        if self._const is not None:
                            cand = base + self._const
                        else:
                            if tv is None:
                                tv = self.triplet(v)
                            w = float(comp(tv, self.triplet(partner), self.triplet(head)))
                            if not (math.isfinite(w) and w >= 0):
                                raise ValueError(f"composition cost must be finite and ≥ 0, "
                                                 f"got {w!r}")
                            cand = base + w
                        if cand < d[head]:
                            d[head] = cand
                            self.parents[head] = (v, partner)
                            heapq.heappush(heap, (cand, head))
                            updated.add(head)
        return len(updated)

    def add_sources(self, sources: Iterable[Iterable[Hashable]] | Mapping,
                    source_cost: Callable[[Triplet], float] | float = 0.0) -> None:
        """Alg. 1 lines 4–5: :meth:`add_source` for each source (a mapping gives its costs)."""
        if isinstance(sources, Mapping):
            items = [(as_triplet(k), float(v)) for k, v in sources.items()]
        else:
            S = as_triplet_set(sources)
            f = source_cost if callable(source_cost) else (lambda t: float(source_cost))
            items = [(t, f(t)) for t in sorted(S, key=fmt)]
        if not items:
            raise ValueError("the source set of triplets is empty")
        for t, c in items:
            self.add_source(t, c)

    # ------------------------------------------------------------------------------ Alg. 4
    def extract(self, target: Iterable[Hashable]) -> CompositionTree | None:
        """``EXTRACTCOMPTREE`` (Z Alg. 4): the optimal composition tree of ``target``.

        ``None`` (the paper's empty tree) when ``d(target) = ∞``. Shared subtrees are shared
        objects; costs on the nodes are the cumulative costs ``d``.
        """
        root = self.triplet_id(target)
        if not math.isfinite(self.d[root]):
            return None
        built: dict[int, CompositionTree] = {}
        stack = [root]
        while stack:
            v = stack[-1]
            if v in built:
                stack.pop()
                continue
            pa, pb = (int(p) for p in self.parents[v])
            if pa < 0:
                built[v] = CompositionTree(self.triplet(v), None, float(self.d[v]))
                stack.pop()
                continue
            missing = [p for p in (pa, pb) if p not in built]
            if missing:
                if len(stack) > 4 * self.num_triplets:
                    raise RuntimeError("cyclic parent pointers (costs must be ≥ 0)")
                stack += missing
                continue
            built[v] = CompositionTree(self.triplet(v), (built[pa], built[pb]), float(self.d[v]))
            stack.pop()
        return built[root]

    # ------------------------------------------------------------------------------ extras
    def tree_cost(self, tree: CompositionTree) -> float:
        """Recompute eq. 3.2 for ``tree`` from this graph's source and composition costs."""
        memo: dict[int, float] = {}
        for n in tree.postorder():
            if n.is_leaf:
                memo[id(n)] = float(self.source_cost[self.triplet_id(n.triplet)])
            else:
                a, b = n.children
                memo[id(n)] = memo[id(a)] + memo[id(b)] + float(
                    self._comp(a.triplet, b.triplet, n.triplet))
        return memo[id(tree)]

    def to_networkx(self):
        """The explicit bipartite graph of Def. 3.2.6 (nodes carry ``kind`` and ``d``)."""
        import networkx as nx

        g = nx.Graph()
        for i in range(self.num_triplets):
            g.add_node(fmt(self.triplet(i)), kind="triplet", d=float(self.d[i]))
        for q in combinations(range(self.n), 4):
            name = "Q:" + fmt(self.landmarks[j] for j in q)
            g.add_node(name, kind="quartet")
            for t in combinations(q, 3):
                g.add_edge(name, fmt(self.landmarks[j] for j in t))
        return g


def optimal_composition_graph(sources: Iterable[Iterable[Hashable]] | Mapping,
                              source_cost: Callable[[Triplet], float] | float = 0.0,
                              comp_cost: CompCost | float = 1.0,
                              landmarks: Iterable[Hashable] | None = None) -> CompositionGraph:
    """Z Alg. 1 lines 1–5: build the composition graph over ``L(T)`` and add every source.

    Args:
        sources: the source triplets, or a mapping from source triplet to its cost.
        source_cost: ``C_source`` of each source, a callable or a constant (finite, ≥ 0).
        comp_cost: ``C_comp(τ_L, τ_R, τ)``, a callable or a constant (finite, ≥ 0).
        landmarks: the landmark space (default ``L(T)``; must contain it).

    Returns:
        :class:`CompositionGraph` with every composable triplet's optimal cost.

    Raises:
        ValueError: for sources outside ``landmarks`` or bad costs.
    """
    S = as_triplet_set(sources.keys() if isinstance(sources, Mapping) else sources)
    space = frozenset().union(*S)
    if landmarks is None:
        lms = sorted(space, key=lambda x: (str(type(x)), x))
    else:
        lms = list(landmarks)
        if not space <= set(lms):
            raise ValueError("source triplets use landmarks outside the given landmark space")
    g = CompositionGraph(lms, comp_cost)
    g.add_sources(sources if isinstance(sources, Mapping) else S, source_cost)
    return g


def optimal_composition_tree(sources: Iterable[Iterable[Hashable]] | Mapping,
                             target: Iterable[Hashable],
                             source_cost: Callable[[Triplet], float] | float = 0.0,
                             comp_cost: CompCost | float = 1.0) -> CompositionTree | None:
    """Z Alg. 1: the optimal composition tree of ``target`` from ``sources``.

    Args:
        sources: the source triplets, or a mapping from source triplet to its cost.
        target: the triplet to compose.
        source_cost: ``C_source`` of each source, a callable or a constant (finite, ≥ 0).
        comp_cost: ``C_comp(τ_L, τ_R, τ)``, a callable or a constant (finite, ≥ 0).

    Returns:
        The optimal :class:`CompositionTree`, or ``None`` when ``target`` cannot be composed.

    Raises:
        ValueError: when ``target`` has a landmark outside ``L(T)``, or for negative or
            non-finite costs.

    >>> t = optimal_composition_tree(["ABC", "BCD", "ADE"], "BCE")
    >>> t.num_compositions(), t.cost
    (3, 3.0)
    """
    S = as_triplet_set(sources.keys() if isinstance(sources, Mapping) else sources)
    tau = as_triplet(target)
    space = frozenset().union(*S)
    if not tau <= space:
        bad = sorted(str(x) for x in tau - space)
        raise ValueError(f"target {fmt(tau)}: landmarks {bad} are outside L(T)")
    g = optimal_composition_graph(sources, source_cost, comp_cost)
    return g.extract(tau)
