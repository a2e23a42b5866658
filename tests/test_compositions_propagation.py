"""Probabilistic composition (Z eq. 2.4 / 4.28) and propagation over a PQRM map."""

import doctest

import jax
import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.compositions import propagation, simulation
from pqrm_jax.compositions.propagation import (
    check_map,
    check_tensor,
    compose,
    fuse,
    propagate,
    propagate_loop,
)


def _random_tensor(q, seed=0, impossible=()):
    rng = np.random.default_rng(seed)
    t = rng.dirichlet(np.full(q, 0.4), size=(q, q)).astype(np.float32)
    for a, b in impossible:
        t[a, b] = 0
    return t


def _random_map(n, q, fraction, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.dirichlet(np.full(q, 0.5), size=(n, n, n)).astype(np.float32)
    i, j, k = np.ogrid[:n, :n, :n]
    obs = (i != j) & (j != k) & (i != k) & (rng.random((n, n, n)) < fraction)
    return p, obs


def _all_orderings(mask):
    """A PQRM map observes every ordering of a measured triplet (P§2.3)."""
    m = mask.copy()
    for perm in ((0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        m |= mask.transpose(perm)
    return m


def test_doctests():
    for mod in (propagation, simulation):
        res = doctest.testmod(mod)
        assert res.failed == 0 and res.attempted > 0, mod.__name__


def test_compose_is_eq_2_4():
    q = 5
    t = _random_tensor(q)
    rng = np.random.default_rng(1)
    p1, p2 = rng.dirichlet(np.ones(q)), rng.dirichlet(np.ones(q))
    expect = sum(p1[a] * p2[b] * t[a, b] for a in range(q) for b in range(q))
    np.testing.assert_allclose(compose(p1, p2, t), expect / expect.sum(), atol=1e-6)
    # point masses pick the table row
    np.testing.assert_allclose(compose(np.eye(q)[2], np.eye(q)[4], t), t[2, 4], atol=1e-6)
    # impossible pair → zeros, never NaN
    t0 = _random_tensor(q, impossible=[(2, 4)])
    assert np.all(np.asarray(compose(np.eye(q)[2], np.eye(q)[4], t0)) == 0)


def test_fuse_rule():
    a = np.array([0.7, 0.2, 0.1])
    b = np.array([0.5, 0.1, 0.4])
    # eps=0, w=1: naive Bayes product under a uniform prior
    np.testing.assert_allclose(fuse(np.stack([a, b]), eps=0.0), a * b / (a * b).sum(), atol=1e-6)
    # weight 0 removes a source; one source is returned unchanged
    np.testing.assert_allclose(fuse(np.stack([a, b]), weights=[1.0, 0.0], eps=0.0), a, atol=1e-6)
    # disjoint supports: no NaN, a proper distribution
    out = np.asarray(fuse(np.stack([[1.0, 0, 0], [0, 1.0, 0]]), eps=0.0))
    assert np.isfinite(out).all() and out.min() >= 0 and abs(out.sum() - 1) < 1e-6
    out = np.asarray(fuse(np.stack([[1.0, 0, 0], [0, 1.0, 0]]), eps=0.1))
    assert out[2] < out[0] == pytest.approx(out[1])


@pytest.mark.parametrize("mode", ["fill", "fuse"])
def test_batched_matches_per_triplet_loop(mode):
    q, n = 6, 9
    t = _random_tensor(q, seed=3, impossible=[(0, 1), (5, 5)])
    p, obs = _random_map(n, q, 0.35, seed=4)
    res = propagate(p, obs, t, mode=mode, batch_size=2)
    for backend in ("numpy", "jax") if mode == "fuse" else ("numpy",):
        ref, cnt = propagate_loop(p, obs, t, mode=mode, backend=backend)
        np.testing.assert_allclose(np.asarray(res.probs), ref, atol=2e-6)
        np.testing.assert_array_equal(np.asarray(res.n_paths), cnt)
    # path counts from first principles on one target
    i, j, d = np.argwhere(np.asarray(res.filled))[0]
    ks = [k for k in range(n) if k not in (i, j, d) and obs[i, j, k] and obs[j, k, d]
          and np.einsum("a,b,abc->", p[i, j, k], p[j, k, d], t) > 1e-12]
    assert res.n_paths[i, j, d] == len(ks)


def test_propagation_output_is_always_a_distribution():
    q, n = 4, 7
    t = _random_tensor(q, seed=5)
    t[:, :, 3] = 0  # state 3 never composed ...
    t /= t.sum(-1, keepdims=True)
    p, obs = _random_map(n, q, 0.5, seed=6)
    p[obs] = np.eye(q)[3]  # ... but every measurement says state 3: sources disagree totally
    p[~obs] = np.nan       # unobserved rows may hold anything
    for mode in ("fill", "fuse"):
        for eps in (0.0, 0.05):
            r = propagate(p, obs, t, mode=mode, eps=eps, rounds=3)
            out = np.asarray(r.probs)
            i, j, k = np.ogrid[:n, :n, :n]
            dist = (i != j) & (j != k) & (i != k)
            assert np.isfinite(out).all() and out.min() >= 0
            np.testing.assert_allclose(out[dist].sum(-1), 1.0, atol=1e-5)


def test_fill_keeps_observed_and_fills_reachable():
    q, n = 5, 8
    t = _random_tensor(q, seed=7)
    p, obs = _random_map(n, q, 0.3, seed=8)
    r = propagate(p, obs, t, mode="fill")
    np.testing.assert_array_equal(np.asarray(r.probs)[obs], p[obs])
    filled = np.asarray(r.filled)
    assert not (filled & obs).any() and filled.sum() > 0
    assert (np.asarray(r.n_paths)[filled] > 0).all()
    # unfilled unobserved targets get the (uniform) prior
    i, j, k = np.ogrid[:n, :n, :n]
    rest = (i != j) & (j != k) & (i != k) & ~obs & ~filled
    np.testing.assert_allclose(np.asarray(r.probs)[rest], 1.0 / q)
    # more rounds reach more triplets, never fewer
    r3 = propagate(p, obs, t, mode="fill", rounds=3)
    assert (np.asarray(r3.filled) >= filled).all() and np.asarray(r3.filled).sum() > filled.sum()


def test_exact_deterministic_composition_recovered():
    # a 2-state "calculus" whose composition is c = a xor b. The labelling
    # state(ij:k) = b_j xor b_k is consistent with it: (b_j^b_k) ^ (b_k^b_d) = b_j^b_d.
    t = np.eye(2, dtype=np.float32)[np.arange(2)[:, None] ^ np.arange(2)]
    n = 7
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2, n)
    i, j, k = np.ogrid[:n, :n, :n]
    dist = (i != j) & (j != k) & (i != k)
    truth = (bits[None, :, None] ^ bits[None, None, :]) * np.ones((n, n, n), int)
    assert 0 < truth[dist].mean() < 1
    obs = _all_orderings(dist & (rng.random((n, n, n)) < 0.15))
    p = np.eye(2, dtype=np.float32)[truth]
    r = propagate(p, obs, t, eps=0.0, rounds=4)
    f = np.asarray(r.filled)
    assert f.sum() > 0.8 * (dist & ~obs).sum()
    out = np.asarray(r.probs)
    assert (out[f].argmax(-1) == truth[f]).all()
    assert out[f].max(-1).min() > 0.999
    # noisy but informative measurements: fusing paths sharpens the observed triplets
    noisy = np.where(np.eye(2, dtype=bool)[truth][..., None].squeeze(-1), 0.7, 0.3)
    noisy = noisy.astype(np.float32)
    obs2 = dist & (rng.random((n, n, n)) < 0.8)
    fused = np.asarray(propagate(noisy, obs2, t, mode="fuse").probs)
    pt_before = noisy[obs2][np.arange(obs2.sum()), truth[obs2]]
    pt_after = fused[obs2][np.arange(obs2.sum()), truth[obs2]]
    assert pt_after.mean() > pt_before.mean() + 0.05


def test_bad_input():
    q, n = 3, 5
    t = _random_tensor(q)
    p, obs = _random_map(n, q, 0.5)
    with pytest.raises(ValueError, match="repeats a landmark"):
        o = obs.copy()
        o[1, 1, 2] = True
        propagate(p, o, t)
    with pytest.raises(ValueError, match="negative"):
        pp = p.copy()
        idx = tuple(np.argwhere(obs)[0])
        pp[idx] = [1.5, -0.5, 0.0]
        propagate(pp, obs, t)
    with pytest.raises(ValueError, match="sums to"):
        pp = p.copy()
        pp[tuple(np.argwhere(obs)[0])] *= 2
        propagate(pp, obs, t)
    pp = p.copy()
    pp[obs] *= 3
    r = propagate(pp, obs, t, renormalize=True)  # documented handling
    np.testing.assert_allclose(np.asarray(r.probs)[obs], p[obs], atol=1e-6)
    with pytest.raises(ValueError, match="NaN"):
        pp = p.copy()
        pp[tuple(np.argwhere(obs)[0])] = np.nan
        propagate(pp, obs, t)
    with pytest.raises(ValueError, match=r"\(Q, Q, Q\)"):
        check_tensor(np.ones((3, 3)))
    with pytest.raises(ValueError, match="sums to"):
        check_tensor(np.ones((3, 3, 3)))
    with pytest.raises(ValueError, match="negative"):
        check_tensor(-np.ones((3, 3, 3)))
    with pytest.raises(ValueError, match="states"):
        propagate(p, obs, _random_tensor(4))
    with pytest.raises(ValueError, match="shape"):
        check_map(p[:, :, :4], obs)
    with pytest.raises(ValueError, match="mode"):
        propagate(p, obs, t, mode="sharpen")
    with pytest.raises(ValueError, match="eps"):
        propagate(p, obs, t, eps=1.5)
    with pytest.raises(ValueError, match="prior"):
        propagate(p, obs, t, prior=[1.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def sampled():
    calc = calculi.get("single_cross")
    t, counts = simulation.sample_compose_tensor(calc, jax.random.key(0), 100_000, chunk=50_000)
    return calc, t, counts


def test_sampled_tensor_is_mirror_symmetric(sampled):
    calc, t, counts = sampled
    assert counts.sum() == 100_000
    q = calc.num_states
    assert (counts > 0).all()
    np.testing.assert_allclose(t.sum(-1), 1.0, atol=1e-5)
    # symmetry: mirroring the whole configuration maps states to mirrored states, so
    # P(c | a, b) must equal P(m(c) | m(a), m(b)) up to sampling error
    pts = jax.random.uniform(jax.random.key(1), (4000, 3, 2))
    s = np.asarray(calc.classify(pts[:, 0], pts[:, 1], pts[:, 2]))
    ms = np.asarray(calc.classify(pts[:, 0] * np.array([-1, 1]), pts[:, 1] * np.array([-1, 1]),
                                  pts[:, 2] * np.array([-1, 1])))
    mirror = np.zeros(q, int)
    mirror[s] = ms
    tm = t[np.ix_(mirror, mirror, mirror)]
    assert np.abs(tm - t).max() < 0.05


def test_propagation_helps_on_simulated_map(sampled):
    calc, t, _ = sampled
    r = simulation.heldout_study(calc, t, jax.random.key(0), num_landmarks=9, fraction=0.5,
                                 sigma=5.0, runs=1, samples=64, rounds=2)
    base, prop = r["heldout/uniform"], r["heldout/propagated"]
    marg = r["heldout/marginal"]
    assert prop["coverage"] > 0.6
    assert prop["error"] < marg["error"] - 0.1 and prop["error"] < base["error"] - 0.1
    assert prop["entropy"] < base["entropy"] - 0.1
    assert prop["nll"] < min(base["nll"], marg["nll"])


def test_pqrm_adapter(sampled):
    from pqrm_jax import pqrm
    from pqrm_jax.compositions.propagation import from_pqrm, to_pqrm_rows

    calc, t, _ = sampled
    pq = pqrm.mapper((calc.name,), num_landmarks=6, num_samples=64)
    st = pq.init()
    pos = jax.random.uniform(jax.random.key(0), (6, 2)) * 100
    for ids in ([0, 1, 2, 3], [2, 3, 4, 5]):
        vis = np.isin(np.arange(6), ids)
        st, _ = pq.update(st, jax.random.key(ids[0]), pos, vis, 2.0)
    probs, obs = from_pqrm(st, 6, calc.name)
    assert obs.sum() == 2 * 24  # two quartets, 4 triplets × 6 orderings each, none shared
    np.testing.assert_allclose(to_pqrm_rows(probs, 6), np.asarray(st.probs[calc.name]))
    r = propagate(probs, obs, t, renormalize=True)
    assert np.asarray(r.filled).sum() > 0
    truth = simulation.true_states(calc, pos)
    f = np.asarray(r.filled)
    assert (np.asarray(r.probs)[f].argmax(-1) == truth[f]).mean() > 0.5


def test_heldout_study_refuses_fractions_without_held_out_or_observed_triplets():
    calc = calculi.get("lr")
    t = calc.tables.prob_compose
    for frac in (0.0, 1.0, -0.5, float("nan")):
        with pytest.raises(ValueError, match="fraction"):
            simulation.heldout_study(calc, t, jax.random.key(0), num_landmarks=6, fraction=frac)


def test_score_of_an_empty_mask_is_the_documented_sentinel():
    p = np.full((4, 2), 0.5)
    r = simulation.score(p, np.zeros(4, int), np.zeros(4, bool))
    assert r["n"] == 0 and all(np.isnan(r[k]) for k in ("error", "entropy", "nll", "brier"))
