"""SERGE (Padgett ch. 3): beliefs, cells, potential, merge search, tree, QSR, relaxed."""

import jax
import numpy as np
import pytest

from pqrm_jax.serge import (
    GaussianBeliefs,
    Grid,
    SampleBeliefs,
    components_per_label,
    direct_log_potential,
    initial_cells,
    problem_from_partition,
    serge,
    serge_sequential,
)
from pqrm_jax.serge.qsr import SergeCalculus, triplet_beliefs
from pqrm_jax.serge.relaxed import project_contiguous, relaxed_serge
from pqrm_jax.serge.scenes import from_frame, to_frame
from pqrm_jax.serge.tree import ResolutionTree

KEY = jax.random.PRNGKey(0)


def lattice(n=3, spacing=10.0, var=0.2):
    xy = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    return GaussianBeliefs(xy * spacing, np.tile(np.eye(2) * var, (n * n, 1, 1)))


@pytest.fixture(scope="module")
def separated():
    return initial_cells(jax.random.PRNGKey(0),
                         lattice(), Grid((-5.0, -5.0), (25.0, 25.0), (30, 30)))


@pytest.fixture(scope="module")
def overlapping():
    rng = np.random.default_rng(3)
    means = rng.uniform(0, 6, (10, 2))
    covs = np.array([np.diag(rng.uniform(0.2, 1.0, 2)) for _ in range(10)])
    return initial_cells(jax.random.PRNGKey(0),
                         GaussianBeliefs(means, covs), Grid((-2.0, -2.0), (8.0, 8.0), (40, 40)),
                         unseparated="attach")


def assert_contiguous(labels, shape):
    omega = components_per_label(labels, shape)
    assert omega and all(v == 1 for v in omega.values()), omega


# grid, beliefs, cells ---------------------------------------------------------------------
def test_grid_clips_and_partitions_plane():
    g = Grid((0.0, 0.0), (2.0, 2.0), (2, 2))
    cells = g.cell_of(np.array([[-5.0, -5.0], [0.5, 1.5], [9.0, 0.1], [9.0, 9.0]]))
    assert cells.tolist() == [0, 1, 2, 3]
    assert len(g.edges()) == 4


def test_initial_cells_are_contiguous_one_per_belief(separated, overlapping):
    for p in (separated, overlapping):
        assert_contiguous(p.cell_region, p.grid.shape)
        assert len(np.unique(p.cell_region)) == p.n_init
        np.testing.assert_allclose(np.asarray(p.mass).sum(axis=1), 1.0, atol=1e-5)
    assert separated.n_init == 9
    np.testing.assert_allclose(np.asarray(separated.mass), np.eye(9), atol=1e-6)


def test_bad_input_errors(separated):
    with pytest.raises(ValueError, match="mu"):
        serge(KEY, separated, 0, 2.0, trials=2)
    with pytest.raises(ValueError, match="mu"):
        serge(KEY, separated, 10, 2.0, trials=2)
    with pytest.raises(ValueError, match="sigma"):
        serge(KEY, separated, 3, -1.0, trials=2)
    bad = np.zeros((2, 5, 2))
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"beliefs \[1\].*NaN"):
        SampleBeliefs(bad)
    with pytest.raises(ValueError, match="empty"):
        SampleBeliefs(np.zeros((2, 0, 2)))
    with pytest.raises(ValueError, match="semidefinite"):
        GaussianBeliefs(np.zeros((1, 2)), np.array([[[1.0, 0.0], [0.0, -1.0]]]))
    # two beliefs in one coarse cell: the grid cannot separate them
    close = GaussianBeliefs(np.array([[0.0, 0.0], [0.05, 0.0], [5.0, 5.0]]),
                            np.tile(np.eye(2) * 1e-4, (3, 1, 1)))
    coarse = Grid((-1.0, -1.0), (6.0, 6.0), (4, 4))
    with pytest.raises(ValueError, match=r"beliefs \[1\].*too coarse"):
        initial_cells(jax.random.PRNGKey(0), close, coarse)
    p = initial_cells(jax.random.PRNGKey(0), close, coarse, unseparated="attach")
    assert p.n_init == 2 and np.asarray(p.belief_region).tolist() == [0, 0, 1]


