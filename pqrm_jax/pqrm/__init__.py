"""PQRM — probabilistic qualitative relational mapping (P ch. 2, SPEC §3).

* :mod:`.measurement` — ``p(R^n = q | Z^n)`` by sampling (eq. 2.9), one pass for every
  representation that is a merge of the sampled calculus.
"""

from .measurement import (
    aggregation_matrix,
    fine_counts,
    multi_state_probabilities,
    state_counts,
    state_probabilities,
)

__all__ = ["aggregation_matrix", "fine_counts", "multi_state_probabilities", "state_counts",
           "state_probabilities"]
