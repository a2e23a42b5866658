"""Q-Link — navigation over qualitative relational maps (P ch. 4, docs/decisions.md §7).

* :mod:`.elements` — map elements (landmark triplets with their PQRM relations for all six
  orderings) from a mapping run, mapping only the co-observed triplets (P §4.2).
* :mod:`.linkgraph` — the Link Graph (edge iff ``|L_i ∩ L_j| ≥ β``), networkx export, batched
  BFS / Bellman–Ford planning from every start to every goal (P §4.3.2, eq. 4.1).
* :mod:`.costs` — unit, expected-length and −log-success edge costs (eqs. 4.2–4.4).
* :mod:`.pomdp` — the QSR-level search POMDP, exact solver batched over elements, the
  finite-state-controller variant (P §4.3.3).
* :mod:`.trajectory` — quarter arcs of radius R, circle searches of radius R′, straight drives.
* :mod:`.navigate` — the executive: one ``lax.while_loop`` per start/goal trial on the
  simulated rover, ``vmap``ped; failure reasons; re-planning inputs (P §4.3, §4.4).
* :mod:`.hybrid` — the in-vivo hybrid map (LR point triplets + wall–wall–point bands), its
  −log p costs and the segment-centre/sweep executive with injected misses (P §4.4.2).
* :mod:`.guarantees` — Assumptions 1–4 and the bounds of Props. 2 and 4 (P §4.3.4).

>>> import jax.numpy as jnp, numpy as np
>>> from pqrm_jax import qlink
>>> lm = jnp.array([[0., 0.], [10., 0.], [5., 6.], [14., 7.]])
>>> el = qlink.exact_elements(lm, np.array([[0, 1, 2], [1, 2, 3]]))
>>> g = qlink.link_graph(el, 2)
>>> qlink.plan_pairs(g, el, [0], [3]).n_elements.tolist()
[2]
"""

from . import costs, elements, guarantees, hybrid, linkgraph, navigate, pomdp, trajectory
from .costs import edge_costs, edge_success, path_success
from .elements import MapElements, exact_elements, from_mapping_run, incidence
from .linkgraph import (
    LinkGraph,
    LinkPlan,
    goal_distances,
    link_graph,
    neighbour_table,
    plan_from,
    plan_pairs,
    to_networkx,
)
from .navigate import (
    FAILURE_REASONS,
    NavParams,
    NavResult,
    PairResult,
    navigate_pairs,
    start_tables,
)
from .navigate import navigate as drive
from .pomdp import SearchPOMDP, open_loop_plan, search_model, solve_exact

__all__ = [
    "costs", "elements", "guarantees", "hybrid", "linkgraph", "navigate", "pomdp", "trajectory",
    "MapElements", "from_mapping_run", "exact_elements", "incidence",
    "LinkGraph", "LinkPlan", "link_graph", "plan_pairs", "plan_from", "goal_distances",
    "neighbour_table", "to_networkx", "edge_costs", "edge_success", "path_success",
    "SearchPOMDP", "search_model", "solve_exact", "open_loop_plan",
    "NavParams", "NavResult", "PairResult", "navigate_pairs", "start_tables", "drive",
    "FAILURE_REASONS",
]
