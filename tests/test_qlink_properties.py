"""Q-Link on any valid input (issue 24): property tests over random Link Graphs and worlds.

* Planning (``plan_pairs``, ``goal_distances`` + ``plan_from``) against a float64 networkx
  Dijkstra for zero, near-zero, unit, random and −log p edge costs at scales 1e-30…1e30: every
  path is simple, made of edges, from a start element to a goal element, sized by its hops,
  and optimal; scaling the costs (1e±40, beyond float32) plans the same or is refused.
* Weighted navigation driven end to end: on an Assumption-1 world with R′ = R every reachable
  trial drives its *whole* plan (``hops == |P|``) and succeeds, for every cost kind; a goal with
  no path gets the ``unreachable`` status.
* Every validation class of :func:`pqrm_jax.qlink.checks.validate` at every entry point, and
  the exact split of a landmark on a dividing line.
"""

from __future__ import annotations

from functools import cache

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi, sim
from pqrm_jax.qlink import costs, hybrid
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import guarantees as gu
from pqrm_jax.qlink import linkgraph as lg
from pqrm_jax.qlink import navigate as nav

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])
KINDS = ("zero", "near_zero", "unit", "random", "neg_log_p", "mixed_zero")
SCALES = (1e-30, 1e-7, 1.0, 1e7, 1e30)
N_LM, N_EL = 9, 12          # fixed shapes: one compile for every example


def _cost_matrix(rng, kind: str, e: int) -> np.ndarray:
    if kind == "zero":
        return np.zeros((e, e))
    if kind == "near_zero":
        return rng.uniform(0.5, 1.5, (e, e)) * 1e-7
    if kind == "unit":
        return np.ones((e, e))
    if kind == "random":
        return rng.uniform(0.0, 1.0, (e, e))
    if kind == "neg_log_p":       # p = 1 (cost 0) on a third of the edges
        p = np.where(rng.random((e, e)) < 0.33, 1.0, rng.uniform(1e-6, 1.0, (e, e)))
        return -np.log(p)
    return np.where(rng.random((e, e)) < 0.5, 0.0, rng.integers(1, 4, (e, e)))  # mixed_zero


def _random_graph(seed: int, beta: int, kind: str, scale: float):
    rng = np.random.default_rng(seed)
    ids = np.sort(np.array([rng.choice(N_LM, 3, replace=False) for _ in range(N_EL)]), 1)
    el = qel.MapElements(jnp.asarray(ids, jnp.int32), jnp.full((N_EL, 6, 4), 0.25), N_LM)
    return el, lg.link_graph(el, beta, _cost_matrix(rng, kind, N_EL) * scale)


def _dijkstra(graph: lg.LinkGraph, sources, targets) -> float:
    g = nx.DiGraph()
    g.add_nodes_from(range(graph.cost.shape[0]))
    for i, j in zip(*np.nonzero(graph.adjacency), strict=True):
        g.add_edge(int(i), int(j), weight=float(graph.cost[i, j]))
    d = nx.multi_source_dijkstra_path_length(g, {int(s) for s in sources})
    return min((d[t] for t in targets if t in d), default=np.inf)


def _check_path(graph, inc, path, n, s, t, reachable, cost, opt):
    path = [int(x) for x in np.asarray(path) if x >= 0]
    assert bool(reachable) == np.isfinite(opt)
    if not np.isfinite(opt):
        assert path == [] and int(n) == 0
        return
    assert len(path) == int(n) >= 1
    assert len(set(path)) == len(path), f"not a simple path: {path}"
    assert inc[s, path[0]] and inc[t, path[-1]]
    assert all(graph.adjacency[a, b] for a, b in zip(path[:-1], path[1:], strict=True))
    along = lg.path_cost(graph, np.array(path))
    assert along <= opt * (1 + 1e-5) + 0.0, (along, opt)
    assert float(cost) == pytest.approx(opt, rel=1e-5, abs=0.0)


@SETTINGS
@given(seed=st.integers(0, 2**20), beta=st.sampled_from([1, 2]), kind=st.sampled_from(KINDS),
       scale=st.sampled_from(SCALES))
