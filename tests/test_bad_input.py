"""Property-based bad-input suite (hypothesis) for the public entry points.

Strategies range over scales 1e-30…1e30, dtypes (int32/int64/float16/float32/float64/
complex), shapes and NaN/inf placements. The contract of every entry point: it returns its
documented result (a state or a documented sentinel, a proper distribution, a map state) or
raises ``ValueError``/``TypeError`` — never a plausible wrong answer, a NaN or another
exception. Two properties close the suite: classification is invariant under power-of-two
scaling (exactly: a power of two changes no mantissa bit) and coincident points get their
coincidence relation for any float coordinates (a vectorised 100 000-case check).

Inputs owned by the entry-point-guard work (D23 empty triple batches, D24 infinite sensor
sigma) are kept out of the strategies and held by the two plain tests at the end.
"""

from __future__ import annotations

from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi, compositions, pqrm, qrm
from pqrm_jax import sim as psim
from pqrm_jax.calculi import BOUNDARY, DEGENERATE, INVALID

SETTINGS = settings(max_examples=15, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])
NAMES = ("edc", "edc_lune", "triple_cross", "double_cross", "single_cross", "lr", "quadrant",
         "dcc", "lr_full")
DTYPES = ("int32", "int64", "float16", "float32", "float64", "complex64")
FLOAT_SCALES = st.sampled_from([1e-30, 1e-20, 1e-10, 1e-3, 1.0, 7.5, 1e3, 1e10, 1e20, 1e30])
SPECIALS = (np.nan, np.inf, -np.inf)


@cache
def _mapper(reps: tuple[str, ...], m: int, s: int):
    return pqrm.mapper(reps, m, s)  # one compiled map per configuration, not per example


@st.composite
def point_arrays(draw, n_max=6):
    """(a, b, c, dtype) coordinate arrays of one batch shape, with NaN/inf placements."""
    dtype = draw(st.sampled_from(DTYPES))
    n = draw(st.integers(1, n_max))
    seed = draw(st.integers(0, 2**16))
    scale = draw(FLOAT_SCALES)
    rng = np.random.default_rng(seed)
    if dtype.startswith("int"):
        hi = 2**62 if dtype == "int64" else 2**30
        mag = int(min(hi, max(1, scale)))
        P = rng.integers(-mag, mag, (n, 3, 2), dtype=np.int64).astype(dtype)
    else:
        P = rng.uniform(-3, 3, (n, 3, 2)) * scale
        if draw(st.booleans()):  # special values at random places
            k = draw(st.integers(1, 3))
            idx = rng.integers(0, P.size, k)
            P.reshape(-1)[idx] = rng.choice(SPECIALS, k)
        if draw(st.booleans()):  # a coincidence
            i, j = draw(st.sampled_from([(0, 1), (1, 2), (0, 2)]))
            P[:, j] = P[:, i]
        with np.errstate(over="ignore", invalid="ignore"):
            P = P.astype(dtype)
    return P[:, 0], P[:, 1], P[:, 2], dtype


@SETTINGS
@given(name=st.sampled_from(NAMES), pts=point_arrays())
def test_classify_returns_documented_results(name, pts):
    c = calculi.get(name)
    a, b, cc, dtype = pts
    if dtype.startswith("complex"):
        with pytest.raises(TypeError, match="complex"):
            c.classify(a, b, cc)
        return
    out = np.asarray(c.classify(a, b, cc))
    assert out.shape == a.shape[:-1] and out.dtype == np.int32
    assert np.all((out >= INVALID) & (out < c.num_states))
    finite = np.all(np.isfinite(np.stack([a, b, cc]).astype(np.float64)), axis=(0, -1))
    assert np.all(out[~finite] == INVALID)
    if c.boundary_inclusive:  # a state for every finite configuration (or INVALID)
        assert not np.any(np.isin(out, (BOUNDARY, DEGENERATE)))
    labels = c.labels(out)
    assert len(labels) == out.size and all(isinstance(x, str) for x in labels)


@SETTINGS
@given(name=st.sampled_from(NAMES), shape=st.sampled_from([(3,), (2, 3), (), (4, 1)]),
       dtype=st.sampled_from(["float32", "object", "bool", "<U3"]))
def test_classify_bad_shapes_and_dtypes(name, shape, dtype):
    c = calculi.get(name)
    good = np.zeros((2,), np.float32)
    bad = np.zeros(shape, np.float32).astype(dtype) if dtype != "object" else \
        np.array([None, None], dtype=object)
    with pytest.raises((ValueError, TypeError)):
        c.classify(bad, good, good + 1)


@SETTINGS
@given(idx=st.lists(st.integers(-10, 30), min_size=1, max_size=6),
       name=st.sampled_from(NAMES))
def test_labels_documented(idx, name):
    c = calculi.get(name)
    ok = all(-3 <= i < c.num_states for i in idx)
    if ok:
        out = c.labels(idx)
        assert [x in ("BOUNDARY", "DEGENERATE", "INVALID") for x in out] == [i < 0 for i in idx]
    else:
        with pytest.raises(ValueError, match="not a state index"):
            c.labels(idx)


