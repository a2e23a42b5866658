"""Numerics and memory: one regression test per defect of the second reliability probe.

D1/D2 scale-free classification and PQRM kernel, S1 coincidences under jit, D12/S2 exact
integers, D13 sentinel labels, D21 complex input, D25 validation gaps, D3 bounded memory
(streamed sample axis, up-front refusals) and the sparse PQRM map.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi, pqrm, qrm
from pqrm_jax.calculi import INVALID
from pqrm_jax.pqrm import measurement
from pqrm_jax.tables.exact import exact_state

CALCS = ("edc", "lr", "quadrant", "dcc", "lr_full", "edc_lune", "triple_cross")


def _configs(n, seed=0, dtype=np.float32):
    return np.random.default_rng(seed).uniform(-3, 3, (n, 3, 2)).astype(dtype)


def _classify(c, P):
    return np.asarray(c.classify(P[:, 0], P[:, 1], P[:, 2]))


# D1 -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", CALCS)
@pytest.mark.parametrize("scale", [1e-30, 1e-20, 1e-19, 1e20, 1e30, 2.0**-100, 2.0**100])
def test_classify_is_scale_free_float32(name, scale):
    c = calculi.get(name)
    P = _configs(4000)
    ref = _classify(c, P)
    got = _classify(c, P * np.float32(scale))
    if np.log2(scale) == int(np.log2(scale)):
        assert np.array_equal(got, ref)  # a power of two keeps every bit: exactly the same
    else:  # decimal scales round the inputs; only configurations within an ulp may move
        assert np.mean(got != ref) <= 1e-3
    assert np.all(got >= 0) or c.boundary_inclusive is False


@pytest.mark.parametrize("name", ["edc", "lr", "dcc"])
def test_classify_is_scale_free_float64(name):
    c = calculi.get(name)
    with jax.enable_x64(True):
        P = _configs(3000, dtype=np.float64)
        ref = _classify(c, P)
        for s in (2.0**-600, 2.0**520, 1e-160, 1e160):
            got = _classify(c, P * s)
            assert np.mean(got != ref) <= (0 if s in (2.0**-600, 2.0**520) else 1e-6)


def test_classify_invalid_when_differences_overflow():
    c = calculi.get("lr_full")
    out = c.classify([-3e38, 0.0], [3e38, 0.0], [0.0, 1.0])  # B − A overflows float32
    assert int(out) == INVALID


@pytest.mark.parametrize("scale", [1e-19, 1e-30, 1e20, 1e30])
def test_fused_edc_kernel_is_scale_free(scale):
    edc = calculi.get("edc")
    P = _configs(4000, seed=1)
    ref = _classify(edc, P)
    Q = P * np.float32(scale)
    fused = np.asarray(measurement.edc_states_fused(Q[:, 0], Q[:, 1], Q[:, 2]))
    ok = ref >= 0
    assert np.mean(fused[ok] != ref[ok]) <= 1e-3
    assert np.mean(fused < 0) <= 1e-3


# D2 -------------------------------------------------------------------------------------------
def test_state_probabilities_scale_free():
    M = np.array([[[0.0, 0.0], [0.0, 10.0], [5.0, 4.0]], [[1.0, 1.0], [3.0, 2.0], [2.0, 1.6]]],
                 np.float32)
    k = jax.random.key(0)
    ref = np.asarray(pqrm.state_counts(k, "edc", M, 1.0, 2000))
    for s in (2.0**100, 2.0**-100):  # exact scales: identical counts
        got = np.asarray(pqrm.state_counts(k, "edc", M * np.float32(s), np.float32(s), 2000))
        assert np.array_equal(got, ref)
    p1 = np.asarray(pqrm.state_probabilities(k, "lr", M, 1.0, 1000))
    for s in (1e30, 1e-30):
        p = np.asarray(pqrm.state_probabilities(k, "lr", M * np.float32(s), s, 1000))
        np.testing.assert_allclose(p.sum(-1), 1.0, atol=1e-6)
        np.testing.assert_allclose(p, p1, atol=0.01)


def test_state_probabilities_refuses_overflowing_differences():
    M = np.array([[[-3e38, 0.0], [3e38, 0.0], [0.0, 1.0]]], np.float32)
    with pytest.raises(ValueError, match="overflow"):
        pqrm.state_probabilities(jax.random.key(0), "lr", M, 1.0, 10)


def test_mapper_scale_free():
    pq = pqrm.mapper(("edc",), 5, 64)
    pos = np.array([[0, 0], [0, 10], [5, 4], [-3, 2], [4, -6]], np.float32)
    vis = np.ones(5, bool)
    k = jax.random.key(2)
    ref, _ = pq.update(pq.init(), k, pos, vis, 0.5)
    for s in (2.0**100, 2.0**-100):
        st, _ = pq.update(pq.init(), k, pos * np.float32(s), vis, 0.5 * s)
        assert int(st.num_rejected.sum()) == 0
        for c in ("edc",):
            assert np.array_equal(np.asarray(st.probs[c]), np.asarray(ref.probs[c]))
    st, _ = pqrm.update_observed(pq, pq.init(), k, np.arange(5), pos * 1e30, 0.5e30)
    assert int(st.num_rejected.sum()) == 0 and bool(st.mapped.all())


# S1 -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["lr_full", "dcc"])
def test_coincidences_exact_for_any_float(name):
    c = calculi.get(name)
    rng = np.random.default_rng(5)
    A = rng.uniform(-7, 7, (100_000, 2)).astype(np.float32)
    B = rng.uniform(-7, 7, (100_000, 2)).astype(np.float32)
    expect = {"lr_full": ("e", "s", "dou", "tri"), "dcc": ("5", "11", "dou", "tri")}[name]
    jitted = jax.jit(c.classify)
    for f in (c.classify, jitted):
        for (a, b, cc), lab in zip(((A, B, B), (A, B, A), (A, A, B), (A, A, A)), expect,
                                   strict=True):
            out = np.asarray(f(a, b, cc))
            assert np.all(out == c.index(lab)), (lab, np.unique(out))


def test_true_relations_of_coincident_landmarks():
    lr = calculi.get("lr_full")
    rng = np.random.default_rng(8)
    lm = rng.uniform(0, 100, (40, 2)).astype(np.float32)
    lm = jnp.asarray(np.concatenate([lm, lm[:20]]))  # landmark 40 + j coincides with j
    j = np.arange(20)
    tri = np.concatenate([np.stack([j + 20, j, j + 40], -1), np.stack([j, j + 40, j + 20], -1)])
    st = jax.jit(lambda x: pqrm.metrics.true_states(lr, x, tri))(lm)  # as the studies call it
    assert lr.labels(st) == ["e"] * 20 + ["dou"] * 20


# D12 / S2 -------------------------------------------------------------------------------------
def test_int64_beyond_int32_is_exact():
    e = calculi.get("edc")
    a, b, c = np.array([0, 0]), np.array([0, 3_000_000_000]), np.array([-3, 1_000_000_000])
    assert int(e.classify(a, b, c)) == exact_state(e, (0, 0), (0, 3_000_000_000),
                                                   (-3, 1_000_000_000)) == 12


@pytest.mark.parametrize("name", ["lr", "edc", "dcc", "lr_full"])
@pytest.mark.parametrize("mag", [10**4, 10**9, 2**62])
def test_integer_coordinates_exact_at_any_magnitude(name, mag):
    c = calculi.get(name)
    rng = np.random.default_rng(mag % 1000)
    n = 60
    P = rng.integers(-mag, mag, (n, 3, 2), dtype=np.int64)
    # long-baseline collinear and coincident cases: the boundary relations must survive
    p, q = rng.integers(1, 1000, (2, n // 3))
    k = rng.integers(-(mag // 2000), mag // 2000, (3, n // 3))
    P[: n // 3] = np.stack([k * p, k * q], -1).transpose(1, 0, 2)
    P[n // 3: n // 2, 2] = P[n // 3: n // 2, 1]
    got = _classify(c, P)
    want = [exact_state(c, *map(tuple, t)) for t in P.tolist()]
    assert got.tolist() == want


def test_integer_valued_floats_exact_within_bound():
    lr = calculi.get("lr_full")
    bound = lr.exact_integer_bound("float32")
    rng = np.random.default_rng(0)
    p, q = rng.integers(1, 40, (2, 500))
    k = rng.integers(-(bound // 80), bound // 80, (3, 500))
    P = np.stack([k * p, k * q], -1).transpose(1, 0, 2)
    P[:, 2, 0] += rng.integers(-1, 2, 500)  # on the line, or one unit off it
    want = [exact_state(lr, *map(tuple, t)) for t in P.tolist()]
    assert _classify(lr, P.astype(np.float32)).tolist() == want
    # traced integers: exact within the bound, INVALID beyond it (never a rounded guess)
    f = jax.jit(lambda a, b, c: lr.classify(a, b, c))
    assert np.asarray(f(*(jnp.asarray(P[:, i], jnp.int32) for i in range(3)))).tolist() == want
    big = jnp.asarray([[0, 0], [0, 3 * bound], [1, bound]], jnp.int32)
    assert int(f(big[0], big[1], big[2])) == INVALID


# D13 ------------------------------------------------------------------------------------------
def test_labels_of_sentinels():
    e = calculi.get("edc")
    s = e.classify([0.0, 0.0], [0.0, 1.0], [0.0, 0.5])
    assert int(s) == -1
    assert e.labels([s]) == ["BOUNDARY"]
    assert e.labels([-2, -3, 0]) == ["DEGENERATE", "INVALID", "1"]
    with pytest.raises(ValueError, match="not a state index"):
        e.labels([20])
    with pytest.raises(ValueError, match="not a state index"):
        e.labels([-4])


# D21 ------------------------------------------------------------------------------------------
def test_complex_inputs_refused():
    e = calculi.get("edc")
    z = np.array([0.0 + 1j, 1.0])
    with pytest.raises(TypeError, match="complex"):
        e.classify(z, [0.0, 1.0], [1.0, 1.0])
    M = np.zeros((1, 3, 2), np.complex64)
    with pytest.raises(TypeError, match="complex"):
        pqrm.state_probabilities(jax.random.key(0), "lr", M, 1.0, 10)
    with pytest.raises(TypeError, match="complex"):
        pqrm.state_probabilities(jax.random.key(0), "lr", M.real, 1.0 + 0j, 10)
    pq = pqrm.mapper(("lr",), 3, 8)
    with pytest.raises(TypeError, match="complex"):
        pq.update(pq.init(), jax.random.key(0), np.zeros((3, 2), np.complex64),
                  np.ones(3, bool), 0.1)


# D25 (numerics part) --------------------------------------------------------------------------
def test_small_validation_gaps():
    M = [[[0.0, 0.0], [0.0, 10.0], [5.0, 4.0]]]  # a plain nested list
    p = pqrm.state_probabilities(jax.random.key(0), "lr", M, 0.0, 10)
    assert np.asarray(p).tolist() == [[0.0, 1.0]]
    with pytest.raises(ValueError, match="num_samples"):
        pqrm.state_probabilities(jax.random.key(0), "lr", M, 0.0, True)
    with pytest.raises(ValueError, match="at least one calculus"):
        pqrm.multi_state_probabilities(jax.random.key(0), [], M, 0.0, 10)
    with pytest.raises(ValueError, match="no state"):
        calculi.Calculus.from_rule("empty", [calculi.alpha], lambda s: None)
    with pytest.raises(ValueError, match="bits outside"):
        qrm.states_of("edc", 1 << 25)
    assert qrm.states_of("edc", 0b101) == ["1", "3"]


# D3 -------------------------------------------------------------------------------------------
def test_bank_rows_are_the_normal_bank():
    k = jax.random.key(11)
    full = jax.random.normal(k, (600, 6))
    assert np.array_equal(measurement.normal_bank_rows(k, 0, 300), full[:300])
    assert np.array_equal(measurement.normal_bank_rows(k, 300, 300), full[300:])
    raw = jax.random.PRNGKey(5)  # legacy uint32 keys too
    assert np.array_equal(measurement.normal_bank_rows(raw, 7, 300),
                          jax.random.normal(raw, (307, 6))[7:])
    with jax.enable_x64(True):
        full64 = jax.random.normal(k, (400, 6), jnp.float64)
        got = measurement.normal_bank_rows(k, 100, 300, jnp.float64)
        assert np.array_equal(got, full64[100:])
    # counters beyond 2**32 (rows ≥ 2**32 / 6) match the 64-bit flat index
    rows = np.array([0, 2**29, 2**30 - 1, 2**30, 715_827_883, 2**31 - 1], np.int64)
    hi, lo = measurement._row_counters(jnp.asarray(rows, jnp.int32))
    flat = np.asarray(hi).astype(np.int64) * 2**32 + np.asarray(lo).astype(np.int64)
    assert np.array_equal(flat, rows[:, None] * 6 + np.arange(6))


def test_streamed_counts_equal_one_bank(monkeypatch):
    rng = np.random.default_rng(3)
    M = rng.uniform(0, 100, (37, 3, 2)).astype(np.float32)
    k = jax.random.key(4)
    one = np.asarray(pqrm.fine_counts(k, "edc", M, 5.0, 1201))  # one piece (1201 ≤ block)
    gen_one = np.asarray(pqrm.fine_counts(k, "dcc", M[:3], 5.0, 301, chunk_triplets=64))
    # smaller blocks; another (result-neutral) chunk_triplets is another static key of the
    # jitted kernel, so the calls below are traced afresh with the patched block sizes
    monkeypatch.setattr(measurement, "_BLOCK_PAIRS", 255 * 37 * 2)  # 510-sample blocks
    monkeypatch.setattr(measurement, "_GENERIC_BLOCK_PAIRS", 3 * 100)  # 100-sample blocks
    assert measurement.sample_block(4095, 37) == 510
    streamed = np.asarray(pqrm.fine_counts(k, "edc", M, 5.0, 1201, chunk_triplets=4095))
    gen_streamed = np.asarray(pqrm.fine_counts(k, "dcc", M[:3], 5.0, 301, chunk_triplets=65))
    assert np.array_equal(streamed, one)
    assert np.array_equal(gen_streamed, gen_one)
    assert one.sum(-1).max() <= 1201


def test_requests_that_cannot_fit_are_refused_up_front():
    M = np.zeros((4, 3, 2), np.float32) + np.arange(3)[None, :, None]
    with pytest.raises(ValueError, match="2\\*\\*31 - 1"):
        pqrm.state_probabilities(jax.random.key(0), "edc", M, 1.0, 2**31)
    with pytest.raises(ValueError, match="chunk_triplets"):
        pqrm.state_probabilities(jax.random.key(0), "edc", M, 1.0, 10**6, max_bytes=2**20)
    with pytest.raises(ValueError, match="chunk_triplets"):
        pqrm.state_probabilities(jax.random.key(0), "edc", M, 1.0, 10, chunk_triplets=0)
    est = measurement.working_set_bytes(10, 10**8)
    assert est == measurement.working_set_bytes(10, 10**9) < 100 * 2**20  # independent of S


_RSS = """
import resource, sys, jax, numpy as np
from pqrm_jax import pqrm
m = np.random.default_rng(0).uniform(0, 100, (10, 3, 2)).astype(np.float32)
for s in (3 * 10**5, int(sys.argv[1])):  # warm-up (streams, compiles), then the big call
    np.asarray(pqrm.state_probabilities(jax.random.key(0), 'edc', m, 5.0, s))
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def _peak_rss_growth_mb(num_samples: int) -> float:
    out = subprocess.run([sys.executable, "-c", _RSS, str(num_samples)], capture_output=True,
                         text=True, check=True)
    small, big = (int(x) / 1024 for x in out.stdout.split()[-2:])
    return big - small


