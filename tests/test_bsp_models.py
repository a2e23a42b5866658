"""Offline BSP models (Z eqs. 4.5, 4.11–4.17, 4.22–4.24): sums, exact supports, cache."""

import numpy as np
import pytest

from pqrm_jax import calculi
from pqrm_jax.bsp import models as M
from pqrm_jax.tables import CacheError

SMALL = M.ModelParams(samples=600, pool=1 << 18, seed=3)  # same as test_bsp_belief (one build)


@pytest.fixture(scope="module")
def mod(request):
    return M.load_models(SMALL, directory=request.config.cache.mkdir("bsp-models"))


def test_rows_sum_to_one_and_counts(mod):
    for name in ("T", "K", "G2", "GA", "GB", "U"):
        t = np.asarray(getattr(mod, name))
        assert np.allclose(t.sum(-1), 1, atol=1e-5), name
        assert mod.counts[name].shape == t.shape[:-1]
        assert (M.stderr(mod, name) <= 0.5 / np.sqrt(SMALL.samples) + 1e-9).all()
    az = np.asarray(mod.AZ)
    assert (az.sum(-1) <= 1 + 1e-5).all() and (az >= 0).all()
    # two frame landmarks farther than 2R apart are never both within R
    assert np.asarray(mod.A)[..., -1].max() == 0
    # association decreases with the frame scale (on average)
    assert np.all(np.diff(np.asarray(mod.A).mean((0, 1))) <= 0)
    d2 = np.asarray(mod.D2)
    assert np.array_equal(d2, d2.T) and (np.diag(d2) > 0).all()


def test_exact_supports(mod):
    t = calculi.get("edc").tables
    Q = t.num_states
    U = np.asarray(mod.U) > 0
    for i, op in enumerate(M.UNARY_TYPES):
        assert not (U[i] & ~getattr(t, op)).any(), op
    # INVERSE of the EDC is the permutation i -> 21 - i (1-based)
    assert np.array_equal(np.asarray(mod.U)[2], np.eye(Q)[::-1])
    K = np.asarray(mod.K) > 0
    kt = dict(zip(M.LINK_TYPES, K, strict=True))
    # BA is INVERSE of the robot's state, whatever C is
    inv = np.broadcast_to(np.eye(Q)[::-1][:, None], (Q, Q, Q))
    assert np.array_equal(np.asarray(mod.K)[0], inv)
    assert not (kt["BA"] & ~t.inverse[:, None, :]).any()
    # BC:X in COMPOSE(AB:C, BC:X) -> AB:X exactly: support K[BC][x, c] = {b: compose[c, b, x]}
    exact_bc = t.compose.transpose(2, 0, 1)  # [x, c, b]
    assert not (kt["BC"] & ~exact_bc).any()
    assert (kt["BC"] & exact_bc).sum() >= 0.8 * exact_bc.sum()
    inv = t.inverse
    exact_cb = np.einsum("xcb,bd->xcd", exact_bc, inv) > 0
    assert not (kt["CB"] & ~exact_cb).any()
    # CA:X in COMPOSE(RIGHT(AB:C) = CA:B, AB:X)
    exact_ca = np.einsum("cr,rxd->xcd", t.right, t.compose) > 0
    assert not (kt["CA"] & ~exact_ca).any()
    exact_ac = np.einsum("xcb,bd->xcd", exact_ca, inv) > 0
    assert not (kt["AC"] & ~exact_ac).any()


def test_transition_concentrates_on_target(mod):
    T = np.asarray(mod.T)
    diag = np.einsum("bjj->bj", T)
    assert diag[3].mean() >= 0.9  # d ~ 1.4 R: noise 0.035 frame units
    assert diag[3].mean() >= diag[0].mean()  # more frame-unit noise in small frames


def test_measurement_diagonal_at_large_scale(mod):
    az = np.asarray(mod.AZ)
    Q = az.shape[0]
    z = az.reshape(Q, Q, -1, Q, Q)
    A = az.sum(-1)
    rate = []
    for b in range(4):  # noise sigma_z / d frame units shrinks as the frame grows
        seen = A[:, :, b] > 0.05
        rate.append((np.einsum("xtxt->xt", z[:, :, b])[seen] / A[:, :, b][seen]).mean())
    assert np.all(np.diff(rate) > 0) and rate[-1] > 0.6


def test_cache_roundtrip_and_corruption(tmp_path, mod):
    path = M.save_models(mod, SMALL, tmp_path / "m.npz")
    back = M.read_models(path, SMALL)
    assert np.array_equal(np.asarray(back.AZ), np.asarray(mod.AZ))
    assert not list(tmp_path.glob("*.tmp"))
    with pytest.raises(CacheError, match="other parameters"):
        M.read_models(path, M.ModelParams(samples=601, pool=1 << 18, seed=3))
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(CacheError, match=str(path.name)):
        M.read_models(path, SMALL)
    path.write_text("not a zip")
    with pytest.raises(CacheError, match="corrupt"):
        M.read_models(path, SMALL)


@pytest.mark.parametrize("bad", [dict(n_f=0), dict(samples=0), dict(window=-1.0),
                                 dict(sigma_m=float("nan")), dict(calculus="nope")])
def test_bad_params(bad):
    with pytest.raises((ValueError, KeyError)):
        M.ModelParams(**bad).validate()


def test_target_points_inside_states():
    edc = calculi.get("edc")
    p = M.target_points(edc)
    assert (np.asarray(edc.classify(np.zeros(2), np.array([0., 1.]), p)) == np.arange(20)).all()
