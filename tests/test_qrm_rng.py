"""RNG estimate (M Alg. 2) against brute-force lune and Delaunay oracles; closed-loop
navigation along RNG paths (M§VII.B)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import Delaunay

from pqrm_jax import sim
from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm import navigation as NAV
from pqrm_jax.qrm import pipeline as P
from pqrm_jax.qrm import rng as R


def _delaunay_edges(p):
    tri = Delaunay(np.asarray(p, np.float64))
    e = np.zeros((len(p), len(p)), bool)
    for s in tri.simplices:
        for a in s:
            e[a, s] = True
    np.fill_diagonal(e, False)
    return e


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fully_constrained_map_gives_true_rng(seed):
    lm = sim.uniform_landmarks(jax.random.key(seed), 30)
    est = R.rng_estimate(H.true_map(lm))
    brute = R.true_rng(np.asarray(lm))
    np.testing.assert_array_equal(np.asarray(est.edges), brute)
    assert float(est.total_cost) == 0.0
    assert (brute <= _delaunay_edges(lm)).all()  # RNG ⊆ Delaunay
    assert brute.sum() // 2 >= 29  # connected graph on 30 nodes has ≥ 29 edges


def test_partial_map_rng_is_sound():
    # same shapes as test_qrm_map's sequence test (shares the compiled program)
    lm = sim.uniform_landmarks(jax.random.key(5), 10)
    poses = sim.random_imaging_points(jax.random.key(6), 8)
    m, met = P.run_sequence(lm, poses, n=8)
    est = R.rng_estimate(m)
    true = R.true_rng(np.asarray(lm))
    e = np.asarray(est.edges)
    assert (true <= e).all()  # a true RNG edge is never pruned while the truth is kept
    zero = e & (np.asarray(est.cost) == 0)
    assert (zero <= true).all()  # zero-cost edges are guaranteed true edges
    assert np.asarray(met.rng_cost)[-1] <= np.asarray(met.rng_cost).max()


def test_rng_needs_lune_calculus():
    with pytest.raises(ValueError, match="no lune"):
        R.rng_estimate(H.empty_map(4, "double_cross"), "double_cross")


def test_navigation_closed_loop():
    lm = sim.uniform_landmarks(jax.random.key(7), 30)
    est = R.rng_estimate(H.true_map(lm))
    k1, k2, k3 = jax.random.split(jax.random.key(8), 3)
    starts = jnp.concatenate([jax.random.uniform(k1, (16, 2)) * 100,
                              jax.random.uniform(k3, (16, 1)) * 6 - 3], 1)
    goals = jax.random.uniform(k2, (16, 2)) * 100
    res = NAV.navigate_many(lm, est, starts, goals, n_steps=1500)
    s = NAV.summarize(res)
    assert s["success_rate"] >= 0.9
    assert 1.0 <= s["length_ratio_median"] < 2.0
    # every planned path follows true RNG edges
    true = R.true_rng(np.asarray(lm))
    for path in np.asarray(res.path):
        p = path[path >= 0]
        assert all(true[a, b] for a, b in zip(p[:-1], p[1:], strict=True))
    with pytest.raises(ValueError, match="NaN"):
        NAV.navigate(lm, est, jnp.array([jnp.nan, 0.0, 0.0]), jnp.array([1.0, 1.0]))
