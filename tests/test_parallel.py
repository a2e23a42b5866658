"""Side-by-side work queues (pqrm_jax/_parallel.py) and the solvers that use them."""

import threading

import jax
import jax.numpy as jnp
import numpy as np
from compile_count import compiles_by_thread

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


def _worker_compiles(run) -> list[str]:
    """Names of the programs compiled outside the main thread while ``run()`` runs, with the
    in-memory caches cleared first (so everything it dispatches compiles anew)."""
    jax.clear_caches()
    with compiles_by_thread() as compiled:
        run()
    return [name for name, main, _ in compiled if not main]


def test_queues_compile_only_their_jitted_program(monkeypatch):
    """The queues of ``side_by_side`` run in threads. JAX serialises the compile of a jitted
    function, but not of an eager op: two threads converting an argument with ``jnp.asarray``
    (even to its own dtype, a ``stage`` program) at once each compile it — measured: a cold
    EDC table build wrote 15 cache entries for 14 programs in 1 of 3 processes. So a queue
    compiles nothing but its solver's jitted program (the arguments go in as NumPy arrays of
    the final dtype); this failed before for the feasibility queues (``convert_element_type``
    and ``stage`` compiled in the threads)."""
    from pqrm_jax import calculi
    from pqrm_jax.tables import feasibility as F
    from pqrm_jax.tables import problems as pb

    batch = pb.to_batch(pb.random_compose_problems(calculi.get("edc"), 16), 8.0)
    names = _worker_compiles(lambda: F.solve(batch, parts=2, frontier=64))
    assert names and set(names) <= {"jit(_solve)"}, names

    rng = np.random.default_rng(3)
    prob = initial_cells(jax.random.PRNGKey(0),
                         GaussianBeliefs(rng.uniform(0, 6, (6, 2)),
                                         np.array([np.eye(2) * 0.5] * 6)),
                         Grid((-2.0, -2.0), (8.0, 8.0), (20, 20)), unseparated="attach")
    monkeypatch.setattr(S, "default_queues", lambda: 2)
    names = _worker_compiles(lambda: serge(jax.random.PRNGKey(1), prob, 3, 2.0,
                                           trials=2 * S.WIDTH))
    assert names and len(names) == len(set(names)), names
    assert not {"jit(convert_element_type)", "jit(stage)"} & set(names), names
