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
