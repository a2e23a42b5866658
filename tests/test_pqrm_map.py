"""PQRM online map (P eq. 2.10, Alg. 1) and metrics (eq. 2.11, Figs 2.6–2.16)."""

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi, pqrm
from pqrm_jax.pqrm import metrics

POS = jnp.array([[0.0, 0.0], [0.0, 10.0], [4.0, 4.0], [-6.0, 2.0]])
ALL = jnp.ones(4, bool)

# docs/decisions.md §2.1 EDC conceptual neighbourhood (test fixture only)
EDC_NEIGHBOURS = {
    1: (2, 3, 4, 5, 6), 2: (1, 3, 4, 9, 10), 3: (1, 2, 4, 5, 6, 7, 8),
    4: (1, 2, 3, 7, 8, 9, 10), 5: (1, 3, 6, 7, 11, 12, 13), 6: (1, 3, 5, 7, 11, 12, 13),
    7: (3, 4, 5, 6, 8, 11, 12, 13, 14), 8: (3, 4, 7, 9, 10, 13, 14, 15, 16),
    9: (2, 4, 8, 10, 14, 15, 16), 10: (2, 4, 8, 9, 14, 15, 16), 11: (5, 6, 7, 12, 13, 17, 19),
    12: (5, 6, 7, 11, 13, 17, 19), 13: (5, 6, 7, 8, 11, 12, 14, 17, 18),
    14: (7, 8, 9, 10, 13, 15, 16, 17, 18), 15: (8, 9, 10, 14, 16, 18, 20),
    16: (8, 9, 10, 14, 15, 18, 20), 17: (11, 12, 13, 14, 18, 19, 20),
    18: (13, 14, 15, 16, 17, 19, 20), 19: (11, 12, 17, 18, 20), 20: (15, 16, 17, 18, 19),
}


def _fixture_distances():
    d = np.full((20, 20), -1, int)
    for s in range(20):
        d[s, s] = 0
        q = deque([s])
        while q:
            u = q.popleft()
            for v in EDC_NEIGHBOURS[u + 1]:
                if d[s, v - 1] < 0:
                    d[s, v - 1] = d[s, u] + 1
                    q.append(v - 1)
    return d


@pytest.fixture(scope="module")
def pq():
    return pqrm.mapper(("edc", "lr"), num_landmarks=4, num_samples=200)


def test_ordered_triplets():
    t = pqrm.ordered_triplets(5)
    assert t.shape == (60, 3) and len({tuple(x) for x in t}) == 60
    assert np.all((t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2]))
    with pytest.raises(ValueError, match="at least three"):
        pqrm.ordered_triplets(2)
    with pytest.raises(ValueError, match="at least three"):
        pqrm.mapper(("edc",), num_landmarks=2)


def test_bayes_update_matches_eq_2_10(pq):
    k1, k2 = jax.random.key(1), jax.random.key(2)
    vis = jnp.array([True, True, True, False])
    pos2 = POS + 0.7
    st, _ = pq.update(pq.init(), k1, POS, vis, 3.0)
    st, _ = pq.update(st, k2, pos2, vis, 3.0)
    tri = pq.triplets
    seen = np.all(np.asarray(vis)[tri], axis=1)
    assert np.array_equal(np.asarray(st.mapped), seen) and seen.sum() == 6  # all orderings
    for name in ("edc", "lr"):
        m1 = np.asarray(pqrm.state_probabilities(k1, name, POS[tri], 3.0, 200))
        m2 = np.asarray(pqrm.state_probabilities(k2, name, pos2[tri], 3.0, 200))
        post = m1 * m2
        post = post / post.sum(1, keepdims=True)
        np.testing.assert_allclose(np.asarray(st.probs[name])[seen], post[seen], atol=1e-6)
        assert np.all(np.asarray(st.probs[name])[~seen] == 0)  # unobserved: unmapped
    assert np.asarray(st.num_updates)[seen].tolist() == [2] * 6