def test_memory_does_not_grow_with_samples():
    # the one-bank version grew ~92 B per sample: ~0.28 GB more at S = 3e6
    assert _peak_rss_growth_mb(3 * 10**6) < 100


@pytest.mark.slow
def test_memory_bounded_at_1e8_samples():
    assert _peak_rss_growth_mb(10**8) < 100


# sparse PQRM map ------------------------------------------------------------------------------
def test_sparse_map_rows_equal_dense_rows():
    m = 8
    rng = np.random.default_rng(0)
    dense = pqrm.mapper(("edc", "lr"), m, 48)
    pick = rng.choice(len(dense.triplets), 30, replace=False)
    tri = dense.triplets[pick]
    sparse = pqrm.mapper(("edc", "lr"), m, 48, triplets=tri)
    sd, ss = dense.init(), sparse.init()
    pos = rng.uniform(0, 40, (m, 2)).astype(np.float32)
    for t in range(3):
        vis = rng.random(m) < 0.8
        k = jax.random.key(t)
        step = rng.normal(0, 1, (m, 2)).astype(np.float32)
        sd, _ = dense.update(sd, k, pos + step, vis, 1.0)
        ss, _ = sparse.update(ss, k, pos + step, vis, 1.0)
    for leaf_d, leaf_s in zip(jax.tree_util.tree_leaves(sd), jax.tree_util.tree_leaves(ss),
                              strict=True):
        leaf_d, leaf_s = np.asarray(leaf_d), np.asarray(leaf_s)
        if leaf_d.ndim == 0:
            assert leaf_d == leaf_s
        else:
            assert np.array_equal(leaf_d[pick], leaf_s)


