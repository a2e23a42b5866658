"""SERGE — salient region generation (Padgett ch. 3, docs/decisions.md §5).

Beliefs over a 2-D domain → fine grid → initial cells (one contiguous region per belief) →
merge search maximising ψ = ψ1(|R|; μ, σ) · ψ2(contiguity) · ψ3(saliency) with T random-order
trials batched in one compiled program; a multi-resolution tree; SR maps as a learned
qualitative calculus with an Alg. 3 compose table; a relaxed (optax) optimiser.

>>> import jax, numpy as np
>>> from pqrm_jax import serge as sg
>>> xy = np.array([[0., 0.], [10., 0.], [0., 10.], [10., 10.]])
>>> prob = sg.initial_cells(jax.random.PRNGKey(0),
...                         sg.GaussianBeliefs(xy, np.tile(np.eye(2) * .3, (4, 1, 1))),
...                         sg.Grid((-5., -5.), (15., 15.), (40, 40)))
>>> sg.serge(jax.random.PRNGKey(1), prob, mu=2, sigma=1.0, trials=32).n_regions
2
"""

from .beliefs import GaussianBeliefs, SampleBeliefs
from .cells import Problem, initial_cells, problem_from_partition
from .grid import Grid, components_per_label, connected_components
from .potential import SAL_FLOOR, SIGMA_MIN, check_params, direct_log_potential, log_psi1
from .qsr import SergeCalculus
from .search import SergeResult, serge, serge_sequential

__all__ = [
    "GaussianBeliefs", "SampleBeliefs", "Problem", "initial_cells", "problem_from_partition",
    "Grid", "components_per_label", "connected_components", "SAL_FLOOR", "SIGMA_MIN",
    "check_params", "direct_log_potential", "log_psi1", "SergeResult", "serge",
    "serge_sequential", "SergeCalculus",
]
