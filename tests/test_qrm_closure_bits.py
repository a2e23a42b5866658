"""The batched path-consistency closure (M§VI.B) equals a literal fixed point.

The closure composes through each fourth landmark with bit tests on transposed tables
(``k ∈ COMPOSE(R, S)`` exactly when ``R & H[k] ≠ 0``, ``H[k]`` the states ``i`` with ``k`` in
``COMPOSE({i}, S)``). This checks it against the definition — ``COMPOSE(R, S)`` the union of
the table over every pair of states — iterated to the greatest fixed point in plain Python,
on random relation arrays of every calculus the QRM holds: sparse and dense sets, single
states, empty relations (inconsistent input) and arrays that are already closed.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm.spec import qrm_spec


def _lift(table, s):
    out = 0
    for i, t in enumerate(table):
        if s >> i & 1:
            out |= int(t)
    return out


def _reference_closure(spec, rel):
    """Greatest fixed point of the unary and composition constraints, by definition."""
    n = rel.shape[0]
    q = spec.num_states
    ct = [[int(x) for x in row] for row in spec.compose]
    r = [[[int(rel[a, b, c]) for c in range(n)] for b in range(n)] for a in range(n)]
    distinct = [(a, b, c) for a in range(n) for b in range(n) for c in range(n)
                if len({a, b, c}) == 3]

    def compose(x, y):
        out = 0
        for i in range(q):
            if x >> i & 1:
                for j in range(q):
                    if y >> j & 1:
                        out |= ct[i][j]
        return out

    if any(r[a][b][c] == 0 for a, b, c in distinct):
        return np.array(r, np.uint32), True
    changed = True
    while changed:
        changed = False
        for a, b, c in distinct:
            v = r[a][b][c]
            v &= _lift(spec.inverse, r[b][a][c])
            v &= _lift(spec.left, r[c][a][b])
            v &= _lift(spec.right, r[b][c][a])
            for d in range(n):
                if d not in (a, b, c):
                    # rel[a,b,c] ∩= COMPOSE(rel[a,b,d], rel[b,d,c])
                    v &= compose(r[a][b][d], r[b][d][c])
            if v != r[a][b][c]:
                r[a][b][c] = v
                changed = True
                if v == 0:
                    return np.array(r, np.uint32), True
    return np.array(r, np.uint32), False


NAMES = ("edc", "double_cross", "single_cross", "lr")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(NAMES), st.integers(3, 6), st.floats(0.05, 1.0),
       st.integers(0, 2**32 - 1), st.booleans())
def test_closure_equals_the_literal_fixed_point(name, n, density, seed, singles):
    spec = qrm_spec(name)
    rng = np.random.default_rng(seed)
    q = spec.num_states
    bits = rng.random((n, n, n, q)) < density
    if singles:  # some relations known exactly
        one = rng.random((n, n, n)) < 0.3
        pick = rng.integers(0, q, (n, n, n))
        bits = np.where(one[..., None], np.arange(q) == pick[..., None], bits)
    rel = (bits * (np.uint64(1) << np.arange(q, dtype=np.uint64))).sum(-1).astype(np.uint32)
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