def test_degenerate_point_mass_belief_is_handled():
    b = GaussianBeliefs(np.array([[0.0, 0.0], [3.0, 0.0]]), np.zeros((2, 2, 2)))
    p = initial_cells(jax.random.PRNGKey(0), b, Grid((-1.0, -1.0), (4.0, 1.0), (10, 4)))
    np.testing.assert_allclose(np.asarray(p.mass), np.eye(2), atol=1e-6)


# potential and search -----------------------------------------------------------------------
@pytest.mark.parametrize("mu", [1, 3, 5, 9])
def test_well_separated_gives_mu_regions_saliency_one(separated, mu):
    r = serge(KEY, separated, mu, 2.0, trials=16)
    assert r.n_regions == mu
    assert abs(r.log_psi3) < 1e-5
    assert_contiguous(r.cell_labels, separated.grid.shape)
    # every belief's samples fall in its own region: zero classification errors
    pts = np.asarray(lattice().sample(jax.random.PRNGKey(5), 200))
    for k in range(9):
        assert np.all(r.label_points(pts[k]) == r.belief_labels[k])


@pytest.mark.parametrize("mu,sigma", [(1, 2.0), (4, 2.0), (7, 0.5), (10, 2.0), (6, 0.0)])
def test_potential_in_log_space_matches_direct_evaluation(overlapping, mu, sigma):
    r = serge(KEY, overlapping, mu, sigma, trials=16)
    assert_contiguous(r.cell_labels, overlapping.grid.shape)
    direct = direct_log_potential(overlapping.cell_mass, r.cell_labels, r.belief_labels, mu,
                                  sigma, overlapping.grid.shape)
    assert np.isfinite(direct)
    np.testing.assert_allclose(r.log_psi, direct, rtol=2e-4, atol=2e-4)
    # the best trial is the maximum over trials
    assert r.log_psi == pytest.approx(r.trial_log_psi.max())
    if sigma == 0.0:
        assert r.n_regions == mu


def test_direct_potential_is_minus_inf_for_disconnected_map(overlapping):
    lab = np.zeros(overlapping.grid.n_cells, int)
    lab[:40] = 1
    lab[-40:] = 1                                   # region 1 in two pieces
    bl = np.zeros(overlapping.k, int)
    assert direct_log_potential(overlapping.cell_mass, lab, bl, 2, 2.0,
                                overlapping.grid.shape) == -np.inf


