"""Issue 31: the cheaper formulations equal the ones they replace (no timing here)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax.pqrm import metrics


def _rank_by_sort(probs, truth):
    """The former topn_error_rates rank: position of the truth in a stable descending sort."""
    order = jnp.argsort(-probs, axis=-1, stable=True)
    return jnp.argmax(order == truth[:, None], axis=-1)


@jax.jit
def _rank_check(probs, truth, mask):
    """(truth_rank, the sort's rank, topn_error_rates, the former rates): one program a shape
    (eager, each of the ~15 operations compiled for every drawn shape: most of the test's
    time)."""
    want = _rank_by_sort(probs, truth)
    rates = metrics.topn_error_rates(probs, truth, mask)
    wrong = want[:, None] >= jnp.arange(1, probs.shape[1] + 1)[None, :]  # the former formula
    ref = jnp.sum(jnp.where(mask[:, None], wrong, False), axis=0) / jnp.maximum(jnp.sum(mask), 1)
    return metrics.truth_rank(probs, truth), want, rates, ref


_SPECIAL = (0.0, -0.0, 1.0, 0.5, 1e-30, 1e30, float("inf"), -float("inf"), float("nan"))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 9), st.integers(1, 12), st.integers(0, 2**31 - 1), st.floats(1e-30, 1e30),
       st.booleans())
def test_truth_rank_equals_the_stable_sort(t, q, seed, scale, special):
    """Counting gives the sort's rank for every row: ties (coarse values), ±0, ±inf, NaN,
    scales 1e-30..1e30, and the top-n rates built on it are the former ones."""
    rng = np.random.default_rng(seed)
    probs = rng.integers(0, 3, size=(t, q)).astype(np.float32) * np.float32(scale)  # many ties
    if special:
        pick = rng.integers(0, len(_SPECIAL), size=(t, q))
        use = rng.random((t, q)) < 0.5
        probs = np.where(use, np.asarray(_SPECIAL, np.float32)[pick], probs)
    truth = rng.integers(0, q, size=t).astype(np.int32)
    mask = rng.random(t) < 0.8
    got, want, rates, ref = _rank_check(jnp.asarray(probs), jnp.asarray(truth),
                                        jnp.asarray(mask))
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    np.testing.assert_array_equal(np.asarray(rates), np.asarray(ref))


def test_truth_rank_undefined_truth_is_zero_and_float64_works():
    probs = jnp.asarray(np.array([[0.2, 0.8], [0.5, 0.5], [0.9, 0.1]], np.float64))
    truth = jnp.array([0, 1, -1])
    assert np.asarray(metrics.truth_rank(probs, truth)).tolist() == [1, 1, 0]
    assert metrics.truth_rank(probs, jnp.array([2, 5, 0])).tolist() == [0, 0, 0]


def test_truth_rank_under_jit_and_vmap():
    probs = jax.random.uniform(jax.random.key(1), (3, 50, 20))
    truth = jax.random.randint(jax.random.key(2), (3, 50), 0, 20)
    got = jax.jit(jax.vmap(metrics.truth_rank))(probs, truth)
    want = jax.vmap(_rank_by_sort)(probs, truth)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


_CACHE_RUN = """
import sys, jax
from jax import monitoring
events = {"miss": 0, "hit": 0}
def listen(name, **kw):
    if name == "/jax/compilation_cache/cache_misses":
        events["miss"] += 1
    elif name == "/jax/compilation_cache/cache_hits":
        events["hit"] += 1
monitoring.register_event_listener(listen)
from pqrm_jax import cli
sys.argv = ["pqrm-jax", "study", "padgett-mc", "--runs", "2", "--levels", "2", "--samples", "8",
            "--landmarks", "4", "--chunk", "2", "--quiet", "--out", sys.argv[1]]
rc = cli.main()
print("EVENTS", events["miss"], events["hit"], jax.config.jax_compilation_cache_dir, rc)
"""


def _cache_run(tmp_path, out: str, env_value: str | None):
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    env.pop("PQRM_JAX_COMPILE_CACHE", None)
    if env_value is not None:
        env["PQRM_JAX_COMPILE_CACHE"] = env_value
    proc = subprocess.run([sys.executable, "-c", _CACHE_RUN, str(tmp_path / out)], env=env,
                          capture_output=True, text=True, check=True)
    line = [x for x in proc.stdout.splitlines() if x.startswith("EVENTS")][-1].split()
    return int(line[1]), int(line[2]), line[3], int(line[4])


def test_command_second_process_compiles_nothing(tmp_path):
    """The pqrm-jax command caches its programs on disk (default under XDG_CACHE_HOME): a second
    process of the same study finds every program there; PQRM_JAX_COMPILE_CACHE=off turns it
    off and =DIR moves it."""
    miss1, hit1, where, rc = _cache_run(tmp_path, "a", None)
    assert rc == 0 and where == str(tmp_path / "xdg" / "pqrm-jax" / "xla")
    assert miss1 > 0 and any((tmp_path / "xdg" / "pqrm-jax" / "xla").iterdir())
    miss2, hit2, _, rc = _cache_run(tmp_path, "b", None)
    assert rc == 0 and miss2 == 0 and hit2 >= miss1 > 0
    miss3, hit3, where, rc = _cache_run(tmp_path, "c", "off")
    assert rc == 0 and hit3 == 0 and where == "None"
    _, _, where, rc = _cache_run(tmp_path, "d", str(tmp_path / "mine"))
    assert rc == 0 and where == str(tmp_path / "mine") and any((tmp_path / "mine").iterdir())


def _closure_all_rounds(left, right, inverse, compose, problems, max_rounds=50):
    """An earlier path_consistency_refutes: float matrices, triple by triple, every problem
    every round until all settle."""
    from pqrm_jax.tables.symmetry import _TID, _TRIPLES  # noqa: PLC2701 (test oracle)

    P, Q = len(problems), left.shape[0]
    rel = np.ones((P, 24, Q), bool)
    rows = np.arange(P)
    for (x, y, z), col in (((0, 1, 2), 0), ((1, 2, 3), 1), ((0, 1, 3), 2)):
        rel[:, _TID[(x, y, z)]] = False
        rel[rows, _TID[(x, y, z)], problems[:, col]] = True
    L, R, Inv = (m.astype(np.float32) for m in (left, right, inverse))
    T = compose.astype(np.float32).reshape(Q * Q, Q)
    for _ in range(max_rounds):
        before = rel.copy()
        for x, y, z in _TRIPLES:
            a = rel[:, _TID[(x, y, z)]].astype(np.float32)
            rel[:, _TID[(y, z, x)]] &= (a @ L) > 0
            rel[:, _TID[(z, x, y)]] &= (a @ R) > 0
            rel[:, _TID[(y, x, z)]] &= (a @ Inv) > 0
        for x, y, z in _TRIPLES:
            w = 6 - x - y - z
            a = rel[:, _TID[(x, y, z)]].astype(np.float32)
            b = rel[:, _TID[(y, z, w)]].astype(np.float32)
            ab = (a[:, :, None] * b[:, None, :]).reshape(P, Q * Q)
            rel[:, _TID[(x, y, w)]] &= (ab @ T) > 0
        if (~rel.any(-1)).any(-1).all() or np.array_equal(rel, before):
            break
    return (~rel.any(-1)).any(-1)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 64), st.integers(0, 40), st.floats(0.3, 0.97), st.integers(0, 2**31 - 1))
def test_path_consistency_bitsets_equal_the_matrix_closure(q, p, density, seed):
    """The closure on bit masks through chunked lookup tables (all triples of a round at
    once, each problem stopping on its own) refutes exactly what the float-matrix closure
    (triple by triple, all problems every round) refutes at its fixpoint: random superset
    tables, 1…64 atoms (one to several chunks, a full 64-bit mask)."""
    from pqrm_jax.tables import symmetry

    rng = np.random.default_rng(seed)
    left, right, inverse = (rng.random((q, q)) < density for _ in range(3))
    compose = rng.random((q, q, q)) < density
    problems = rng.integers(0, q, size=(p, 3))
    got = symmetry.path_consistency_refutes(left, right, inverse, compose, problems)
    # every round that does not stop a problem removes an atom of one of its 24 relations
    want = _closure_all_rounds(left, right, inverse, compose, problems,
                               max_rounds=24 * q + 2)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("op", ["left", "right", "inverse", "compose"])
def test_path_consistency_each_operation_refutes_on_its_own(op):
    """Every step of a round counts: tables that constrain nothing but ``op`` (two atoms;
    ``op`` sends every atom to atom 1, or composes atom 0 with atom 0 to nothing) refute the
    problem (0, 0, 0), and without that constraint nothing is refuted."""
    from pqrm_jax.tables import symmetry

    tabs = {k: np.ones((2, 2), bool) for k in ("left", "right", "inverse")}
    tabs["compose"] = np.ones((2, 2, 2), bool)
    problems = np.zeros((1, 3), np.int64)
    assert not symmetry.path_consistency_refutes(**tabs, problems=problems).any()
    if op == "compose":
        tabs[op][0, 0] = False
    else:
        tabs[op] = np.array([[False, True], [False, True]])
    assert symmetry.path_consistency_refutes(**tabs, problems=problems).all()
    want = _closure_all_rounds(tabs["left"], tabs["right"], tabs["inverse"], tabs["compose"],
                               problems)
    assert want.all()


def test_path_consistency_beyond_64_atoms_refutes_nothing():
    """Sets of more than 64 atoms do not fit a mask: nothing is refuted (sound, documented),
    even a problem the closure would refute at once."""
    from pqrm_jax.tables import symmetry

    q = 65
    none = np.zeros((q, q), bool)
    problems = np.array([[0, 1, 2]])
    assert _closure_all_rounds(none, none, none, np.zeros((q, q, q), bool), problems)[0]
    got = symmetry.path_consistency_refutes(none, none, none, np.zeros((q, q, q), bool),
                                            problems)
    assert got.dtype == bool and not got.any()


@settings(max_examples=10, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 30.0), st.integers(1, 40))
def test_numpy_fused_baseline_counts_equal_the_kernel(seed, sigma_max, n):
    """bench_pqrm's vectorised NumPy baseline computes the kernel's counts (same draws)."""
    from pqrm_jax import pqrm
    from pqrm_jax.pqrm import measurement, reference

    rng = np.random.default_rng(seed)
    means = rng.uniform(-50, 50, (n, 3, 2)).astype(np.float32)
    sigma = rng.uniform(0, sigma_max, (n, 3)).astype(np.float32)
    key = jax.random.key(seed)
    counts = np.asarray(pqrm.fine_counts(key, "edc", means, sigma, 300))
    z = np.asarray(measurement.sample_bank(key, 300, np.float32)).reshape(-1, 3, 2)[:300]
    np.testing.assert_array_equal(reference.numpy_fused_counts(means, sigma, z), counts)
