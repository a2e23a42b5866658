"""Bearing tolerance of the camera measurement (issue #27): sound for the scene, not only
for the rounded bearings.

* bearings that float32 rounds to one value for three landmarks that are *not* on one ray
  (the scene has an open true state) were refused / emptied at tolerance 0 (an inconsistent
  noise-free update); with the default tolerance their sets hold the truth;
* the sets at tolerance τ hold every state feasible for bearings within τ (checked against
  the float64 exact sets of randomly perturbed bearings, at τ up to 1e-2 rad);
* random scenes of every kind imaged by the float32/float64 simulator keep the exact true
  state (decided in rational arithmetic) in every measured set, and the mapper never
  reports a noise-free update inconsistent (reduced version of
  benchmarks/bench_qrm_tolerance.py);
* tolerance 0 keeps the exact sets (tests/test_qrm_camera_exact.py compares with z3), and
  the default costs nothing in float64 on generic input;
* one fused ``apply_relations`` call and image-by-image updates differ on inconsistent
  input: an update is accepted or rejected as a whole (docs/qrm.md §hypergraph).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import qrm, sim
from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm import hypergraph as H
from pqrm_jax.qrm import pipeline as P
from pqrm_jax.qrm.spec import CYCLIC, popcount, qrm_spec
from pqrm_jax.tables.exact import exact_interior_state

SPEC = qrm_spec("edc")


def exact_state(P3, X, Y, Z) -> int:
    """True state of XY:Z from the exact (rational) coordinates; −1 on a boundary."""
    return exact_interior_state(SPEC.calc, *(tuple(float(c) for c in P3[i]) for i in (X, Y, Z)))


def _ray_triple(seed: int) -> np.ndarray:
    """(3, 2) float32 landmarks in range order, not collinear, whose float32 bearings from
    the origin are all equal (offsets across the ray far below float32's angle rounding)."""
    rng = np.random.default_rng(seed)
    while True:
        th = rng.uniform(-np.pi, np.pi)
        w, n = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
        r = np.sort(rng.uniform(5, 60, 3))
        P = (r[:, None] * w + (rng.normal(0, 2e-8, 3) * r)[:, None] * n).astype(np.float32)
        b = np.arctan2(P[:, 1], P[:, 0])
        order = np.argsort(np.linalg.norm(P.astype(np.float64), axis=1))
        if (order == np.arange(3)).all() and (b == b[0]).all() and all(
                exact_state(P, *c) >= 0 for c in CYCLIC):
            return P


@pytest.mark.parametrize("seed", range(3))
def test_equal_float32_bearings_keep_the_true_state(seed):
    """Regression (fails on the tolerance-0 kernel): three landmarks just off one ray have
    equal float32 bearings; they are not collinear, so their true states are open states.
    Tolerance 0 calls the row "three on one ray" (ValueError; empty sets when traced, an
    inconsistent noise-free update); the default tolerance keeps every true state."""
    Pt = _ray_triple(seed)
    b = np.arctan2(Pt[:, 1], Pt[:, 0])[None]
    m = C.measure_triples(b)
    truth = [exact_state(Pt, *c) for c in CYCLIC]
    sets = np.asarray(m.sets)[0]
    assert all(int(sets[o]) >> s & 1 for o, s in enumerate(truth)), (truth, sets)
    with pytest.raises(ValueError, match="all equal"):
        C.measure_triples(b, tol=0)


def test_equal_float32_bearings_update_is_consistent():
    """The same layout through the simulator and the pipeline: the noise-free image is not
    reported inconsistent and the truth is kept (at tolerance 0 the update is rejected)."""
    Pt = _ray_triple(0)
    lm = np.concatenate([Pt, np.array([[3.0, -7.0], [-9.0, 4.0]], np.float32)])
    pose = np.zeros((1, 3), np.float32)
    cam = sim.camera(pose[0], lm, sim.SensorParams(max_range=1e6))
    assert len(set(np.asarray(cam.bearings)[:3].tolist())) == 1
    m, met = P.run_sequence(lm, pose, n=5)
    assert not bool(met.inconsistent[0]) and bool(met.truth_kept[0])
    _, met0 = P.run_sequence(lm, pose, n=5, tol=0)
    assert bool(met0.inconsistent[0])  # what the exact-for-the-rounded-bearings kernel did


def test_reported_far_cluster():
    """The issue's far cluster (bearings −2.10895, −2.10921, −2.10928 rad, ranges 245.7 /
    246.5 / 247.0; relation 20:1 is truly 13): rebuilt from these five-digit values as a
    float32 scene, the measured 20:1 holds 13 and stays small (the lune states)."""
    th = np.array([-2.10895, -2.10921, -2.10928])
    r = np.array([245.7, 246.5, 247.0])
    Pt = (r[:, None] * np.stack([np.cos(th), np.sin(th)], -1)).astype(np.float32)
    assert exact_state(Pt, 2, 0, 1) == SPEC.calc.index("13")
    b = np.arctan2(Pt[:, 1], Pt[:, 0])[None]
    sets = np.asarray(C.measure_triples(b).sets)[0]
    assert int(sets[2]) >> SPEC.calc.index("13") & 1
    with jax.enable_x64(True):
        s64 = np.asarray(C.measure_triples(b.astype(np.float64),
                                           tol=C.default_tolerance(np.float32)).sets)[0]
    assert int(s64[2]) >> SPEC.calc.index("13") & 1 and popcount(s64[2]) <= 6


@settings(max_examples=12, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1),
       tol=st.sampled_from([1e-6, 1e-4, 1e-3, 1e-2]),
       spread=st.sampled_from([1e-3, 0.05, 0.5, 2 * np.pi]))
