"""The plain-NumPy per-problem B&B (tables/reference.py) against the batched JAX solver."""

import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.tables import problems as pb
from pqrm_jax.tables.feasibility import FEASIBLE, INFEASIBLE, solve
from pqrm_jax.tables.reference import solve_reference

N_PROBLEMS = 64


@pytest.fixture(scope="module")
def compose_batch():
    """EDC compose problems built exactly as benchmarks/bench_tables.py does."""
    probs = pb.random_compose_problems(calculi.get("edc"), N_PROBLEMS)
    return probs, pb.to_batch(probs, 8.0)


@pytest.mark.parametrize("probes", [2, 0])
def test_reference_is_the_same_algorithm(compose_batch, probes):
    """Both solvers probe the same points (drawn at problem, round, box and coordinate), so
    the batched program must return exactly the verdicts and witnesses of the NumPy
    per-problem loop, with random probes and with box centres only."""
    probs, batch = compose_batch
    jx = solve(batch, probes=probes)
    ref = solve_reference(batch, probes=probes)
    np.testing.assert_array_equal(jx.status, ref.status)
    f = ref.status == FEASIBLE
    np.testing.assert_array_equal(jx.witness[f], ref.witness[f])
    assert f.sum() >= (15 if probes else 5) and (ref.status == INFEASIBLE).sum() >= 15
    for i in np.flatnonzero(f):
        assert pb.verify(probs[i], ref.witness[i]), (i, ref.witness[i])


def test_verdicts_do_not_depend_on_batching(compose_batch):
    """Side-by-side queues, a tiny frontier and a shuffled sub-batch (with the problems' ids)
    give the verdicts and witnesses of one queue over the whole batch."""
    _, batch = compose_batch
    one = solve(batch, parts=1)
    two = solve(batch, parts=2, frontier=256)
    idx = np.random.default_rng(3).permutation(batch.size)[: batch.size // 2]
    sub = solve(batch.take(idx), parts=1, ids=idx)
    f = one.status == FEASIBLE
    assert f.any()
    np.testing.assert_array_equal(two.status, one.status)
    np.testing.assert_array_equal(two.witness[f], one.witness[f])
    np.testing.assert_array_equal(sub.status, one.status[idx])
    np.testing.assert_array_equal(sub.witness[f[idx]], one.witness[idx][f[idx]])


def test_support_classes_skip_only_zero_terms(compose_batch):
    """Splitting the constraints by the variables they use (the solver's default) gives
    exactly the upper bounds and values of one dense class over every variable and pair, on random
    boxes and points, and the classes do split the EDC compose problems (C only, D only,
    both)."""
    import jax
    import jax.numpy as jnp

    from pqrm_jax.tables import feasibility as F

    _, batch = compose_batch
    sub, classes = F.support_classes(batch)
    nv, K = sub.b.shape[-1], sub.A.shape[1]
    assert len(classes) > 1 and any(len(v) < nv for _, _, v, _ in classes)
    dense = (0, K, tuple(range(nv)),
             tuple((p, int(i), int(j))
                   for p, (i, j) in enumerate(zip(*np.triu_indices(nv, 1), strict=True))))
    rng = np.random.default_rng(1)
    with jax.enable_x64(True):
        T = F._unpack(F._tables(*(jnp.asarray(x) for x in (sub.A, sub.b, sub.c, sub.sign,
                                                            sub.active))), nv)
        lo = rng.uniform(-8, 8, (sub.size, 4, nv))
        l, u = jnp.asarray(lo), jnp.asarray(lo + rng.uniform(0, 4, lo.shape))
        x = jnp.asarray(rng.uniform(-8, 8, (2, sub.size, 4, nv)))
        want_hi = F._upper(T, l, u, dense)
        want_val = F._values(T, x, dense)
        np.testing.assert_array_equal(
            np.concatenate([F._upper(T, l, u, c) for c in classes], -1), want_hi)
        np.testing.assert_array_equal(
            np.concatenate([F._values(T, x, c) for c in classes], -1), want_val)
    split = solve(batch, probes=0)
    full = solve(sub, probes=0, classes=(dense,))
    np.testing.assert_array_equal(split.status, full.status)
    np.testing.assert_array_equal(split.witness, full.witness)