def test_unobserved_unchanged_new_initialised(pq):
    st, _ = pq.update(pq.init(), jax.random.key(1), POS, jnp.array([1, 1, 1, 0], bool), 2.0)
    before = {k: np.asarray(v) for k, v in st.probs.items()}
    st2, _ = pq.update(st, jax.random.key(2), POS, jnp.array([1, 1, 0, 1], bool), 2.0)
    tri = pq.triplets
    s1 = np.all(np.array([1, 1, 1, 0], bool)[tri], 1)
    s2 = np.all(np.array([1, 1, 0, 1], bool)[tri], 1)
    new = s2 & ~s1
    untouched = s1 & ~s2
    meas = np.asarray(pqrm.state_probabilities(jax.random.key(2), "edc", POS[tri], 2.0, 200))
    np.testing.assert_allclose(np.asarray(st2.probs["edc"])[new], meas[new], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(st2.probs["edc"])[untouched],
                                  before["edc"][untouched])


def test_conflict_keeps_prior_and_is_counted(pq):
    vis = jnp.array([True, True, True, False])
    right = POS
    left = POS.at[2, 0].set(-4.0)
    st, _ = pq.update(pq.init(), jax.random.key(1), right, vis, 0.0)
    st2, _ = pq.update(st, jax.random.key(2), left, vis, 0.0)
    for name in ("edc", "lr"):
        p = np.asarray(st2.probs[name])
        assert np.isfinite(p).all()
        np.testing.assert_array_equal(p, np.asarray(st.probs[name]))
        assert int(st2.num_conflicts[name].sum()) == 6


def test_rejected_and_dropped_measurements_never_nan(pq):
    on_line = POS.at[2].set(jnp.array([0.0, 5.0]))  # C on AB, σ = 0: no defined sample
    st, _ = pq.update(pq.init(), jax.random.key(1), on_line, jnp.array([1, 1, 1, 0], bool), 0.0)
    assert int(st.num_rejected.sum()) == 6 and not bool(st.mapped.any())
    nan_pos = POS.at[3].set(jnp.nan)
    st, _ = pq.update(pq.init(), jax.random.key(1), nan_pos, ALL, 1.0)
    assert int(st.num_dropped) == 1 and int(st.mapped.sum()) == 6
    assert all(np.isfinite(np.asarray(v)).all() for v in st.probs.values())


def test_update_validation(pq):
    st = pq.init()
    k = jax.random.key(0)
    with pytest.raises(ValueError, match="non-negative"):
        pq.update(st, k, POS, ALL, -1.0)
    with pytest.raises(ValueError, match="non-negative"):
        pq.update(st, k, POS, ALL, float("nan"))
    with pytest.raises(ValueError, match="shape"):
        pq.update(st, k, POS[:3], ALL, 1.0)
    with pytest.raises(ValueError, match="duplicate"):
        pqrm.update_observed(pq, st, k, [0, 1, 1], np.asarray(POS[:3]), 1.0)
    with pytest.raises(ValueError, match="NaN or infinite"):
        pqrm.update_observed(pq, st, k, [0, 1, 2], np.asarray(POS[:3]) * np.nan, 1.0)
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        pqrm.update_observed(pq, st, k, [0, 1, 7], np.asarray(POS[:3]), 1.0)
    two, _ = pqrm.update_observed(pq, st, k, [0, 1], np.asarray(POS[:2]), 1.0)
    assert not bool(two.mapped.any()) and int(two.step) == 1
    three, _ = pqrm.update_observed(pq, st, k, [3, 0, 1], np.asarray(POS)[[3, 0, 1]], 1.0)
    assert int(three.mapped.sum()) == 6


def test_update_under_vmap_and_scan(pq):
    keys = jax.random.split(jax.random.key(3), 5)

    def one(key):
        def step(s, k):
            return pq.update(s, k, POS, ALL, 1.5)[0], None

        s, _ = jax.lax.scan(step, pq.init(), jax.random.split(key, 3))
        return s

    st = jax.jit(jax.vmap(one))(keys)
    assert st.probs["edc"].shape == (5, 24, 20)
    assert np.all(np.asarray(st.num_updates) == 3)
    np.testing.assert_allclose(np.asarray(st.probs["edc"]).sum(-1), 1.0, atol=1e-5)