def test_batched_trials_equal_sequential_loop(overlapping):
    a = serge(KEY, overlapping, 4, 2.0, trials=16)
    b = serge_sequential(KEY, overlapping, 4, 2.0, trials=16)
    np.testing.assert_allclose(a.trial_log_psi, b.trial_log_psi, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    np.testing.assert_array_equal(a.cell_labels, b.cell_labels)


def test_batched_blocks_with_finished_trials_equal_sequential_loop(overlapping):
    """Several blocks (T > WIDTH, last block padded): trials that converge early keep their
    state while the rest of their block runs on."""
    from pqrm_jax.serge import search as S

    t = 2 * S.WIDTH + 7
    a = serge(KEY, overlapping, 6, 2.0, trials=t)
    b = serge_sequential(KEY, overlapping, 6, 2.0, trials=t)
    assert len(set(a.iterations.tolist())) > 1
    np.testing.assert_array_equal(a.iterations, b.iterations)
    np.testing.assert_allclose(a.trial_log_psi, b.trial_log_psi, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(a.cell_labels, b.cell_labels)


def test_search_bit_set_and_argmax_helpers():
    import jax.numpy as jnp

    from pqrm_jax.serge import search as S

    rng = np.random.default_rng(0)
    mask = rng.random((6, 70)) < 0.15
    mask[0] = False                                                # empty set
    mask[1, [0, 31, 32, 69]] = True                                # word boundaries
    words = S._bitset(jnp.asarray(mask))
    assert words.shape == (6, 3) and words.dtype == jnp.uint32
    for r in range(6):
        want = np.flatnonzero(mask[r])
        got, w = [], words[r]
        while True:
            idx, found, w = S._pop_lowest(w, S.BLOCK)
            got += np.asarray(idx)[np.asarray(found)].tolist()
            assert np.all(np.asarray(idx)[~np.asarray(found)] == 0)
            if not np.any(np.asarray(w)):
                break
        assert got == want.tolist()
    x = jnp.asarray(np.array([[-np.inf] * 5, [1.0, 3.0, 3.0, -np.inf, 0.0],
                              [0.5, 0.25, 0.5, 0.5, -1.0]], np.float32))
    idx, m = jax.vmap(S._argmax)(x)
    np.testing.assert_array_equal(idx, jnp.argmax(x, axis=1))
    np.testing.assert_array_equal(m, jnp.max(x, axis=1))


def test_larger_sigma_fewer_regions_higher_saliency(overlapping):
    small = serge(KEY, overlapping, 9, 0.5, trials=16)
    large = serge(KEY, overlapping, 9, 8.0, trials=16)
    assert large.n_regions <= small.n_regions
    assert large.log_psi3 >= small.log_psi3 - 1e-6
    assert small.n_regions == 9 or small.n_regions == overlapping.n_init


# resolution tree ----------------------------------------------------------------------------
def test_resolution_tree_levels_and_branches(separated):
    t = ResolutionTree.build(separated, key=KEY, mu=2, sigma=1.0, trials=16)
    assert len(np.unique(t.map_at(0))) == 1
    counts = [len(np.unique(t.map_at(lv))) for lv in range(t.depth + 1)]
    assert counts == sorted(counts) and counts[-1] == 9      # finest level = C_init
    for lv in range(t.depth + 1):
        assert_contiguous(t.map_at(lv), separated.grid.shape)
    # per-branch resolution: refine only the first child of the root
    first, second = t.nodes[0].children
    frontier = [*t.nodes[first].children, second]
    lab = t.map_of(frontier)
    assert len(np.unique(lab)) == len(frontier)
    assert_contiguous(lab, separated.grid.shape)
    with pytest.raises(ValueError, match="cover"):
        t.map_of([first])


# SERGE as a calculus -------------------------------------------------------------------------
def test_frame_roundtrip_and_triplet_beliefs():
    rng = np.random.default_rng(0)
    d, e, f = rng.normal(size=(3, 50, 2))
    p = to_frame(d, e, f)
    np.testing.assert_allclose(from_frame(d, e, p), f, atol=1e-9)
    b = triplet_beliefs(d[None], e[None], f[None])
    np.testing.assert_allclose(b.samples[0], p, atol=1e-5)
    with pytest.raises(ValueError, match="D = E"):
        triplet_beliefs(d[None], d[None], f[None])


def test_serge_calculus_classify_and_sentinels():
    g = Grid((-3.0, -3.0), (3.0, 4.0), (12, 14))
    c = g.centers()
    lab = (c[:, 0] > 0).astype(int) + 2 * (c[:, 1] > 0.5).astype(int)    # quadrant-like
    calc = SergeCalculus("q_learned", g, lab)
    assert calc.num_states == 4
    rng = np.random.default_rng(1)
    a, b, x = rng.normal(size=(3, 100, 2)) * 3
    got = np.asarray(jax.jit(calc.classify)(a, b, x))
    p = to_frame(a, b, x)
    want = (p[:, 0] > 0).astype(int) + 2 * (p[:, 1] > 0.5).astype(int)
    assert np.mean(got == want) > 0.99               # (float32 vs float64 at boundaries)
    s = np.asarray(calc.classify(np.zeros((2, 2)), np.array([[0.0, 0.0], [np.nan, 1.0]]),
                                 np.ones((2, 2))))
    assert s.tolist() == [-2, -3]


def test_alg3_compose_is_witnessed_and_within_exact_table():
    """Every SERGE compose entry is realised by a configuration of cell centres; for SRs equal
    to the quadrant calculus's regions it lies within the core's exact compose table."""
    from pqrm_jax import calculi

    g = Grid((-4.0, -3.5), (4.0, 4.5), (16, 16))                   # edges on α = 0, β = 0.5
    c = g.centers()
    quad = calculi.get("quadrant")
    lab = np.asarray(quad.classify(np.zeros((len(c), 2)), np.tile([0.0, 1.0], (len(c), 1)), c))
    assert lab.min() >= 0
    calc = SergeCalculus("quad_learned", g, lab, states=quad.states)
    comp = calc.compose_counts(stride=1) > 0
    assert comp.any(axis=2).all()                                 # every (p, q) has an outcome
    np.testing.assert_allclose(calc.compose_prob.sum(axis=2), 1.0)
    try:
        exact = np.asarray(quad.tables.compose)
    except Exception as exc:                                      # core tables still in flux
        pytest.skip(f"exact tables unavailable: {exc}")
    assert exact.shape == comp.shape
    assert not np.any(comp & ~exact), np.argwhere(comp & ~exact)[:5]


# relaxed optimiser ---------------------------------------------------------------------------
def test_projection_makes_slots_contiguous():
    adj = np.zeros((4, 4), bool)
    for i, j in [(0, 1), (1, 2), (2, 3)]:
        adj[i, j] = adj[j, i] = True
    start = project_contiguous(np.array([0, 1, 0, 0]), adj)        # slot 0 in two pieces
    assert start.tolist() == [0, 1, 2, 2]


def test_relaxed_optimiser_gives_valid_competitive_map(overlapping):
    rr = relaxed_serge(KEY, overlapping, 5, 2.0, steps=150, restarts=4, polish_trials=16)
    r = rr.result
    assert_contiguous(r.cell_labels, overlapping.grid.shape)
    assert r.log_psi >= rr.projected_log_psi - 1e-5                # polishing never hurts
    direct = direct_log_potential(overlapping.cell_mass, r.cell_labels, r.belief_labels, 5, 2.0,
                                  overlapping.grid.shape)
    np.testing.assert_allclose(r.log_psi, direct, rtol=2e-4, atol=2e-4)
    plain = serge(KEY, overlapping, 5, 2.0, trials=16)
    assert r.log_psi >= plain.log_psi - 2.0


def test_problem_from_partition_roundtrip(separated):
    p = problem_from_partition(separated.cell_mass, separated.grid, separated.cell_region,
                               separated.belief_region)
    np.testing.assert_allclose(np.asarray(p.mass), np.asarray(separated.mass), atol=1e-6)
    np.testing.assert_array_equal(np.asarray(p.adj), np.asarray(separated.adj))


@pytest.mark.parametrize("steps", [6, 30])
def test_incremental_pair_gains_equal_direct_evaluation(overlapping, steps):
    """The merge search's cached pair gains (updated only for the merged region) equal the
    direct [R0, R0] evaluation on the partial map, and log ψ3 equals the direct sum."""
    import jax.numpy as jnp

    from pqrm_jax.serge import search as S

    args = S.prepare_inputs(overlapping, 4, 2.0, None, None)
    init = S._init_state(*args[:5])
    for branch in (False, True):
        run = jax.jit(S._run_trial, static_argnames=("max_steps", "branch"))
        s = run(init, args[5], args[6], jax.random.PRNGKey(steps), max_steps=steps,
                branch=branch)
        lab, mt, g, lb, logs, sal, alive = s[:7]
        assert int(s[10]) <= steps
        # rebuild the partial map from scratch and evaluate the gains directly
        _, mt_d, a_d, lb_d, alive_d, bm = S._setup(*args[:3], lab, args[4])
        np.testing.assert_array_equal(np.asarray(alive), np.asarray(alive_d))
        np.testing.assert_array_equal(np.asarray(lb), np.asarray(lb_d))
        g_d = np.asarray(S.pair_gains(mt_d, a_d, lb_d, alive_d, bm))
        ok = np.asarray(alive)[:, None] & np.asarray(alive)[None, :]
        g_i = np.where(ok, np.asarray(g), -np.inf)
        np.testing.assert_array_equal(np.isfinite(g_i), np.isfinite(g_d))
        fin = np.isfinite(g_d)
        np.testing.assert_allclose(g_i[fin], g_d[fin], rtol=1e-4, atol=1e-4)
        direct3 = np.log(np.maximum(np.asarray(mt_d).T[np.arange(overlapping.k), lb_d],
                                    S.SAL_FLOOR)).sum()
        np.testing.assert_allclose(float(jnp.sum(logs)), direct3, rtol=1e-5, atol=1e-4)
