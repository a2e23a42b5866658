"""HSSH global levels: tree of topological maps, global metrical layout, navigation (B ch. 8–9).

* :mod:`~pqrm_jax.hssh_global.star` — stars, views, isomorphism matching (B §5.1, §8.2).
* :mod:`~pqrm_jax.hssh_global.world` — abstract corridor worlds and explorations (B §8.4).
"""

from .star import Star, isomorphisms, match_matrix, pad_views, view_match
from .world import CorridorWorld, Experience, explore, grid_world, office_world, world_from_lattice

__all__ = ["Star", "isomorphisms", "match_matrix", "pad_views", "view_match",
           "CorridorWorld", "Experience", "explore", "grid_world", "office_world",
           "world_from_lattice"]
