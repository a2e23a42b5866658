"""Qualitative map (M§VI): fixed point = one-at-a-time reference, order independence,
soundness on the true layout, inconsistency handling, data-association filter, FDC design."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import sim
from pqrm_jax.qrm import association as A
from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm import pipeline as P
from pqrm_jax.qrm.reference import ReferenceMap
from pqrm_jax.qrm.spec import mask_of, popcount, qrm_spec, states_of

N = 8
SENSOR = sim.SensorParams(max_range=1e3)


@pytest.fixture(scope="module")
def world():
    lm = sim.uniform_landmarks(jax.random.key(11), N)
    poses = sim.random_imaging_points(jax.random.key(12), 6)
    meas = []
    for p in poses:
        cam = sim.camera(p, lm, SENSOR)
        meas.append(C.measure_image(cam.bearings, cam.range_rank, cam.visible, n=6))
    return lm, poses, meas


def _apply_all(meas, order):
    m = H.empty_map(N)
    for i in order:
        m, rep = H.update_image(m, meas[i])
        assert not bool(rep.inconsistent)
    return m


def test_fixed_point_is_order_independent_and_sound(world):
    lm, _, meas = world
    a = _apply_all(meas, range(len(meas)))
    b = _apply_all(meas, reversed(range(len(meas))))
    c = _apply_all(meas, [3, 0, 5, 1, 4, 2])
    np.testing.assert_array_equal(np.asarray(a.rel), np.asarray(b.rel))
    np.testing.assert_array_equal(np.asarray(a.rel), np.asarray(c.rel))
    truth = np.asarray(H.true_relations(lm))
    d = truth >= 0
    rel = np.asarray(a.rel).astype(np.int64)
    assert ((rel[d] >> truth[d]) & 1).all()
    # propagation did something beyond the raw measurements
    assert popcount(np.asarray(a.rel)[d]).mean() < 5


def test_batched_fixed_point_equals_one_at_a_time_reference(world):
    spec = qrm_spec("edc")
    _, _, meas = world
    ref = ReferenceMap(spec, N)
    for mz in meas[:3]:
        tri = np.asarray(mz.triples)
        sets = np.asarray(mz.sets)
        for t in range(tri.shape[0]):
            for o, (X, Y, Z) in enumerate(C.CYCLIC):
                assert ref.update((tri[t, X], tri[t, Y], tri[t, Z]), int(sets[t, o]))
    m = _apply_all(meas, range(3))
    d = H.distinct_mask(N)
    np.testing.assert_array_equal(np.asarray(m.rel)[d], ref.rel[d].astype(np.uint32))


def test_unary_pseudo_measurements_and_composition():
    full = (1 << 20) - 1
    m, rep = H.apply_relations(H.empty_map(4), [[0, 1, 2]], [[mask_of("edc", [7]), full, full]])
    assert states_of("edc", int(m.rel[1, 2, 0])) == ["1", "5"]  # LEFT(7) (M Table I)
    assert states_of("edc", int(m.rel[1, 0, 2])) == ["14"]  # INVERSE(7) = 21 − 7
    # M§III.C: AB:C ∈ {6, 7}, AC:D = 16 ⇒ BC:D ⊆ {1, 5, 11, 12, 17, 18, 19, 20}
    m, _ = H.apply_relations(H.empty_map(4), [[0, 1, 2], [0, 2, 3]],
                             [[mask_of("edc", [6, 7]), full, full],
                              [mask_of("edc", [16]), full, full]])
    assert set(states_of("edc", int(m.rel[1, 2, 3]))) <= {"1", "5", "11", "12", "17", "18",
                                                         "19", "20"}


def test_inconsistency_is_reported_and_map_stays_usable(world):
    lm, _, meas = world
    m = _apply_all(meas, range(len(meas)))
    truth = np.asarray(H.true_relations(lm))
    t = truth[0, 1, 2]
    wrong = ((1 << 20) - 1) & ~int(m.rel[0, 1, 2])  # disjoint from what the map allows
    full = (1 << 20) - 1
    m2, rep = H.apply_relations(m, [[0, 1, 2]], [[wrong, full, full]])
    assert bool(rep.inconsistent) and int(rep.n_empty) >= 1
    np.testing.assert_array_equal(np.asarray(m2.rel), np.asarray(m.rel))
    # the map is still usable: a consistent measurement (the truth) is accepted
    m3, rep3 = H.apply_relations(m2, [[0, 1, 2]], [[1 << int(t), full, full]])
    assert not bool(rep3.inconsistent) and int(m3.rel[0, 1, 2]) == 1 << int(t)


def test_sequence_keeps_truth_and_first_measurement_halves():
    lm = sim.uniform_landmarks(jax.random.key(21), 10)
    poses = sim.random_imaging_points(jax.random.key(22), 8)
    m, met = P.run_sequence(lm, poses, n=8)
    assert bool(met.truth_kept.all()) and not bool(met.inconsistent.any())
    r = np.asarray(met.removed_pct)
    assert (np.diff(r) >= -1e-4).all() and r[-1] > r[0] > 0
    hist = np.asarray(met.first_open).sum(0)
    assert hist[:11].sum() / hist.sum() > 0.9  # ≥ half the states removed "almost always"


def test_association_candidates():
    lm = sim.uniform_landmarks(jax.random.key(31), 10)
    m = H.true_map(lm)
    cam = sim.camera(jnp.array([40.0, 60.0, 0.0]), lm, SENSOR)
    cand = np.asarray(A.association_candidates(m, cam.bearings, cam.range_rank, cam.visible,
                                               unknown=4, n=10))
    assert cand[4] and cand.sum() < 4
    # an empty map cannot rule anything out among known nodes; unknown nodes never qualify
    m0 = H.QRMMap(H.empty_map(10).rel, jnp.ones(10, bool).at[7].set(False))
    cand0 = np.asarray(A.association_candidates(m0, cam.bearings, cam.range_rank, cam.visible,
                                                unknown=4, n=10))
    assert cand0[4] and not cand0[7]
    with pytest.raises(ValueError, match="not a visible"):
        A.association_candidates(m, cam.bearings, cam.range_rank,
                                 np.where(np.arange(10) == 4, False, np.asarray(cam.visible)),
                                 unknown=4, n=10)


def test_bad_ids():
    full = (1 << 20) - 1
    with pytest.raises(ValueError, match="outside the map's capacity"):
        H.apply_relations(H.empty_map(4), [[0, 1, 7]], [[full, full, full]])
    with pytest.raises(ValueError, match="repeats a landmark"):
        H.apply_relations(H.empty_map(4), [[0, 1, 1]], [[full, full, full]])
    with pytest.raises(ValueError, match="capacity"):
        H.empty_map(2)


def test_repeated_rows_are_intersected():
    """Issue #14 item 3: rows for the same relation in one call intersect (not last-wins)."""
    full = (1 << 20) - 1
    a, b, c = (mask_of("edc", s) for s in ([1, 5, 11, 12], [1, 2, 3, 5], [2, 4]))
    m, rep = H.apply_relations(H.empty_map(3), [[0, 1, 2], [0, 1, 2]], [[a, full, full],
                                                                      [b, full, full]])
    assert not bool(rep.inconsistent)
    assert states_of("edc", int(m.rel[0, 1, 2])) == ["1", "5"]
    # the same relation reached through a rotation of the triple is intersected too
    m, rep = H.apply_relations(H.empty_map(3), [[0, 1, 2], [1, 2, 0]], [[a, full, full],
                                                                      [full, full, b]])
    assert states_of("edc", int(m.rel[0, 1, 2])) == ["1", "5"]
    m0 = H.empty_map(3)
    m, rep = H.apply_relations(m0, [[0, 1, 2], [0, 1, 2]], [[a, full, full], [c, full, full]])
    assert bool(rep.inconsistent)
    np.testing.assert_array_equal(np.asarray(m.rel), np.asarray(m0.rel))


def test_all_images_in_one_call_reach_the_image_by_image_fixed_point(world):
    _, _, meas = world
    one_by_one = _apply_all(meas, range(len(meas)))
    tri = np.concatenate([np.asarray(mz.triples) for mz in meas])
    sets = np.concatenate([np.asarray(mz.sets) for mz in meas])
    valid = np.concatenate([np.asarray(mz.valid) for mz in meas])
    at_once, rep = H.apply_relations(H.empty_map(N), tri, sets, valid=valid)
    assert not bool(rep.inconsistent)
    np.testing.assert_array_equal(np.asarray(at_once.rel), np.asarray(one_by_one.rel))
