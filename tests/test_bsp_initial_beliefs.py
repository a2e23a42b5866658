"""Initial beliefs of many environments at once (``bsp.initial_beliefs``), the composition trees
of ``bsp.augment``, and ``bsp.plans_exist``: each equal, bit for bit, to its one-at-a-time
definition (the qbsp study's figures do not change with the batching)."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi
from pqrm_jax import compositions as C
from pqrm_jax.bsp import compose as BC
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.compositions.simulation import measure_map, measured_rows, place_rows

PARAMS = M.ModelParams(samples=600, pool=1 << 18, seed=3)
EDC = calculi.get("edc")


@pytest.fixture(scope="module")
def mod(request):
    return M.load_models(PARAMS, directory=request.config.cache.mkdir("bsp-models"))


def _envs(count: int, seed: int = 5):
    """Environments of 5..12 landmarks (3..10 measured triplets: padded widths 8 and 16)."""
    rng = np.random.default_rng(seed)
    return [E.generate(rng, n, float(rng.choice([1.5, 2.5])))
            for n in [5, 11, 7, 12, 9, 6, 10, 8][:count]]


@pytest.mark.parametrize("scale_model", ["composed", "belief"])
def test_initial_beliefs_equal_one_by_one(mod, scale_model):
    envs = _envs(7)
    assert {len(e.triplets) <= 8 for e in envs} == {True, False}  # both padded widths
    keys = jax.random.split(jax.random.key(4), len(envs))
    got = E.initial_beliefs(keys, mod, envs, scale_model=scale_model)
    assert set(got) == set(E.MODES)
    for mode in E.MODES:
        for e, env in enumerate(envs):
            one = E.initial_belief(keys[e], mod, env, compositions=mode == "with",
                                   scale_model=scale_model)
            for name, want in one._asdict().items():
                have = np.asarray(getattr(got[mode], name)[e])
                assert have.dtype == np.asarray(want).dtype, name
                assert np.array_equal(have, np.asarray(want)), (mode, e, name)
    # one mode alone is that mode of both
    only = E.initial_beliefs(keys, mod, envs, modes=("without",), scale_model=scale_model)
    assert set(only) == {"without"}
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(only["without"]),
                                                    jax.tree.leaves(got["without"]),
                                                    strict=True))


def test_initial_beliefs_refuse_bad_input(mod):
    envs = _envs(3)
    keys = jax.random.split(jax.random.key(0), 3)
    with pytest.raises(ValueError, match="keys"):
        E.initial_beliefs(keys[:2], mod, envs)
    with pytest.raises(ValueError, match="envs is empty"):
        E.initial_beliefs(keys[:0], mod, [])
    with pytest.raises(ValueError, match="modes"):
        E.initial_beliefs(keys, mod, envs, modes=("both",))
    with pytest.raises(ValueError, match="modes"):
        E.initial_beliefs(keys, mod, envs, modes=())
    with pytest.raises(ValueError, match="scale_model"):
        E.initial_beliefs(keys, mod, envs, scale_model="metric")
    bad = envs[1]._replace(goal=(0, 1, 99))
    with pytest.raises(ValueError, match="environment 1: .*target triplet"):
        E.initial_beliefs(keys, mod, [envs[0], bad, envs[2]])


def test_measure_map_is_measured_rows_placed():
    """The dense map is the rows of ``measured_rows`` placed by ``place_rows``; padding the
    triplet list with more rows leaves the first rows' draws unchanged."""
    rng = np.random.default_rng(2)
    pos = rng.uniform(0, 3, (9, 2)).astype(np.float32)
    tri = sorted(tuple(sorted(t)) for t in
                 {tuple(rng.choice(9, 3, replace=False)) for _ in range(6)})
    key = jax.random.key(7)
    probs, obs = measure_map(EDC, key, pos, tri, 0.05, 64)
    padded = np.asarray(tri + [(0, 1, 2)] * 5, np.int32)
    rows = np.asarray(measured_rows(EDC, key, jnp.asarray(pos), jnp.asarray(padded), 0.05, 64))
    p2 = np.full(probs.shape, 1 / 20, np.float32)
    o2 = np.zeros(obs.shape, bool)
    place_rows(p2, o2, np.asarray(tri, np.int32), rows[:len(tri)])
    assert np.array_equal(probs, p2) and np.array_equal(obs, o2)
    assert obs.sum() == 6 * len(tri)