# properties -----------------------------------------------------------------------------------
@settings(max_examples=20, deadline=None, derandomize=True)
@given(name=st.sampled_from(NAMES), seed=st.integers(0, 2**16), k=st.integers(-99, 99),
       dtype=st.sampled_from(["float32", "float64"]))
def test_scale_invariance_property(name, seed, k, dtype):
    """classify(2^k · P + t) == classify(P + t) for random P: exact for powers of two."""
    c = calculi.get(name)
    rng = np.random.default_rng(seed)
    with jax.enable_x64(dtype == "float64"):
        P = rng.uniform(-3, 3, (400, 3, 2)).astype(dtype)
        P[:50, 2] = P[:50, 1]  # coincidences and boundaries survive too
        P[50:100, 2] = P[50:100, 0] + 0.5 * (P[50:100, 1] - P[50:100, 0])
        ref = np.asarray(c.classify(P[:, 0], P[:, 1], P[:, 2]))
        Q = P * np.asarray(2.0**k, dtype)
        got = np.asarray(c.classify(Q[:, 0], Q[:, 1], Q[:, 2]))
    assert np.array_equal(got, ref)


@settings(max_examples=6, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), scale=FLOAT_SCALES,
       name=st.sampled_from(["lr_full", "dcc"]))
def test_coincidence_property_100k(seed, scale, name):
    """C = B, C = A, A = B, A = B = C on 100 000 random non-integer floats, under jit."""
    c = calculi.get(name)
    rng = np.random.default_rng(seed)
    A = (rng.uniform(-1, 1, (100_000, 2)) * scale).astype(np.float32)
    B = (rng.uniform(-1, 1, (100_000, 2)) * scale).astype(np.float32)
    keep = np.any(A != B, axis=-1)
    f = jax.jit(c.classify)
    want = {"lr_full": ("e", "s", "dou", "tri"), "dcc": ("5", "11", "dou", "tri")}[name]
    for (a, b, x), lab in zip(((A, B, B), (A, B, A), (A, A, B), (A, A, A)), want, strict=True):
        out = np.asarray(f(a, b, x))
        sel = keep if lab != "tri" else slice(None)
        assert np.all(out[sel] == c.index(lab)), (lab, np.unique(out[sel]))


# pqrm -----------------------------------------------------------------------------------------
@st.composite
def measurements(draw):
    dtype = draw(st.sampled_from(DTYPES))
    n = draw(st.sampled_from([1, 3]))
    scale = draw(FLOAT_SCALES)
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    M = rng.uniform(0, 10, (n, 3, 2)) * scale
    special = draw(st.booleans()) and not dtype.startswith("int")
    if special:
        M.reshape(-1)[rng.integers(0, M.size)] = rng.choice(SPECIALS)
    with np.errstate(over="ignore", invalid="ignore"):
        M = M.astype(dtype) if not dtype.startswith("int") else \
            np.clip(M, -2**30, 2**30).astype(dtype)
    sigma = draw(st.sampled_from([0.0, 0.5, -1.0, np.nan, np.inf, "scaled", "per_landmark",
                                  "complex"]))
    if sigma == "scaled":
        sigma = 0.1 * scale
    elif sigma == "per_landmark":
        sigma = np.full((n, 3), 0.2 * scale)
    elif sigma == "complex":
        sigma = 0.5 + 0.5j
    num_samples = draw(st.sampled_from([1, 64, 0, -5, True, 2.5, 2**31]))
    return M, sigma, num_samples


@SETTINGS
@given(meas=measurements(), name=st.sampled_from(["edc", "lr", "dcc"]))
def test_state_probabilities_documented(meas, name):
    M, sigma, num_samples = meas
    c = calculi.get(name)
    try:
        p = np.asarray(pqrm.state_probabilities(jax.random.key(0), name, M, sigma, num_samples))
    except (ValueError, TypeError) as err:
        assert str(err)
        bad = (np.iscomplexobj(M) or np.iscomplexobj(sigma) or isinstance(num_samples, bool)
               or not isinstance(num_samples, int) or not 1 <= num_samples < 2**31
               or not np.all(np.isfinite(M)) or np.any(np.isnan(sigma))
               or np.any(np.asarray(sigma, complex).real < 0)
               or np.any(np.isinf(np.asarray(sigma, complex))))
        if not bad:  # the only other refusal: differences that overflow the dtype
            assert "overflow" in str(err)
        return
    assert p.shape == (M.shape[0], c.num_states)
    assert not np.any(np.isnan(p))
    sums = p.sum(-1)
    assert np.all((np.abs(sums - 1) < 1e-5) | (sums == 0))


@SETTINGS
@given(pts=point_arrays(n_max=1), vis=st.lists(st.booleans(), min_size=4, max_size=4),
       sigma=st.sampled_from([0.0, 0.3, -1.0, np.nan, np.inf]))
