"""Planner (Z §4.2): Fig. 4.6a fixture, pruned vs full tree, plan-exists properties, bad input."""

import itertools
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import graph as G
from pqrm_jax.bsp import models as M
from pqrm_jax.bsp import planner as P
from pqrm_jax.bsp.belief import LINK_K

PARAMS = M.ModelParams(samples=600, pool=1 << 18, seed=3)
D1 = jnp.asarray(calculi.get("edc").tables.neighbor_distance, jnp.float32)
NAMES = "ABCDEFGHIJ"


@pytest.fixture(scope="module")
def mod(request):
    return M.load_models(PARAMS, directory=request.config.cache.mkdir("bsp-models"))


def _ids(s):
    return tuple(NAMES.index(c) for c in s)


def fig46_env(rng):
    """Fig. 4.6a: F_1 = EG, M_1 as in the thesis, goal ABC; a compact layout (all within R)."""
    M1 = [_ids(t) for t in ["ABC", "ABD", "ABE", "ABH", "ACI", "DEF", "DEG", "EGJ"]]
    while True:
        pos = rng.uniform(0, 0.9, (10, 2))
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(10)
        if d.min() > 0.08:
            break
    start = (pos[4] + pos[6]) / 2
    return E.Environment(pos=pos, triplets=tuple(M1), frame=_ids("EG"), goal=_ids("ABC"),
                         start=start)


def _graph(mod, env, comp, key=0):
    b = E.initial_belief(jax.random.key(key), mod, env, compositions=comp, L_max=12)
    fg = G.frame_graph(mod, b.trip, b.trip_src, b.scale, b.lm_mask, jnp.asarray(env.goal))
    return b, fg


def _reachable(obs, f0):
    seen, todo = {f0}, [f0]
    while todo:
        i, j = todo.pop()
        for k in np.flatnonzero(obs[i, j]):
            for f in ((i, int(k)), (j, int(k))):
                if f not in seen:
                    seen.add(f)
                    todo.append(f)
    return {"".join(sorted(NAMES[x] for x in f)) for f in seen}


def test_fig46a_scenario(mod):
    env = fig46_env(np.random.default_rng(0))
    b0, fg0 = _graph(mod, env, False)
    b1, fg1 = _graph(mod, env, True)
    assert not bool(G.plan_exists(fg0, b0.frame))
    assert bool(G.plan_exists(fg1, b1.frame))
    assert _reachable(np.asarray(fg0.obs), _ids("EG")) == {"DE", "DF", "DG", "EF", "EG", "EJ",
                                                             "GJ"}
    assert int(fg1.hops[4, 6]) == 2  # EG -> (A E or B E ...) -> AB, then observe ABC
    assert int(b1.ncomp[0, 4, 6]) == 2  # AEG needs two compositions
    pp = P.PlannerParams(depth=1)
    p0 = P.plan(jax.random.key(0), mod, D1, b0.trip, b0.scale, fg0, jnp.asarray(env.goal),
                b0.frame, b0.robot, pp)
    p1 = P.plan(jax.random.key(0), mod, D1, b1.trip, b1.scale, fg1, jnp.asarray(env.goal),
                b1.frame, b1.robot, pp)
    assert not bool(p0.exists) and bool(p1.exists)
    # the best first-level branch links out of EG into a frame with A (via a composed triplet)
    best = int(np.argmin(np.asarray(p1.q)))
    ks = np.asarray(p1.ks)[best]
    assert any(NAMES[k] in "AB" for k in ks)


def _small_envs(n_env, n=6, size=1.6, seed=0):
    rng = np.random.default_rng(seed)
    return [E.generate(rng, n, size) for _ in range(n_env)]