def test_plans_are_simple_optimal_and_sized_by_hops(seed, beta, kind, scale):
    el, g = _random_graph(seed, beta, kind, scale)
    inc = qel.incidence(el)
    lms = np.flatnonzero(inc.any(1))
    pairs = np.array([(s, t) for s in lms for t in lms if s != t])
    # padded to fixed lengths by repeating the first pair and landmark (independent rows,
    # checked only up to the real ones): one program for every example, as N_LM and N_EL
    # intend, instead of one for every number of landmarks an example's elements touch
    padded = np.concatenate([pairs, np.repeat(pairs[:1], N_LM * (N_LM - 1) - len(pairs), 0)])
    goals = np.concatenate([lms, np.repeat(lms[:1], N_LM - len(lms))])
    plan = lg.plan_pairs(g, el, padded[:, 0], padded[:, 1])
    table = lg.goal_distances(g, el, goals)
    row = {int(x): i for i, x in enumerate(lms)}
    rows = np.array([row[int(t)] for t in padded[:, 1]])
    cands = np.full((len(padded), N_EL), -1)
    for k, s in enumerate(padded[:, 0]):
        cs = np.flatnonzero(inc[s])
        cands[k, :len(cs)] = cs
    fwd = lg.plan_from(g, table, rows, cands)
    for k, (s, t) in enumerate(pairs):
        opt = _dijkstra(g, np.flatnonzero(inc[s]), set(np.flatnonzero(inc[t]).tolist()))
        _check_path(g, inc, plan.path[k], plan.n_elements[k], s, t, plan.reachable[k],
                    plan.cost[k], opt)
        _check_path(g, inc, fwd.path[k], fwd.n_elements[k], s, t, fwd.reachable[k],
                    fwd.cost[k], opt)
    # the cost-to-go of every element is the Dijkstra distance to the goal's elements
    for i, t in enumerate(lms[:3]):
        for u in range(N_EL):
            want = _dijkstra(g, [u], set(np.flatnonzero(inc[t]).tolist()))
            got = float(table.cost[i, u])
            assert got == pytest.approx(want, rel=1e-5) if np.isfinite(want) else got == want


@SETTINGS
@given(seed=st.integers(0, 2**20), kind=st.sampled_from(KINDS),
       exp2=st.sampled_from([-133, -100, 100, 133]), dec=st.sampled_from([1e-40, 1e40]))
def test_scaled_costs_plan_the_same(seed, kind, exp2, dec):
    el, g = _random_graph(seed, 1, kind, 1.0)
    lms = np.flatnonzero(qel.incidence(el).any(1))
    pairs = np.array([(s, t) for s in lms for t in lms if s != t])
    base = lg.plan_pairs(g, el, pairs[:, 0], pairs[:, 1])
    # a power of two changes no mantissa bit: the very same plans
    g2 = g._replace(cost=g.cost * 2.0 ** exp2)
    p2 = lg.plan_pairs(g2, el, pairs[:, 0], pairs[:, 1])
    np.testing.assert_array_equal(np.asarray(p2.path), np.asarray(base.path))
    np.testing.assert_array_equal(np.asarray(p2.n_elements), np.asarray(base.n_elements))
    # 1e±40 (not representable in float32): same reachability and optimal costs
    g3 = g._replace(cost=g.cost * dec)
    p3 = lg.plan_pairs(g3, el, pairs[:, 0], pairs[:, 1])
    np.testing.assert_array_equal(np.asarray(p3.reachable), np.asarray(base.reachable))
    ok = np.asarray(base.reachable)
    np.testing.assert_allclose(np.asarray(p3.cost, np.float64)[ok] / dec,
                               np.asarray(base.cost, np.float64)[ok], rtol=1e-5)


def test_costs_beyond_the_working_precision_are_refused():
    el, g = _random_graph(0, 1, "random", 1.0)
    c = np.where(g.adjacency, 1e30, np.inf)
    i, j = np.argwhere(g.adjacency)[0]
    c[i, j] = 1e-30                  # 60 orders of magnitude: the 1e-30 edge would be 0
    bad = g._replace(cost=c)
    if jnp.zeros(()).dtype == jnp.float32:
        with pytest.raises(ValueError, match="graph.cost spans"):
            lg.plan_pairs(bad, el, [int(el.ids[0, 0])], [int(el.ids[1, 0])])
        with pytest.raises(ValueError, match="graph.cost spans"):
            lg.goal_distances(bad, el, [int(el.ids[1, 0])])


def test_zero_cost_edges_give_simple_paths():
    # a chain 0 - 1 - 2 - 3 of elements with zero costs (p = 1): the old argmin backtracking
    # looped [.., 1, 0, 1, 0] and returned |P| = number of elements
    el = qel.MapElements(jnp.array([[0, 1, 2], [1, 2, 3], [2, 3, 4], [3, 4, 5]]),
                         jnp.full((4, 6, 4), 0.25), 6)
    g = lg.link_graph(el, 2, np.zeros((4, 4)))
    p = lg.plan_pairs(g, el, [0], [5])
    assert p.path.tolist() == [[0, 1, 2, 3]] and p.n_elements.tolist() == [4]
    t = lg.goal_distances(g, el, [5])
    assert np.asarray(t.next).tolist() == [[1, 2, 3, -1]]
    assert np.asarray(t.hops).tolist() == [[3, 2, 1, 0]]
    fwd = lg.plan_from(g, t, [0], [[0]])
    assert fwd.path.tolist() == [[0, 1, 2, 3]] and fwd.n_elements.tolist() == [4]