def test_dense_map_bound_and_sparse_validation():
    with pytest.raises(ValueError, match="triplets="):
        pqrm.mapper(("edc",), 300, 16)  # 26.7 M triplets
    with pytest.raises(ValueError, match="triplets="):
        pqrm.mapper(("edc",), 20, 16, max_bytes=2**20)
    sp = pqrm.mapper(("edc",), 300, 16, triplets=[[0, 1, 2], [299, 5, 7]])
    assert sp.init().probs["edc"].shape == (2, 20)
    for bad, err in (([[0, 0, 1]], ValueError), ([[0, 1, 300]], ValueError),
                     ([[0, 1, 2], [0, 1, 2]], ValueError), ([[0.0, 1.0, 2.0]], TypeError),
                     (np.zeros((0, 3), int), ValueError)):
        with pytest.raises(err):
            pqrm.mapper(("edc",), 300, 16, triplets=bad)
    assert json.dumps(pqrm.map.map_bytes_per_triplet(("edc",)))


def _elementwise_check(means, sigma) -> str | None:
    """The value checks of ``check_measurement_inputs`` as they were, element by element: the
    error it raised first (None: accepted). The reference of the test below."""
    m = np.asarray(means)
    if not np.all(np.isfinite(m)):
        return "NaN or infinite"
    if m.size and np.issubdtype(m.dtype, np.floating):
        dt = np.result_type(m.dtype, np.float32)
        with np.errstate(over="ignore", invalid="ignore"):
            diff = m.astype(dt)[:, 1:] - m.astype(dt)[:, :1]
        if not np.all(np.isfinite(diff)):
            return "overflow"
    s = np.asarray(sigma, dtype=float)
    if np.any(np.isnan(s)):
        return "got NaN"
    if np.any(s < 0):
        return f"got {s.min()}"
    if np.any(np.isinf(s)):
        return "must be finite"
    return None


