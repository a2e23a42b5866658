"""Localizing in the LPM while it is being built (B §4.1, §4.3) on a simulated run."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax.hssh.localization import LocalizeParams
from pqrm_jax.hssh.lpm import LPMParams, lpm_classify
from pqrm_jax.hssh.motion import ACTION_MODELS
from pqrm_jax.hssh.tracking import lpm_tracker, track_run
from pqrm_jax.sim import corridors
from pqrm_jax.sim.lidar import LidarParams, lidar_scan

RES = 0.1


def _world(side=201):
    img = np.asarray(corridors.render_free_rectangles(side, corridors.network_rectangles(),
                                                      supersample=2))
    return jnp.asarray((img < 128)[::-1].copy())


def _run(steps):
    """Drive along the y = 0.65 corridor through the + at x = 0.35 (20 m world)."""
    side = 201 * RES
    x = np.linspace(0.15, 0.45, steps + 1) * side
    true = np.stack([x, np.full_like(x, 0.65 * side), np.zeros_like(x)], axis=1)
    # odometry under-reads travel by 8 % and drifts 0.01 rad per step to the left
    d = np.diff(true[:, 0])
    th = np.concatenate([[0.0], np.cumsum(np.full(steps, 0.01))])
    ox = np.concatenate([[true[0, 0]], true[0, 0] + np.cumsum(0.92 * d * np.cos(th[:-1]))])
    oy = np.concatenate([[true[0, 1]], true[0, 1] + np.cumsum(0.92 * d * np.sin(th[:-1]))])
    odom = np.stack([ox, oy, th], axis=1)
    return true.astype(np.float32), odom.astype(np.float32)


def _lpm_agreement(state, world, params):
    """Fraction of the LPM's occupied cells within one cell of a wall of the world (a beam
    end on a wall face may fall in the free cell next to it)."""
    from scipy import ndimage

    occ = np.asarray(lpm_classify(state.lpm, params)[0])
    i, j = np.nonzero(occ)
    org = np.asarray(state.lpm.origin)
    wi = np.floor((org[1] + (i + 0.5) * params.resolution) / RES).astype(int)
    wj = np.floor((org[0] + (j + 0.5) * params.resolution) / RES).astype(int)
    w = ndimage.binary_dilation(np.asarray(world), np.ones((3, 3), bool))
    ok = (wi >= 0) & (wi < w.shape[0]) & (wj >= 0) & (wj < w.shape[1])
    return float(w[wi[ok], wj[ok]].mean()) if ok.any() else 0.0


@pytest.mark.slow
def test_tracking_in_the_lpm_beats_dead_reckoning():
    # shrink-and-grow with the "large" model; ~40 s (compile of the whole scan loop)
    world = _world()
    true, odom = _run(24)
    lp = LidarParams(n_beams=90, max_range=6.0, sigma=0.01)
    keys = jax.random.split(jax.random.key(0), len(true))
    scans = jax.vmap(lambda k, p: lidar_scan(k, p, world, RES, params=lp))(keys,
                                                                           jnp.asarray(true))
    lpm_p = LPMParams(size=100, resolution=RES)
    loc_p = LocalizeParams(blocks=3, block=64, sigma=0.1)
    tracker = lpm_tracker(jnp.asarray(ACTION_MODELS["large"]), lpm_params=lpm_p,
                          loc_params=loc_p)
    final, steps = track_run(tracker, jax.random.key(1), jnp.asarray(true[0]),
                             jnp.asarray(odom), scans)
    est = np.asarray(steps.pose)
    assert est.shape == (24, 3) and np.asarray(steps.particles).max() <= 3 * 64
    err_track = np.hypot(*(est[:, :2] - true[1:, :2]).T)
    err_odom = np.hypot(*(odom[1:, :2] - true[1:, :2]).T)
    assert err_odom[-1] > 0.4                    # dead reckoning drifts by tens of cm
    assert err_track.max() < 0.3 and err_track[-1] < 0.5 * err_odom[-1], (err_track, err_odom)
    # the map built at the localized poses agrees with the world
    agree = _lpm_agreement(final, world, lpm_p)
    assert agree > 0.8, agree

    # the same LPM built at the odometry poses is worse
    from pqrm_jax.hssh.lpm import lpm_init, lpm_update

    s = lpm_init(jnp.asarray(odom[0]), lpm_p)
    for k in range(len(odom)):
        s = lpm_update(s, jnp.asarray(odom[k]), jax.tree.map(lambda x, k=k: x[k], scans), lpm_p)
    odo_state = final._replace(lpm=s)
    assert _lpm_agreement(odo_state, world, lpm_p) < agree


def test_tracker_bad_input():
    tracker = lpm_tracker(jnp.asarray(ACTION_MODELS["small"]))
    with pytest.raises(ValueError, match="field_cap_cells"):
        lpm_tracker(jnp.asarray(ACTION_MODELS["small"]), field_cap_cells=0)
    z = jax.tree.map(lambda x: jnp.stack([x, x]),
                     lidar_scan(jax.random.key(0), jnp.array([1.0, 1.0, 0.0]), _world(41), 0.5,
                                params=LidarParams(n_beams=8, max_range=3.0)))
    with pytest.raises(ValueError, match="one scan per odometry"):
        track_run(tracker, jax.random.key(0), jnp.zeros(3), jnp.zeros((3, 3)), z)
    with pytest.raises(ValueError, match="odoms"):
        track_run(tracker, jax.random.key(0), jnp.zeros(3), jnp.zeros((2, 2)), z)