# ---------------------------------------------------------------- weighted navigation

R = 15.0


@cache
def _world():
    """An Assumption-1 world (elements co-observed at R with MEC radius <= 0.95 R, exact
    relations) plus a far cluster of two elements that no path reaches."""
    size = (45.0, 45.0)
    lm = np.asarray(sim.uniform_landmarks(jax.random.key(5), 18, size=size), np.float64)
    vis = np.asarray(jax.vmap(sim.visibility, (0, None, None))(
        sim.lawnmower(size, spacing=R, step=1.0), jnp.asarray(lm), sim.SensorParams(max_range=R)))
    ids, _ = qel.co_observed_triplets(vis, 1)
    ids = ids[gu.assumption1(lm, ids, 0.95 * R)]
    far = np.array([[0, 0], [5, 0], [2, 4], [6, 5]], float) + 1000.0
    n = lm.shape[0]
    lm = np.concatenate([lm, far])
    ids = np.concatenate([ids, [[n, n + 1, n + 2], [n + 1, n + 2, n + 3]]])
    el = qel.exact_elements(jnp.asarray(lm, jnp.float32), ids)
    return jnp.asarray(lm, jnp.float32), el


@pytest.mark.parametrize("kind", ["neg_log_success", "random", "zero"])
def test_weighted_plans_are_driven_whole(kind):
    lm, el = _world()
    inc = qel.incidence(el)
    lms = np.flatnonzero(inc.any(1))
    if kind == "neg_log_success":
        g = costs.edge_costs(el, 2, "neg_log_success")
    else:
        rng = np.random.default_rng(1)
        e = inc.shape[1]
        c = rng.uniform(0.05, 3.0, (e, e)) if kind == "random" else np.zeros((e, e))
        g = lg.link_graph(el, 2, c)
    goal_row = np.full(el.num_landmarks, -1)
    goal_row[lms] = np.arange(len(lms))
    to_go = lg.goal_distances(g, el, lms)
    rng = np.random.default_rng(0)
    near = lms[lms < el.num_landmarks - 4]
    pairs = np.array([(s, t) for s in near for t in near if s != t])
    pairs = pairs[rng.choice(len(pairs), 30, replace=False)]
    pairs = np.concatenate([pairs, [[near[0], el.num_landmarks - 1]]])   # unreachable goal
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(2), i))(jnp.arange(len(pairs)))
    p = nav.NavParams(map_range=R, nav_range=R, ds=R / 40, start_offset=R / 20)
    r = nav.navigate_pairs(nav.Trials(keys, pairs[:, 0], pairs[:, 1]),
                           nav.NavMap(lm, el, g, to_go, goal_row, nav.start_tables(el)), p,
                           chunk=16)
    reach = np.asarray(r.reachable)
    assert not reach[-1] and int(r.status[-1]) == nav.UNREACHABLE
    assert reach[:-1].all()
    st_ = np.asarray(r.status)[:-1]
    assert (st_ == nav.SUCCESS).all(), [nav.FAILURE_REASONS[int(x)] for x in st_]
    # the whole plan is driven: one transition per element on the path
    assert (np.asarray(r.nav.hops)[:-1] == np.asarray(r.n_elements)[:-1]).all()
    if kind != "zero":     # weighted plans are longer than the cost-to-go suggests
        assert np.asarray(r.n_elements).max() > 2


# ---------------------------------------------------------------- validation classes

def _small():
    lm = jnp.array([[0., 0.], [10., 1.], [4., 7.], [13., 8.], [20., 2.]])
    ids = np.array([[0, 1, 2], [1, 2, 3], [1, 3, 4]])
    el = qel.exact_elements(lm, ids)
    return lm, el, lg.link_graph(el, 2)


BAD_IDS = [(-4, "outside"), (5, "outside"), (1.5, "integer"), (float("nan"), "integer"),
           (True, "integer")]


