"""HSSH global levels: tree of topological maps, global metrical layout, navigation (B ch. 8–9).

* :mod:`~pqrm_jax.hssh_global.star` — views and their matching (B §8.2) on the local levels'
  star type and isomorphism (``Star``, ``star_isomorphisms`` of :mod:`pqrm_jax.hssh.star`).
* :mod:`~pqrm_jax.hssh_global.world` — abstract corridor worlds and explorations (B §8.4).
* :mod:`~pqrm_jax.hssh_global.tree` — the tree of topological map hypotheses (B Alg. 8.1).
* :mod:`~pqrm_jax.hssh_global.layout` — SE(2) compounding, LM spring relaxation (B ch. 9).
* :mod:`~pqrm_jax.hssh_global.navigation` — routes and turn commands (B §7.1.3).
* :mod:`~pqrm_jax.hssh_global.relocalize` — re-localisation at revisits: the current LPM
  matched against the place's stored LPM, corrected displacements for the layout (B §9.2).
* :mod:`~pqrm_jax.hssh_global.simulation` — exploration, navigation and the global occupancy
  map driven by the simulator and the local levels (lidar → LPM → gateways → star views).
"""

from .layout import (
    LayoutProblem,
    layout_supported,
    pack,
    relax,
    relax_loop,
    relax_many,
    scale_trajectory,
    score_hypotheses,
    se2_compose,
    se2_compose_host,
    se2_inverse,
    se2_inverse_host,
    true_layout,
)
from .navigation import (
    NavigationError,
    apply_command,
    command,
    evaluate_navigation,
    execute,
    map_graph,
    plan_route,
    shortest_distance,
)
from .relocalize import Relocalization, RelocParams, visit_offsets
from .simulation import (
    SimExperience,
    SimParams,
    SimulationError,
    SimWorld,
    evaluate_navigation_sim,
    explore_sim,
    global_occupancy,
    map_agreement,
    navigate_sim,
    revisit_jitter,
    sim_world,
    true_layout_sim,
)
from .star import (
    Star,
    match_matrix,
    pad_views,
    star_isomorphisms,
    view_from_local_star,
    view_match,
)
from .tree import (
    MapHypothesis,
    TreeLog,
    TreeTooLarge,
    build_basic_tree,
    build_tree,
    canonical_places,
    extend,
    is_planar,
    is_true_map,
    minimal_models,
    preference_order,
    root,
    view_symbol,
)
from .world import (
    CorridorWorld,
    Experience,
    explore,
    global_paths,
    grid_world,
    office_world,
    world_from_lattice,
)

__all__ = ["Star", "star_isomorphisms", "match_matrix", "pad_views", "view_match",
           "view_from_local_star",
           "CorridorWorld", "Experience", "explore", "grid_world", "office_world",
           "world_from_lattice", "global_paths",
           "MapHypothesis", "TreeLog", "TreeTooLarge", "build_basic_tree", "build_tree",
           "canonical_places", "extend",
           "is_planar", "is_true_map", "minimal_models", "preference_order", "root", "view_symbol",
           "LayoutProblem", "se2_compose", "se2_compose_host", "se2_inverse", "se2_inverse_host",
           "pack",
           "relax", "relax_loop", "relax_many", "layout_supported",
           "scale_trajectory",
           "score_hypotheses", "true_layout",
           "NavigationError", "apply_command", "command", "evaluate_navigation", "execute",
           "map_graph", "plan_route", "shortest_distance",
           "SimParams", "SimWorld", "SimExperience", "SimulationError", "sim_world",
           "explore_sim", "navigate_sim", "evaluate_navigation_sim", "global_occupancy",
           "map_agreement", "true_layout_sim", "revisit_jitter",
           "RelocParams", "Relocalization", "visit_offsets"]