def test_mapper_update_documented(pts, vis, sigma):
    a, b, c, dtype = pts
    pos = np.concatenate([a, b, c, a + 1 if not dtype.startswith("int") else a])
    pq = _mapper(("edc", "lr"), 4, 16)
    try:
        st_, _ = pq.update(pq.init(), jax.random.key(1), pos, np.asarray(vis), sigma)
    except (ValueError, TypeError) as err:
        assert dtype.startswith("complex") or not (sigma >= 0 and np.isfinite(sigma)), err
        return
    for probs in st_.probs.values():
        p = np.asarray(probs)
        assert not np.any(np.isnan(p))
        s = p.sum(-1)
        assert np.all((np.abs(s - 1) < 1e-5) | (s == 0))
    assert int(st_.step) == 1


@SETTINGS
@given(ids=st.lists(st.integers(-2, 6), max_size=5),
       scale=FLOAT_SCALES, special=st.booleans())
def test_update_observed_documented(ids, scale, special):
    pq = _mapper(("lr",), 5, 8)
    pos = np.random.default_rng(len(ids)).uniform(0, 10, (len(ids), 2)) * scale
    if special and len(ids):
        pos[0, 0] = np.nan
    try:
        st_, _ = pqrm.update_observed(pq, pq.init(), jax.random.key(0), np.asarray(ids, int), pos,
                                   0.1 * scale)
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    assert int(st_.step) == 1
    assert not np.any(np.isnan(np.asarray(st_.probs["lr"])))


@SETTINGS
@given(tri=st.lists(st.lists(st.integers(-1, 7), min_size=3, max_size=3), min_size=0,
                    max_size=4))
def test_sparse_triplets_documented(tri):
    try:
        pq = pqrm.mapper(("lr",), 6, 8, triplets=np.asarray(tri, int).reshape(-1, 3))
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    assert pq.init().probs["lr"].shape == (len(tri), 2)


# qrm measurement, compositions, sim -----------------------------------------------------------
@settings(max_examples=12, deadline=None, derandomize=True)
@given(seed=st.integers(0, 99), special=st.booleans(),
       dtype=st.sampled_from(["float32", "float64", "int32", "complex64"]),
       shape=st.sampled_from([(2, 3), (2, 2), (3,)]))
def test_qrm_measure_triples_documented(seed, special, dtype, shape):
    rng = np.random.default_rng(seed)
    bearings = rng.uniform(-np.pi, np.pi, shape)
    if special:
        bearings.reshape(-1)[0] = np.nan
    with np.errstate(invalid="ignore"):
        bearings = bearings.astype(dtype)
    try:
        m = qrm.measure_triples(bearings, "edc")
    except (ValueError, TypeError) as err:
        assert str(err)
        assert special or shape != (2, 3) or dtype == "complex64", err
        return
    assert shape == (2, 3) and not special and dtype != "complex64"
    sets = np.asarray(m.sets)
    assert sets.shape == (2, 3) and np.all(sets > 0)  # every triple keeps a possible state


@SETTINGS
@given(mask=st.one_of(st.integers(-5, 2**22), st.sampled_from([1 << 20, 1 << 25, True])))
def test_states_of_documented(mask):
    try:
        labs = qrm.states_of("edc", mask)
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    assert qrm.mask_of("edc", labs) == mask


@SETTINGS
@given(tri=st.lists(st.text(alphabet="ABCDEA1", min_size=0, max_size=4), max_size=4))
def test_compositions_documented(tri):
    try:
        out = compositions.is_composable(tri)
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    assert isinstance(out, bool)


@settings(max_examples=8, deadline=None, derandomize=True)
@given(n=st.sampled_from([-2, 0, 1, 7, 2.5, True, "3", None]))
def test_sim_uniform_landmarks_documented(n):
    try:
        lm = psim.uniform_landmarks(jax.random.key(0), n)
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    lm = np.asarray(lm)
    assert lm.shape == (n, 2) and np.all(np.isfinite(lm))


@SETTINGS
@given(scale=FLOAT_SCALES, special=st.booleans(), sigma=st.sampled_from([0.0, 1.0, -1.0]))
def test_sim_observe_documented(scale, special, sigma):
    lm = np.array([[10.0, 0.0], [0.0, 20.0], [5.0, 5.0]]) * scale
    pose = np.zeros(3)
    if special:
        lm[1, 0] = np.nan
    try:
        obs = psim.observe(jax.random.key(0), pose, lm,
                           psim.SensorParams(max_range=60.0 * scale, sigma=sigma * scale))
    except (ValueError, TypeError) as err:
        assert str(err)
        return
    for leaf in jax.tree_util.tree_leaves(obs):
        leaf = np.asarray(leaf)
        assert leaf.shape[0] == 3 or leaf.ndim == 0


# inputs owned by the entry-point-guard work (D23, D24; merged from branch store) -------------
def test_measure_triples_empty_batch():  # D23, fixed on branch store
    with pytest.raises(ValueError):
        qrm.measure_triples(jnp.zeros((0, 3)), "edc")


def test_sensor_params_infinite_sigma():  # D24, fixed on branch store
    with pytest.raises(ValueError):
        psim.observe(jax.random.key(0), jnp.zeros(3), jnp.ones((3, 2)),
                     psim.SensorParams(max_range=60.0, sigma=float("inf")))