@pytest.mark.slow
def test_pruned_vs_full_tree(mod):
    """Action pruning alone (4 of 20 actions) keeps the full tree's plan up to near ties;
    truncating β to the 3 likeliest candidates (renormalised, docs/bsp.md §Z-24) shifts the
    value (an expectation over another distribution) more than the decision.

    Regret = the full tree's value of the pruned tree's first action, relative to the full
    tree's value. Measured on 60 instances (docs/bsp.md §Z-18): actions 93 % same, regret
    < 1 % in 97 %, max 2 %; β truncation value change median 15 %, regret max 5 %.
    """
    agree, rel, reg, agree3, rel3, reg3 = [], [], [], [], [], []
    for e, env in enumerate(_small_envs(12)):
        b, fg = _graph(mod, env, True, key=e)
        args = (jax.random.key(e), mod, D1, b.trip, b.scale, fg, jnp.asarray(env.goal),
                b.frame, b.robot)
        full = P.plan(*args, P.PlannerParams(depth=2, n_actions=20, n_beta=6))
        pa = P.plan(*args, P.PlannerParams(depth=2, n_actions=4, n_beta=6))
        pr = P.plan(*args, P.PlannerParams(depth=2, n_actions=4, n_beta=3))
        assert bool(full.exists) == bool(pa.exists) == bool(pr.exists) == bool(
            G.plan_exists(fg, b.frame))
        fv = float(full.value)
        qf = dict(zip(np.asarray(full.actions).tolist(), np.asarray(full.q).tolist(),
                      strict=True))
        assert set(qf) == set(range(20)) and min(qf.values()) == pytest.approx(fv)
        agree.append(int(full.action) == int(pa.action))
        rel.append(abs(float(pa.value) - fv) / fv)
        reg.append((qf[int(pa.action)] - fv) / fv)
        agree3.append(int(full.action) == int(pr.action))
        rel3.append(abs(float(pr.value) - fv) / fv)
        reg3.append((qf[int(pr.action)] - fv) / fv)
    assert np.mean(agree) >= 0.8 and np.median(rel) < 0.01 and max(rel) < 0.05, (agree, rel)
    assert min(reg) >= 0 and np.median(reg) < 1e-6 and max(reg) < 0.03, reg
    assert np.mean(agree3) >= 0.5 and np.median(rel3) < 0.2, (agree3, rel3)
    assert min(reg3) >= 0 and np.median(reg3) < 0.01 and max(reg3) < 0.1, reg3


@pytest.mark.slow
def test_plan_exists_same_for_both_costs_and_monotone(mod):
    for e, env in enumerate(_small_envs(10, n=8, size=2.5, seed=1)):
        ex = {}
        for comp in (False, True):
            b, fg = _graph(mod, env, comp, key=e)
            for cost in (1, 2):
                p = P.plan(jax.random.key(e), mod, D1, b.trip, b.scale, fg, jnp.asarray(env.goal),
                           b.frame, b.robot, P.PlannerParams(depth=1, cost=cost))
                ex[comp, cost] = (bool(G.plan_exists(fg, b.frame)), bool(p.exists))
        assert ex[False, 1] == ex[False, 2] and ex[True, 1] == ex[True, 2]
        assert (not ex[False, 1][0]) or ex[True, 1][0]  # without => with


def test_bad_input(mod):
    env = fig46_env(np.random.default_rng(1))
    with pytest.raises(ValueError, match="distinct"):
        E.check_environment(env._replace(goal=(0, 0, 1)), 12)
    with pytest.raises(ValueError, match="unknown"):
        E.check_environment(env._replace(goal=(0, 1, 11)), 12)
    with pytest.raises(ValueError, match="at least 3"):
        E.check_environment(env._replace(pos=env.pos[:2]), 12)
    with pytest.raises(ValueError, match="finite"):
        E.check_environment(env._replace(pos=np.where(np.eye(10, 2) > 0, np.nan, env.pos)), 12)
    with pytest.raises(ValueError, match="not composable"):
        E.check_environment(env._replace(triplets=((0, 1, 2), (3, 4, 5), (5, 6, 7), (6, 7, 8),
                                                   (7, 8, 9))), 12)
    with pytest.raises(ValueError, match="at least 3"):
        E.generate(np.random.default_rng(0), 2, 1.0)
    b, fg = _graph(mod, env, True)
    with pytest.raises(ValueError, match="depth"):
        P.plan(jax.random.key(0), mod, D1, b.trip, b.scale, fg, jnp.asarray(env.goal),
               b.frame, b.robot, P.PlannerParams(depth=0))


def test_generator_properties():
    rng = np.random.default_rng(5)
    from pqrm_jax import compositions as C
    for _ in range(20):
        n = int(rng.integers(8, 13))
        env = E.generate(rng, n, 2.5)
        assert len(env.triplets) == n - 2
        assert set(itertools.chain(*env.triplets)) == set(range(n))
        assert C.is_composable(env.triplets, range(n))
        assert env.goal in env.triplets and not set(env.frame) <= set(env.goal)
        assert all(E.mec_radius(env.pos[list(t)]) <= 1.0 for t in env.triplets)


