"""``pqrm_jax.hssh``: the HSSH local levels -- gateways, local topology, places (B ch. 5--6).

* :mod:`~pqrm_jax.hssh.cellular` -- batched JAX cellular stages: island removal, distance
  transform, Zhang--Suen thinning, the extended Voronoi graph (B §6.1.1, §6.3.1).
* :mod:`~pqrm_jax.hssh.skeleton` -- frontier-based pruning to the spanning tree of exits
  (B §6.1.1), on the host with networkx.
* :mod:`~pqrm_jax.hssh.gateways` -- base points and core (B Alg. 6.1), search spaces (Alg.
  6.2), anchor-based gateways (Alg. 6.4--6.5) and the constriction baseline (Alg. 6.2--6.3).
* :mod:`~pqrm_jax.hssh.star` -- the small-scale star, path continuity, isomorphisms,
  left/right (B §5.1--5.2).
* :mod:`~pqrm_jax.hssh.topology` -- :func:`local_topology` (one grid) and
  :func:`local_topology_batch` (a stack), place detection (B §5.3).
* :mod:`~pqrm_jax.hssh.lpm` -- the scrolling local perceptual map: log-odds occupancy,
  whole-cell scrolling, per-scan lidar updates, ``vmap``-able over runs (B §3.3, §4.1).
* :mod:`~pqrm_jax.hssh.motion` -- the 21-parameter turn--travel--turn action model with the
  Table 4.1 presets (B §4.3.1).
* :mod:`~pqrm_jax.hssh.localization` -- raw odometry, PF, shrink, grow and shrink-and-grow
  proposals as fixed particle blocks with masks, KLD-sampling (Fox 2003) as a mask on each
  block, likelihood-field scan likelihood (B §4.3.2).
* :mod:`~pqrm_jax.hssh.shapes` -- T, L, straight corridor and dead end drawn like the +
  corpus, with the robot off the centre, and their expected local topology (issue 26).
* :mod:`~pqrm_jax.hssh.tracking` -- localizing in the LPM while it is being built: each scan
  localized against the LPM so far, then added at the localized pose, one ``lax.scan``
  (B §4.1, §4.3).
"""

from pqrm_jax.hssh import (
    cellular,
    gateways,
    localization,
    lpm,
    motion,
    shapes,
    skeleton,
    star,
    topology,
    tracking,
)
from pqrm_jax.hssh.cellular import (
    CellularMaps,
    cellular_stages,
    evg_skeleton,
    remove_islands,
    squared_distance_transform,
    zhang_suen_thin,
)
from pqrm_jax.hssh.gateways import Core, Gateway, core, find_gateways, search_spaces
from pqrm_jax.hssh.localization import (
    METHODS,
    KLDParams,
    LocalizeParams,
    kld_bound,
    kld_mask,
    localize,
    localize_with_count,
    scan_likelihood,
)
from pqrm_jax.hssh.lpm import LPMParams, LPMState, lpm_classify, lpm_init, lpm_update
from pqrm_jax.hssh.motion import ACTION_MODELS, decompose, sample_motion
from pqrm_jax.hssh.shapes import ShapeCase, shape_cases, shape_check, shape_image
from pqrm_jax.hssh.skeleton import PrunedSkeleton, prune_skeleton, skeleton_graph
from pqrm_jax.hssh.star import (
    Star,
    StarEntry,
    build_star,
    left_of,
    path_continuity,
    right_of,
    star_isomorphisms,
)
from pqrm_jax.hssh.topology import (
    MIN_SIDE,
    LocalTopology,
    local_topology,
    local_topology_batch,
    occupancy_from_grid,
    place_kind,
    resolution_bound,
    topology_from_maps,
)
from pqrm_jax.hssh.tracking import Tracker, TrackState, TrackStep, lpm_tracker, track_run

__all__ = [
    "cellular", "skeleton", "gateways", "star", "topology", "lpm", "motion",
    "ACTION_MODELS", "decompose", "sample_motion", "localization",
    "METHODS", "LocalizeParams", "localize", "scan_likelihood",
    "KLDParams", "kld_bound", "kld_mask", "localize_with_count",
    "shapes", "ShapeCase", "shape_cases", "shape_check", "shape_image",
    "tracking", "Tracker", "TrackState", "TrackStep", "lpm_tracker", "track_run",
    "LPMParams", "LPMState", "lpm_init", "lpm_update", "lpm_classify",
    "CellularMaps", "cellular_stages", "remove_islands", "squared_distance_transform",
    "zhang_suen_thin", "evg_skeleton",
    "PrunedSkeleton", "prune_skeleton", "skeleton_graph",
    "Core", "Gateway", "core", "search_spaces", "find_gateways",
    "Star", "StarEntry", "build_star", "path_continuity", "star_isomorphisms", "right_of",
    "left_of",
    "LocalTopology", "MIN_SIDE", "local_topology", "local_topology_batch",
    "topology_from_maps", "place_kind", "occupancy_from_grid", "resolution_bound",
]
