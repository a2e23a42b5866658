"""qrm.mapper: the init/update/metrics shape gives exactly the maps of run_sequence/map_step."""

import jax
import numpy as np
import pytest

from pqrm_jax import qrm, sim
from pqrm_jax.protocols import run

N_LM, N_POSES, N = 7, 4, 6


@pytest.fixture(scope="module")
def world():
    lm = sim.uniform_landmarks(jax.random.key(5), N_LM)
    poses = sim.random_imaging_points(jax.random.key(6), N_POSES)
    return lm, poses


def test_scan_over_update_equals_run_sequence_and_eager_updates(world):
    lm, poses = world
    qm = qrm.mapper("edc", N_LM, n=N)  # small B&B: fast to compile
    sensor = sim.SensorParams(max_range=1e6)  # run_sequence's default sensor
    images = jax.vmap(lambda p: sim.camera(p, lm, sensor))(poses)
    m_scan, reports = run(qm, jax.random.key(0), qm.init(), images)
    m_ref, met = qrm.run_sequence(lm, poses, n=N)
    np.testing.assert_array_equal(np.asarray(m_scan.rel), np.asarray(m_ref.rel))
    np.testing.assert_array_equal(np.asarray(m_scan.known), np.asarray(m_ref.known))
    assert reports.inconsistent.shape == (N_POSES,) and not bool(reports.inconsistent.any())
    # image by image, eagerly (one compiled update, called per image)
    m_a = qm.init()
    for t in range(N_POSES):
        m_a, _ = qm.update(m_a, jax.random.key(t), sim.camera(poses[t], lm, sensor))
    np.testing.assert_array_equal(np.asarray(m_a.rel), np.asarray(m_ref.rel))
    np.testing.assert_array_equal(np.asarray(m_a.known), np.asarray(m_ref.known))
    got = qm.metrics(m_scan, lm)
    assert got == qrm.map_metrics(m_ref, lm)
    assert got["removed_pct"] == pytest.approx(float(met.removed_pct[-1]))
    assert got["truth_kept"] == 1.0


def test_mapper_checks_its_configuration():
    with pytest.raises(ValueError, match="num_landmarks"):
        qrm.mapper("edc", 2)
    with pytest.raises(ValueError, match="n must be"):
        qrm.mapper("edc", 5, n=2)
    assert qrm.mapper("edc", 5, n=18).n == 5


@pytest.mark.parametrize("bad", [-1, 2.5, True, "4", None, np.float32(3.0)])
def test_a_bad_sweep_cap_is_refused_by_name_everywhere(bad, world):
    """max_sweeps: an integer (NumPy integers too), ≥ 0 for the mapper and the pipeline (0:
    no propagation), ≥ 1 for closure and apply_relations (which documented the check but
    passed a negative cap through as 'no sweep', and 2.5 as three sweeps)."""
    lm, poses = world
    calls = [lambda: qrm.mapper("edc", N_LM, n=N, max_sweeps=bad),
             lambda: qrm.run_sequence(lm, poses, n=N, max_sweeps=bad),
             lambda: qrm.map_step(qrm.empty_map(N_LM), poses[0], lm, N, max_sweeps=bad),
             lambda: qrm.apply_relations(qrm.empty_map(3), [[0, 1, 2]],
                                         [[1 << 6, (1 << 20) - 1, (1 << 20) - 1]],
                                         max_sweeps=bad)]
    for call in calls:
        with pytest.raises(ValueError, match="max_sweeps"):
            call()
    with pytest.raises(ValueError, match="max_sweeps"):
        qrm.apply_relations(qrm.empty_map(3), [[0, 1, 2]],
                            [[1 << 6, (1 << 20) - 1, (1 << 20) - 1]], max_sweeps=0)


def test_the_sweep_cap_of_the_pipeline_and_the_mapper(world):
    """max_sweeps = 64 (the default) is the fixed point; 0 leaves the map the intersection of
    the measured sets (an ablation: sound, a superset of the propagated map, fewer states
    removed); map_step and the mapper with the same cap give the same map; a NumPy integer
    is the same cap as the int."""
    lm, poses = world
    m64, met64 = qrm.run_sequence(lm, poses, n=N)
    m_np, _ = qrm.run_sequence(lm, poses, n=N, max_sweeps=np.int64(64))
    np.testing.assert_array_equal(np.asarray(m_np.rel), np.asarray(m64.rel))
    m0, met0 = qrm.run_sequence(lm, poses, n=N, max_sweeps=0)
    assert bool(met0.truth_kept.all()) and bool(met64.truth_kept.all())
    r0, r64 = np.asarray(m0.rel), np.asarray(m64.rel)
    assert not (r64 & ~r0).any()  # propagation only removes states
    assert (r64 != r0).any() and float(met0.removed_pct[-1]) < float(met64.removed_pct[-1])
    # image by image (map_step, the mapper's update) with the same cap: the same map
    sensor = sim.SensorParams(max_range=1e6)
    m = qrm.empty_map(N_LM)
    for t in range(N_POSES):
        m, _ = qrm.map_step(m, poses[t], lm, N, max_sweeps=0)
    np.testing.assert_array_equal(np.asarray(m.rel), r0)
    qm = qrm.mapper("edc", N_LM, n=N, max_sweeps=0)
    m_a = qm.init()
    for t in range(N_POSES):
        m_a, _ = qm.update(m_a, jax.random.key(t), sim.camera(poses[t], lm, sensor))
    np.testing.assert_array_equal(np.asarray(m_a.rel), r0)
