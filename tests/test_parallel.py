"""Side-by-side work queues (pqrm_jax/_parallel.py) and the solvers that use them."""

import threading

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import _parallel
from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells, serge
from pqrm_jax.serge import search as S


def test_side_by_side_keeps_order_threads_and_float64_setting():
    seen = []

    def f(i):
        seen.append(threading.get_ident())
        return i, jnp.zeros(()).dtype

    with jax.enable_x64(True):  # JAX keeps this per thread: the queues must inherit it
        out = _parallel.side_by_side(f, [0, 1, 2])
    assert [i for i, _ in out] == [0, 1, 2]
    assert all(d == jnp.float64 for _, d in out)
    assert threading.get_ident() not in seen
    assert _parallel.side_by_side(f, [5]) == [(5, jnp.float32)]
    assert _parallel.default_queues() >= 1 and _parallel.usable_cpus() >= 1


def test_serge_result_does_not_depend_on_the_number_of_queues(monkeypatch):
    rng = np.random.default_rng(3)
    means = rng.uniform(0, 6, (10, 2))
    covs = np.array([np.diag(rng.uniform(0.2, 1.0, 2)) for _ in range(10)])
    prob = initial_cells(jax.random.PRNGKey(0),
                         GaussianBeliefs(means, covs), Grid((-2.0, -2.0), (8.0, 8.0), (40, 40)),
                         unseparated="attach")
    key = jax.random.PRNGKey(1)
    runs = []
    for q in (1, 3):  # 3 queues: 5 blocks of trials padded to 6
        monkeypatch.setattr(S, "default_queues", lambda q=q: q)
        runs.append(serge(key, prob, 5, 2.0, trials=4 * S.WIDTH + 9))
    a, b = runs
    np.testing.assert_array_equal(a.iterations, b.iterations)
    np.testing.assert_array_equal(a.trial_log_psi, b.trial_log_psi)
    np.testing.assert_array_equal(a.cell_labels, b.cell_labels)
