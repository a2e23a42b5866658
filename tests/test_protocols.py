"""The step convention (pqrm_jax.protocols): every estimator is ``init`` / ``update(state, key,
*obs) -> (state, info)``, and one generic scan runs any of them."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import hssh, pqrm, qrm
from pqrm_jax.hssh.motion import ACTION_MODELS
from pqrm_jax.protocols import Estimator, run


@pytest.fixture(scope="module")
def pq():
    return pqrm.mapper(("edc", "lr"), num_landmarks=5, num_samples=32)


def test_every_estimator_of_the_faces_satisfies_the_protocol(pq):
    for est in (pq, qrm.mapper("edc", 5, n=5), hssh.lpm_tracker(ACTION_MODELS["small"])):
        assert isinstance(est, Estimator), type(est)
    assert not isinstance(object(), Estimator)


def _sequence(t: int, seed: int):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-20, 20, (t, 5, 2)).astype(np.float32)
    vis = rng.uniform(size=(t, 5)) < 0.8
    sig = rng.uniform(0.0, 3.0, t).astype(np.float32)
    return jnp.asarray(pos), jnp.asarray(vis), jnp.asarray(sig)


@settings(max_examples=4, deadline=None)
@given(t=st.integers(1, 4), seed=st.integers(0, 2**16))
def test_run_equals_the_eager_loop_and_info_counts_the_step(pq, t, seed):
    pos, vis, sig = _sequence(t, seed)
    key = jax.random.key(seed)
    final, info = run(pq, key, pq.init(), pos, vis, sig)
    s = pq.init()
    for i, k in enumerate(jax.random.split(key, t)):
        prev = s
        s, inf = pq.update(s, k, pos[i], vis[i], sig[i])
        # info is this call's counters: the change of the running totals
        assert int(inf.num_updated) == int(jnp.sum(s.num_updates - prev.num_updates))
        assert int(inf.num_updated) == int(info.num_updated[i])
        for name in ("edc", "lr"):
            assert int(inf.num_conflicts[name]) == int(
                jnp.sum(s.num_conflicts[name] - prev.num_conflicts[name]))
        assert int(inf.num_rejected) == int(jnp.sum(s.num_rejected - prev.num_rejected))
    for a, b in zip(jax.tree.leaves(final), jax.tree.leaves(s), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert info.num_updated.shape == (t,) and info.num_dropped.shape == (t,)
    assert int(info.num_updated.sum()) == int(final.num_updates.sum())


def test_update_batch_info_has_the_batch_axis(pq):
    r = 3
    pos, vis, sig = _sequence(r, 7)
    states = jax.tree.map(lambda x: jnp.stack([x] * r), pq.init())
    new, info = pq.update_batch(states, jax.random.split(jax.random.key(0), r), pos, vis, 1.0)
    assert info.num_updated.shape == (r,) and info.num_conflicts["lr"].shape == (r,)
    np.testing.assert_array_equal(np.asarray(info.num_updated),
                                  np.asarray(new.num_updates.sum(-1)))


def test_non_finite_positions_are_counted_in_info(pq):
    pos, vis, _ = _sequence(1, 3)
    bad = pos[0].at[1].set(jnp.nan)
    _, info = pq.update(pq.init(), jax.random.key(0), bad, jnp.ones(5, bool), 1.0)
    assert int(info.num_dropped) == 1


def test_run_refuses_bad_sequences(pq):
    pos, vis, sig = _sequence(3, 0)
    with pytest.raises(ValueError, match="at least one observation"):
        run(pq, jax.random.key(0), pq.init())
    with pytest.raises(ValueError, match="leading axis"):
        run(pq, jax.random.key(0), pq.init(), pos, vis[:2], sig)
    with pytest.raises(ValueError, match="leading axis T"):
        run(pq, jax.random.key(0), pq.init(), pos, vis, 1.0)


def test_tracker_is_its_parameters():
    a = hssh.lpm_tracker(ACTION_MODELS["small"])
    b = hssh.lpm_tracker(np.asarray(ACTION_MODELS["small"], np.float64))
    assert a == b and hash(a) == hash(b)
    assert a != hssh.lpm_tracker(ACTION_MODELS["large"])
    assert a != hssh.lpm_tracker(ACTION_MODELS["small"], field_cap_cells=21)
    with pytest.raises(ValueError, match="method"):
        hssh.lpm_tracker(ACTION_MODELS["small"], method="nope")
    with pytest.raises(ValueError, match=r"c must be the \[21\]"):
        hssh.lpm_tracker(np.zeros(20))