@pytest.mark.slow
def test_nothing_seen_branch(mod):
    """The EXTENSION (docs/bsp.md §nothing-seen): at depth 1 with every action kept, each
    action's value is c + P_seen · Σ_β w_β v_β + (1 − P_seen) · (h(F) + c̄), the renormalised
    tree's expectation mixed with staying; P_seen = min(1, Σ_β P(β | a)) from the model."""
    rng = np.random.default_rng(4)
    for _ in range(20):  # a study-like environment where P_seen varies over the actions
        env = E.generate(rng, 10, 2.5)
        b, fg = _graph(mod, env, True)
        i, j = (int(x) for x in b.frame)
        wt = np.asarray(jnp.einsum("b,bax,kxb->ak", b.scale[i, j], mod.T, fg.Ab[i, j])
                        * fg.obs[i, j][None])
        if wt.sum(1).min() < 0.5 < wt.sum(1).max():
            break
    goal = jnp.asarray(env.goal)
    plans = {}
    for flag in (False, True):
        pp = P.PlannerParams(depth=1, n_actions=20, nothing_seen=flag)
        plans[flag] = P.plan(jax.random.key(0), mod, D1, b.trip, b.scale, fg, goal,
                             b.frame, b.robot, pp)
    i, j = (int(x) for x in b.frame)
    sf = b.scale[i, j]
    wt = np.asarray(jnp.einsum("b,bax,kxb->ak", sf, mod.T, fg.Ab[i, j]) * fg.obs[i, j][None])
    seen = np.clip(wt.sum(1), 0, 1)
    cb = float(P.cbar(mod, D1, 1))
    stuck = float(P.leaf_values(fg, b.frame, cb, jnp.asarray(1.0e5), 10.0)) + cb
    cost = np.asarray(P.step_costs(mod, D1, sf, b.robot, 1))
    q0, q1 = ({int(a): float(v) for a, v in zip(np.asarray(plans[f].actions),
                                                np.asarray(plans[f].q), strict=True)}
              for f in (False, True))
    assert set(q0) == set(q1) == set(range(20))
    for a in range(20):
        if wt[a].sum() > 0:
            want = cost[a] + seen[a] * (q0[a] - cost[a]) + (1 - seen[a]) * stuck
            assert np.isclose(q1[a], want, rtol=1e-4), (a, q1[a], want)
    assert seen.min() < 0.5 < seen.max()  # the branch weight really varies over actions
    assert bool(plans[True].exists) == bool(plans[False].exists)


def test_planner_tables_and_graph_parts(mod):
    """The planner's precomputed tables equal their definitions (docs/bsp.md §planner): TA
    contracted with a frame's triplet rows gives the frame graph's P(β | a) from ``Ab``, the
    ẑ CDF draws what ``sample_index`` draws; ``frame_graph`` is ``visibility`` + ``link_hops``."""
    env = fig46_env(np.random.default_rng(4))
    b, fg = _graph(mod, env, True)
    i, j = (int(x) for x in b.frame)
    sf = b.scale[i, j]
    want = jnp.einsum("b,bax,kxb->ak", sf, mod.T, fg.Ab[i, j])
    got = jnp.einsum("b,bat,kt->ak", sf, P.transition_association(mod), b.trip[i, j])
    got = jnp.where(G.available(b.trip_src, b.lm_mask)[i, j][None], got, 0.0)
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-5)
    np.testing.assert_allclose(np.asarray(mod.AZ_cdf[..., -1]), np.asarray(mod.A), atol=1e-5)
    # AZ_by_z[ẑ, b, s_x, s_τ] = AZ[s_x, s_τ, b, ẑ] (the planner's per-bin blocks)
    assert np.array_equal(np.asarray(mod.AZ_by_z),
                          np.transpose(np.asarray(mod.AZ), (3, 2, 0, 1)))
    for s in range(20):
        key, w = jax.random.key(s), mod.AZ[s % 20, (3 * s) % 20, s % 6]
        assert int(P.sample_cdf(key, jnp.cumsum(w))) == int(P.sample_index(key, w))
    _, pvis = G.visibility(mod, b.trip, b.trip_src, b.scale, b.lm_mask)
    hops, goal_obs = G.link_hops(G.available(b.trip_src, b.lm_mask) & (pvis >= 0.01),
                                 jnp.asarray(env.goal))
    assert np.array_equal(np.asarray(hops), np.asarray(fg.hops))
    assert np.array_equal(np.asarray(goal_obs), np.asarray(fg.goal_obs))


@partial(jax.jit, static_argnums=1)
def _top_k_pair(x, k):
    return P.top_k(x, k), jax.lax.top_k(x, k)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 24), st.integers(1, 4), st.integers(0, 2 ** 31 - 1),
       st.sampled_from([1e-30, 1e-3, 1.0, 1e30]), st.booleans())