def test_metrics_on_known_maps():
    q = 20
    uniform = jnp.full((3, q), 1.0 / q)
    assert np.allclose(np.asarray(metrics.entropy(uniform)), np.log(20))
    onehot = jax.nn.one_hot(jnp.array([0, 5, 7]), q)
    mask = jnp.array([True, True, False])
    assert float(metrics.mean_map_entropy(onehot, mask)) == 0.0
    truth = jnp.array([0, 6, 7])
    assert float(metrics.error_rate(onehot, truth, mask)) == 0.5
    topn = np.asarray(metrics.topn_error_rates(onehot + 0.01 * jax.nn.one_hot(truth, q),
                                              truth, mask))
    assert topn[0] == 0.5 and topn[1] == 0.0 and np.all(np.diff(topn) <= 0)
    assert float(metrics.ml_probability(onehot, mask)) == 1.0
    cm = np.asarray(metrics.confusion_matrix(onehot, truth, mask))
    assert cm.sum() == 2 and cm[0, 0] == 1 and cm[6, 5] == 1
    d = _fixture_distances()
    assert d.max() == 4  # P §2.3.1
    nd = float(metrics.neighbor_distance(onehot, truth, mask, jnp.asarray(d)))
    assert nd == (0 + d[5, 6]) / 2 == 0.5
    assert float(metrics.mean_map_entropy(onehot, jnp.zeros(3, bool))) == 0.0  # empty: 0
    try:  # the lead's tables, when present, must agree with the fixture (docs/decisions.md §2.1)
        np.testing.assert_array_equal(np.asarray(calculi.get("edc").neighbor_distance), d)
    except (ImportError, AttributeError, FileNotFoundError):
        pass


def test_true_states_and_normalized_positions():
    lm = jnp.array([[10.0, 10.0], [10.0, 30.0], [15.0, 20.0], [0.0, 0.0]])
    tri = np.array([[0, 1, 2], [1, 0, 2]])
    xy, dab = metrics.normalized_positions(lm, tri)
    np.testing.assert_allclose(np.asarray(xy), [[0.25, 0.5], [-0.25, 0.5]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(dab), [20.0, 20.0])
    edc = calculi.get("edc")
    st = np.asarray(metrics.true_states(edc, lm, tri))
    assert st.tolist() == [int(edc.classify(lm[i], lm[j], lm[k])) for i, j, k in tri]


@pytest.mark.parametrize("block", [2, 7, 64, 1024])
def test_update_batch_equals_vmapped_update_bit_for_bit(block):
    """Sparse batched update (seen triplets only) == vmap(update), with priors, bit for bit
    at every piece size (before issue 31 only at 1024: LLVM contracted the eq. 2.10
    normaliser into FMAs depending on the piece shape), with the small compact buffer (few
    landmarks seen) and the full one (most seen)."""
    pq = pqrm.mapper(("edc", "single_cross", "lr"), num_landmarks=5, num_samples=40,
                     sparse_block=block)
    r = 6
    rng = np.random.default_rng(3)
    dense = jax.jit(jax.vmap(pq.update, in_axes=(0, 0, 0, 0, None)))
    a = b = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (r, *x.shape)), pq.init())
    for t, (sigma, p_vis) in enumerate(((0.0, 0.7), (3.0, 0.4), (3.0, 0.9), (20.0, 0.3),
                                        (0.0, 1.0), (5.0, 0.5))):
        keys = jax.random.split(jax.random.key(t), r)
        pos = jnp.asarray(rng.uniform(-20, 20, (r, 5, 2)).astype(np.float32))
        vis = jnp.asarray(rng.uniform(size=(r, 5)) < p_vis)
        a, _ = dense(a, keys, pos, vis, jnp.float32(sigma))
        b, _ = pq.update_batch(b, keys, pos, vis, jnp.float32(sigma), groups=1 + t % 2)
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert int(a.mapped.sum()) > 0 and int(a.num_updates.max()) > 1
    with pytest.raises(ValueError, match="positions"):
        pq.update_batch(b, keys, pos[0], vis, 1.0)
    with pytest.raises(ValueError, match="sigma"):
        pq.update_batch(b, keys, pos, vis, -1.0)