@pytest.mark.parametrize("bad,msg", BAD_IDS)
def test_bad_landmark_ids_are_refused_everywhere(bad, msg):
    lm, el, g = _small()
    p = nav.NavParams(map_range=R, nav_range=R)
    to_go = lg.goal_distances(g, el, [0, 1, 2, 3, 4])
    row = np.arange(5)
    keys = jax.random.split(jax.random.key(0), 1)
    path = np.array([[0]])
    world = nav.NavMap(lm, el, g, to_go, row, nav.start_tables(el))
    calls = {
        "starts": [lambda s: lg.plan_pairs(g, el, [s], [3]),
                   lambda s: nav.navigate(nav.Trials(keys, [s], [2], path, [1]), world, p),
                   lambda s: nav.navigate_pairs(nav.Trials(keys, [s], [3]), world, p)],
        "goals": [lambda s: lg.plan_pairs(g, el, [0], [s]),
                  lambda s: lg.goal_distances(g, el, [s]),
                  lambda s: nav.navigate(nav.Trials(keys, [0], [s], path, [1]), world, p),
                  lambda s: nav.navigate_pairs(nav.Trials(keys, [0], [s]), world, p)],
    }
    for name, fns in calls.items():
        for fn in fns:
            with pytest.raises(ValueError, match=rf"{name}.*{msg}"):
                fn(bad)


def _one(path):
    return nav.Trials(jax.random.split(jax.random.key(0), 1), [0], [2], path, [1])


def test_bad_maps_and_arguments_are_refused():
    lm, el, g = _small()
    p = nav.NavParams(map_range=R, nav_range=R)
    # element ids: repeated, negative, out of range, non-integer
    for ids, msg in (([[0, 1, 1]], "repeats"), ([[0, 1, -4]], "outside"),
                     ([[0, 1, 5]], "outside"), ([[0, 1, 2.5]], "integer")):
        with pytest.raises(ValueError, match=f"ids.*{msg}"):
            qel.exact_elements(lm, np.array(ids))
    bad_el = el._replace(ids=el.ids.at[0, 2].set(1))
    for fn in (lambda: lg.link_graph(bad_el, 2), lambda: costs.edge_costs(bad_el, 2),
               lambda: lg.plan_pairs(g, bad_el, [0], [3]),
               lambda: lg.goal_distances(g, bad_el, [3])):
        with pytest.raises(ValueError, match="elements.ids.*repeats"):
            fn()
    # landmark positions: NaN/inf, coincident
    nan_lm = lm.at[2, 0].set(jnp.nan)
    same_lm = lm.at[3].set(lm[1])
    for bad, msg in ((nan_lm, "not finite"), (same_lm, "coincide")):
        with pytest.raises(ValueError, match=f"landmarks.*{msg}"):
            qel.exact_elements(bad, np.array([[0, 1, 2]]))
        with pytest.raises(ValueError, match=f"landmarks.*{msg}"):
            qel.from_mapping_run(jax.random.key(0), bad, jnp.zeros((2, 3)),
                                 sim.SensorParams(max_range=10.0, sigma=0.1))
        with pytest.raises(ValueError, match=f"landmarks.*{msg}"):
            nav.navigate(_one(np.array([[0]])), nav.NavMap(bad, el),
                         p)
    # an element whose probability rows are all zero (never produced by exact_elements)
    zero = el._replace(probs=el.probs.at[1, 3].set(0.0))
    with pytest.raises(ValueError, match=r"elements.probs\[1, 3\] is all zero"):
        nav.navigate(_one(np.array([[0]])), nav.NavMap(lm, zero),
                     p)
    with pytest.raises(ValueError, match="all zero"):
        costs.edge_costs(zero, 2, "neg_log_success")
    # empty start / goal lists
    with pytest.raises(ValueError, match="starts is empty"):
        lg.plan_pairs(g, el, [], [])
    with pytest.raises(ValueError, match="goals is empty"):
        lg.goal_distances(g, el, [])
    # NaN / non-positive ranges
    for field in ("nav_range", "map_range", "ds", "circle_margin"):
        for v in (float("nan"), 0.0, -1.0, float("inf")):
            with pytest.raises(ValueError, match=rf"params.{field}.*{v}"):
                nav.navigate(_one(np.array([[0]])), nav.NavMap(lm, el),
                             p._replace(**{field: v}))
    with pytest.raises(ValueError, match="max_range"):
        qel.from_mapping_run(jax.random.key(0), lm, jnp.zeros((2, 3)),
                             sim.SensorParams(max_range=float("nan"), sigma=0.1))
    with pytest.raises(ValueError, match="params.sense_epochs"):
        nav.navigate(_one(np.array([[0]])), nav.NavMap(lm, el),
                     p._replace(sense_epochs=0.5))
    # paths that are not elements; costs that are NaN / negative
    with pytest.raises(ValueError, match=r"paths\[0, 0\] = 7"):
        nav.navigate(_one(np.array([[7]])), nav.NavMap(lm, el),
                     p)
    for v in (float("nan"), -1.0):
        c = np.ones((3, 3))
        c[0, 1] = v
        with pytest.raises(ValueError, match=r"cost\[0, 1\]"):
            lg.link_graph(el, 2, c)
    # the hybrid map: the same checks
    walls = np.array([[[30., -5.], [30., 5.]], [[60., -5.], [60., 5.]]])
    for bad, msg in ((np.asarray(nan_lm), "not finite"), (np.asarray(same_lm), "coincide")):
        with pytest.raises(ValueError, match=msg):
            hybrid.hybrid_elements(jax.random.key(0), bad, walls, jnp.zeros((2, 3)), 60.0, 0.7)
    with pytest.raises(ValueError, match="max_range"):
        hybrid.hybrid_elements(jax.random.key(0), lm, walls, jnp.zeros((2, 3)), float("nan"),
                               0.7)