def test_top_k_equals_lax_top_k(n, rows, seed, scale, ties):
    """The planner's comparison-count ``top_k`` returns what ``jax.lax.top_k`` returns —
    values and indices, equal values in index order — over row lengths 1…24, scales
    1e-30…1e30, with and without ties (few distinct values, zeros, negatives)."""
    rng = np.random.default_rng(seed)
    x = (rng.integers(-2, 3, (rows, n)) if ties else rng.normal(size=(rows, n))) * scale
    x = jnp.asarray(x, jnp.float32)
    for k in sorted({1, min(3, n), n}):
        # one program a drawn shape and k (eager, each comparison step compiled apart)
        (v, i), (vw, iw) = _top_k_pair(x, k)
        assert np.array_equal(np.asarray(i), np.asarray(iw)), (x, k, i, iw)
        assert np.array_equal(np.asarray(v), np.asarray(vw))


@settings(max_examples=80, deadline=None)
@given(st.integers(2, 16), st.data())
def test_child_slots_place_every_child_in_its_frame(L, data):
    """The sort-free slots of one node's children (``_child_slots``) put every child in the
    slot of its own frame (:func:`_children`), distinct frames in distinct slots, equal
    frames in one: what ``jnp.unique`` gives up to the order of the slots — over frame
    orders (i < j and i > j), candidate sets with repeats, zero weights and 2…16 landmarks."""
    i, j = data.draw(st.lists(st.integers(0, L - 1), min_size=2, max_size=2, unique=True))
    others = [k for k in range(L) if k not in (i, j)]
    na, nb = data.draw(st.integers(1, 4)), data.draw(st.integers(1, 3))
    ks = np.array(data.draw(st.lists(st.sampled_from(others) if others else st.just(0),
                                     min_size=na * nb, max_size=na * nb))).reshape(na, nb)
    w = np.array(data.draw(st.lists(st.sampled_from([0.0, 0.3, 1.0]), min_size=na * nb,
                                    max_size=na * nb)), np.float32).reshape(na, nb)
    if not others:
        w[:] = 0.0  # no third landmark: nothing is observable
    frame = jnp.asarray([i, j], jnp.int32)
    ks, w = jnp.asarray(ks, jnp.int32), jnp.asarray(w)
    slot, sframes = P._child_slots(L, frame, ks, w)
    children = np.asarray(P._children(frame, ks, w)).reshape(-1, 2)
    slot, sframes = np.asarray(slot), np.asarray(sframes)
    assert sframes.shape == (1 + 2 * (L - 2), 2)
    assert np.array_equal(sframes[slot], children)
    assert len({tuple(f) for f in sframes.tolist()}) == len(sframes)  # no frame twice


def test_child_slots_and_sorted_slots_give_the_same_plans(mod):
    """Depth 2 with the children's frame parts placed by ``_child_slots`` (L − 2 ≤
    n_actions · n_beta) equals the same planner with the level's frames sorted into slots by
    ``jnp.unique`` (the path for more landmarks): plans identical, on several environments
    and both costs."""
    orig = P._child_slots

    def sorted_slots(L, frame, ks, w):  # the unique-sorted slots of the same children
        return P._sorted_slots(P._children(frame, ks, w).reshape(-1, 2), 1 + 2 * (L - 2), L)

    cases = []
    for e, env in enumerate(_small_envs(4, n=7, seed=3)):
        b, fg = _graph(mod, env, True, key=e)
        cases += [(jax.random.key(e), mod, D1, b.trip, b.scale, fg, jnp.asarray(env.goal),
                   b.frame, b.robot, P.PlannerParams(depth=2), jnp.int32(c)) for c in (1, 2)]
    fast = [P.plan(*c) for c in cases]
    P._child_slots = sorted_slots
    try:
        P.plan.clear_cache()
        slow = [P.plan(*c) for c in cases]
    finally:
        P._child_slots = orig
        P.plan.clear_cache()
    for n, (f, s) in enumerate(zip(fast, slow, strict=True)):
        for a, c in zip(jax.tree.leaves(f), jax.tree.leaves(s), strict=True):
            assert np.array_equal(np.asarray(a), np.asarray(c)), n


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.integers(1, 9))
def test_node_costs_and_link_operators_equal_their_definitions(mod, seed, n):
    """``node_costs`` (one product for all nodes) equals :func:`step_costs` node by node for
    both costs; ``link_operators`` applied to a joint (s_x, s_τ) gives the stay marginal and
    the two link models of Z eq. 4.24."""
    rng = np.random.default_rng(seed)
    Q, nb = mod.T.shape[1], mod.T.shape[0]
    robots = jnp.asarray(rng.dirichlet(np.ones(Q), n), jnp.float32)
    sfs = jnp.asarray(rng.dirichlet(np.ones(nb), n), jnp.float32)
    for cost in (1, 2):
        got = P.node_costs(mod, D1, sfs, robots, cost)
        want = jnp.stack([P.step_costs(mod, D1, sfs[m], robots[m], cost) for m in range(n)])
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=2e-5, atol=1e-7)
    J = jnp.asarray(rng.dirichlet(np.ones(Q * Q)).reshape(Q, Q), jnp.float32)
    got = (J.reshape(-1) @ P.link_operators(mod)).reshape(3, Q)
    want = [J.sum(1)] + [jnp.einsum("xt,xts->s", J, mod.K[k]) for k in LINK_K]
    np.testing.assert_allclose(np.asarray(got), np.asarray(jnp.stack(want)), atol=1e-6)