def _augment_by_trees(trip, measured, n, tensor, U):
    """Reference: Z Alg. 4's tree of every composable target, composed along ``steps()``."""
    trip = np.array(trip, np.float32, copy=True)
    L = trip.shape[0]
    src = np.where(measured, 1, 0).astype(np.int8)
    ncomp = np.zeros((L, L, L), np.int8)
    sources = {frozenset(map(int, t)) for t in np.argwhere(measured) if t[0] < t[1] < t[2]}
    g = C.optimal_composition_graph(sources, landmarks=range(n))
    done = set()
    for t in itertools.combinations(range(n), 3):
        tree = g.extract(t)
        if frozenset(t) in sources or frozenset(t) in done or tree is None:
            continue
        for head, tl, tr in tree.steps():
            if head in sources or head in done:
                continue
            shared = tl & tr
            (i,), (d,) = tl - shared, tr - shared
            (j,) = head & shared
            (k,) = shared - {j}
            p = BC.compose_step(trip[i, j, k], trip[j, k, d], tensor)
            done.add(head)
            for perm, q in BC.orderings(p, U).items():
                a, b, c = ((i, j, d)[x] for x in perm)
                trip[a, b, c], src[a, b, c] = q, 2
                ncomp[a, b, c] = min(int(round(g.cost(head))), 127)
    return trip, src, ncomp


triplet_lists = st.lists(st.sets(st.integers(0, 7), min_size=3, max_size=3), min_size=1,
                         max_size=9)


@settings(max_examples=40, deadline=None)
@given(triplet_lists, st.integers(0, 2 ** 31 - 1))
def test_augment_follows_the_minimal_trees(ts, seed):
    """augment composes each triplet once along the parent pointers of the composition graph:
    bit for bit the rows of composing every target's Alg. 4 tree, composable or not."""
    rng = np.random.default_rng(seed)
    n, L, Q = 8, 9, 20
    trip = np.full((L, L, L, Q), 1.0 / Q, np.float32)
    measured = np.zeros((L, L, L), bool)
    for t in {tuple(sorted(t)) for t in ts}:
        p = rng.dirichlet(np.full(Q, 0.3)).astype(np.float32)
        for a, b, c in itertools.permutations(t):
            trip[a, b, c], measured[a, b, c] = p, True
    U = _unary()
    P = np.asarray(EDC.tables.prob_compose, np.float32)
    got = BC.augment(trip, measured, n, P, U)
    want = _augment_by_trees(trip, measured, n, P, U)
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a, b)


def _unary():
    t = EDC.tables
    U = np.stack([t.left, t.right, t.inverse]).astype(np.float32)
    return U / U.sum(-1, keepdims=True)


def test_plans_exist_equals_one_by_one(mod):
    envs = _envs(6, seed=9)
    keys = jax.random.split(jax.random.key(1), len(envs))
    goals = jnp.asarray([e.goal for e in envs], jnp.int32)
    bels = E.initial_beliefs(keys, mod, envs)
    seen = set()
    for mode, eps in itertools.product(E.MODES, (0.0, 0.1, 0.3, 0.6, 0.9, 1.01)):
        got = np.asarray(G.plans_exist(mod, bels[mode], goals, eps))
        for e in range(len(envs)):
            b = jax.tree.map(lambda x, e=e: x[e], bels[mode])
            fg = G.frame_graph(mod, b.trip, b.trip_src, b.scale, b.lm_mask, goals[e], eps)
            assert bool(got[e]) == bool(G.plan_exists(fg, b.frame))
        seen |= set(got.tolist())
    assert seen == {True, False}  # both answers occur: the comparison could fail


def test_trees_exist_equals_one_by_one(mod):
    from pqrm_jax.bsp import planner as P

    D1 = jnp.asarray(EDC.tables.neighbor_distance, jnp.float32)
    envs = _envs(6, seed=9)
    keys = jax.random.split(jax.random.key(2), len(envs))
    goals = jnp.asarray([e.goal for e in envs], jnp.int32)
    b = E.initial_beliefs(keys, mod, envs)["with"]
    pp = P.PlannerParams(depth=1)
    seen = set()
    for eps in (0.1, 1.01):
        got = np.asarray(P.trees_exist(keys, mod, D1, b, goals, eps, pp))
        for e in range(len(envs)):
            one = jax.tree.map(lambda x, e=e: x[e], b)
            fg = G.frame_graph(mod, one.trip, one.trip_src, one.scale, one.lm_mask, goals[e], eps)
            want = P.plan(keys[e], mod, D1, one.trip, one.scale, fg, goals[e], one.frame,
                          one.robot, pp, 1).exists
            assert bool(got[e]) == bool(want)
        seen |= set(got.tolist())
    assert seen == {True, False}
