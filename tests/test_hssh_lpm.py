"""Scrolling LPM (B §3.3, §4.1): whole-cell scrolling, scan updates, batching, lidar → gateways."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import hssh
from pqrm_jax.hssh.lpm import LPMParams, LPMState, lpm_classify, lpm_init, lpm_update
from pqrm_jax.sim import corridors
from pqrm_jax.sim.lidar import LidarParams, LidarScan, lidar_scan

P = LPMParams(size=21, resolution=0.5)
NO_SCAN = LidarScan(jnp.zeros(1), jnp.zeros(1), jnp.zeros(1, bool))


def test_scrolls_by_whole_cells_and_forgets():
    pose = jnp.array([5.2, 5.2, 0.0])
    s = lpm_init(pose, P)
    pattern = jnp.arange(21 * 21, dtype=jnp.float32).reshape(21, 21) / 1000
    s = LPMState(pattern, s.origin)
    moved = pose + jnp.array([1.5, -1.0, 0.0])          # +3 cells in x, -2 in y
    s2 = lpm_update(s, moved, NO_SCAN, P)
    np.testing.assert_allclose(np.asarray(s2.origin), np.asarray(s.origin) + [1.5, -1.0])
    lo = np.asarray(s2.logodds)
    np.testing.assert_array_equal(lo[2:, :-3], np.asarray(pattern)[:-2, 3:])
    assert not lo[:2].any() and not lo[:, -3:].any()     # scrolled-in cells are unknown
    rc = np.floor((np.asarray(moved[:2]) - np.asarray(s2.origin)) / P.resolution)
    assert rc.tolist() == [10, 10]                       # robot in the central cell


def test_scan_update_free_occupied_unknown_and_nan_beams():
    pose = jnp.array([5.25, 5.25, 0.0])
    s = lpm_init(pose, P)
    scan = LidarScan(jnp.array([0.0, jnp.pi / 2, jnp.pi]), jnp.array([2.1, jnp.nan, 3.0]),
                     jnp.array([True, True, False]))
    s = lpm_update(s, pose, scan, P)
    occ, unk = (np.asarray(m) for m in lpm_classify(s, P))
    assert occ[10, 14] and occ.sum() == 1                # the hit, 2.1 m east
    assert not unk[10, 10:14].any() and not unk[10, 4:10].any()   # beams' free cells
    assert unk[11:, 10].all()                            # the NaN beam changed nothing
    assert np.all(np.isfinite(np.asarray(s.logodds)))


def test_batched_runs_equal_single_runs():
    poses = jnp.array([[5.2, 5.2, 0.0], [6.0, 4.1, 1.0], [3.3, 7.7, -2.0]])
    scans = LidarScan(jnp.tile(jnp.array([0.0, 1.0]), (3, 1)), jnp.array([[2.0, 1.0]] * 3),
                      jnp.ones((3, 2), bool))
    init = jax.vmap(lambda p: lpm_init(p, P))(poses)
    batch = jax.vmap(lambda s, p, z: lpm_update(s, p, z, P))(init, poses + 0.7, scans)
    for k in range(3):
        one = lpm_update(lpm_init(poses[k], P), poses[k] + 0.7,
                         jax.tree.map(lambda x, k=k: x[k], scans), P)
        np.testing.assert_array_equal(np.asarray(batch.logodds[k]), np.asarray(one.logodds))


def test_lidar_lpm_to_local_topology_at_a_tee():
    img = corridors.render_free_rectangles(241, corridors.intersection_rectangles(
        corridors.INTERSECTIONS["T"], 0.12))
    world = jnp.asarray((np.asarray(img) < 128)[::-1].copy())   # rows along y
    p = LPMParams(size=121, resolution=0.1)
    pose = jnp.array([12.05, 12.05, 0.0])
    s = lpm_init(pose, p)
    for k in range(3):
        ps = pose.at[2].set(0.2 * k)
        scan = lidar_scan(jax.random.key(k), ps, world, 0.1,
                          params=LidarParams(n_beams=1080, max_range=8.0))
        s = lpm_update(s, ps, scan, p)
    occ, unk = (np.asarray(m)[::-1].copy() for m in lpm_classify(s, p))
    lt = hssh.local_topology(occ, (60, 60), unknown=unk)
    assert lt.kind == "place" and len(lt.gateways) == 3
    assert hssh.star_isomorphisms(lt.star, [(0, -1, False), (1, 1, True), (0, 1, True),
                                            (1, -1, True)])