def test_depth_one_values_from_the_definitions(mod):
    """At depth 1 every first-level value is c(p, a) + Σ_β w_β min(h(F), h(i, k), h(j, k))
    (0 for the goal triplet) over the n_beta likeliest observable candidates, renormalised
    (module docstring of ``planner``) — recomputed here from the public pieces
    (``step_costs``, ``transition_association``, ``leaf_values``) for random environments, both
    costs; the planner computes the same from per-frame tables instead of child frames."""
    pp = P.PlannerParams(depth=1)
    for e, env in enumerate(_small_envs(4)):
        b, fg = _graph(mod, env, True, key=e)
        goal = jnp.asarray(env.goal)
        i, j = (int(x) for x in b.frame)
        for cost in (1, 2):
            out = P.plan(jax.random.key(e), mod, D1, b.trip, b.scale, fg, goal, b.frame,
                         b.robot, pp, cost=cost)
            cb = P.cbar(mod, D1, cost)
            lam = jnp.float32(pp.lam)
            sf = b.scale[i, j]
            c = P.step_costs(mod, D1, sf, b.robot, cost)
            wt = jnp.einsum("b,bat,kt->ak", sf, P.transition_association(mod), b.trip[i, j])
            wt = np.asarray(jnp.where(fg.obs[i, j][None], wt, 0.0))

            def h(f, fg=fg, cb=cb, lam=lam):
                return float(P.leaf_values(fg, jnp.asarray(f), cb, lam, pp.rho))
            third = int(goal.sum()) - i - j
            for n, a in enumerate(np.asarray(out.actions)):
                ks = np.argsort(-wt[a], kind="stable")[:pp.n_beta]
                assert np.array_equal(ks[wt[a, ks] > 0], np.asarray(out.ks[n])[wt[a, ks] > 0])
                w = wt[a, ks] / wt[a, ks].sum()
                vb = [0.0 if (bool(fg.goal_obs[i, j]) and k == third)
                      else min(h([i, j]), h([i, k]), h([j, k])) for k in ks]
                want = float(c[a]) + float(np.dot(w, vb))
                assert np.isclose(float(out.q[n]), want, rtol=1e-5), (e, cost, a, out.q[n], want)


# ------------------------------------------------------------------ the planner's draws
@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(0, 2 ** 32 - 1),
       st.lists(st.integers(0, 2 ** 32 - 1), min_size=1, max_size=6), st.integers(1, 7))
def test_draws_equal_jax_random(w0, w1, data, n):
    """bsp.draws' unrolled threefry gives jax.random's fold_in, split and uniform bit for
    bit (typed and raw keys, counters up to 2³² − 1), so the planner keeps its draws."""
    from pqrm_jax.bsp import draws

    words = jnp.asarray([w0, w1], jnp.uint32)
    key = jax.random.wrap_key_data(words)
    assert np.array_equal(draws.key_words(key), words)
    assert np.array_equal(draws.key_words(words), words)
    d = jnp.asarray(data, jnp.uint32)
    want = jax.random.key_data(jax.vmap(lambda x: jax.random.fold_in(key, x))(d))
    assert np.array_equal(draws.fold_in(words, d), want)
    subs = jax.random.key_data(jax.random.split(key, n))
    for i in range(n):
        assert np.array_equal(draws.split(words, i), subs[i])
    batch = jax.random.split(key, 5)
    got = draws.uniform(draws.key_words(batch))
    assert np.array_equal(got, jax.vmap(jax.random.uniform)(batch))
    assert np.all((got >= 0) & (got < 1))


def test_draws_refuse_other_keys():
    from pqrm_jax.bsp import draws

    with pytest.raises(ValueError, match="key: .*threefry2x32"):
        draws.key_words(jax.random.key(0, impl="rbg"))
    with pytest.raises(ValueError, match="key: expected"):
        draws.key_words(jnp.zeros(3, jnp.int32))
