"""Compositions (Zilberman 2022, ch. 2.4 and 3): composable sets, optimal composition
sequences, and probabilistic composition propagation over a PQRM map.

* :mod:`.composable` — Z Def. 3.2.1–3.2.4, Thm. 3.1 (decision procedure + certificate,
  constructive composition trees).
* :mod:`.sequence` — Z Alg. 1–4 (composition graph, hypergraph Dijkstra, tree extraction).
* :mod:`.propagation` — Z eq. 2.4 / 4.28 as a batched array program over a PQRM map
  (:func:`propagate`, :func:`fuse`, :func:`compose`; :func:`from_pqrm` / :func:`to_pqrm_rows`
  convert between PQRM rows and the dense ``[L, L, L, Q]`` layout).
* :mod:`.simulation` — worlds, sampled compose tensors and the held-out study.

>>> from pqrm_jax import compositions as C
>>> C.is_composable(["ABC", "BCD", "ADE"])
True
>>> C.optimal_composition_tree(["ABC", "BCD", "ADE"], "ACE").num_compositions()
2
"""

from .composable import (
    CompositionTree,
    CutTree,
    as_triplet,
    as_triplet_set,
    clusters,
    composable_triplets,
    compose_from_cut_tree,
    cut_tree,
    fmt,
    is_composable,
    landmark_space,
    verify_cut_tree,
)
from .propagation import PropagationResult, compose, from_pqrm, fuse, propagate, to_pqrm_rows
from .sequence import (
    CompositionGraph,
    optimal_composition_graph,
    optimal_composition_tree,
    unit_cost,
)

__all__ = [
    "CompositionTree", "CutTree", "as_triplet", "as_triplet_set", "clusters",
    "compose_from_cut_tree", "composable_triplets", "cut_tree", "fmt", "is_composable",
    "landmark_space", "verify_cut_tree", "CompositionGraph", "optimal_composition_graph",
    "optimal_composition_tree", "unit_cost", "PropagationResult", "propagate", "fuse", "compose",
    "from_pqrm", "to_pqrm_rows",
]
