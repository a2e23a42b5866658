"""The calculus protocol: registry checks, pass-through, and a SERGE calculus inside PQRM."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi, pqrm
from pqrm_jax.calculi import BOUNDARY, DEGENERATE, INVALID, TernaryCalculus
from pqrm_jax.serge import Grid, SergeCalculus, qsr


def learned_lr(name="lr_learned_t"):
    """Two SRs on a grid: left (α < 0) and right (α > 0) of AB, the labels of ``lr``."""
    g = Grid((-3.0, -3.0), (3.0, 3.0), (6, 6))
    return SergeCalculus(name, g, (g.centers()[:, 0] > 0).astype(int), states=("l", "r"))


def test_sentinels_are_defined_once():
    assert (BOUNDARY, DEGENERATE, INVALID) == (-1, -2, -3)
    assert qsr.DEGENERATE is calculi.DEGENERATE and qsr.INVALID is calculi.INVALID
    from pqrm_jax.calculi import calculus

    assert calculus.BOUNDARY is calculi.BOUNDARY


def test_builtin_and_serge_calculi_implement_the_protocol():
    assert isinstance(calculi.get("edc"), TernaryCalculus)
    assert isinstance(learned_lr(), TernaryCalculus)


def test_register_checks_the_protocol():
    class NoClassify:
        name, states, num_states = "nc", ("a",), 1

    with pytest.raises(TypeError, match="missing classify"):
        calculi.register(NoClassify())
    with pytest.raises(TypeError, match="missing name, states, num_states, classify"):
        calculi.register(object())
    with pytest.raises(TypeError, match="missing"):
        calculi.get(42)


def test_get_passes_a_calculus_object_through():
    c = learned_lr()
    assert calculi.get(c) is c
    edc = calculi.get("edc")
    assert calculi.get(edc) is edc


def test_serge_calculus_in_state_probabilities_and_mapper():
    c = learned_lr()
    c.register(overwrite=True)
    key = jax.random.key(3)
    pts = jax.random.uniform(jax.random.key(1), (40, 3, 2), minval=-10.0, maxval=10.0)
    exact = pqrm.state_probabilities(key, "lr", pts, 0.0, 8)
    for calc in ("lr_learned_t", c):
        p = pqrm.state_probabilities(key, calc, pts, 0.0, 8)
        np.testing.assert_array_equal(np.asarray(p), np.asarray(exact))
    noisy = pqrm.state_probabilities(key, c, pts, 0.5, 256)
    assert noisy.shape == (40, 2)
    np.testing.assert_allclose(np.asarray(noisy.sum(-1)), 1.0, atol=1e-5)
    # the map: the same rows as the exact lr map (an EDC merge) for noise-free positions
    pos = jnp.array([[0.3, 0.1], [0.2, 9.7], [5.1, 4.3], [-4.7, 2.2]])  # off EDC boundaries
    vis = jnp.ones(4, bool)
    ref = pqrm.mapper(("lr",), 4, 16)
    got = pqrm.mapper(("lr_learned_t",), 4, 16)
    s_ref, _ = ref.update(ref.init(), key, pos, vis, 0.0)
    s_got, _ = got.update(got.init(), key, pos, vis, 0.0)
    np.testing.assert_array_equal(np.asarray(s_got.probs["lr_learned_t"]),
                                  np.asarray(s_ref.probs["lr"]))
    np.testing.assert_array_equal(np.asarray(s_got.mapped), np.asarray(s_ref.mapped))
    truth = pqrm.metrics.true_states(c, pos, ref.triplets)
    np.testing.assert_array_equal(np.asarray(truth),
                                  np.asarray(pqrm.metrics.true_states(calculi.get("lr"), pos,
                                                                      ref.triplets)))


def test_serge_calculus_definition_hash_tracks_the_map():
    a, b = learned_lr("h1"), learned_lr("h2")
    assert a.definition_hash == b.definition_hash
    g = a.grid
    c = SergeCalculus("h3", g, (g.centers()[:, 1] > 0).astype(int))
    assert c.definition_hash != a.definition_hash
