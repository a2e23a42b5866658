"""Belief update ψ (Z eq. 4.25) against a brute-force metric particle simulation."""

import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.bsp import belief as B
from pqrm_jax.bsp import models as M

PARAMS = M.ModelParams(samples=600, pool=1 << 18, seed=3)
EDC = calculi.get("edc")


@pytest.fixture(scope="module")
def mod(request):
    return M.load_models(PARAMS, directory=request.config.cache.mkdir("bsp-models"))


@pytest.fixture(scope="module")
def pool_and_state():
    """The particle pool drawn from ``default_rng(0)`` and that generator's state after it
    (a test continuing the same stream starts from there)."""
    rng = np.random.default_rng(0)
    return _pool(rng), rng.bit_generator.state


def _pool(rng, n=400_000, w=3.0):
    pts = rng.uniform(-w, w, (n, 2))
    st = np.asarray(EDC.classify(np.zeros(2), np.array([0.0, 1.0]), pts))
    return {q: pts[st == q] for q in range(20)}


def particle_update(rng, pool, mod, scale_f, a, row, zhat, link, n=200_000, resample=True):
    """Metric particles under the model's assumptions (uniform-in-state priors).

    ``resample``: before the link, redraw X and C uniformly within their (posterior) states,
    as the link model of eq. 4.25 assumes; ``False`` keeps the metric particles (then the
    visibility/measurement-induced correlation inside states, which eq. 4.25 drops, shows).
    """
    edges = np.asarray(mod.bin_edges)
    b = rng.choice(len(scale_f), n, p=scale_f)
    d = np.maximum(rng.uniform(edges[b], edges[b + 1]), PARAMS.r_min)
    x1 = np.asarray(mod.targets)[a] + rng.normal(size=(n, 2)) * (PARAMS.sigma_m / d)[:, None]
    sx = np.asarray(EDC.classify(np.zeros(2), np.array([0.0, 1.0]), x1))
    ok = sx >= 0
    sx, d = sx[ok], d[ok]
    x = np.empty((len(sx), 2))
    for q in np.unique(sx):
        m = sx == q
        x[m] = pool[q][rng.integers(0, len(pool[q]), m.sum())]
    st = rng.choice(20, len(sx), p=row)
    c = np.empty_like(x)
    for q in np.unique(st):
        m = st == q
        c[m] = pool[q][rng.integers(0, len(pool[q]), m.sum())]
    lms = np.stack([np.zeros_like(x), np.tile([0.0, 1.0], (len(x), 1)), c], 1)
    rel = d[:, None, None] * (lms - x[:, None])
    vis = np.all((rel ** 2).sum(-1) <= 1.0, -1)
    meas = rel + PARAMS.sigma_z * rng.normal(size=rel.shape)
    z = np.asarray(B.discretise(meas[:, 0], meas[:, 1], meas[:, 2], 20, EDC))
    keep = vis & (z == zhat)
    x, c = x[keep], c[keep]
    if resample:
        sx_k = sx[keep]
        st_k = st[keep]
        for q in np.unique(sx_k):
            m = sx_k == q
            x[m] = pool[q][rng.integers(0, len(pool[q]), m.sum())]
        for q in np.unique(st_k):
            m = st_k == q
            c[m] = pool[q][rng.integers(0, len(pool[q]), m.sum())]
    if link == 0:
        s = np.asarray(EDC.classify(np.zeros(2), np.array([0.0, 1.0]), x))
    elif link == 1:
        s = np.asarray(EDC.classify(np.zeros_like(c), c, x))
    else:
        s = np.asarray(EDC.classify(np.tile([0.0, 1.0], (len(c), 1)), c, x))
    s = s[s >= 0]
    return np.bincount(s, minlength=20) / max(len(s), 1), int(keep.sum())


