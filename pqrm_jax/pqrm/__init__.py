"""PQRM — probabilistic qualitative relational mapping (P ch. 2, docs/decisions.md §3).

* :mod:`.measurement` — ``p(R^n = q | Z^n)`` by sampling (eq. 2.9), one pass for every
  representation that is a merge of the sampled calculus (the EDC for Padgett's six).
* :mod:`.map` — the online map over all ordered triplets: ``mapper(...).init/update``
  (eq. 2.10, Alg. 1), the step convention of :mod:`pqrm_jax.protocols`.
* :mod:`.metrics` — mean map entropy (eq. 2.11), ML / top-n error rates, P(ML state),
  neighbour distance, confusion matrix, error locations in the normalised AB frame.
* :mod:`.reference` — an independent plain NumPy estimator (test oracle, benchmark baseline).

>>> import jax, jax.numpy as jnp
>>> from pqrm_jax import pqrm
>>> means = jnp.array([[[0., 0.], [0., 10.], [-4., 4.]]])
>>> pqrm.state_probabilities(jax.random.key(0), "lr", means, 0.0, 10).tolist()
[[1.0, 0.0]]
"""

from . import metrics, reference
from .map import MapInfo, Mapper, MapState, fuse_rows, mapper, ordered_triplets, update_observed
from .measurement import (
    aggregation_matrix,
    fine_counts,
    multi_state_probabilities,
    state_counts,
    state_probabilities,
)

__all__ = [
    "MapInfo", "MapState", "Mapper", "aggregation_matrix", "fine_counts", "fuse_rows", "mapper",
    "metrics", "multi_state_probabilities", "ordered_triplets", "reference", "state_counts",
    "state_probabilities", "update_observed",
]
