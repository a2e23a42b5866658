"""The triplet vocabulary: layouts, converters, and agreement with the helpers it replaced."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi, compositions, pqrm, qrm, triplets
from pqrm_jax.compositions import simulation
from pqrm_jax.qrm import hypergraph


def old_ordered_triplets(m):  # pqrm/map.py before the move
    i, j, k = np.meshgrid(np.arange(m), np.arange(m), np.arange(m), indexing="ij")
    keep = (i != j) & (i != k) & (j != k)
    return np.stack([i[keep], j[keep], k[keep]], axis=-1).astype(np.int32)


def old_cyclic_mask(n):  # qrm/pipeline.py before the move
    i, j, k = np.ix_(np.arange(n), np.arange(n), np.arange(n))
    inc = (i < j) & (j < k)
    return inc | np.transpose(inc, (2, 0, 1)) | np.transpose(inc, (1, 2, 0))


@pytest.mark.parametrize("m", [3, 4, 7])
def test_masks_and_order(m):
    t = triplets.ordered_triplets(m)
    np.testing.assert_array_equal(t, old_ordered_triplets(m))
    assert t.shape == (triplets.num_triplets(m), 3)
    assert [tuple(r) for r in t] == list(itertools.permutations(range(m), 3))
    d = triplets.distinct_mask(m)
    i, j, k = np.ogrid[:m, :m, :m]
    np.testing.assert_array_equal(d, (i != j) & (j != k) & (i != k))
    assert d.sum() == len(t) and d[t[:, 0], t[:, 1], t[:, 2]].all()
    c = triplets.cyclic_mask(m)
    np.testing.assert_array_equal(c, old_cyclic_mask(m))
    assert c.sum() == len(t) // 2 and not (c & ~d).any()
    # the old names are the same objects
    assert pqrm.ordered_triplets is triplets.ordered_triplets
    assert hypergraph.distinct_mask is triplets.distinct_mask


@pytest.mark.parametrize("backend", [np.asarray, jnp.asarray])
def test_rows_dense_round_trip(backend):
    m, q = 5, 4
    rows = backend(np.random.default_rng(0).random((triplets.num_triplets(m), q), np.float32))
    dense = triplets.rows_to_dense(rows, m)
    assert dense.shape == (m, m, m, q) and type(dense) is type(rows)
    np.testing.assert_array_equal(np.asarray(dense)[~triplets.distinct_mask(m)], 0.0)
    back = triplets.dense_to_rows(dense, m)
    np.testing.assert_array_equal(np.asarray(back), np.asarray(rows))
    jitted = jax.jit(lambda r: triplets.dense_to_rows(triplets.rows_to_dense(r, m), m))
    np.testing.assert_array_equal(np.asarray(jitted(jnp.asarray(rows))), np.asarray(rows))
    with pytest.raises(ValueError, match="rows"):
        triplets.rows_to_dense(rows[:-1], m)
    with pytest.raises(ValueError, match="leading shape"):
        triplets.dense_to_rows(dense, m + 1)


def test_pqrm_composition_converters_agree():
    m = 4
    pq = pqrm.mapper(("edc", "lr"), m, 32)
    pos = jnp.array([[0.3, 0.1], [0.2, 9.7], [5.1, 4.3], [-4.7, 2.2]])
    st, _ = pq.update(pq.init(), jax.random.key(0), pos, jnp.array([True, True, True, False]), 0.5)
    probs, observed = compositions.from_pqrm(st, m, "lr")
    t = triplets.ordered_triplets(m)
    np.testing.assert_array_equal(probs[t[:, 0], t[:, 1], t[:, 2]], np.asarray(st.probs["lr"]))
    np.testing.assert_array_equal(observed[t[:, 0], t[:, 1], t[:, 2]], np.asarray(st.mapped))
    assert probs.dtype == np.float32 and observed.dtype == bool
    np.testing.assert_array_equal(compositions.to_pqrm_rows(probs, m), np.asarray(st.probs["lr"]))


@pytest.mark.parametrize("name", ["edc", "dcc", "lr"])
def test_true_states_layouts_agree(name):
    calc = calculi.get(name)
    lm = jax.random.uniform(jax.random.key(2), (6, 2)) * 100
    rows = triplets.true_states(calc, lm)
    dense = triplets.true_states(calc, lm, "dense")
    np.testing.assert_array_equal(np.asarray(triplets.dense_to_rows(dense, 6)), np.asarray(rows))
    assert np.all(np.asarray(dense)[~triplets.distinct_mask(6)] == calculi.DEGENERATE)
    t = triplets.ordered_triplets(6)
    old_rows = calc.classify(lm[t[:, 0]], lm[t[:, 1]], lm[t[:, 2]])
    np.testing.assert_array_equal(np.asarray(pqrm.metrics.true_states(calc, lm, t)),
                                  np.asarray(old_rows))
    raw = np.asarray(calc.classify(lm[:, None, None], lm[None, :, None], lm[None, None, :]))
    np.testing.assert_array_equal(simulation.true_states(calc, lm), raw)
    d = triplets.distinct_mask(6)
    np.testing.assert_array_equal(np.asarray(qrm.hypergraph.true_relations(lm, name)),
                                  np.where(d, raw, -2))
    with pytest.raises(ValueError, match="layout"):
        triplets.true_states(calc, lm, "masks")


def test_masks_round_trip():
    st = jnp.array([[0, 3], [-2, 1]])
    masks = triplets.states_to_masks(st, 0b1111)
    assert masks.tolist() == [[1, 8], [15, 2]]
    sets = triplets.masks_to_sets(masks, 4)
    assert sets.shape == (2, 2, 4)
    assert sets[0, 1].tolist() == [False, False, False, True] and bool(sets[1, 0].all())


def test_orderings_and_their_unary_maps():
    """Issue 28: one copy of the six orderings and of the INVERSE / LEFT / RIGHT index maps."""
    o = triplets.ORDERINGS
    assert o.tolist() == [list(p) for p in itertools.permutations(range(3))]
    np.testing.assert_array_equal(o, triplets.ordered_triplets(3))
    rows = [tuple(r) for r in o.tolist()]
    for k, (a, b, c) in enumerate(rows):
        assert rows[triplets.INVERSE_OF[k]] == (b, a, c)
        assert rows[triplets.LEFT_OF[k]] == (b, c, a)
        assert rows[triplets.RIGHT_OF[k]] == (c, a, b)
        assert triplets.ORDERING_INDEX[a, b] == k
    inv, left, right = triplets.INVERSE_OF, triplets.LEFT_OF, triplets.RIGHT_OF
    ident = np.arange(6)
    np.testing.assert_array_equal(inv[inv], ident)               # INVERSE is an involution
    np.testing.assert_array_equal(left[left[left]], ident)       # LEFT has order 3
    np.testing.assert_array_equal(left[right], ident)            # RIGHT undoes LEFT
    # bsp.compose.orderings reaches each ordering by the same operators
    from pqrm_jax.bsp import compose as bc

    q = 3
    u = np.stack([np.roll(np.eye(q), s, 1) for s in (1, 2, 0)])  # any three distinct maps
    got = bc.orderings(np.eye(q)[0], u)
    assert set(got) == set(rows)
    np.testing.assert_array_equal(got[rows[triplets.LEFT_OF[0]]], np.eye(q)[0] @ u[bc.LEFT])
    np.testing.assert_array_equal(got[rows[triplets.RIGHT_OF[0]]], np.eye(q)[0] @ u[bc.RIGHT])
    np.testing.assert_array_equal(got[rows[triplets.INVERSE_OF[0]]],
                                  np.eye(q)[0] @ u[bc.INVERSE])
    assert not o.flags.writeable and not triplets.INVERSE_OF.flags.writeable


@settings(max_examples=20, deadline=None)
@given(m=st.integers(3, 9), e=st.integers(1, 12), seed=st.integers(0, 2**16),
       beta=st.integers(1, 3))
def test_one_link_graph_adjacency(m, e, seed, beta):
    """triplets.link_adjacency is Q-Link's Link Graph and, at beta = 2, bsp's Link-Graph."""
    import networkx as nx

    from pqrm_jax import bsp, qlink

    rng = np.random.default_rng(seed)
    ids = np.sort(np.stack([rng.choice(m, 3, replace=False) for _ in range(e)]), 1)
    ids = np.unique(ids, axis=0)
    adj = triplets.link_adjacency(ids, beta)
    el = qlink.MapElements(jnp.asarray(ids), jnp.zeros((len(ids), 6, 2)), m)
    np.testing.assert_array_equal(adj, qlink.link_graph(el, beta).adjacency)
    np.testing.assert_array_equal(triplets.shared_landmarks(ids), qlink.linkgraph.shared_counts(el))
    if beta == 2:
        g = bsp.triplet_link_graph([tuple(r) for r in ids.tolist()])
        want = nx.Graph()
        want.add_nodes_from(frozenset(r) for r in ids.tolist())
        want.add_edges_from((frozenset(ids[i].tolist()), frozenset(ids[j].tolist()))
                            for i, j in zip(*np.nonzero(adj), strict=True))
        assert nx.utils.graphs_equal(g, want)
    with pytest.raises(ValueError, match="beta"):
        triplets.link_adjacency(ids, 0)


def test_elements_layout_to_dense():
    rng = np.random.default_rng(1)
    ids = np.array([[0, 2, 3], [1, 2, 4]])
    probs = rng.uniform(size=(2, 6, 5))
    d = triplets.elements_to_dense(ids, probs, 5, fill=-1.0)
    for e in range(2):
        for k, (a, b, c) in enumerate(triplets.ORDERINGS):
            np.testing.assert_allclose(d[ids[e, a], ids[e, b], ids[e, c]], probs[e, k])
    assert (d == -1).all(-1).sum() == 125 - 12
    with pytest.raises(ValueError, match="ids must be in"):
        triplets.elements_to_dense(ids, probs, 4)
    with pytest.raises(ValueError, match=r"\[E, 6, Q\]"):
        triplets.elements_to_dense(ids, probs[:, :5], 5)
