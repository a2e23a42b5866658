"""A relaxed SERGE optimiser: soft assignments by gradient (optax), then merge-search polish.

Not in Padgett; an alternative to the random-order merge search of Alg. 2: soft assignments
of the initial regions to μ region slots are optimised with Adam under an annealed
temperature, projected onto contiguous regions and polished by the merge search.

The loss, the annealing and the projection: docs/serge.md §relaxed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .cells import Problem
from .potential import SAL_FLOOR, check_params, log_psi1
from .search import SergeResult, serge


@partial(jax.jit, static_argnames=("n_slots", "steps", "restarts"))
def _optimise(mass, adj, belief_region, mu, sigma, key, n_slots, steps, restarts, tau0, tau1,
              lr, smooth):
    r0 = mass.shape[1]
    s2 = jnp.maximum(sigma, 1e-3) ** 2
    edges = jnp.triu(adj, 1).astype(jnp.float32)

    def loss(w, tau):
        p = jax.nn.softmax(w / tau, axis=1)                           # (R0, J)
        slot_mass = mass @ p                                          # (K, J)
        s = jnp.sum(p[belief_region] * slot_mass, axis=1)
        used = 1.0 - jnp.prod(1.0 - p, axis=0)
        count = jnp.sum(used)
        diff = jnp.sum((p[:, None, :] - p[None, :, :]) ** 2, axis=2)
        return (-jnp.sum(jnp.log(jnp.maximum(s, SAL_FLOOR))) + (count - mu) ** 2 / (2 * s2)
                + smooth * jnp.sum(edges * diff))

    opt = optax.adam(lr)

    def run(k):
        w = jax.random.normal(k, (r0, n_slots))
        state = opt.init(w)

        def step(carry, i):
            w, state = carry
            tau = tau0 * (tau1 / tau0) ** (i / (steps - 1))
            g = jax.grad(loss)(w, tau)
            upd, state = opt.update(g, state, w)
            return (optax.apply_updates(w, upd), state), None

        (w, _), _ = jax.lax.scan(step, (w, state), jnp.arange(steps, dtype=jnp.float32))
        return jnp.argmax(w, axis=1), loss(w, tau1)

    return jax.vmap(run)(jax.random.split(key, restarts))


def project_contiguous(slots: np.ndarray, adj: np.ndarray) -> np.ndarray:
    """Split every slot into its connected components on the initial-region graph.

    Returns ``start`` [R0]: the representative (smallest initial region) of each region."""
    slots = np.asarray(slots)
    adj = np.asarray(adj, bool)
    rep = np.arange(len(slots))
    same = adj & (slots[:, None] == slots[None, :])
    while True:
        nb = np.where(same, rep[None, :], len(slots))
        new = np.minimum(rep, nb.min(axis=1))
        if np.array_equal(new, rep):
            return rep
        rep = new


@dataclass
class RelaxedResult:
    result: SergeResult          # polished map
    projected_log_psi: float     # log ψ of the best projection before polishing
    seconds: float


def relaxed_serge(key: jax.Array, problem: Problem, mu: int, sigma: float = 2.0, *,
                  steps: int = 300, restarts: int = 8, polish_trials: int = 32,
                  tau0: float = 1.0, tau1: float = 0.05, lr: float = 0.1,
                  smooth: float = 0.05) -> RelaxedResult:
    """Relaxed optimiser, projection onto contiguous regions and merge-search polish.

    The method (not in Padgett) is described in docs/serge.md §relaxed.

    Args:
        key: PRNG key of the restarts and of the polish.
        problem: the SERGE problem.
        mu: the count prior's mean number of regions (the number of region slots).
        sigma: the count prior's standard deviation.
        steps: Adam steps per restart.
        restarts: random initialisations, run as one vmap.
        polish_trials: merge-search trials of the polish.
        tau0: initial softmax temperature.
        tau1: final temperature (annealed geometrically from ``tau0``).
        lr: Adam learning rate.
        smooth: weight λ of the contiguity surrogate.

    Returns:
        A :class:`RelaxedResult` whose ``result`` is the polished SERGE map.

    Raises:
        ValueError: for bad prior parameters.

    >>> import jax, numpy as np
    >>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells
    >>> xy = np.array([[0., 0.], [10., 0.], [0., 10.], [10., 10.]])
    >>> p = initial_cells(jax.random.PRNGKey(0),
    ...                   GaussianBeliefs(xy, np.tile(np.eye(2) * .3, (4, 1, 1))),
    ...                   Grid((-5., -5.), (15., 15.), (40, 40)))
    >>> relaxed_serge(jax.random.PRNGKey(0), p, 2, 1.0, steps=50).result.n_regions
    2
    """
    check_params(mu, sigma, problem.k, problem.grid.n_cells)
    t0 = time.perf_counter()
    k1, k2 = jax.random.split(key)
    slots, _ = _optimise(problem.mass, problem.adj, problem.belief_region, jnp.float32(mu),
                         jnp.float32(sigma), k1, int(mu), int(steps), int(restarts),
                         float(tau0), float(tau1), float(lr), float(smooth))
    slots = np.asarray(slots)
    adj = np.asarray(problem.adj)
    best, best_lp, best_start = None, -np.inf, None
    keys = jax.random.split(k2, restarts)
    for i in range(restarts):
        start = project_contiguous(slots[i], adj)
        res = serge(keys[i], problem, mu, sigma, trials=polish_trials, start=start)
        if res.log_psi > best_lp:
            best, best_lp, best_start = res, res.log_psi, start
    # log ψ of the best projection itself, before polishing
    br = np.asarray(problem.belief_region)
    m = np.asarray(problem.mass, np.float64)
    cnt = len(np.unique(best_start))
    sal = np.array([m[k, best_start == best_start[br[k]]].sum() for k in range(problem.k)])
    proj = float(log_psi1(cnt, mu, sigma, problem.k, problem.k)) + float(
        np.sum(np.log(np.maximum(sal, SAL_FLOOR))))
    return RelaxedResult(best, proj, time.perf_counter() - t0)