def _belief(mod, row, scale_f):
    L, Q, nb = 4, 20, mod.num_bins
    trip = jnp.full((L, L, L, Q), 1.0 / Q).at[0, 1, 2].set(row)
    scale = jnp.broadcast_to(jnp.asarray(scale_f, jnp.float32), (L, L, nb))
    return B.QBelief(frame=jnp.array([0, 1]), robot=jnp.full(Q, 1.0 / Q), trip=trip,
                     trip_src=jnp.zeros((L, L, L), jnp.int8), ncomp=jnp.zeros((L, L, L), jnp.int8),
                     scale=scale, lm_mask=jnp.ones(L, bool), conflicts=jnp.zeros((), jnp.int32))


def test_psi_matches_particles(mod, pool_and_state):
    pool, state = pool_and_state
    rng = np.random.default_rng()
    rng.bit_generator.state = state  # the stream continues after the pool's draws
    tvs, metric_tv = [], []
    for case in range(6):
        a = int(rng.integers(0, 20))
        row = np.zeros(20)
        row[rng.choice(20, 3, replace=False)] = rng.dirichlet(np.ones(3))
        scale_f = np.zeros(mod.num_bins)
        scale_f[1:4] = rng.dirichlet(np.ones(3))
        link = case % 3
        bel = _belief(mod, row, scale_f)
        pz = np.asarray(jnp.einsum("b,bx,t,xtbz->z", jnp.asarray(scale_f, jnp.float32),
                                   mod.T[:, a], jnp.asarray(row, jnp.float32), mod.AZ))
        zhat = int(np.argmax(pz))  # the most likely measurement: enough particles
        new, eta = B.update(mod, bel, a, 2, zhat, link)
        got = np.asarray(new.robot)
        assert np.isclose(got.sum(), 1, atol=1e-5) and np.all(np.isfinite(got))
        assert int(new.conflicts) == 0
        want, kept = particle_update(rng, pool, mod, scale_f, a, row, zhat, link)
        assert kept > 200
        tvs.append(0.5 * np.abs(got - want).sum())
        if link == 0:  # only the stay cases are asserted (links differ by design, below)
            metric, _ = particle_update(rng, pool, mod, scale_f, a, row, zhat, link,
                                        resample=False)
            metric_tv.append(0.5 * np.abs(got - metric).sum())
        expect = [[0, 1], [0, 2], [1, 2]][link]
        assert np.asarray(new.frame).tolist() == expect
    assert np.mean(tvs) < 0.06, tvs
    assert max(tvs) < 0.12, tvs
    # the stay cases are exact either way; links drop the within-state correlation (Z eq. 4.25)
    assert max(metric_tv) < 0.05, metric_tv
    print("psi vs fully metric particles, TV of the stay cases:", np.round(metric_tv, 3))


def test_zero_evidence_counted_not_nan(mod):
    row = np.zeros(20)
    row[0] = 1.0  # AB:C = 1 (front-left outside B circle)
    scale_f = np.zeros(mod.num_bins)
    scale_f[-1] = 1.0  # unobservable frame: association is exactly 0
    bel = _belief(mod, row, scale_f)
    new, eta = B.update(mod, bel, 5, 2, 0, 1)
    assert float(eta) == 0 and int(new.conflicts) == 1
    assert np.all(np.isfinite(np.asarray(new.robot)))
    assert np.asarray(new.frame).tolist() == [0, 1]  # no link without evidence
    assert np.allclose(np.asarray(new.robot), np.asarray(mod.T)[-1, 5])


def test_scale_posteriors(mod):
    L, Q, nb = 5, 20, mod.num_bins
    rng = np.random.default_rng(1)
    trip = rng.dirichlet(np.ones(Q), (L, L, L)).astype(np.float32)
    known = np.zeros((L, L, L), bool)
    known[0, 1, 2] = known[0, 1, 3] = True
    ref_scale = np.eye(nb)[2]
    s = np.asarray(B.scale_posteriors(mod, trip, known, jnp.array([0, 1]),
                                      jnp.asarray(ref_scale, jnp.float32), jnp.ones(L, bool)))
    assert np.allclose(s.sum(-1), 1, atol=1e-5) and np.all(np.isfinite(s))
    assert np.allclose(s, s.transpose(1, 0, 2), atol=1e-6)
    assert np.allclose(s[0, 1], ref_scale)
    assert np.allclose(s[0, 2], np.einsum("q,qcs,c->s", trip[0, 1, 2], np.asarray(mod.GA),
                                          ref_scale), atol=1e-5)
    assert np.allclose(s[2, 3], np.einsum("q,r,qrcs,c->s", trip[0, 1, 2], trip[0, 1, 3],
                                          np.asarray(mod.G2), ref_scale), atol=1e-4)
    assert np.allclose(s[0, 4], 1.0 / nb)  # pair in no known triplet


