"""HSSH global levels driven by the simulator and the real local levels (B §8.1, §7.1.3, ch. 9).

One exploration of a small network with a loop (an L-L-T-L square, a T with a dead-end spur)
is shared by the tests: lidar -> scrolling LPM -> gateways -> local topology -> star views,
with noisy odometry, fed to the tree of maps.
"""

import numpy as np
import pytest

from pqrm_jax import hssh_global as hg
from pqrm_jax.hssh_global import simulation as hs

LOOP = {((0, 0), (1, 0)), ((1, 0), (2, 0)), ((0, 0), (0, 1)), ((1, 0), (1, 1)),
        ((0, 1), (1, 1)), ((2, 0), (2, 1))}


@pytest.fixture(scope="module")
def run():
    w = hg.world_from_lattice(LOOP)
    sw = hs.sim_world(w)
    se = hs.explore_sim(sw, 10, seed=1)
    log = hg.build_tree(se.experience)
    return w, sw, se, log


def test_views_from_local_levels_match_truth(run):
    w, _, se, _ = run
    ex = se.experience
    assert len(ex.views) == 11 and ex.turns.shape == (10,) and ex.odometry.shape == (10, 3)
    assert len(set(ex.true_places.tolist())) >= 5          # the loop and the spur were seen
    for v, p, a in zip(ex.views, ex.true_places, ex.true_arrivals, strict=True):
        assert hg.view_match(v, (w.stars[int(p)], int(a)))
    # odometry is the rover's dead reckoning: close to, but not equal to, the truth
    err = np.abs(ex.odometry - ex.true_odometry)
    err[:, 2] = np.abs((err[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    assert 0 < err[:, :2].max() < 0.05 and err[:, 2].max() < 0.1


def test_dead_end_read_at_the_dead_end(run):
    """Issue 26 item 4: a dead end's view is read where the dead end is (its end wall half a
    width ahead), not where the end wall first came into view (0.83 widths off before)."""
    w, sw, se, _ = run
    ex = se.experience
    ends = [i for i, p in enumerate(ex.true_places) if sum(w.stars[int(p)].alpha) == 1]
    assert ends, "the exploration reached the dead-end spur"
    d = np.hypot(*(se.true_poses[ends, :2] - w.positions[ex.true_places[ends]]).T) / sw.width
    assert d.max() < 0.25


def test_true_map_among_leaves_and_loop_closed(run):
    _, _, se, log = run
    ex = se.experience
    truth = [h for h in log.leaves if hg.is_true_map(h, ex)]
    assert len(truth) == 1
    h = truth[0]
    assert h.n_places == len(set(ex.true_places.tolist()))
    assert len(h.visits) > h.n_places                      # revisits were recognised


def test_layout_and_global_occupancy(run):
    _, sw, se, log = run
    ex = se.experience
    k = next(i for i, h in enumerate(log.leaves) if hg.is_true_map(h, ex))
    prob = hg.pack([log.leaves[k]], ex.odometry, 0.02, 0.02)
    chi, _ = hg.relax(prob)
    gt = hs.true_layout_sim(se)
    m = log.leaves[k].n_places
    err = np.linalg.norm(np.asarray(chi[0, :m, :2]) - gt[:, :2], axis=1).mean()
    assert err < 0.1                                        # lattice spacing 1
    grid, origin, res = hs.global_occupancy(sw, se, log.leaves[k], np.asarray(chi[0]))
    assert grid.ndim == 2 and res == pytest.approx(sw.width / hs.SimParams().cells)
    agree = hs.map_agreement(sw, grid, origin, res, se.true_dividing[0])
    assert agree > 0.6
    # the same snapshots placed by a wrong frame do not agree with the walls
    shifted = hs.map_agreement(sw, grid, origin + 0.5 * sw.width, res, se.true_dividing[0])
    assert shifted < 0.2
    jxy, jth = hs.revisit_jitter(se, log.leaves[k])
    assert 0 < jxy < 0.5 * sw.width and 0 <= jth < 0.2


def test_relocalization_at_revisits(run):
    """Re-localising each revisit in the place's stored LPM (B §9.2) removes most of the
    place-frame jitter, so the relaxed layout and the global map improve on plain relaxation."""
    _, sw, se, log = run
    ex = se.experience
    k = next(i for i, h in enumerate(log.leaves) if hg.is_true_map(h, ex))
    h = log.leaves[k]
    rl = hg.visit_offsets(sw, se, log.leaves)              # every leaf, one batched match
    n = len(ex.views)
    assert rl.offsets.shape == (len(log.leaves), n, 3) and rl.odometry.shape == (
        len(log.leaves), n - 1, 3)
    first = {p: i for i, (p, _) in reversed(list(enumerate(h.visits)))}
    revisits = [i for i, (p, _) in enumerate(h.visits) if first[p] != i]
    assert np.isnan(rl.score[k][[first[p] for p in first]]).all()
    assert np.all(rl.offsets[k][[first[p] for p in first]] == 0)
    assert rl.used[k][revisits].mean() >= 0.8
    # the residual jitter after re-localisation is well below the jitter without it
    j0, t0 = hs.revisit_jitter(se, h)
    j1, t1 = hs.revisit_jitter(se, h, rl.offsets[k])
    assert j1 < 0.6 * j0 and t1 < t0 + 0.01
    gt = hs.true_layout_sim(se)
    m = h.n_places
    errs, agree = [], []
    for odo, off in ((ex.odometry, None), (rl.odometry[k], rl.offsets[k])):
        chi, _ = hg.relax(hg.pack([h], odo, 0.02, 0.02))
        errs.append(np.linalg.norm(np.asarray(chi[0, :m, :2]) - gt[:, :2], axis=1).mean())
        agree.append(hs.map_agreement(sw, *hs.global_occupancy(sw, se, h, np.asarray(chi[0]),
                                                               off), se.true_dividing[0]))
    assert errs[1] < errs[0] and agree[1] >= agree[0]
    # bad input: another exploration's hypotheses, per-hypothesis odometry of the wrong shape
    with pytest.raises(ValueError, match="different explorations"):
        hg.visit_offsets(sw, se, [h._replace(visits=h.visits[:-1])])
    with pytest.raises(ValueError, match="per-hypothesis odometry"):
        hg.pack([h], np.zeros((2, n - 1, 3)), 0.02, 0.02)


def test_navigation_in_the_simulator(run):
    w, sw, se, log = run
    ex = se.experience
    h = next(h for h in log.leaves if hg.is_true_map(h, ex))
    route, cmds = hg.plan_route(h, ex.odometry, h.visits[0], h.visits[3][0])
    places, dist, done = hs.navigate_sim(sw, (int(ex.true_places[0]),
                                              int(ex.true_arrivals[0])), cmds, seed=3)
    assert done and places[-1] == int(ex.true_places[3]) and len(places) == len(route)
    sd = hg.shortest_distance(w, int(ex.true_places[0]), int(ex.true_places[3]))
    assert 0.9 < dist / sd < 1.3
    res = hs.evaluate_navigation_sim(sw, se, h, n_pairs=1, seed=0)
    assert res["success"] == 1.0 and res["lost"] == 0 and res["lost_reasons"] == []


def test_bad_input_and_lost_rover(run):
    w, sw, _, _ = run
    with pytest.raises(ValueError, match="width"):
        hs.sim_world(w, hs.SimParams(width=0.9))
    with pytest.raises(ValueError, match="n_travels"):
        hs.explore_sim(sw, -1)
    with pytest.raises(ValueError, match="start place"):
        hs.explore_sim(sw, 1, start=99)
    with pytest.raises(ValueError, match="rendered with"):
        hs.explore_sim(sw, 1, params=hs.SimParams(cells=20))
    with pytest.raises(hs.SimulationError, match="no place reached"):
        hs.explore_sim(sw, 1, seed=1, params=hs.SimParams(max_checks=3))


@pytest.mark.slow
def test_simulator_exploration_is_scale_free():
    """The same world at lattice spacing 1 and 3: the same views and turns, and odometry that
    scales with the world (everything in the simulator is measured in corridor widths)."""
    runs = []
    for scale in (1.0, 3.0):
        lattice = hg.world_from_lattice(LOOP, scale=scale)
        runs.append(hs.explore_sim(hs.sim_world(lattice), 6, seed=2).experience)
    a, b = runs
    assert [v[0] for v in a.views] == [v[0] for v in b.views]
    assert [v[1] for v in a.views] == [v[1] for v in b.views]
    np.testing.assert_array_equal(a.turns, b.turns)
    np.testing.assert_allclose(b.odometry[:, :2] / 3.0, a.odometry[:, :2], atol=0.02)
    np.testing.assert_allclose(b.odometry[:, 2], a.odometry[:, 2], atol=0.05)
