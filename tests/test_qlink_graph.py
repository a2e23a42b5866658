"""Q-Link map elements and Link Graph planning (P §4.2, §4.3.2), checked against networkx."""

import itertools

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest

from pqrm_jax import sim
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import linkgraph as lg


def _random_elements(rng, n_landmarks, n_elements):
    tri = set()
    while len(tri) < n_elements:
        tri.add(tuple(sorted(int(x) for x in rng.choice(n_landmarks, 3, replace=False))))
    ids = np.array(sorted(tri), np.int32)
    return qel.MapElements(jnp.asarray(ids), jnp.zeros((len(ids), 6, 4)), n_landmarks)


@pytest.mark.parametrize("beta", [1, 2])
def test_edges_match_brute_force(beta):
    rng = np.random.default_rng(beta)
    el = _random_elements(rng, 12, 30)
    g = lg.link_graph(el, beta)
    ids = np.asarray(el.ids)
    for i, j in itertools.product(range(len(ids)), repeat=2):
        want = i != j and len(set(ids[i]) & set(ids[j])) >= beta
        assert g.adjacency[i, j] == want
    assert (g.adjacency == g.adjacency.T).all()
    if beta == 2:
        assert not (g.adjacency & ~lg.link_graph(el, 1).adjacency).any()


@pytest.mark.parametrize("trials", [range(0, 8), pytest.param(range(8, 16),
                                                                 marks=pytest.mark.slow)])
def test_planning_matches_networkx_unit_and_weighted(trials):
    # the first 8 random graphs cover beta 1 and 2, unit and weighted, twice each (each graph
    # size is a compile, so the other 8 are slow)
    rng = np.random.default_rng(trials.start)
    for trial in trials:
        el = _random_elements(rng, 10, 14)
        inc = qel.incidence(el)
        landmarks = np.flatnonzero(inc.any(axis=1))
        beta = 1 + trial % 2
        weighted = trial % 4 >= 2
        e = len(el.ids)
        cost = rng.uniform(0.1, 3.0, (e, e)) if weighted else None
        g = lg.link_graph(el, beta, cost)
        pairs = np.array(list(itertools.permutations(landmarks, 2)))
        plan = lg.plan_pairs(g, el, pairs[:, 0], pairs[:, 1])
        G = lg.to_networkx(g, el)
        for b, (s, t) in enumerate(pairs):
            srcs = list(np.flatnonzero(inc[s]))
            d = nx.multi_source_dijkstra_path_length(G, srcs, weight="weight")
            goals = [v for v in np.flatnonzero(inc[t]) if v in d]
            if not goals:
                assert not bool(plan.reachable[b])
                continue
            best = min(d[v] for v in goals)
            assert bool(plan.reachable[b])
            np.testing.assert_allclose(float(plan.cost[b]), best, rtol=1e-5)
            path = [int(x) for x in np.asarray(plan.path[b]) if x >= 0]
            assert len(path) == int(plan.n_elements[b])
            assert s in np.asarray(el.ids)[path[0]] and t in np.asarray(el.ids)[path[-1]]
            for u, v in zip(path[:-1], path[1:], strict=True):  # share >= beta
                assert G.has_edge(u, v)
            np.testing.assert_allclose(lg.path_cost(g, np.array(path)), best, rtol=1e-5)
            if not weighted:
                assert int(plan.n_elements[b]) == best + 1
                # |P| = 1 iff s and t share an element
                share = bool((inc[s] & inc[t]).any())
                assert (int(plan.n_elements[b]) == 1) == share


def test_bfs_matches_scipy_bipartite_hops_beta1():
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import shortest_path

    rng = np.random.default_rng(3)
    el = _random_elements(rng, 30, 60)
    inc = qel.incidence(el)
    n, e = inc.shape
    # bipartite landmark-element graph: with beta = 1, |P| = hop distance / 2
    big = np.zeros((n + e, n + e))
    big[:n, n:] = inc
    big[n:, :n] = inc.T
    hops = shortest_path(csr_matrix(big), unweighted=True, indices=range(n))[:, :n]
    g = lg.link_graph(el, 1)
    pairs = np.array([(s, t) for s in range(n) for t in range(n) if s != t
                      and inc[s].any() and inc[t].any()])
    plan = lg.plan_pairs(g, el, pairs[:, 0], pairs[:, 1])
    want = hops[pairs[:, 0], pairs[:, 1]]
    reach = np.isfinite(want)
    assert (np.asarray(plan.reachable) == reach).all()
    assert (np.asarray(plan.n_elements)[reach] == want[reach] / 2).all()


