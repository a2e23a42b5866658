"""Deterministic qualitative relational mapping with camera measurements (M, MT).

Decisions: docs/decisions.md §4; how it works: docs/qrm.md.

* :mod:`~pqrm_jax.qrm.camera` — camera measurement (M§IV, Table III): exact feasible sets
  of every triple × state × cyclic relation, batched, for images and triples.
* :mod:`~pqrm_jax.qrm.exact_camera` — the exact decision from the boundary of the
  range-ordering cone (M§V); :mod:`~pqrm_jax.qrm.camera_oracle` — z3 decision of every
  state (the oracle, and the exact stage for undecided states).
* :mod:`~pqrm_jax.qrm.hypergraph` — the map (3-uniform hypergraph of state bitmasks) and its
  path-consistency update to a fixed point (M§VI.B).
* :mod:`~pqrm_jax.qrm.association` — data-association candidate filter (M§VI.C).
* :mod:`~pqrm_jax.qrm.rng` — RNG estimate with edge costs (M Alg. 2).
* :mod:`~pqrm_jax.qrm.navigation` — RNG navigation between Voronoi cells, closed loop (M§VII.B).
* :mod:`~pqrm_jax.qrm.mapper` — ``mapper(calc, num_landmarks, n)`` → ``Mapper(init, update,
  metrics)``, pure functions as :func:`pqrm_jax.pqrm.mapper` (the step convention of
  :mod:`pqrm_jax.protocols`: a sequence is ``protocols.run``).
* :mod:`~pqrm_jax.qrm.pipeline` — image-by-image mapping in the simulator and the M§VIII.A
  metrics; :mod:`~pqrm_jax.qrm.reference` — one-relation-at-a-time reference update.

Example::

    import jax, sim
    from pqrm_jax import qrm
    lm = sim.uniform_landmarks(jax.random.key(0), 30)
    poses = sim.random_imaging_points(jax.random.key(1), 50)
    m, metrics = qrm.run_sequence(lm, poses, n=18)        # M§VIII.B, one run
    rng = qrm.rng_estimate(m)                             # M Alg. 2
"""

from .association import association_candidates
from .camera import ImageMeasurement, measure_image, measure_triples
from .hypergraph import QRMMap, apply_relations, closure, empty_map, true_map, update_image
from .mapper import Mapper, mapper
from .navigation import navigate, navigate_many
from .pipeline import map_metrics, map_step, run_sequence
from .rng import rng_estimate, true_rng
from .spec import QRMSpec, mask_of, qrm_spec, states_of

__all__ = ["association_candidates", "ImageMeasurement", "measure_image", "measure_triples",
           "QRMMap", "apply_relations", "closure", "empty_map", "true_map", "update_image",
           "navigate", "navigate_many", "map_metrics", "map_step", "run_sequence",
           "rng_estimate", "true_rng", "QRMSpec", "mask_of", "qrm_spec", "states_of", "Mapper",
           "mapper"]
