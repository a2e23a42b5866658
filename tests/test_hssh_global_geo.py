"""Issue 26 item 5 and 8: the declared geometric test on layouts, and relax_many.

Before issue 26 minimality ("fewest places first") preferred aliased maps whose layout cost was
~10⁴× the true map's; ``layout_supported`` is the declared χ² test that demotes them, and
``layout.relax_many`` is the bucketed relaxation that lived in ``studies/hssh_maps.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from pqrm_jax import hssh_global as hg


def _run(nx_, ny, world_seed, travels, explore_seed):
    w = hg.grid_world(nx_, ny, loop_prob=0.5, seed=world_seed)
    e = hg.explore(w, travels, seed=explore_seed, sigma_xy=0.03, sigma_theta=0.02)
    leaves = hg.build_tree(e).leaves
    _, _, cost = hg.relax_many(leaves, e.odometry, 0.03, 0.02)
    truth = [k for k, h in enumerate(leaves) if hg.is_true_map(h, e)]
    return e, leaves, cost, truth[0]


def test_relax_many_equals_relax():
    e, leaves, cost, _ = _run(3, 3, 100, 12, 200)
    prob = hg.pack(leaves, e.odometry, 0.03, 0.02, m_max=len(e.odometry) + 1)
    _, ref = hg.relax(prob)
    np.testing.assert_allclose(cost, np.asarray(ref), rtol=1e-5, atol=1e-6)
    # chunks smaller than the leaves: the same costs
    _, _, chunked = hg.relax_many(leaves, e.odometry, 0.03, 0.02, chunk=2, least=1)
    np.testing.assert_allclose(chunked, cost, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="no hypothesis"):
        hg.relax_many([], e.odometry)
    with pytest.raises(ValueError, match="chunk"):
        hg.relax_many(leaves, e.odometry, chunk=0)


@pytest.mark.parametrize("world_seed, explore_seed", [(100, 200), (101, 201), (104, 204)])
def test_true_map_is_supported(world_seed, explore_seed):
    """The true map's layout fits the odometry noise model: the test keeps it."""
    e, leaves, cost, k = _run(3, 3, world_seed, 24, explore_seed)
    ok = hg.layout_supported(cost, leaves, len(e.odometry))
    assert ok[k]
    order = hg.preference_order(leaves, cost, ok)
    assert all(ok[i] for i in order[:int(ok.sum())])      # every supported map first


def test_layout_supported_bad_input_and_no_loop():
    e, leaves, cost, _ = _run(3, 3, 100, 6, 200)
    with pytest.raises(ValueError, match="alpha"):
        hg.layout_supported(cost, leaves, len(e.odometry), alpha=0.0)
    with pytest.raises(ValueError, match="cost"):
        hg.layout_supported(cost[:-1], leaves, len(e.odometry))
    with pytest.raises(ValueError, match="supported"):
        hg.preference_order(leaves, cost, np.ones(len(leaves) + 1, bool))
    # a map with as many places as travels + 1 has no loop (dof 0): always supported
    many = [h for h in leaves if h.n_places == len(e.odometry) + 1]
    if many:
        assert hg.layout_supported(np.full(len(many), 1e9), many, len(e.odometry)).all()
    assert not hg.layout_supported(np.array([np.nan]), leaves[:1], len(e.odometry))[0] \
        or leaves[0].n_places == len(e.odometry) + 1


THETA = {((0, 0), (1, 0)), ((1, 0), (2, 0)), ((0, 0), (0, 1)), ((1, 0), (1, 1)),
         ((0, 1), (1, 1)), ((1, 1), (2, 1)), ((2, 0), (2, 1))}
FIG8 = {((0, 0), (1, 0)), ((1, 0), (1, 1)), ((1, 1), (0, 1)), ((0, 1), (0, 0)),
        ((1, 1), (2, 1)), ((2, 1), (2, 2)), ((2, 2), (1, 2)), ((1, 2), (1, 1))}


@pytest.mark.parametrize("lattice", [THETA, FIG8], ids=["theta", "figure-8"])
def test_geometric_test_demotes_the_aliased_minimal_map(lattice):
    """Minimality alone prefers an aliased map whose layout cost is > 1000x the true map's
    (10 travels, seed 0); with the declared χ² test the true map comes first."""
    w = hg.world_from_lattice(lattice)
    e = hg.explore(w, 10, seed=0, sigma_xy=0.03, sigma_theta=0.02)
    leaves = hg.build_tree(e).leaves
    _, _, cost = hg.relax_many(leaves, e.odometry, 0.03, 0.02)
    k = [i for i, h in enumerate(leaves) if hg.is_true_map(h, e)][0]
    off = hg.preference_order(leaves, cost)[0]
    assert off != k and cost[off] > 1000 * cost[k]
    ok = hg.layout_supported(cost, leaves, len(e.odometry))
    assert ok[k] and not ok[off]
    assert hg.preference_order(leaves, cost, ok)[0] == k
