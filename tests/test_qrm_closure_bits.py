"""The batched path-consistency closure (M§VI.B) equals the one-relation-at-a-time reference.

The closure composes through each fourth landmark with bit tests on transposed tables
(``k ∈ COMPOSE(R, S)`` exactly when ``R & H[k] ≠ 0``, ``H[k]`` the states ``i`` with ``k`` in
``COMPOSE({i}, S)``). This checks it against :class:`~pqrm_jax.qrm.reference.ReferenceMap`
(the worklist propagation of M§VI.B, ``COMPOSE(R, S)`` lifted from the table state by state)
fed every relation of random arrays of every calculus the QRM holds: sparse and dense sets,
single states, empty relations (inconsistent input) and arrays that are already closed.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm.reference import ReferenceMap
from pqrm_jax.qrm.spec import qrm_spec
from pqrm_jax.triplets import sets_to_masks


def _reference_closure(spec, rel):
    """(greatest fixed point, inconsistent): every distinct relation of ``rel`` fed to the
    reference; the first rejected update proves an empty relation in the fixed point."""
    n = rel.shape[0]
    ref = ReferenceMap(spec, n)
    for t in np.argwhere(np.ones((n, n, n), bool)):
        if len(set(t.tolist())) == 3 and not ref.update(t, int(rel[tuple(t)])):
            return None, True
    return ref.rel.astype(np.uint32), False


NAMES = ("edc", "double_cross", "single_cross", "lr")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(NAMES), st.integers(3, 6), st.floats(0.05, 1.0),
       st.integers(0, 2**32 - 1), st.booleans())
def test_closure_equals_the_one_at_a_time_reference(name, n, density, seed, singles):
    spec = qrm_spec(name)
    rng = np.random.default_rng(seed)
    q = spec.num_states
    bits = rng.random((n, n, n, q)) < density
    if singles:  # some relations known exactly
        one = rng.random((n, n, n)) < 0.3
        pick = rng.integers(0, q, (n, n, n))
        bits = np.where(one[..., None], np.arange(q) == pick[..., None], bits)
    rel = sets_to_masks(bits)
    idx = np.arange(n)
    same = ((idx[:, None, None] == idx[None, :, None]) | (idx[None, :, None] == idx[None, None, :])
            | (idx[:, None, None] == idx[None, None, :]))
    rel = np.where(same, np.uint32(spec.full), rel)
    got = H.closure(rel, spec, max_sweeps=10_000)
    ref, empty = _reference_closure(spec, rel)
    assert bool(got.inconsistent) == empty
    assert bool(got.converged)
    if not empty:
        np.testing.assert_array_equal(np.asarray(got.rel), ref)
        # a closed array is its own closure
        again = H.closure(np.asarray(got.rel), spec)
        np.testing.assert_array_equal(np.asarray(again.rel), ref)
        assert int(again.sweeps) == 1


@pytest.mark.parametrize("name", NAMES)
def test_closure_of_the_full_array_is_the_full_array(name):
    spec = qrm_spec(name)
    m = H.empty_map(5, spec)
    got = H.closure(m.rel, spec)
    np.testing.assert_array_equal(np.asarray(got.rel), np.asarray(m.rel))
    assert not bool(got.inconsistent)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(NAMES), st.integers(5, 6), st.floats(0.05, 0.6), st.floats(0.0, 0.5),
       st.integers(0, 2**32 - 1))
def test_closure_from_a_closed_map_equals_the_full_closure(name, n, density, keep, seed):
    """Narrowing a closed map by new relations and closing again from it as a closed base —
    the first sweep visits only the fourth landmarks whose relations differ from the base —
    gives the fixed point of the closure that starts with every landmark (also with the base
    declared not closed). The map: the closure of a random layout's true states plus random
    others (consistent); the narrowing: the true state plus random others on a tenth of the
    relations."""
    spec = qrm_spec(name)
    rng = np.random.default_rng(seed)
    q = spec.num_states
    truth = np.asarray(H.true_relations(jnp.asarray(rng.normal(0, 1, (n, 2)), jnp.float32),
                                        spec))
    same = truth < 0
    bit = np.left_shift(np.uint32(1), np.maximum(truth, 0).astype(np.uint32))
    one = np.where(same, np.uint32(spec.full), bit)

    def around_truth(p):  # the true state and each other state with probability p
        bits = rng.random((n, n, n, q)) < p
        return one | sets_to_masks(bits)

    base = H.closure(around_truth(density), spec, max_sweeps=10_000)
    assert not bool(base.inconsistent)
    M = np.asarray(base.rel)
    touched = rng.random((n, n, n)) < 0.1
    meas = np.where(touched & ~same, around_truth(keep), np.uint32(spec.full))
    # as a camera narrows a relation in every orientation: the unary closure of the narrowing
    # (then the first sweep's unary step changes nothing, and only the comparison with the
    # base finds the fourth landmarks to visit)
    for rel in (M & meas, _unary_closed(spec, M & meas)):
        want = H.closure(rel, spec, max_sweeps=10_000)
        assert not bool(want.inconsistent)
        for closed in (True, False):
            got = H._closure(spec, jnp.asarray(rel), max_sweeps=10_000, base=jnp.asarray(M),
                             closed=closed)
            np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want.rel))


def _unary_closed(spec, rel):
    """``rel`` under INVERSE, LEFT and RIGHT to their fixed point (no composition)."""
    full = np.uint32(spec.full)
    same = ~np.asarray(H.distinct_mask(rel.shape[0]))
    inv, left, right = (jnp.asarray(t, jnp.uint32) for t in (spec.inverse, spec.left, spec.right))
    r = jnp.asarray(rel)
    while True:
        new = r & H._lift(inv, jnp.transpose(r, (1, 0, 2)))
        new = new & H._lift(left, jnp.transpose(new, (1, 2, 0)))
        new = new & H._lift(right, jnp.transpose(new, (2, 0, 1)))
        new = jnp.where(same, full, new)
        if bool((new == r).all()):
            return np.asarray(r)
        r = new


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(NAMES), st.integers(4, 7), st.integers(1, 8), st.floats(0.05, 0.6),
       st.integers(0, 2**32 - 1))
def test_closure_is_the_same_for_every_block_of_middle_landmarks(name, n, rows, density, seed):
    """The composition visits the middle landmarks b with a changed input in blocks of
    ``_B_ROWS`` (padding to a block multiple is never written): every block size, with and
    without padding, one block or several, gives the closure of one block of all the
    landmarks, from scratch and from a closed base narrowed on a tenth of the relations."""
    spec = qrm_spec(name)
    rng = np.random.default_rng(seed)
    q = spec.num_states
    same = ~np.asarray(H.distinct_mask(n))

    def rand(p):
        return np.where(same, np.uint32(spec.full), sets_to_masks(rng.random((n, n, n, q)) < p))

    one = np.asarray(H.true_map(jnp.asarray(rng.normal(0, 1, (n, 2)), jnp.float32), spec).rel)
    start = rand(density)  # may be inconsistent
    base_in = one | rand(density)
    narrow = np.where(rng.random((n, n, n)) < 0.1, one | rand(density), np.uint32(spec.full))

    def run(block):
        f = H._closure.__wrapped__  # traced afresh: the block size is read at trace time
        keep, H._B_ROWS = H._B_ROWS, block
        try:
            a = f(spec, jnp.asarray(start), max_sweeps=10_000)
            base = f(spec, jnp.asarray(base_in), max_sweeps=10_000)[0]
            b = f(spec, base & jnp.asarray(narrow), max_sweeps=10_000, base=base, closed=True)
        finally:
            H._B_ROWS = keep
        return [np.asarray(x) for x in (*a, *b)]

    want = run(n)
    got = run(rows)
    for w, g in zip(want, got, strict=True):
        np.testing.assert_array_equal(g, w)