@pytest.mark.parametrize("mode", ["direct", "cond", "full"])
def test_update_batch_buffer_modes_are_identical(monkeypatch, mode):
    """The ways the sparse update writes its rows (each piece scattered into the map the loop
    carries; the ``lax.cond`` small/full buffer choice; always the full buffer) give the dense
    update's maps bit for bit, also when more rows are
    seen than the small buffer holds (every landmark visible, pieces of 3 rows) and when none
    is (docs/pqrm.md §map)."""
    from pqrm_jax.pqrm import map as pqrm_map

    monkeypatch.setattr(pqrm_map, "BUFFER_MODE", mode)
    pq = pqrm.mapper(("edc", "lr"), num_landmarks=5, num_samples=30, sparse_block=3)
    r = 4
    rng = np.random.default_rng(5)
    dense = jax.jit(jax.vmap(pq.update, in_axes=(0, 0, 0, 0, None)))
    a = b = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (r, *x.shape)), pq.init())
    for t, p_vis in enumerate((1.0, 0.0, 0.5, 1.0)):
        keys = jax.random.split(jax.random.key(10 + t), r)
        pos = jnp.asarray(rng.uniform(-20, 20, (r, 5, 2)).astype(np.float32))
        vis = jnp.asarray(rng.uniform(size=(r, 5)) < p_vis)
        a, _ = dense(a, keys, pos, vis, jnp.float32(2.0))
        b, _ = pq.update_batch(b, keys, pos, vis, jnp.float32(2.0))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert int(b.num_updates.sum()) == int(a.num_updates.sum()) >= 2 * r * 60


def test_merged_counts_equal_the_aggregation_product():
    """``map._merge_counts`` (column sums) equals ``counts @ aggregation_matrix`` bit for bit
    for every Padgett representation, at zero counts, at S = 2**16 and on random counts
    (sums of at most 20 integers ≤ S are exact in float32 in any order while 20·S ≤ 2**24)."""
    from pqrm_jax.pqrm import map as pqrm_map
    from pqrm_jax.pqrm.measurement import aggregation_matrix

    rng = np.random.default_rng(3)
    fine = np.concatenate([np.zeros((1, 20)), np.full((1, 20), 2.0**16),
                           rng.integers(0, 257, (64, 20))]).astype(np.float32)
    for name in calculi.PADGETT_REPRESENTATIONS:
        c = calculi.get(name)
        got = np.asarray(jax.jit(lambda f, c=c: pqrm_map._merge_counts(f, c))(fine))
        want = fine.astype(np.float64) @ aggregation_matrix(c).astype(np.float64)
        assert got.shape == (len(fine), c.num_states)
        np.testing.assert_array_equal(got, want.astype(np.float32))


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 300), st.integers(1, 70), st.sampled_from([0.0, 0.1, 0.5, 0.9, 1.0]),
       st.integers(0, 2**31 - 1))
def test_seen_order_is_nonzero_padded_to_whole_pieces(n, block, p_seen, seed):
    """``map._seen_order`` (one running count and a scatter) gives exactly the seen rows
    of ``jnp.nonzero(mask, size=N, fill_value=N)`` in order, padded with N to whole pieces,
    for every mask: none seen, all seen, pieces larger than N, a last piece cut short."""
    from pqrm_jax.pqrm.map import _seen_order

    mask = np.random.default_rng(seed).random(n) < p_seen
    order, num_seen, blk, pieces = _seen_order(jnp.asarray(mask), block)
    assert blk == max(1, min(block, n)) and pieces == -(-n // blk)
    want = np.full(pieces * blk, n, np.int32)
    want[:mask.sum()] = np.flatnonzero(mask)
    np.testing.assert_array_equal(np.asarray(order), want)
    assert order.dtype == jnp.int32 and int(num_seen) == mask.sum()
    ref = jnp.nonzero(jnp.asarray(mask), size=n, fill_value=n)[0]
    np.testing.assert_array_equal(np.asarray(order)[:n], np.asarray(ref))
