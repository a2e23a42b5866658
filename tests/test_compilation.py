"""Compile counts of the hot entry points (in the manner of blackjax's test_compilation.py).

A second call with new values and the same shapes must not trace or compile again: compiling
is most of the cost of these programs (the B&B solvers especially), so an accidental
recompile (a value made static, a Python scalar changing type, a new closure per call) is a
performance bug that no result test sees. Compilations are counted from JAX's own
``log_compiles`` records.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_count import count_compiles

from pqrm_jax import calculi, pqrm, qrm, sim
from pqrm_jax import serge as sg
from pqrm_jax.tables import feasibility
from pqrm_jax.tables import problems as pb


def test_counter_sees_a_compile():
    f = jax.jit(lambda x: x * 3 + 1)
    with count_compiles() as first:
        f(jnp.ones(7)).block_until_ready()
    with count_compiles() as second:
        f(jnp.zeros(7)).block_until_ready()
    assert len(first) >= 1 and second == []


def test_the_suite_keeps_compiled_programs_on_disk_and_still_counts_their_compiles():
    """conftest.py gives each test process a fresh persistent compilation cache: a program
    compiled there is written to it, and after the in-memory caches are dropped the same
    program loads from disk yet still shows in ``count_compiles`` (JAX logs the compile
    before it looks in the cache), so the compile-count tests keep their meaning."""
    from pathlib import Path

    where = Path(jax.config.jax_compilation_cache_dir)
    assert where.is_dir() and where.name.startswith("pqrm-jax-test-xla-")
    f = jax.jit(lambda x: jnp.cos(x) * 5 - 2)  # a program no other test compiles
    before = set(where.iterdir())
    f(jnp.ones(11)).block_until_ready()
    assert set(where.iterdir()) - before, "nothing written to the compilation cache"
    jax.clear_caches()
    with count_compiles() as again:
        f(jnp.ones(11)).block_until_ready()
    assert len(again) >= 1


def test_pqrm_mapper_update_compiles_once():
    pq = pqrm.mapper(("edc", "lr"), num_landmarks=5, num_samples=32)
    st = pq.init()
    vis = jnp.array([True, True, True, True, False])
    pos0 = jax.random.uniform(jax.random.key(0), (5, 2)) * 10
    pos1 = jax.random.uniform(jax.random.key(1), (5, 2)) * 10
    k0, k1 = jax.random.key(2), jax.random.key(3)
    vis1 = jnp.array([False, True, True, True, True])
    s1, _ = pq.update(st, k0, pos0, vis, 0.5)
    jax.block_until_ready(s1)
    with count_compiles() as again:
        s2, _ = pq.update(s1, k1, pos1, vis1, 0.75)
        jax.block_until_ready(s2)
    assert again == []


@pytest.mark.slow
def test_pqrm_mapper_update_batch_compiles_once():
    pq = pqrm.mapper(("edc", "lr"), num_landmarks=5, num_samples=32)
    st = pq.init()
    vis = jnp.array([True, True, True, True, False])
    vis1 = jnp.array([False, True, True, True, True])
    pos0 = jax.random.uniform(jax.random.key(0), (5, 2)) * 10
    k0, k1 = jax.random.key(2), jax.random.key(3)
    r = 3
    keys = jax.random.split(k0, r)
    states = jax.tree_util.tree_map(lambda x: jnp.stack([x] * r), st)
    posr = jnp.stack([pos0] * r)
    visr = jnp.stack([vis] * r)
    keys1, posr1, visr1 = jax.random.split(k1, r), posr + 1.0, jnp.stack([vis1] * r)
    jax.block_until_ready(pq.update_batch(states, keys, posr, visr, 0.5))
    with count_compiles() as again:
        jax.block_until_ready(pq.update_batch(states, keys1, posr1, visr1, 0.25))
    assert again == []


def test_tables_solver_compiles_once():
    probs = pb.random_compose_problems(calculi.get("edc"), 8)
    batch = pb.to_batch(probs, 8.0)
    feasibility.solve(batch, parts=1)
    with count_compiles() as again:
        sol = feasibility.solve(batch, parts=1, seed=7, min_width=2.0**-20,
                                ids=np.arange(batch.size) + 1000)
    assert again == []
    assert sol.status.shape == (batch.size,)


def test_camera_kernel_compiles_once():
    lm = sim.uniform_landmarks(jax.random.key(0), 7)
    sensor = sim.SensorParams(max_range=1e6)
    cam0 = sim.camera(jnp.array([50.0, 50.0, 0.0]), lm, sensor)
    cam1 = sim.camera(jnp.array([20.0, 70.0, 1.0]), lm, sensor)
    jax.block_until_ready(qrm.measure_image(cam0.bearings, cam0.range_rank, cam0.visible, n=6))
    with count_compiles() as again:
        jax.block_until_ready(qrm.measure_image(cam1.bearings, cam1.range_rank, cam1.visible,
                                                n=6))
    assert again == []


@pytest.mark.slow
def test_camera_kernel_with_target_map_compiles_once():
    lm = sim.uniform_landmarks(jax.random.key(0), 7)
    sensor = sim.SensorParams(max_range=1e6)
    cam0 = sim.camera(jnp.array([50.0, 50.0, 0.0]), lm, sensor)
    cam1 = sim.camera(jnp.array([20.0, 70.0, 1.0]), lm, sensor)
    target = qrm.true_map(lm).rel
    target1 = jax.block_until_ready(target ^ 1)
    jax.block_until_ready(qrm.measure_image(cam0.bearings, cam0.range_rank, cam0.visible, n=6,
                                            target_map=target))
    with count_compiles() as again:
        jax.block_until_ready(qrm.measure_image(cam1.bearings, cam1.range_rank, cam1.visible,
                                                n=6, target_map=target1))
    assert again == []


def test_serge_compiles_once():
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    prob = sg.initial_cells(jax.random.PRNGKey(0),
                            sg.GaussianBeliefs(xy, np.tile(np.eye(2) * 0.3, (4, 1, 1))),
                            sg.Grid((-5.0, -5.0), (15.0, 15.0), (24, 24)))
    r0 = sg.serge(jax.random.key(1), prob, mu=2, sigma=1.0, trials=16)
    with count_compiles() as again:
        r1 = sg.serge(jax.random.key(2), prob, mu=2, sigma=1.5, trials=16)
    assert again == []
    assert r0.n_regions >= 1 and r1.n_regions >= 1


def _tiny_log(steps: int = 3):
    """A short lidar log in a small corridor world (for the tracker's compile count)."""
    from pqrm_jax.sim import corridors
    from pqrm_jax.sim.lidar import LidarParams, lidar_scan

    img = np.asarray(corridors.render_free_rectangles(41, corridors.network_rectangles(),
                                                      supersample=1))
    world = jnp.asarray((img < 128)[::-1].copy())
    x = np.linspace(0.3, 0.4, steps + 1) * 4.1
    true = np.stack([x, np.full_like(x, 0.65 * 4.1), np.zeros_like(x)], 1).astype(np.float32)
    keys = jax.random.split(jax.random.key(0), steps + 1)
    lp = LidarParams(n_beams=16, max_range=2.0)
    scans = jax.vmap(lambda k, p: lidar_scan(k, p, world, 0.1, params=lp))(keys,
                                                                          jnp.asarray(true))
    return jnp.asarray(true), scans


def test_equal_trackers_share_one_track_run_program():
    """Issue 28: each ``lpm_tracker(...)`` call used to compile ``track_run`` again."""
    from pqrm_jax import hssh
    from pqrm_jax.hssh.motion import ACTION_MODELS

    true, scans = _tiny_log()
    kw = dict(lpm_params=hssh.LPMParams(size=24, resolution=0.1),
              loc_params=hssh.LocalizeParams(blocks=1, block=8))

    def tracker():  # a fresh object each time, from equal arguments
        return hssh.lpm_tracker(np.array(ACTION_MODELS["small"]), **kw)

    assert tracker() == tracker() and hash(tracker()) == hash(tracker())
    with count_compiles() as first:
        jax.block_until_ready(hssh.track_run(tracker(), jax.random.key(0), true[0], true, scans))
    assert any("track_run" in m for m in first), first
    pose1, odoms1 = jax.block_until_ready((true[0] + 0.01, true * 1.001))
    with count_compiles() as again:
        jax.block_until_ready(hssh.track_run(tracker(), jax.random.key(1), pose1, odoms1,
                                             scans))
    assert again == []
    other = hssh.lpm_tracker(np.array(ACTION_MODELS["small"]), method="raw", **kw)
    assert other != tracker()


def test_hssh_global_relocalization_compiles_once():
    from pqrm_jax.hssh_global import relocalize

    rng = np.random.default_rng(0)
    k, p, n = 2, 16, 12

    def args(shift):
        pts = rng.uniform(0, 1, (k, p, 2)).astype(np.float32)
        fields = rng.uniform(0, 1, (k, n, n)).astype(np.float32)
        return (pts, np.ones((k, p), bool), fields, np.zeros((k, 2), np.float32) + shift,
                np.zeros((k, 3), np.float32), np.zeros((k, 3), np.float32))

    params = relocalize.RelocParams()
    jax.block_until_ready(relocalize.match_pairs(*args(0.0), 0.1, 1.0, params))
    with count_compiles() as again:
        c, s = relocalize.match_pairs(*args(0.5), 0.12, 1.5, params)
        jax.block_until_ready(c)
    assert again == []
    assert c.shape == (k, 3) and s.shape == (k,)


def test_hssh_global_drive_compiles_once():
    """The simulated exploration's drive (and the local levels it calls) compile only on the
    first exploration: a second one, other seed and length, compiles nothing."""
    from pqrm_jax import hssh_global as hg
    from pqrm_jax.hssh_global import simulation as hs

    sw = hs.sim_world(hg.world_from_lattice({((0, 0), (1, 0)), ((1, 0), (1, 1))}))
    with count_compiles() as first:
        hs.explore_sim(sw, 1, seed=1)
    assert any("_drive" in m for m in first), first
    with count_compiles() as again:
        hs.explore_sim(sw, 2, seed=2)
    assert again == [], again


def test_prepass_classification_compiles_once():
    """``tables.exact.realised`` jitted a fresh lambda per call: every table build compiled
    the pre-pass program again (issue 31 item 4)."""
    from pqrm_jax.tables import exact

    calc = calculi.get("edc")
    atoms, _ = pb.atoms(calc)
    exact.realised(calc, atoms, exact.sample_configs(jax.random.PRNGKey(0), 256))
    exact.sampled_realised(calc, atoms, jax.random.PRNGKey(0), 256)
    with count_compiles() as again:
        exact.realised(calc, atoms, exact.sample_configs(jax.random.PRNGKey(1), 256))
        exact.sampled_realised(calc, atoms, jax.random.PRNGKey(1), 256)
    assert again == []
