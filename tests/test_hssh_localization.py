"""Adaptive proposals (B §4.3.2) and the hssh-localization study (slow: 5 compiled filters)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax.hssh import squared_distance_transform
from pqrm_jax.hssh.localization import METHODS, localize, scan_likelihood
from pqrm_jax.hssh.motion import ACTION_MODELS
from pqrm_jax.sim.lidar import LidarParams, lidar_scan


def _room():
    world = np.zeros((60, 60), bool)
    world[[0, -1], :] = world[:, [0, -1]] = True
    world[20:25, 30:45] = True
    return jnp.asarray(world)


@pytest.mark.slow
def test_scan_likelihood_peaks_at_the_true_pose():
    world = _room()
    d2 = squared_distance_transform(world[None], cap=20)[0]
    pose = jnp.array([2.05, 3.05, 0.3])
    z = lidar_scan(jax.random.key(0), pose, world, 0.1, params=LidarParams(n_beams=90,
                                                                           max_range=8.0))
    poses = jnp.stack([pose, pose + jnp.array([0.2, 0.0, 0.0]), pose + jnp.array([0, 0, 0.1])])
    lik = np.asarray(scan_likelihood(poses, z, d2, jnp.zeros(2), 0.1, 0.1))
    assert lik[0] > 0.95 and lik[0] > lik[1] and lik[0] > lik[2]


@pytest.mark.slow
def test_every_method_beats_raw_odometry_on_a_biased_step():
    world = _room()
    d2 = squared_distance_transform(world[None], cap=20)[0]
    prior, true = jnp.array([2.0, 3.0, 0.0]), jnp.array([2.5, 3.1, 0.1])
    odom0, odom1 = jnp.zeros(3), jnp.array([0.35, 0.0, 0.0])      # odometry under-reads
    z = lidar_scan(jax.random.key(1), true, world, 0.1, params=LidarParams(n_beams=90,
                                                                           max_range=8.0))
    c = jnp.asarray(ACTION_MODELS["large"])
    got = {m: float(localize(jax.random.key(2), prior, odom0, odom1, z, d2, jnp.zeros(2), 0.1,
                             c, method=m)[1]) for m in METHODS}
    assert all(got[m] > got["raw"] for m in METHODS if m != "raw")
    with pytest.raises(ValueError, match="method"):
        localize(jax.random.key(2), prior, odom0, odom1, z, d2, jnp.zeros(2), 0.1, c,
                 method="kld")


@pytest.mark.slow
def test_reduced_localization_study(tmp_path):
    from pqrm_jax.studies import hssh_localization as study

    assert study.main(["--steps", "8", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "Published orderings" in report and "not available" in report
    assert len(list((tmp_path / "units").glob("*.json"))) == 6
