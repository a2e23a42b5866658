"""Compositions in planning (Z eqs. 4.26-4.28) and Thm 4.1 as a property test."""

import itertools

import networkx as nx
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi
from pqrm_jax import compositions as C
from pqrm_jax.bsp import compose as BC
from pqrm_jax.compositions.propagation import compose as prop_compose

EDC = calculi.get("edc")

triplet_sets = st.lists(st.sets(st.integers(0, 6), min_size=3, max_size=3), min_size=1,
                        max_size=7)


@settings(max_examples=300, deadline=None)
@given(triplet_sets)
def test_thm_4_1_connected_implies_composable(ts):
    g = BC.triplet_link_graph(ts)
    if nx.is_connected(g):
        assert C.is_composable(ts)


def test_thm_4_1_not_conversely():
    ts = ["ABC", "BCD", "ADE"]  # Fig. 4.3
    assert C.is_composable(ts) and not nx.is_connected(BC.triplet_link_graph(ts))
    # and over random sets the inclusion is strict: some composable sets are disconnected
    rng = np.random.default_rng(0)
    strict = 0
    for _ in range(300):
        ts = [tuple(rng.choice(6, 3, replace=False)) for _ in range(rng.integers(2, 6))]
        if C.is_composable(ts) and not nx.is_connected(BC.triplet_link_graph(ts)):
            strict += 1
    assert strict > 0


def _fig46_measured():
    names = "ABCDEFGHIJ"
    M1 = ["ABC", "ABD", "ABE", "ABH", "ACI", "DEF", "DEG", "EGJ"]
    return [tuple(names.index(c) for c in t) for t in M1]


def test_augment_fig46_supports_and_entropy():
    t = EDC.tables
    Q, L, n = 20, 10, 10
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 3, (n, 2))
    truth = np.asarray(EDC.classify(pos[:, None, None], pos[None, :, None], pos[None, None, :]))
    trip = np.full((L, L, L, Q), 1.0 / Q, np.float32)
    measured = np.zeros((L, L, L), bool)
    for tr in _fig46_measured():
        for a, b, c in itertools.permutations(tr):
            trip[a, b, c] = np.eye(Q)[truth[a, b, c]]
            measured[a, b, c] = True
    U = np.stack([t.left, t.right, t.inverse]).astype(np.float32)
    U /= U.sum(-1, keepdims=True)
    P = np.asarray(t.prob_compose, np.float32)
    out, src, ncomp = BC.augment(trip, measured, n, P, U)
    assert (src > 0).sum() == 6 * 120  # M1 is composable: every triplet is available
    assert ncomp[0, 4, 6] == 2  # AEG: ADE <- (ABE, ABD), AEG <- (DEG, ADE)
    # composed rows: supports contain the truth (exact support: sources are exact one-hots)
    comp = src == 2
    assert np.all(out[comp][np.arange(comp.sum()), truth[comp]] > 0)
    assert np.allclose(out.sum(-1), 1, atol=1e-5)
    # entropy grows with the number of compositions (Z ch. 6 item 4)
    ent = -(out * np.log(np.where(out > 0, out, 1))).sum(-1)
    means = [ent[comp & (ncomp == c)].mean() for c in range(1, 4) if (comp & (ncomp == c)).any()]
    assert np.all(np.diff(means) > 0), means


def test_compose_step_equals_propagation_compose():
    rng = np.random.default_rng(1)
    P = np.asarray(EDC.tables.prob_compose, np.float32)
    p1, p2 = rng.dirichlet(np.ones(20), 2).astype(np.float32)
    assert np.allclose(BC.compose_step(p1, p2, P), np.asarray(prop_compose(p1, p2, P)), atol=1e-5)
