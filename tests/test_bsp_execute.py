"""Execution-side rules of qualitative BSP: one PQRM row fusion (``pqrm.fuse_rows``), the
scale models of docs/bsp.md §Z-10, and refusal of bad input at the API and the CLI."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import calculi
from pqrm_jax.bsp import belief as B
from pqrm_jax.bsp import env as E
from pqrm_jax.bsp import execute as X
from pqrm_jax.bsp import models as M
from pqrm_jax.pqrm import fuse_rows, state_probabilities
from pqrm_jax.triplets import ORDERINGS

PARAMS = M.ModelParams(samples=600, pool=1 << 18, seed=3)
EDC = calculi.get("edc")
Q = 20


@pytest.fixture(scope="module")
def mod(request):
    return M.load_models(PARAMS, directory=request.config.cache.mkdir("bsp-models"))


# ------------------------------------------------------------------ one PQRM row fusion
def _ref_fuse(prior, meas, mapped, seen):
    """P eq. 2.10 with initialisation and the conflict rule, in float64 NumPy."""
    prior, meas = np.asarray(prior, np.float64), np.asarray(meas, np.float64)
    post = prior * meas
    z = post.sum(-1, keepdims=True)
    conflict = seen & mapped & (z[..., 0] <= 0)
    new = np.where((seen & ~mapped)[..., None], meas, prior)
    ok = seen & mapped & ~conflict
    new = np.where(ok[..., None], post / np.where(z > 0, z, 1.0), new)
    return new, conflict


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 5), st.integers(2, 8), st.integers(-30, 30), st.integers(0, 2 ** 31 - 1))
def test_fuse_rows_is_eq_2_10_with_conflicts(n, q, log_scale, seed):
    """Every shape, scales 1e-30..1e30 of the likelihood, zeros (conflicts), never NaN."""
    rng = np.random.default_rng(seed)
    prior = rng.dirichlet(np.ones(q), n) * (rng.random((n, q)) > 0.4)
    prior = prior / np.maximum(prior.sum(-1, keepdims=True), 1e-30)
    meas = rng.random((n, q)) * (rng.random((n, q)) > 0.5) * 10.0 ** log_scale
    mapped, seen = rng.random(n) > 0.3, rng.random(n) > 0.3
    rows, conflict = fuse_rows(jnp.asarray(prior, jnp.float32), jnp.asarray(meas, jnp.float32),
                               jnp.asarray(mapped), jnp.asarray(seen))
    want, wc = _ref_fuse(np.float32(prior), np.float32(meas), mapped, seen)
    assert np.all(np.isfinite(np.asarray(rows)))
    assert np.asarray(conflict).tolist() == wc.tolist()
    np.testing.assert_allclose(np.asarray(rows), want, rtol=2e-5, atol=1e-6)
    # a conflict keeps the prior exactly
    assert np.array_equal(np.asarray(rows)[wc], np.float32(prior)[wc])


def _belief(L=4):
    trip = np.full((L, L, L, Q), 1.0 / Q, np.float32)
    src = np.zeros((L, L, L), np.int8)
    return B.QBelief(frame=jnp.array([0, 1], jnp.int32), robot=jnp.full(Q, 1.0 / Q),
                     trip=jnp.asarray(trip), trip_src=jnp.asarray(src),
                     ncomp=jnp.zeros((L, L, L), jnp.int8),
                     scale=jnp.full((L, L, 6), 1 / 6, jnp.float32),
                     lm_mask=jnp.ones(L, bool), conflicts=jnp.zeros((), jnp.int32))


def test_execution_uses_the_pqrm_rule(mod):
    """A measurement with zero likelihood on a row's prior keeps the prior and counts a
    conflict per row (the PQRM map's rule); the old executive replaced the row by the
    measurement and counted nothing."""
    L = 4
    pos = np.array([[0.0, 0.0], [0.0, 0.6], [0.5, 0.3], [-0.4, 0.2]], np.float32)
    x = np.array([0.05, 0.3], np.float32)
    rel = jnp.asarray(pos - x)
    ep = X.ExecParams()
    key = jax.random.key(7)
    perms = np.asarray(ORDERINGS)
    pid = np.stack([[0, 1, k] for k in range(L)])[:, perms]  # (L, 6, 3)
    meas = np.asarray(state_probabilities(key, EDC, rel[pid].reshape(-1, 3, 2), ep.sigma_z,
                                          ep.pqrm_samples)).reshape(L, 6, Q)
    bel = _belief(L)
    trip = np.asarray(bel.trip).copy()
    src = np.asarray(bel.trip_src).copy()
    for o in range(6):  # triplet (0, 1, 2): composed rows one-hot where the measurement is 0
        a, b, c = pid[2, o]
        wrong = int(np.flatnonzero(meas[2, o] == 0)[0])
        trip[a, b, c] = np.eye(Q)[wrong]
        src[a, b, c] = B.COMPOSED
        a, b, c = pid[3, o]  # triplet (0, 1, 3): measured, uniform prior
        src[a, b, c] = B.MEASURED
    bel = bel._replace(trip=jnp.asarray(trip), trip_src=jnp.asarray(src))
    cand = jnp.asarray([False, False, True, True])
    out = X.map_update(key, mod, bel, bel, rel, cand, jnp.array([0, 1]),
                       jnp.asarray(np.eye(6)[2], jnp.float32), ep)
    got, gsrc = np.asarray(out.trip), np.asarray(out.trip_src)
    assert int(out.conflicts) == 6
    for o in range(6):
        a, b, c = pid[2, o]
        assert np.array_equal(got[a, b, c], trip[a, b, c])  # prior kept
        assert gsrc[a, b, c] == B.COMPOSED  # not promoted to measured by a conflict
        a, b, c = pid[3, o]
        np.testing.assert_allclose(got[a, b, c], meas[3, o] / meas[3, o].sum(), atol=1e-6)
        assert gsrc[a, b, c] == B.MEASURED
    assert np.all(np.isfinite(got))


# ------------------------------------------------------------------ scale models (§Z-10)
def _env():
    rng = np.random.default_rng(11)
    return E.generate(rng, 9, 2.5)


@pytest.mark.parametrize("scale_model", ["composed", "belief"])
def test_scale_models(mod, scale_model):
    """"composed": both modes have the same frame scales and the without mode's composed rows
    are never candidates; "belief" (the previous model) keeps the mode's own rows."""
    env = _env()
    key = jax.random.key(3)
    b0 = E.initial_belief(key, mod, env, compositions=False, scale_model=scale_model)
    b1 = E.initial_belief(key, mod, env, compositions=True, scale_model=scale_model)
    s0, s1 = np.asarray(b0.trip_src), np.asarray(b1.trip_src)
    assert np.array_equal(s0 == B.MEASURED, s1 == B.MEASURED)
    assert not np.any(np.asarray(B.in_belief(s0)) & (s0 != B.MEASURED))
    if scale_model == "composed":
        assert np.array_equal(np.asarray(b0.scale), np.asarray(b1.scale))
        assert np.array_equal(s0 == B.SCALE_ONLY, s1 == B.COMPOSED)
        # every pair of real landmarks gets a derived scale (M_1 is composable)
        n = len(env.pos)
        obs_uniform = np.where(np.arange(mod.num_bins) < mod.num_bins - 1,
                               1 / (mod.num_bins - 1), 0)
        sc = np.asarray(b0.scale)[:n, :n]
        off = ~np.eye(n, dtype=bool)
        assert not np.any(np.all(np.isclose(sc[off], obs_uniform, atol=1e-6), -1))
    else:
        assert not np.any(s0 == B.SCALE_ONLY)
    with pytest.raises(ValueError, match="scale_model"):
        E.initial_belief(key, mod, env, compositions=False, scale_model="metric")


# ------------------------------------------------------------------ bad input (API and CLI)
def test_bad_model_params():
    # NumPy integers are accepted (and stored as Python ints: the cache key is JSON)
    p = M.ModelParams(n_f=np.int64(5), samples=np.int32(600), sigma_z=np.float32(0.05))
    assert p.validate().n_f == 5 and type(p.n_f) is int and type(p.samples) is int
    assert p.key() == M.ModelParams(samples=600, sigma_z=float(np.float32(0.05))).key()
    for bad, name in ((dict(samples=True), "samples"), (dict(n_f=False), "n_f"),
                      (dict(n_f=2.0), "n_f"), (dict(pool=0), "pool"),
                      (dict(sigma_z=float("inf")), "sigma_z"), (dict(window=0.0), "window"),
                      (dict(r_min=-0.1), "r_min"), (dict(sigma_m="0.1"), "sigma_m")):
        with pytest.raises(ValueError, match=name):
            M.ModelParams(**bad).validate()


def test_bad_environment():
    env = _env()
    rng = np.random.default_rng(0)
    for size in (float("nan"), 0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="size"):
            E.generate(rng, 8, size)
    for n in (8.0, True, "8"):
        with pytest.raises(ValueError, match="n must be an integer"):
            E.generate(rng, n, 2.5)
    assert len(E.generate(rng, np.int64(8), np.float32(2.5)).pos) == 8
    with pytest.raises(ValueError, match="R must"):
        E.generate(rng, 8, 2.5, R=0.0)
    for goal in ((0, 1, 2.5), (0.0, 1, 2), (True, 1, 2), ("0", 1, 2)):
        with pytest.raises(ValueError, match="target triplet .* integer"):
            E.check_environment(env._replace(goal=goal), 12)
    with pytest.raises(ValueError, match="initial frame .* integer"):
        E.check_environment(env._replace(frame=(0, 1.5)), 12)
    with pytest.raises(ValueError, match="initial-belief triplet .* integer"):
        E.check_environment(env._replace(triplets=((0, 1, 2.0),) + env.triplets[1:]), 12)
    pos = env.pos.copy()
    pos[3] = pos[5]
    with pytest.raises(ValueError, match="landmarks 3 and 5 coincide"):
        E.check_environment(env._replace(pos=pos), 12)
    with pytest.raises(ValueError, match="start"):
        E.check_environment(env._replace(start=np.array([0.1, np.nan])), 12)
    # NumPy integer ids are fine
    E.check_environment(env._replace(goal=tuple(np.int64(x) for x in env.goal)), 12)


@pytest.mark.parametrize("argv, flag", [
    (["--eps", "nan"], "--eps"), (["--eps", "-0.1"], "--eps"), (["--eps", "1.5"], "--eps"),
    (["--size", "0"], "--size"), (["--size", "nan"], "--size"), (["--size", "-2"], "--size"),
    (["--size", "0.05"], "--size"), (["--samples", "0"], "--samples"),
    (["--scale-model", "metric"], "--scale-model")])
def test_cli_refuses_bad_options(tmp_path, capsys, argv, flag):
    from pqrm_jax.studies import qbsp

    out = tmp_path / "s"
    with pytest.raises(SystemExit) as e:
        qbsp.main(["--tiny", "--out", str(out), "--no-progress", *argv])
    assert e.value.code == 2
    assert flag in capsys.readouterr().err
    assert not out.exists()
