"""PQRM measurement model (P eq. 2.9): fused kernel vs classify, closed forms, NumPy oracle."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import norm

from pqrm_jax import calculi, pqrm
from pqrm_jax.pqrm import measurement as M
from pqrm_jax.pqrm.reference import numpy_counts, numpy_state_probabilities

EDC = calculi.get("edc")


def test_fused_kernel_equals_classify_on_continuous_points():
    pts = jax.random.normal(jax.random.key(1), (100_000, 3, 2)) * jnp.array([1.0, 3.0])
    fused = M.edc_states_fused(pts[:, 0], pts[:, 1], pts[:, 2])
    ref = EDC.classify(pts[:, 0], pts[:, 1], pts[:, 2])
    np.testing.assert_array_equal(np.asarray(fused), np.asarray(ref))
    assert set(np.unique(np.asarray(ref)).tolist()) == set(range(20))  # all states exercised


def test_fused_kernel_on_integer_grid_boundaries():
    # every C on a 0.25-grid around A=(0,0), B=(0,1) (scaled by 4 to stay integral): many
    # boundary points; fused equals classify wherever it gives a state, else rejects.
    g = np.arange(-10, 11, dtype=np.float32)
    cx, cy = np.meshgrid(g, g - 2)
    c = np.stack([cx.ravel(), cy.ravel()], -1)
    a = np.zeros_like(c)
    b = np.tile(np.array([[0.0, 4.0]], np.float32), (len(c), 1))
    fused = np.asarray(M.edc_states_fused(a, b, c))
    ref = np.asarray(EDC.classify(a, b, c))
    ok = fused >= 0
    np.testing.assert_array_equal(fused[ok], ref[ok])
    assert (~ok).sum() > 50  # boundary points exist and are rejected
    vals = np.asarray(EDC.constraint_values(a, b, c))
    assert np.all(np.any(vals[~ok] == 0, axis=-1))  # rejected only on a zero constraint
    # A == B is rejected
    assert int(M.edc_states_fused(jnp.zeros(2), jnp.zeros(2), jnp.ones(2))) == -1


def test_kernel_counts_equal_numpy_on_the_same_draws():
    key = jax.random.key(3)
    means = np.asarray(jax.random.uniform(key, (300, 3, 2)) * 100)
    sigma = np.asarray(jax.random.uniform(jax.random.key(4), (300, 3)) * 20)
    s = 700
    got = np.asarray(pqrm.fine_counts(key, "edc", means, sigma, s))
    z = np.asarray(M.sample_bank(key, s, jnp.float32)).reshape(-1, 3, 2)[:s]
    ref = numpy_counts("edc", means[:, None] + sigma[:, None, :, None] * z[None])
    assert got.sum() == ref.sum() == 300 * s
    # NumPy divides (α = u/n ...) and the kernel does not: allow rare rounding flips
    assert np.abs(got - ref).sum() <= 4


def test_statistically_equal_to_independent_numpy_estimator():
    key = jax.random.key(5)
    means = np.asarray(jax.random.uniform(key, (40, 3, 2)) * 30)
    s = 20_000
    p_jax = np.asarray(pqrm.state_probabilities(key, "edc", means, 5.0, s))
    p_np = numpy_state_probabilities(np.random.default_rng(0), "edc", means, 5.0, s)
    sd = np.sqrt(np.maximum(p_np * (1 - p_np), 1e-4) * 2 / s)
    z = np.abs(p_jax - p_np) / sd
    assert z.max() < 5.5, z.max()
    assert np.allclose(p_jax.sum(1), 1.0, atol=1e-5)


@pytest.mark.parametrize("offset", [-2.0, -0.5, 0.0, 0.7, 3.0])
def test_closed_form_only_c_noisy_lr(offset):
    # A, B exact, C ~ N(mean, σ²): P(right of AB) = Φ(x_C / σ) (A=(0,0), B=(0,10))
    sigma = 1.0
    means = np.array([[[0.0, 0.0], [0.0, 10.0], [offset, 4.0]]], np.float32)
    sig = np.array([[0.0, 0.0, sigma]], np.float32)
    s = 40_000
    p = np.asarray(pqrm.state_probabilities(jax.random.key(7), "lr", means, sig, s))[0]
    r = calculi.get("lr").index("r")
    exact = norm.cdf(offset / sigma)
    assert abs(p[r] - exact) <= 4.5 * np.sqrt(max(exact * (1 - exact), 1e-3) / s) + 1e-4


def test_closed_form_only_c_noisy_single_cross_front():
    # front of the mid-perpendicular: P = Φ((β_C − 5) / σ) for A=(0,0), B=(0,10)
    means = np.array([[[0.0, 0.0], [0.0, 10.0], [3.0, b]] for b in (3.0, 5.0, 6.5)], np.float32)
    sig = np.array([[0.0, 0.0, 2.0]] * 3, np.float32)
    s = 40_000
    sc = calculi.get("single_cross")
    p = np.asarray(pqrm.state_probabilities(jax.random.key(8), sc, means, sig, s))
    front = p[:, sc.index("lf")] + p[:, sc.index("rf")]
    exact = norm.cdf((np.array([3.0, 5.0, 6.5]) - 5.0) / 2.0)
    assert np.all(np.abs(front - exact) <= 4.5 * np.sqrt(exact * (1 - exact) / s) + 1e-4)


def test_one_pass_serves_every_merge():
    key = jax.random.key(9)
    means = jax.random.uniform(key, (50, 3, 2)) * 50
    multi = pqrm.multi_state_probabilities(key, calculi.PADGETT_REPRESENTATIONS, means, 8.0,
                                           500)
    fine = np.asarray(multi["edc"])
    for name in calculi.PADGETT_REPRESENTATIONS:
        calc = calculi.get(name)
        single = np.asarray(pqrm.state_probabilities(key, name, means, 8.0, 500))
        np.testing.assert_allclose(np.asarray(multi[name]), single, atol=1e-6)
        agg = np.zeros_like(single)
        np.add.at(agg.T, calc.parent_map, fine.T)
        np.testing.assert_allclose(single, agg, atol=1e-5)


def test_zero_sigma_is_the_classified_state_and_chunking_is_exact():
    key = jax.random.key(10)
    means = jax.random.uniform(key, (1000, 3, 2)) * 100
    p = np.asarray(pqrm.state_probabilities(key, "edc", means, 0.0, 10))
    st = np.asarray(EDC.classify(means[:, 0], means[:, 1], means[:, 2]))
    np.testing.assert_array_equal(p.argmax(1), st)
    assert np.all(p.max(1) == 1.0)
    big = pqrm.fine_counts(key, "edc", means, 3.0, 300)
    small = pqrm.fine_counts(key, "edc", means, 3.0, 300, chunk_triplets=64)
    np.testing.assert_array_equal(np.asarray(big), np.asarray(small))


def test_generic_path_for_a_calculus_not_merged_from_edc():
    key = jax.random.key(11)
    means = jax.random.uniform(key, (20, 3, 2)) * 10
    dcc = calculi.get("dcc")
    p = np.asarray(pqrm.state_probabilities(key, dcc, means, 0.0, 4))
    np.testing.assert_array_equal(p.argmax(1), np.asarray(dcc.classify(means[:, 0],
                                                                       means[:, 1],
                                                                       means[:, 2])))
    p = np.asarray(pqrm.state_probabilities(key, "lr_full", means, 1.0, 200))
    assert np.allclose(p.sum(1), 1.0, atol=1e-5)


def test_bad_inputs_raise_or_give_zero_rows():
    ok = np.zeros((1, 3, 2), np.float32) + np.array([[0, 0], [0, 1], [1, 1]], np.float32)
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="shape"):
        pqrm.state_probabilities(key, "edc", np.zeros((1, 2, 2)), 1.0, 10)
    with pytest.raises(ValueError, match="NaN or infinite"):
        pqrm.state_probabilities(key, "edc", np.where(ok > 0.5, np.nan, ok), 1.0, 10)
    with pytest.raises(ValueError, match="NaN or infinite"):
        pqrm.state_probabilities(key, "edc", np.where(ok > 0.5, np.inf, ok), 1.0, 10)
    with pytest.raises(ValueError, match="non-negative"):
        pqrm.state_probabilities(key, "edc", ok, -1.0, 10)
    with pytest.raises(ValueError, match="NaN"):
        pqrm.state_probabilities(key, "edc", ok, float("nan"), 10)
    with pytest.raises(ValueError, match="num_samples"):
        pqrm.state_probabilities(key, "edc", ok, 1.0, 0)
    # inside jit values are not inspected: non-finite rows are all zeros, never NaN
    bad = jnp.asarray(np.concatenate([ok, np.full((1, 3, 2), np.nan, np.float32)]))
    counts = jax.jit(lambda m: M.root_counts(key, m, 1.0, root=EDC, num_samples=50,
                                              chunk_triplets=8))(bad)
    p = np.asarray(M.counts_to_probabilities(counts))
    assert np.isfinite(p).all() and p[1].sum() == 0 and abs(p[0].sum() - 1) < 1e-6
    # A == B with σ = 0: no defined sample, zero row
    degenerate = np.array([[[1.0, 1.0], [1.0, 1.0], [2.0, 3.0]]], np.float32)
    assert np.asarray(pqrm.state_probabilities(key, "edc", degenerate, 0.0, 5)).sum() == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unrolled_threefry_equals_jax_primitive(seed):
    """``measurement.threefry2x32`` (unrolled, what the bank uses) gives the bits of JAX's
    ``threefry2x32_p`` for random keys and counters, incl. 0 and 2^32 − 1."""
    from jax.extend.random import threefry2x32_p

    rng = np.random.default_rng(seed)
    words = [rng.integers(0, 2**32, size=4096, dtype=np.uint64).astype(np.uint32)
             for _ in range(4)]
    for w in words:
        w[:2] = (0, 2**32 - 1)
    got = M.threefry2x32(*[jnp.asarray(w) for w in words])
    want = threefry2x32_p.bind(*[jnp.asarray(w) for w in words])
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(g), np.asarray(w))


@pytest.mark.parametrize("s", [1, 7, 255, 256, 300, 1000])
def test_sample_bank_is_jax_random_normal(s):
    """The bank (unrolled threefry, one flat array) holds exactly ``jax.random.normal(key,
    (S, 6))``, eagerly and under ``vmap`` over keys, NaN-padded to whole chunks."""
    for key in (jax.random.key(s), jax.random.PRNGKey(s + 1)):
        z = np.asarray(M.sample_bank(key, s, jnp.float32)).reshape(-1, 6)
        np.testing.assert_array_equal(z[:s], np.asarray(jax.random.normal(key, (s, 6))))
        assert np.isnan(z[s:]).all()
    keys = jax.random.split(jax.random.key(7), 3)
    zb = jax.jit(jax.vmap(lambda k: M.sample_bank(k, s, jnp.float32)))(keys)
    for i in range(3):
        np.testing.assert_array_equal(np.asarray(zb[i]).reshape(-1, 6)[:s],
                                      np.asarray(jax.random.normal(keys[i], (s, 6))))


@pytest.mark.parametrize("s", [300, 300_000])  # one bank; streamed (the eager host loop)
def test_counts_equal_eager_staged_and_batched(s):
    """An eager call runs its own program with the kernel's XLA options
    (``KERNEL_COMPILER_OPTIONS``, which JAX refuses on a nested jit); inside an outer ``jit``
    — inputs traced or closed over — and under ``vmap`` the plain program runs: the counts are
    the same in all four."""
    rng = np.random.default_rng(5)
    m = rng.uniform(-3, 3, (37, 3, 2)).astype(np.float32)
    sig = rng.uniform(0, 0.8, (37, 3)).astype(np.float32)
    k = jax.random.key(11)
    eager = np.asarray(pqrm.fine_counts(k, "edc", m, sig, s, chunk_triplets=16))
    got = [jax.jit(lambda: pqrm.fine_counts(k, "edc", m, sig, s, chunk_triplets=16))(),
           jax.jit(lambda mm: pqrm.fine_counts(k, "edc", mm, sig, s, chunk_triplets=16))(m),
           jax.vmap(lambda mm: pqrm.fine_counts(k, "edc", mm, sig, s, chunk_triplets=16))(
               m[None])[0]]
    for g in got:
        assert np.array_equal(np.asarray(g), eager)
    assert 37 * s - 10 <= eager.sum() <= 37 * s  # a rare sample on a boundary is rejected
