"""Camera measurement vs the exact z3 oracle (issue #14): equal sets at every bearing spread.

The oracle (:mod:`pqrm_jax.qrm.camera_oracle`) decides every state of every cyclic relation
with z3 on the exact polynomial system (rational unit vectors, range-ordering cone) and
re-verifies each SAT witness in rational arithmetic. Checked per triple:

* ``measure_triples(exact=True)`` returns exactly the oracle's sets;
* the batched kernel alone (``exact=False``) is sound and its decisions are right: every
  state it keeps without counting it undecided is feasible, every state it removes is
  infeasible, and the true state of the configuration the bearings came from is feasible;
* in float64 the kernel alone already equals the oracle, with nothing undecided.
"""

from __future__ import annotations

import numpy as np
import pytest

from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm.camera_oracle import exact_vectors, oracle_sets
from pqrm_jax.qrm.spec import popcount, qrm_spec

SPREADS = (0.05, 0.3, 1.0, 2.0, 2 * np.pi)


def _by_range(P):
    order = np.argsort(np.linalg.norm(P, axis=-1), kind="stable")
    P = P[order]
    return np.arctan2(P[:, 1], P[:, 0]).astype(np.float32)


def _triples(kind: str, count: int, seed: int, spread: float = 1.0) -> np.ndarray:
    """(count, 3) float32 bearings in range order of one kind of layout."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        if kind == "uniform":  # bearings uniform in a random sector of width ``spread``
            th = rng.uniform(-np.pi, np.pi) + rng.uniform(0, spread, 3)
            r = rng.uniform(1, 20, 3)
            P = r[:, None] * np.stack([np.cos(th), np.sin(th)], -1)
        elif kind == "clustered":  # a distant cluster of rocks
            P = rng.uniform(30, 60) * np.array([1.0, 0.0]) + rng.normal(0, 1.5, (3, 2))
        elif kind == "near_collinear":  # three landmarks almost on a line
            a, b = rng.uniform(-10, 10, (2, 2))
            P = np.stack([a, b, a + rng.uniform(-2, 3) * (b - a) + rng.normal(0, 1e-3, 2)])
        elif kind == "near_equidistant":  # almost equal ranges
            th = rng.uniform(-np.pi, np.pi, 3)
            P = (5 + rng.normal(0, 1e-3, 3))[:, None] * np.stack([np.cos(th), np.sin(th)], -1)
        else:
            raise ValueError(kind)
        out.append(_by_range(P))
    return np.stack(out)


def _check(bear):
    spec = qrm_spec("edc")
    exact = np.stack([oracle_sets(b, spec) for b in bear])
    assert (popcount(exact) > 0).all()  # the configuration the bearings came from is one
    kern = C.measure_triples(bear, spec, exact=False, tol=0)
    sets, und = np.asarray(kern.sets), np.asarray(kern.undecided)
    assert ((exact & ~sets) == 0).all(), "kernel removed a feasible state"
    assert ((sets & ~und & ~exact) == 0).all(), "kernel proved an infeasible state"
    ex = C.measure_triples(bear, spec, exact=True, tol=0)
    np.testing.assert_array_equal(np.asarray(ex.sets), exact)
    assert not np.asarray(ex.undecided).any()
    assert 0 <= ex.exact_decisions <= 3 * spec.num_states * len(bear)
    import jax

    with jax.enable_x64(True):
        k64 = C.measure_triples(bear.astype(np.float64), spec, exact=False, tol=0)
    s64, u64 = np.asarray(k64.sets), np.asarray(k64.undecided)
    # two equal bearings make constraints vanish identically on a cone edge, which the
    # rounding band cannot tell from "nearly": such rows may keep undecided states
    ray = np.array([len(set(b.tolist())) < 3 for b in bear])
    np.testing.assert_array_equal(s64[~ray], exact[~ray])
    assert not u64[~ray].any()
    assert ((exact & ~s64) == 0).all() and ((s64 & ~u64 & ~exact) == 0).all()
    return np.asarray(ex.sets)


def test_exact_sets_equal_oracle_every_spread_and_kind():
    """One triple per spread 0.05–2π and per layout kind, the issue's example (bearings
    (−2.901, −2.913, −3.065): 01:2 is exactly {1, 2, 4, 9, 10}) and two landmarks on one
    ray (ordinary input), in one batch."""
    from pqrm_jax.qrm.spec import states_of

    bear = np.concatenate([_triples("uniform", 1, 10 + i, s) for i, s in enumerate(SPREADS)]
                          + [_triples(k, 1, 20 + i) for i, k in
                             enumerate(("clustered", "near_collinear", "near_equidistant"))]
                          + [np.array([[-2.901, -2.913, -3.065], [0.4, 0.4, 1.3]], np.float32)])
    sets = _check(bear)
    assert states_of("edc", int(sets[-2, 0])) == ["1", "2", "4", "9", "10"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["uniform", "clustered", "near_collinear", "near_equidistant"])
def test_exact_sets_equal_oracle_slow(kind):
    if kind == "uniform":
        bear = np.concatenate([_triples(kind, 8, 100 + i, s) for i, s in enumerate(SPREADS)])
    else:
        bear = _triples(kind, 24, 200)
    _check(bear)


def test_documented_bad_input():
    spec = qrm_spec("edc")
    # three on one ray: collinear for every range assignment, no open state (tolerance 0;
    # with a tolerance, bearings within it of each other are ordinary input)
    with pytest.raises(ValueError, match="all equal"):
        C.measure_triples(np.array([[0.7, 0.7, 0.7]], np.float32), spec, tol=0)
    assert (np.asarray(C.measure_triples(np.array([[0.7, 0.7, 0.7]], np.float32), spec,
                                         exact=False).sets) != 0).all()
    with pytest.raises(ValueError, match="NaN"):
        C.measure_triples(np.array([[0.7, np.inf, 0.1]], np.float32), spec)
    with pytest.raises(ValueError, match="non-finite"):
        exact_vectors([0.0, np.nan, 1.0])
    w = exact_vectors([0.3, 3.1, -2.0])
    assert all(x * x + y * y == 1 for x, y in w)


def test_float64_pipeline_leaves_nothing_undecided():
    """float64 input runs the whole pipeline in float64 (with x64 on): same sound map, and
    no state left undecided in any image."""
    import jax

    from pqrm_jax import sim
    from pqrm_jax.qrm import pipeline as P

    lm = np.asarray(sim.uniform_landmarks(jax.random.key(3), 10), np.float64)
    poses = np.asarray(sim.random_imaging_points(jax.random.key(4), 4), np.float64)
    with jax.enable_x64(True):
        m64, met64 = P.run_sequence(lm, poses, 10)
        assert m64.rel.dtype == np.uint32 and bool(met64.truth_kept.all())
        assert int(np.asarray(met64.undecided).sum()) == 0
    m32, met32 = P.run_sequence(lm.astype(np.float32), poses.astype(np.float32), 10)
    a, b = np.asarray(m64.rel), np.asarray(m32.rel)
    assert ((a & ~b) == 0).all()  # float32 keeps at most its counted undecided states more