def test_mapping_run_elements_are_co_observed():
    lm = sim.uniform_landmarks(jax.random.key(1), 25, size=(60.0, 60.0))
    poses = sim.lawnmower((60.0, 60.0), spacing=15.0, step=5.0)
    el, vis = qel.from_mapping_run(jax.random.key(2), lm, poses,
                                   sim.SensorParams(max_range=15.0, sigma=0.3))
    ids = np.asarray(el.ids)
    for row in ids[:50]:
        assert vis[:, row].all(axis=1).any()
    np.testing.assert_allclose(np.asarray(el.probs).sum(-1), 1.0, atol=1e-5)
    # low noise: the ML state equals the true state for almost every ordering
    exact = qel.exact_elements(lm, ids)
    agree = (np.asarray(el.probs).argmax(-1) == np.asarray(exact.probs).argmax(-1)).mean()
    assert agree > 0.95


def test_bad_input():
    el = _random_elements(np.random.default_rng(0), 8, 6)
    for beta in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="beta"):
            lg.link_graph(el, beta)
    with pytest.raises(ValueError, match="empty"):
        lg.link_graph(qel.MapElements(jnp.zeros((0, 3), jnp.int32), jnp.zeros((0, 6, 4)), 5), 1)
    g = lg.link_graph(el, 1)
    missing = int(np.flatnonzero(~qel.incidence(el).any(axis=1))[0]) if (
        ~qel.incidence(el).any(axis=1)).any() else 99
    with pytest.raises(ValueError, match="not in the map"):
        lg.plan_pairs(g, el, [missing], [int(el.ids[0, 0])])
    with pytest.raises(ValueError, match="not in the map"):
        lg.plan_pairs(g, el, [int(el.ids[0, 0])], [-3])


@pytest.mark.parametrize("graphs", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_neg_log_success_costs_give_max_product_paths(graphs):
    # one random graph in the default suite (each graph compiles its own edge-success and
    # planning programs); the slow case adds a second
    from pqrm_jax.qlink import costs

    rng = np.random.default_rng(7)
    for _ in range(graphs):
        lm = jnp.asarray(rng.uniform(0, 30, (7, 2)), jnp.float32)
        el = _random_elements(rng, 7, 8)
        el = qel.exact_elements(lm, np.asarray(el.ids))
        g = costs.edge_costs(el, 1, "neg_log_success")
        assert np.all(g.cost[g.adjacency] >= 0)
        G = lg.to_networkx(g, el)
        inc = qel.incidence(el)
        pairs = np.array(list(itertools.permutations(np.flatnonzero(inc.any(1)), 2)))
        plan = lg.plan_pairs(g, el, pairs[:, 0], pairs[:, 1])
        pe = np.exp(-g.cost).tolist()
        e = len(el.ids)
        best_uv = np.eye(e)   # max product over all simple paths u -> v (enumeration)
        for u, v in itertools.permutations(range(e), 2):
            for p in nx.all_simple_paths(G, u, v):
                prod = 1.0
                for a, b in itertools.pairwise(p):
                    prod *= pe[a][b]
                best_uv[u, v] = max(best_uv[u, v], prod)
        for k, (s, t) in enumerate(pairs):
            best = best_uv[np.ix_(inc[s], inc[t])].max()
            if best == 0.0:
                assert not bool(plan.reachable[k])
                continue
            np.testing.assert_allclose(costs.path_success(g, plan.path[k]), best, rtol=1e-4)
            np.testing.assert_allclose(np.exp(-float(plan.cost[k])), best, rtol=1e-4)