def test_check_distribution():
    with pytest.raises(ValueError, match="sum to 1"):
        B.check_distribution("robot", [0.5, 0.4])
    with pytest.raises(ValueError, match="NaN"):
        B.check_distribution("robot", [np.nan, 1.0])
    with pytest.raises(ValueError, match="negative"):
        B.check_distribution("robot", [-0.5, 1.5])


def test_non_detection_matches_particles(mod, pool_and_state):
    """The EXTENSION (docs/bsp.md §non-detection): P(ij:k | β not seen) against particles
    under the same uniform-in-state priors; never NaN; seen rows untouched."""
    pool = pool_and_state[0]
    rng = np.random.default_rng(7)
    edges = np.asarray(mod.bin_edges)
    n = 60_000
    tvs, moved = [], []
    for _ in range(4):
        robot = np.zeros(20)
        robot[rng.choice(20, 2, replace=False)] = rng.dirichlet(np.ones(2))
        row = np.zeros(20)
        row[rng.choice(20, 4, replace=False)] = rng.dirichlet(np.ones(4))
        scale_f = np.zeros(mod.num_bins)
        scale_f[:3] = rng.dirichlet(np.ones(3))
        rows = jnp.asarray(np.stack([row, row]), jnp.float32)
        new, bad = B.non_detection(mod, jnp.asarray(scale_f, jnp.float32),
                                   jnp.asarray(robot, jnp.float32), rows,
                                   jnp.array([True, False]))
        new = np.asarray(new)
        assert np.all(np.isfinite(new)) and np.isclose(new[0].sum(), 1, atol=1e-5)
        assert np.array_equal(new[1], np.asarray(rows[1])) and int(bad) == 0
        sx = rng.choice(20, n, p=robot)
        st = rng.choice(20, n, p=row)
        x, c = np.empty((n, 2)), np.empty((n, 2))
        for q in range(20):
            for s, p in ((sx, x), (st, c)):
                m = s == q
                p[m] = pool[q][rng.integers(0, len(pool[q]), m.sum())]
        b = rng.choice(len(scale_f), n, p=scale_f)
        d = np.maximum(rng.uniform(edges[b], edges[b + 1]), PARAMS.r_min)
        lms = np.stack([np.zeros_like(x), np.tile([0.0, 1.0], (n, 1)), c], 1)
        vis = np.all(((d[:, None, None] * (lms - x[:, None])) ** 2).sum(-1) <= 1.0, -1)
        want = np.bincount(st[~vis], minlength=20) / max((~vis).sum(), 1)
        tvs.append(0.5 * np.abs(new[0] - want).sum())
        moved.append(0.5 * np.abs(want - row).sum())
    print("non-detection vs particles, TV:", np.round(tvs, 4), "moved:", np.round(moved, 3))
    assert max(moved) > 0.1, moved  # the cases carry real evidence
    assert max(tvs) < 0.02, tvs
    # evidence the model calls impossible: kept, counted, finite
    A = np.asarray(mod.A)
    sx, st = np.unravel_index(np.argmax(A[:, :, 0]), A.shape[:2])
    assert A[sx, st, 0] == 1.0
    new, bad = B.non_detection(mod, jnp.eye(mod.num_bins)[0], jnp.eye(20)[sx],
                               jnp.eye(20)[st][None], jnp.array([True]))
    assert int(bad) == 1 and np.array_equal(np.asarray(new[0]), np.eye(20)[st])