@SETTINGS
@given(seed=st.integers(0, 2**20), grid=st.sampled_from([2, 3, 4]),
       scale=st.sampled_from([2.0 ** -50, 2.0 ** -10, 1.0, 2.0 ** 10, 2.0 ** 50]))
def test_a_landmark_on_a_dividing_line_is_split_exactly(seed, grid, scale):
    # integer-grid landmarks put many of them exactly on a line AB or on a bisector; a
    # power-of-two scale keeps them exact in float32 (the reference classify works in float32,
    # and off the lines a grid point is at least 1/24 of a grid unit away from them)
    rng = np.random.default_rng(seed)
    pts = np.array([(x, y) for x in range(grid + 1) for y in range(grid + 1)], float) * 2
    lm = pts[rng.choice(len(pts), 6, replace=False)] * scale
    ids = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5], [0, 3, 5]])
    el = qel.exact_elements(jnp.asarray(lm), ids)
    probs = np.asarray(el.probs, np.float64)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-6)
    # the split is the mean over four tiny diagonal shifts of C (the sigma -> 0 PQRM limit)
    quad = calculi.get("quadrant")
    trip = np.sort(ids, 1)[:, qel.ORDERINGS]
    a, b, c = (lm[trip[..., i]] for i in range(3))
    u = (b - a) / np.linalg.norm(b - a, axis=-1, keepdims=True)
    nrm = np.stack([-u[..., 1], u[..., 0]], -1)
    want = np.zeros_like(probs)
    eps = scale / 256
    for su in (-1, 1):
        for sn in (-1, 1):
            cc = c + eps * (su * u + sn * nrm)
            s = np.asarray(quad.classify(np.asarray(a), np.asarray(b), cc))
            assert (s >= 0).all()
            want += np.eye(4)[s] / 4
    np.testing.assert_allclose(probs, want, atol=1e-6)


def test_the_hybrid_executive_validates_its_inputs():
    pts = np.array([[0., 0.], [10., 1.], [4., 7.]])
    walls = np.array([[[30., -5.], [30., 5.]], [[60., -5.], [60., 5.]]])
    lm = jnp.asarray(np.concatenate([pts, walls.mean(1)]))
    el = qel.MapElements(jnp.array([[0, 1, 2], [1, 2, 3]]), jnp.full((2, 6, 3), 1 / 3), 5)
    hmap = hybrid.HybridMap(el, np.array([hybrid.LR, hybrid.LR]), (3, 4))
    tables = (jnp.zeros((2, 6, 4), jnp.int32), jnp.zeros((2, 6, 4), jnp.int32))
    keys = jax.random.split(jax.random.key(0), 1)
    ok = dict(paths=np.array([[0, 1]]), n=np.array([2]), refs=np.array([[0, 1]]),
              pos=np.zeros((1, 2)), params=hybrid.HybridParams(60.0, 0.7, 0.0))

    def drive(**kw):
        a = {**ok, **kw}
        return hybrid.drive(keys, hmap, lm, walls, a["paths"], a["n"], a["refs"], a["pos"],
                            a["params"], tables)

    for kw, msg in ((dict(pos=np.full((1, 2), np.nan)), "positions"),
                    (dict(params=hybrid.HybridParams(float("nan"), 0.7, 0.0)), "nav_range"),
                    (dict(params=hybrid.HybridParams(60.0, 0.7, 1.5)), "p_miss"),
                    (dict(paths=np.array([[0, 9]])), r"paths\[0, 1\] = 9"),
                    (dict(n=np.array([0])), "n_elements")):
        with pytest.raises(ValueError, match=msg):
            drive(**kw)
    with pytest.raises(ValueError, match="beta"):
        hybrid.hybrid_costs(hmap, 0, hybrid.search_models())