def test_tolerant_sets_hold_every_nearby_exact_set(seed, tol, spread):
    """Soundness of the tolerance: the union of the exact (float64, tolerance 0) sets of
    bearings perturbed by at most τ (corners and random points of the box) is inside the
    τ-sets; both dtypes."""
    rng = np.random.default_rng(seed)
    T, K = 24, 12
    b = rng.uniform(-np.pi, np.pi, (T, 1)) + rng.uniform(0, spread, (T, 3))
    corners = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)]) * 2 - 1.0
    pert = np.concatenate([corners, rng.uniform(-1, 1, (K - 8, 3))]) * tol * (1 - 1e-6)
    with jax.enable_x64(True):
        bb = (b[:, None] + pert[None]).reshape(-1, 3)
        ex = np.asarray(C.measure_triples(bb, exact=False, tol=0).sets).reshape(T, K, 3)
        union = np.bitwise_or.reduce(ex, axis=1)
        s64 = np.asarray(C.measure_triples(b, exact=False, tol=tol).sets)
    assert ((union & ~s64) == 0).all()
    s32 = np.asarray(C.measure_triples(b.astype(np.float32), exact=False, tol=tol).sets)
    assert ((union & ~s32) == 0).all()


def _scene(kind, rng):
    if kind == "uniform":
        lm, xy = rng.uniform(0, 100, (6, 2)), rng.uniform(0, 100, (3, 2))
    elif kind == "far_cluster":
        c = rng.uniform(-50, 50, 2)
        lm = c + rng.normal(0, rng.uniform(0.1, 2.0), (6, 2))
        ang = rng.uniform(-np.pi, np.pi, 3)
        xy = c + rng.uniform(50, 800, 3)[:, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    elif kind == "collinear":
        a, ang = rng.uniform(-50, 50, 2), rng.uniform(-np.pi, np.pi)
        u, v = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
        rel = 10.0 ** rng.uniform(-9, -5)
        off = rel * 100 * rng.normal(0, 1, 6)
        lm = a + rng.uniform(-50, 50, 6)[:, None] * u + off[:, None] * v
        xy = a + rng.uniform(-60, 60, 3)[:, None] * u + rng.uniform(5, 60, 3)[:, None] * v
    elif kind == "equal_bearings":
        p = rng.uniform(-50, 50, 2)
        phi = np.repeat(rng.uniform(-np.pi, np.pi, 3), 2)
        lm = p + rng.uniform(5, 60, 6)[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        xy = np.concatenate([p[None], rng.uniform(-60, 60, (2, 2))])
    elif kind == "equidistant":
        p = rng.uniform(-50, 50, 2)
        phi = rng.uniform(-np.pi, np.pi, 6)
        r = rng.uniform(10, 60) * (1 + 1e-7 * rng.normal(0, 1, 6))
        lm = p + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        xy = np.concatenate([p[None], rng.uniform(-60, 60, (2, 2))])
    else:  # camera at a landmark
        lm = rng.uniform(0, 100, (6, 2))
        xy = lm[rng.integers(0, 6, 3)]
    return lm, np.concatenate([xy, rng.uniform(-np.pi, np.pi, (3, 1))], -1)


@jax.jit
def _inconsistent_updates(cams: sim.sensors.CameraObservation) -> jax.Array:
    """[T] whether the mapper reported each image's update inconsistent. One jitted
    function for every scene and example (a fresh lambda per scene recompiled the mapper
    scan, ~7 s each, 18 times per dtype)."""
    qm = qrm.mapper(SPEC, 6, n=6)
    _, rep = jax.lax.scan(lambda m, img: qm.update(m, jax.random.key(0), img), qm.init(), cams)
    return rep.inconsistent


KINDS = ("uniform", "far_cluster", "collinear", "equal_bearings", "equidistant",
         "camera_at_landmark")


# float32 is the dtype whose rounding dropped truths (the near-ray class); the float64 run
# of the same property is slow-marked to keep the default suite within its budget (the
# full two-dtype evidence: benchmarks/bench_qrm_tolerance.py)
@pytest.mark.parametrize("dtype", ["float32", pytest.param("float64", marks=pytest.mark.slow)])
@settings(max_examples=3, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1))
def test_scenes_of_every_kind_keep_the_exact_truth(dtype, seed):
    """Reduced benchmarks/bench_qrm_tolerance.py: one layout of every kind, three images
    each, through the simulator camera and the mapper in ``dtype`` at the default
    tolerance: the exact true state is in every measured set and no update is
    inconsistent."""
    rng = np.random.default_rng(seed)
    sensor = sim.SensorParams(max_range=1e9)
    with jax.enable_x64(dtype == "float64"):
        for kind in KINDS:
            lm, poses = _scene(kind, rng)
            lm, poses = lm.astype(dtype), poses.astype(dtype)
            cams = jax.vmap(lambda p, lm=lm: sim.sensors.camera_kernel(
                p, jnp.asarray(lm), sensor))(jnp.asarray(poses))
            for im in range(poses.shape[0]):
                m = C.measure_image(cams.bearings[im], cams.range_rank[im], cams.visible[im],
                                    6, SPEC, check=False)
                ids, sets = np.asarray(m.triples), np.asarray(m.sets)
                for r in np.flatnonzero(np.asarray(m.valid)):
                    for o, (X, Y, Z) in enumerate(CYCLIC):
                        s = exact_state(lm, *ids[r, [X, Y, Z]])
                        assert s < 0 or int(sets[r, o]) >> s & 1, (kind, dtype, im, r, o)
            assert not np.asarray(_inconsistent_updates(cams)).any(), kind


def test_default_tolerance_and_bad_values():
    assert C.default_tolerance(np.float32) == pytest.approx(C.BEARING_ULPS * 2.0**-23)
    assert C.default_tolerance(np.float64) == pytest.approx(C.BEARING_ULPS * 2.0**-52)
    b = np.array([[0.1, 0.5, 1.3]], np.float32)
    for bad in (-1e-3, float("nan"), float("inf"), 1.0, True, "0.1"):
        with pytest.raises(ValueError, match="tol"):
            C.measure_triples(b, tol=bad)
    lm = sim.uniform_landmarks(jax.random.key(0), 6)
    poses = sim.random_imaging_points(jax.random.key(1), 2)
    with pytest.raises(ValueError, match="tol"):
        P.run_sequence(lm, poses, n=6, tol=-1.0)
    with pytest.raises(ValueError, match="tol"):
        P.map_step(H.empty_map(6), poses[0], lm, 6, tol=float("nan"))
    with pytest.raises(ValueError, match="tol"):
        qrm.mapper("edc", 6, n=6, tol=2.0)
    cam = sim.camera(poses[0], lm, sim.SensorParams(max_range=1e6))
    with pytest.raises(ValueError, match="tol"):
        C.measure_image(cam.bearings, cam.range_rank, cam.visible, 6, tol=-0.5)


def test_tolerance_zero_is_exact_and_default_costs_nothing_in_float64():
    """Tolerance 0 gives the sets of the given bearings (the z3 comparison is in
    test_qrm_camera_exact.py); the default's sets contain them; in float64 on generic
    bearings the default keeps the same sets."""
    rng = np.random.default_rng(0)
    b = rng.uniform(-np.pi, np.pi, (400, 3))
    s0 = np.asarray(C.measure_triples(b.astype(np.float32), exact=False, tol=0).sets)
    s1 = np.asarray(C.measure_triples(b.astype(np.float32), exact=False).sets)
    assert ((s0 & ~s1) == 0).all()
    with jax.enable_x64(True):
        a = np.asarray(C.measure_triples(b, exact=False, tol=0).sets)
        d = np.asarray(C.measure_triples(b, exact=False).sets)
    np.testing.assert_array_equal(a, d)


def test_inconsistent_image_fused_versus_one_by_one():
    """An update is accepted or rejected as a whole. Image by image, an inconsistent image
    is rejected alone and the others are kept; fused in one ``apply_relations`` call, the
    same rows make the whole call inconsistent and nothing is kept (the previous map is
    returned). Consistent images give the same map both ways."""
    lm = sim.uniform_landmarks(jax.random.key(5), 6)
    poses = sim.random_imaging_points(jax.random.key(6), 3)
    meas = []
    for p in poses:
        cam = sim.camera(p, lm, sim.SensorParams(max_range=1e6))
        meas.append(C.measure_image(cam.bearings, cam.range_rank, cam.visible, n=6))
    # a wrong image (noisy bearings could give one): the first triple's 01:2 keeps no state
    wrong = np.asarray(meas[1].sets).copy()
    wrong[0, 0] = 0
    bad = meas[1]._replace(sets=jnp.asarray(wrong))
    seq, flags = H.empty_map(6), []
    for m in (meas[0], bad, meas[2]):
        seq, rep = H.update_image(seq, m)
        flags.append(bool(rep.inconsistent))
    assert flags == [False, True, False]
    good = H.empty_map(6)
    for m in (meas[0], meas[2]):
        good, _ = H.update_image(good, m)
    np.testing.assert_array_equal(np.asarray(seq.rel), np.asarray(good.rel))
    cat = lambda f: jnp.concatenate([getattr(m, f) for m in (meas[0], bad, meas[2])])  # noqa: E731
    fused, rep = H.apply_relations(H.empty_map(6), cat("triples"), cat("sets"),
                                   valid=cat("valid"))
    assert bool(rep.inconsistent)
    np.testing.assert_array_equal(np.asarray(fused.rel), np.asarray(H.empty_map(6).rel))
    both, rep = H.apply_relations(H.empty_map(6), *(jnp.concatenate(
        [getattr(m, f) for m in (meas[0], meas[2])]) for f in ("triples", "sets")),
        valid=jnp.concatenate([meas[0].valid, meas[2].valid]))
    assert not bool(rep.inconsistent)
    np.testing.assert_array_equal(np.asarray(both.rel), np.asarray(good.rel))