_FINITE = [0.0, -0.0, 1.0, -1.5, 1e-30, -1e-30, 1e30, -1e30, 3e38, -3e38, 1.7e38, -1.7e38,
           6e4, -6e4, 1e300, -1e300, 1.7e308, -1.7e308]


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 4), st.sampled_from([np.float16, np.float32, np.float64, np.int32]),
       st.data())
def test_value_checks_equal_the_elementwise_checks(n, dtype, data):
    """check_measurement_inputs decides finiteness and overflowing differences by the extremes
    (issue 31, the host time of an eager fine_counts): the same error as the element-wise
    checks for every input — NaN, ±inf, differences that overflow float16/32/64 or sit at the
    edge, scales 1e-30…1e300 — and the same error for sigma (NaN, negative, inf)."""
    with np.errstate(over="ignore", invalid="ignore"):
        # values finite in ``dtype`` (the others are the non-finite ones, drawn apart)
        pool = [v for v in _FINITE if np.isfinite(np.array(v).astype(dtype))]
        if data.draw(st.booleans()):
            pool += [np.inf, -np.inf, np.nan]
        vals = np.array(data.draw(st.lists(st.sampled_from(pool), min_size=6 * n,
                                           max_size=6 * n)))
        if np.issubdtype(dtype, np.integer):
            vals = np.nan_to_num(np.clip(vals, -2e9, 2e9))
        means = vals.astype(dtype).reshape(n, 3, 2)
    sigma = np.array(data.draw(st.lists(st.sampled_from([0.0, 2.0, -1.0, np.inf, np.nan]),
                                        min_size=3, max_size=3))).reshape(1, 3)
    want = _elementwise_check(means, sigma)
    event(str(want))
    # as a NumPy array and as a JAX array (float64 would be narrowed to float32 without x64)
    for m in [means] + ([jnp.asarray(means)] if dtype != np.float64 else []):
        if want is None:
            measurement.check_measurement_inputs(m, sigma, 4)
        else:
            with pytest.raises(ValueError, match=re.escape(want)):
                measurement.check_measurement_inputs(m, sigma, 4)
