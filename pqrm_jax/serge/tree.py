"""Multi-resolution SR maps: the resolution tree (Padgett §3.3.1, eqs. 3.8–3.10).

The root (level 0) is one SR holding every initial region and belief. Splitting a node runs
SERGE restricted to the node's initial regions and beliefs (the selections ψ_B, ψ_C of
eqs. 3.9–3.10) with its own μ and σ; every resulting SR becomes a child. The finest possible
level is ``C_init`` (one SR per belief). The map can be reconstructed at any level, or with a
different resolution per branch (any *frontier*: a set of nodes whose initial regions
partition the map).

>>> import jax, numpy as np
>>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells
>>> from pqrm_jax.serge.tree import ResolutionTree
>>> xy = np.array([[0., 0.], [1., 0.], [10., 0.], [11., 0.]])
>>> p = initial_cells(jax.random.PRNGKey(0),
...                   GaussianBeliefs(xy, np.tile(np.eye(2) * .02, (4, 1, 1))),
...                   Grid((-2., -3.), (13., 3.), (60, 24)))
>>> t = ResolutionTree.build(p, key=jax.random.PRNGKey(0), mu=2, sigma=1.0, trials=32)
>>> [len(np.unique(t.map_at(l))) for l in range(t.depth + 1)]
[1, 2, 4]
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import jax
import numpy as np

from .cells import Problem
from .search import serge


@dataclass
class Node:
    """One SR of the resolution tree."""

    id: int
    level: int
    init_regions: np.ndarray
    beliefs: np.ndarray
    parent: int | None = None
    children: list[int] = field(default_factory=list)
    mu: int | None = None
    sigma: float | None = None
    log_psi: float | None = None


class ResolutionTree:
    """A resolution tree over a :class:`~pqrm_jax.serge.cells.Problem`."""

    def __init__(self, problem: Problem):
        self.problem = problem
        br = np.asarray(problem.belief_region)
        root = Node(0, 0, np.arange(problem.n_init), np.arange(len(br)))
        self.nodes: list[Node] = [root]

    # growing -----------------------------------------------------------------------------
    def split(self, node_id: int, mu: int, sigma: float, *, key: jax.Array,
              trials: int | None = None) -> list[int]:
        """Split a node with SERGE(μ, σ) on its own cells and beliefs; returns child ids.

        μ is capped at the node's number of initial regions; a node with one initial region
        cannot be split (``ValueError``)."""
        node = self.nodes[node_id]
        if node.children:
            raise ValueError(f"ResolutionTree.split: node {node_id} is already split")
        n = len(node.init_regions)
        if n < 2:
            raise ValueError(f"ResolutionTree.split: node {node_id} is a single initial cell")
        active = np.zeros(self.problem.n_init, bool)
        active[node.init_regions] = True
        mu = max(1, min(int(mu), n, len(node.beliefs)))
        res = serge(key, self.problem, mu, sigma, trials=trials, active=active)
        node.mu, node.sigma, node.log_psi = mu, float(sigma), res.log_psi
        br = np.asarray(self.problem.belief_region)
        for r in range(res.n_regions):
            regs = np.flatnonzero(res.region_of_init == r)
            bel = node.beliefs[np.isin(br[node.beliefs], regs)]
            child = Node(len(self.nodes), node.level + 1, regs, bel, parent=node_id)
            self.nodes.append(child)
            node.children.append(child.id)
        return list(node.children)

    @classmethod
    def build(cls, problem: Problem, *, key: jax.Array, mu: int | Sequence[int] = 2,
              sigma: float = 1.0, depth: int | None = None,
              trials: int | None = None) -> ResolutionTree:
        """Split depth-first (P Fig. 3.3) until every leaf is one initial cell or ``depth`` is hit.

        ``mu`` may be one value or one per level.
        """
        tree = cls(problem)
        stack = [0]
        while stack:
            nid = stack.pop()
            node = tree.nodes[nid]
            if len(node.init_regions) < 2 or (depth is not None and node.level >= depth):
                continue
            m = mu if isinstance(mu, int) else mu[min(node.level, len(mu) - 1)]
            key, sub = jax.random.split(key)
            kids = tree.split(nid, m, sigma, key=sub, trials=trials)
            if len(kids) == 1:                      # no split possible at this μ: stop here
                tree.nodes[nid].children = []
                tree.nodes.pop()
                continue
            stack.extend(reversed(kids))
        return tree

    # reading -----------------------------------------------------------------------------
    @property
    def depth(self) -> int:
        return max(n.level for n in self.nodes)

    def leaves(self) -> list[int]:
        return [n.id for n in self.nodes if not n.children]

    def frontier_at(self, level: int) -> list[int]:
        """Nodes of the map at ``level``: nodes of that level plus shallower leaves."""
        return [n.id for n in self.nodes
                if n.level == level or (n.level < level and not n.children)]

    def map_of(self, frontier: Iterable[int]) -> np.ndarray:
        """[N] cell labels of a frontier (label i = i-th node of the frontier).

        ``ValueError`` unless the frontier's initial regions partition the map."""
        frontier = list(frontier)
        of_init = np.full(self.problem.n_init, -1)
        for i, nid in enumerate(frontier):
            regs = self.nodes[nid].init_regions
            if np.any(of_init[regs] >= 0):
                raise ValueError(f"ResolutionTree.map_of: node {nid} overlaps another node")
            of_init[regs] = i
        if np.any(of_init < 0):
            raise ValueError("ResolutionTree.map_of: the frontier does not cover the map")
        return of_init[self.problem.cell_region]

    def map_at(self, level: int) -> np.ndarray:
        """The full SR map reconstructed at ``level`` (P Fig. 3.3, right)."""
        return self.map_of(self.frontier_at(level))

    def node_of_point(self, point, frontier: Iterable[int]) -> int:
        """The frontier node containing a point (2,)."""
        frontier = list(frontier)
        lab = self.map_of(frontier)
        return frontier[int(lab[int(self.problem.grid.cell_of(np.asarray(point, float)))])]
