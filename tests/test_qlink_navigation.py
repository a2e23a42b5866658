"""Q-Link trajectory level, executive and path-completion guarantees (P §4.3.4, Props. 1–4)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import sim
from pqrm_jax.qlink import elements as qel
from pqrm_jax.qlink import guarantees as gu
from pqrm_jax.qlink import linkgraph as lg
from pqrm_jax.qlink import navigate as nav
from pqrm_jax.qlink import trajectory as tr

R = 15.0
SIZE = (60.0, 60.0)


@pytest.fixture(scope="module")
def world():
    """A world satisfying Assumption 1 with a 5 % margin: elements co-observed at range R, kept
    when their minimum enclosing circle has radius <= 0.95 R; exact relations (no map noise)."""
    lm = sim.uniform_landmarks(jax.random.key(11), 30, size=SIZE)
    poses = sim.lawnmower(SIZE, spacing=R, step=1.0)
    vis = np.asarray(jax.vmap(sim.visibility, (0, None, None))(
        poses, lm, sim.SensorParams(max_range=R)))
    ids, _ = qel.co_observed_triplets(vis, 1)
    ids = ids[gu.assumption1(lm, ids, 0.95 * R)]
    el = qel.exact_elements(lm, ids)
    g = lg.link_graph(el, 2)
    inc = qel.incidence(el)
    lms = np.flatnonzero(inc.any(1))
    goal_row = np.full(el.num_landmarks, -1)
    goal_row[lms] = np.arange(len(lms))
    to_go = lg.goal_distances(g, el, lms)
    rng = np.random.default_rng(0)
    pairs = np.array([(s, t) for s in lms for t in lms if s != t])
    pairs = pairs[rng.choice(len(pairs), 96, replace=False)]
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(96))
    return dict(lm=lm, el=el, g=g, to_go=to_go, goal_row=goal_row,
                tables=nav.start_tables(el), pairs=pairs, keys=keys)


def _run(w, frac=1.0, occ=0.0, sigma=0.0, **kw):
    p = nav.NavParams(map_range=R, nav_range=frac * R, occluder_radius=occ, sigma=sigma,
                      ds=R / 40, start_offset=R / 20, **kw)
    return nav.navigate_pairs(nav.Trials(w["keys"], w["pairs"][:, 0], w["pairs"][:, 1]),
                              _map(w), p)


def _map(w):
    return nav.NavMap(w["lm"], w["el"], w["g"], w["to_go"], w["goal_row"], w["tables"])


def test_prop1_geometry_lemmas():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-R, R, (20000, 3, 2))
    pts = pts[gu.mec_radius(pts) <= R]
    a, b, e = pts[:, 0], pts[:, 1], pts[:, 2]
    # (a) the circle of radius R about a member has a point within R of every other member
    u = (e - a) / np.linalg.norm(e - a, axis=1, keepdims=True)
    assert (np.linalg.norm(a + R * u - e, axis=1) <= R * (1 + 1e-9)).all()
    # (b) the quarter arc of radius R about the midpoint in e's quadrant passes within R of e
    from pqrm_jax import calculi
    q = np.asarray(calculi.get("quadrant").classify(jnp.asarray(a), jnp.asarray(b),
                                                    jnp.asarray(e)))
    centre, lo = jax.vmap(tr.quadrant_wedge)(jnp.asarray(a), jnp.asarray(b), jnp.asarray(q))
    d = jax.vmap(tr.arc_min_distance, (0, 0, None, 0))(jnp.asarray(e), centre, R, lo)
    assert float(jnp.max(d)) <= R * (1 + 1e-5)


def test_arc_primitive_drives_a_quarter_circle():
    m = tr.arc_motion(jnp.array([0.0, -3.0]), jnp.zeros(2), 10.0, -jnp.pi / 2)
    pose, length, on_arc = jnp.array([0.0, -3.0, 0.3]), 0.0, []
    for _ in range(400):
        u, m = tr.motion_control(pose, m, 0.25, 0.5, 1.0)
        pose = sim.step(sim.RoverState(pose, jnp.zeros(())), u,
                        sim.RoverParams(dt=1.0, max_speed=0.25, max_turn_rate=0.5)).pose
        length += float(u[0])
        m, done = tr.advance(m, u, 1.0)
        if int(m.stage) == 1:
            on_arc.append(float(jnp.linalg.norm(pose[:2])))
        if bool(done):
            break
    assert bool(done)
    np.testing.assert_allclose(on_arc, 10.0, atol=1e-3)
    np.testing.assert_allclose(length, 7.0 + np.pi * 10.0 / 2, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(pose[:2]), [10.0, 0.0], atol=1e-2)


def test_no_failure_at_full_range_and_prop2_bounds(world):
    qlink = _run(world)
    assert qlink.reachable.all()
    assert (qlink.status == nav.SUCCESS).all()              # 0 % failure at R' = R
    n = qlink.n_elements
    for k in np.unique(n):                                   # Fig. 4.7: means under the bound
        assert qlink.length[n == k].mean() < gu.bound_prop2(k, R)
    circ = _run(world, circle_only=1.0)
    assert (circ.status == nav.SUCCESS).all()
    # Prop. 2 per trial: each of the |P| transitions (localisation into M_1 included) and the
    # goal search cost at most (2π + 1) R
    assert (circ.length <= gu.bound_prop2(circ.n_elements + 1, R) * (1 + 1e-4)).all()


def test_smaller_range_fails_with_reasons(world):
    r = _run(world, frac=0.6)
    fail = r.reachable & (r.status != nav.SUCCESS)
    assert fail.any()
    assert set(np.unique(r.status[fail])) <= {nav.LINK_NOT_FOUND, nav.REFS_NOT_FOUND,
                                              nav.GOAL_NOT_FOUND}


def test_props_3_4_straight_drives():
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, R, (5000, 3, 2))
    tri = pts[np.array([gu.assumption3(p, np.array([[0, 1, 2]]), R)[0] for p in pts])]
    s = np.linspace(0, 1, 41)[None, :, None]
    for a, b, c in tri[:500]:
        path = a + s[0] * (b - a)                            # straight drive L_n -> L_k
        assert (np.linalg.norm(path - a, axis=1) <= R + 1e-9).all()
        assert (np.linalg.norm(path - b, axis=1) <= R + 1e-9).all()
        assert np.linalg.norm(b - a) <= gu.bound_prop4(1, R)
        _ = c


def test_partial_occlusion_matches_sampled_oracle():
    rng = np.random.default_rng(2)
    r = 0.4
    disagree = 0
    total = 0
    for _ in range(60):
        lm = rng.uniform(-10, 10, (12, 2))
        pos = np.zeros(2)
        vis = np.asarray(sim.disc_visibility(jnp.asarray(pos), jnp.asarray(lm), 30.0, r))
        for t in range(len(lm)):
            d_t = np.linalg.norm(lm[t])
            if d_t <= r:
                continue
            # oracle: is any sampled point of t's disc hidden behind a nearer disc?
            th = rng.uniform(0, 2 * np.pi, 400)
            rad = r * np.sqrt(rng.uniform(0, 1, (400, 1)))
            pts = lm[t] + rad * np.stack([np.cos(th), np.sin(th)], 1)
            hidden = False
            for k in range(len(lm)):
                if k == t or np.linalg.norm(lm[k]) >= d_t:
                    continue
                dirs = pts / np.linalg.norm(pts, axis=1, keepdims=True)
                proj = dirs @ lm[k]
                perp = np.linalg.norm(lm[k] - proj[:, None] * dirs, axis=1)
                hidden |= bool(np.any((perp < r) & (proj > 0)))
            total += 1
            disagree += hidden == bool(vis[t])
    assert disagree / total < 0.02
    lm = jnp.asarray(rng.uniform(-10, 10, (30, 2)))
    d = jnp.linalg.norm(lm, axis=1)
    assert (np.asarray(sim.disc_visibility(jnp.zeros(2), lm, 8.0, 0.0)) ==
            np.asarray(d <= 8.0)).all()


@pytest.mark.parametrize("cases", [((20.0, 0.35), (6.0, 2.5)),
                                   pytest.param(((5.0, 0.05), (3.0, 0.0)),
                                                marks=pytest.mark.slow)])
def test_local_visibility_equals_testing_every_landmark(cases):
    # occluder_table's reach (2R', or max(R' + 2r, 4r) with r known) loses no occluder; the
    # default cases take each branch of the reach (R' + 2r and 4r); each table width compiles
    rng = np.random.default_rng(4 + int(cases[0][0]))
    vis = jax.jit(jax.vmap(sim.local_target_visibility, (0, None, 0, 0, None, None)))
    for rng_range, r in cases:
        lm = jnp.asarray(rng.uniform(0, 30, (150, 2)))
        pos = jnp.asarray(rng.uniform(0, 30, (400, 2)))
        targets = jnp.asarray(rng.integers(-1, 150, (400, 6)))
        full = jax.vmap(sim.target_visibility, (0, None, 0, None, None))(
            pos, lm, targets, rng_range, r)
        for tab in (sim.occluder_table(lm, rng_range), sim.occluder_table(lm, rng_range, r)):
            occ = jnp.asarray(tab)[jnp.maximum(targets, 0)]
            loc = vis(pos, lm, targets, occ, rng_range, r)
            assert (np.asarray(loc) == np.asarray(full)).all()
        assert np.asarray(full).any() and not np.asarray(full).all()
    with pytest.raises(ValueError, match="max_range"):
        sim.occluder_table(np.zeros((3, 2)), 0.0)
    with pytest.raises(ValueError, match="radius"):
        sim.occluder_table(np.zeros((3, 2)), 1.0, -0.1)


def test_plan_from_matches_the_dense_walk_and_is_optimal():
    # unit costs: plan_from follows the recorded successors, which equal a NumPy walk over
    # the dense [E, E] matrix (argmin of cost + cost-to-go, ties to the smaller index);
    # other costs (ties broken either way): every path is simple, ends at the goal and costs
    # exactly the cost-to-go of its first element
    rng = np.random.default_rng(6)
    lm = jnp.asarray(rng.uniform(0, 40, (25, 2)))
    vis = np.asarray(jax.vmap(sim.visibility, (0, None, None))(
        sim.lawnmower((40.0, 40.0), spacing=12.0, step=2.0), lm, sim.SensorParams(max_range=12.0)))
    ids, _ = qel.co_observed_triplets(vis, 1)
    el = qel.exact_elements(lm, ids)
    e = ids.shape[0]
    for cost in (None, rng.integers(1, 4, (e, e)).astype(float)):
        g = lg.link_graph(el, 2, cost)
        lms = np.flatnonzero(qel.incidence(el).any(1))
        table = lg.goal_distances(g, el, lms)
        to_go = np.asarray(table.cost)
        rows = rng.integers(0, len(lms), 64)
        cands = rng.integers(-1, e, (64, 5))
        cands[:, 0] = rng.integers(0, e, 64)
        plan = lg.plan_from(g, table, rows, cands, 40)
        dense = np.where(g.adjacency, g.cost, np.inf)
        for i in range(64):
            d = to_go[rows[i]]
            c = cands[i][cands[i] >= 0]
            u = int(c[np.argmin(d[c])])
            got = np.asarray(plan.path[i])
            got = got[got >= 0].tolist()
            assert int(plan.n_elements[i]) == len(got)
            if not np.isfinite(d[u]):
                assert got == [] and not bool(plan.reachable[i])
                continue
            assert got[0] == u and len(set(got)) == len(got)
            assert lms[rows[i]] in ids[got[-1]]
            assert lg.path_cost(g, np.array(got)) == pytest.approx(d[u], rel=1e-6)
            if cost is None:
                want = [u]
                while d[u] > 0:
                    row = dense[u] + d
                    row[u] = np.inf
                    u = int(np.argmin(row))
                    want.append(u)
                assert got == want


def test_results_do_not_depend_on_the_batch_or_lanes(world):
    # per-trial keys: a trial gives the same outcome alone, in a small batch, and among 96
    # trials queued on the 64 lanes of the pool (lanes that finish take the next trial)
    w = world
    full = _run(w, frac=0.8, sigma=0.3)
    p = nav.NavParams(map_range=R, nav_range=0.8 * R, sigma=0.3, ds=R / 40, start_offset=R / 20)
    for sl in (slice(5, 9), slice(90, 91)):
        part = nav.navigate_pairs(nav.Trials(w["keys"][sl], w["pairs"][sl, 0],
                                             w["pairs"][sl, 1]), _map(w), p)
        assert (full.status[sl] == part.status).all()
        np.testing.assert_allclose(full.length[sl], part.length, rtol=1e-5)
        np.testing.assert_array_equal(np.asarray(full.nav.steps)[sl], np.asarray(part.nav.steps))
    assert len(w["pairs"]) > 64 and len(set(np.asarray(full.nav.steps).tolist())) > 1


@pytest.mark.slow
def test_results_do_not_depend_on_the_lane_count(world):
    w = world
    p = nav.NavParams(map_range=R, nav_range=0.8 * R, sigma=0.3, ds=R / 40, start_offset=R / 20)
    a, b = (nav.navigate_pairs(nav.Trials(w["keys"], w["pairs"][:, 0], w["pairs"][:, 1]),
                               _map(w), p, chunk=c) for c in (4, 64))
    assert (a.status == b.status).all()
    np.testing.assert_allclose(a.length, b.length, rtol=1e-5)


def test_budget_and_bad_input(world):
    w = world
    s, t = w["pairs"][:4, 0], w["pairs"][:4, 1]
    plan = lg.plan_pairs(w["g"], w["el"], s, t)
    p = nav.NavParams(map_range=R, nav_range=R, ds=R / 40)
    tri = nav.Trials(w["keys"][:4], s, t, np.asarray(plan.path), np.asarray(plan.n_elements))
    world_ = nav.NavMap(w["lm"], w["el"])
    r = nav.navigate(tri._replace(budget=np.full(4, 3)), world_, p)
    assert (np.asarray(r.status) == nav.BUDGET).all()        # ends with a reason, no hang
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="nav_range"):
            nav.navigate(tri, world_, p._replace(nav_range=bad))
    with pytest.raises(ValueError, match="NaN"):
        nav.navigate(tri._replace(poses=jnp.full((4, 3), jnp.nan)), world_, p)
    with pytest.raises(ValueError, match="path"):
        nav.navigate(tri._replace(n_elements=np.zeros(4)), world_, p)
    with pytest.raises(ValueError, match="not in the map"):
        lg.plan_pairs(w["g"], w["el"], [999], [int(t[0])])


@pytest.mark.slow
def test_unreachable_goal_is_reported_not_failed():
    # two clusters far apart: no Link Graph path between them
    a = np.array([[0, 0], [5, 0], [2, 4], [6, 5]], float)
    lm = jnp.asarray(np.concatenate([a, a + 500.0]))
    el = qel.exact_elements(lm, np.array([[0, 1, 2], [1, 2, 3], [4, 5, 6], [5, 6, 7]]))
    g = lg.link_graph(el, 2)
    to_go = lg.goal_distances(g, el, np.arange(8))
    p = nav.NavParams(map_range=R, nav_range=R, ds=R / 40)
    r = nav.navigate_pairs(nav.Trials(jax.random.split(jax.random.key(0), 2), [0, 0], [3, 7]),
                           nav.NavMap(lm, el, g, to_go, np.arange(8), nav.start_tables(el)), p)
    assert r.reachable.tolist() == [True, False]
    assert int(r.status[0]) == nav.SUCCESS and int(r.n_elements[1]) == 0
    assert int(r.status[1]) == nav.UNREACHABLE           # its own status, not "running"


@pytest.mark.slow
def test_contingency_replanning_resumes_failed_trials(world):
    w = world
    p = nav.NavParams(map_range=R, nav_range=0.6 * R, sigma=0.0, ds=R / 40, start_offset=R / 20)
    s, t = w["pairs"][:, 0], w["pairs"][:, 1]
    plan = lg.plan_pairs(w["g"], w["el"], s, t)
    first = nav.navigate(nav.Trials(w["keys"], s, t, np.asarray(plan.path),
                                    np.asarray(plan.n_elements)), nav.NavMap(w["lm"], w["el"]), p)
    idx, paths, n = nav.replan_inputs(first, w["lm"], w["el"], w["g"], t, plan.path, p)
    st = np.asarray(first.status)
    assert idx.size and set(st[idx]) <= {nav.LINK_NOT_FOUND, nav.REFS_NOT_FOUND}
    ids = np.asarray(w["el"].ids)
    for j, i in enumerate(idx):
        vis = np.asarray(sim.disc_visibility(first.pose[i, :2], w["lm"], p.nav_range, 0.0))
        assert vis[ids[paths[j, 0]]].sum() >= 2            # starts from an element in view
        assert t[i] in ids[paths[j, n[j] - 1]]              # ends at the goal
        k = int(first.k[i])
        failed = (int(plan.path[i, max(k, 0)]), int(plan.path[i, k + 1]))
        assert failed not in set(zip(paths[j, :-1].tolist(), paths[j, 1:].tolist(),
                                     strict=True))
    start_lm = ids[paths[:, 0], 0]
    again = nav.navigate(nav.Trials(w["keys"][idx], start_lm, t[idx], paths, n,
                                    first.pose[idx]), nav.NavMap(w["lm"], w["el"]), p)
    assert (np.asarray(again.status) != nav.RUNNING).all()
