"""Kept libraries where they do the job: Wilson intervals and the paired bootstrap from
scipy.stats (qbsp report), the neighbour-distance BFS from scipy.sparse.csgraph (tables) —
each checked against the hand-written code it replaced."""

from __future__ import annotations

from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi
from pqrm_jax.studies.qbsp import paired_bootstrap, wilson
from pqrm_jax.tables.build import neighbor_distance

Z = 1.959963984540054  # scipy.stats.norm.ppf(0.975)


def _wilson_closed_form(k, n, z=Z):
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 10**6), frac=st.floats(0, 1))
def test_wilson_is_the_closed_form(n, frac):
    k = int(round(frac * n))
    lo, hi = wilson(k, n)
    want = _wilson_closed_form(k, n)
    np.testing.assert_allclose((lo, hi), want, rtol=1e-9, atol=1e-12)
    # the replaced code used z = 1.96: the intervals differ by < 2e-5
    np.testing.assert_allclose((lo, hi), _wilson_closed_form(k, n, 1.96), atol=2e-5)
    assert 0 <= lo <= k / n <= hi <= 1


def test_wilson_of_nothing_is_nan():
    assert all(np.isnan(wilson(0, 0)))


def _old_bootstrap(wo, wi, rng, n=2000):
    k = len(wo)
    boots, dboot = [], []
    for _ in range(n):
        s = rng.integers(0, k, k)
        boots.append(wi[s].mean() / max(wo[s].mean(), 1e-12))
        dboot.append((wo[s] - wi[s]).mean())
    return np.percentile(boots, [2.5, 97.5]), np.percentile(dboot, [2.5, 97.5])


@settings(max_examples=10, deadline=None)
@given(k=st.integers(8, 60), seed=st.integers(0, 10**6))
def test_paired_bootstrap_agrees_with_the_hand_loop(k, seed):
    g = np.random.default_rng(seed)
    wo = g.uniform(5, 20, k)
    wi = wo - g.normal(1.0, 2.0, k)
    ratio, diff = paired_bootstrap(wo, wi, np.random.default_rng(1))
    old_r, old_d = _old_bootstrap(wo, wi, np.random.default_rng(1))
    # both percentile intervals of 2000 resamples: equal up to resampling noise
    sd_d = (wo - wi).std() / np.sqrt(k)
    np.testing.assert_allclose(diff, old_d, atol=0.5 * sd_d)
    assert ratio[0] <= wi.mean() / wo.mean() <= ratio[1]
    assert diff[0] <= (wo - wi).mean() <= diff[1]
    # same generator state -> same intervals (the report is reproducible)
    assert paired_bootstrap(wo, wi, np.random.default_rng(1)) == (ratio, diff)


def test_paired_bootstrap_of_a_constant_difference_is_that_constant():
    wo = np.arange(1.0, 11.0)
    (r_lo, r_hi), (d_lo, d_hi) = paired_bootstrap(wo, wo - 0.5, np.random.default_rng(0))
    assert d_lo == d_hi == 0.5 or np.allclose((d_lo, d_hi), 0.5)


def _bfs(adjacency):
    q = adjacency.shape[0]
    dist = np.full((q, q), -1, np.int32)
    for s in range(q):
        dist[s, s] = 0
        queue = deque([s])
        while queue:
            a = queue.popleft()
            for b in np.flatnonzero(adjacency[a]):
                if dist[s, b] < 0:
                    dist[s, b] = dist[s, a] + 1
                    queue.append(b)
    return dist


@settings(max_examples=100, deadline=None)
@given(q=st.integers(1, 25), p=st.floats(0, 1), seed=st.integers(0, 10**6),
       sym=st.booleans())
def test_neighbor_distance_equals_the_replaced_bfs(q, p, seed, sym):
    adj = np.random.default_rng(seed).random((q, q)) < p
    if sym:
        adj |= adj.T
    np.testing.assert_array_equal(neighbor_distance(adj), _bfs(adj))


def test_neighbor_distance_of_every_shipped_calculus_is_unchanged():
    # shipped calculi only: other tests may register a SERGE calculus (no tables) in this
    # process, so calculi.names() depends on the test order
    shipped = [name for name in calculi.names() if calculi.is_builtin(name)]
    assert len(shipped) >= 9
    for name in shipped:
        t = calculi.get(name).tables
        got = neighbor_distance(t.adjacency)
        assert got.dtype == np.int32
        np.testing.assert_array_equal(got, _bfs(t.adjacency))
