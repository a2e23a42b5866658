"""The tolerant camera kernel runs its full decision only on the triples a cheap sound test
flags (issue #27 item 4: the Mars-Yard traverse's speed; docs/qrm.md §camera).

:func:`pqrm_jax.qrm.exact_camera.exact_sets` screens every triple
(:func:`~pqrm_jax.qrm.exact_camera.tolerant_flags`): an unflagged triple keeps its exact edge
sets, which the screen proves equal to the tolerant ones; the flagged ones run the full
tolerant decision in chunks of one static buffer size (as many as they fill).
The sets must equal the all-triples path (``screen=False``, the decision before the screen)
bit for bit, on generic, near-degenerate (narrow spreads, two or three nearly equal
bearings) and mixed batches, in one chunk and in several.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax.qrm import camera as C
from pqrm_jax.qrm import exact_camera as X
from pqrm_jax.qrm.spec import qrm_spec

SPEC = qrm_spec("edc")
T = 64  # one compiled shape per dtype and path


def _batch(rng: np.random.Generator, near: int, dtype,
           spreads=(0.05, 0.3, 1.0, 2 * np.pi)) -> np.ndarray:
    """[T, 3] range-order bearings: generic triples (spreads 0.05–2π) and ``near``
    near-degenerate ones (three within ~1e-7 rad, two equal, a 1e-5 spread)."""
    spread = rng.choice(spreads, (T, 1))
    b = rng.uniform(-np.pi, np.pi, (T, 1)) + rng.uniform(0, 1, (T, 3)) * spread
    for r in range(near):
        kind = rng.integers(3)
        c = rng.uniform(-np.pi, np.pi)
        if kind == 0:  # three on (nearly) one ray
            b[r] = c + rng.normal(0, 1e-7, 3)
        elif kind == 1:  # two equal bearings
            b[r, :2] = c
        else:
            b[r] = c + rng.uniform(0, 1e-5, 3)
    return b.astype(dtype)


def _paths(dtype):
    return (jax.jit(lambda b, t: X.exact_sets(SPEC, b, t)),
            jax.jit(lambda b, t: X.exact_sets(SPEC, b, t, screen=False)),
            jax.jit(lambda b, t: X.tolerant_flags(SPEC, b, t)))


_PATHS = {}


def _get(dtype):
    if dtype not in _PATHS:
        _PATHS[dtype] = _paths(dtype)
    return _PATHS[dtype]


def _assert_same_sets(got, ref):
    """(possible, undecided) of the screened path equal the all-triples path's bit for bit."""
    for x, y in zip(got, ref, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _screened_equals_all_triples(seed, near, dtype, scale):
    """Bit-identical sets (possible and undecided) through the screen and without it, at
    tolerance 0 (nothing flagged), the default and wider tolerances (up to ~5e-4 rad in
    float64); returns the screen's flags."""
    rng = np.random.default_rng(seed)
    with jax.enable_x64(dtype == np.float64):
        b = jnp.asarray(_batch(rng, near, dtype))
        tol = jnp.asarray(scale * C.default_tolerance(dtype), dtype)
        screened, full, flags = _get(dtype)
        got, ref = screened(b, tol), full(b, tol)
        _assert_same_sets(got, ref)
        return np.asarray(flags(b, tol))


_SEEDS = st.integers(0, 2**31 - 1)
_NEAR = st.sampled_from([0, 3, 12])
_SCALE = st.sampled_from([0.0, 1.0, 30.0, 3000.0])


@pytest.mark.slow  # float64's three programs compile for ~20 s; float32 runs by default
@settings(max_examples=8, deadline=None, derandomize=True)
@given(seed=_SEEDS, near=_NEAR, scale=_SCALE)
def test_screened_sets_equal_the_all_triples_path_float64(seed, near, scale):
    f = _screened_equals_all_triples(seed, near, np.float64, scale)
    if scale == 0:
        assert not f.any()
    elif near:
        assert f.any()


@settings(max_examples=6, deadline=None, derandomize=True)
@given(seed=_SEEDS, near=_NEAR, scale=_SCALE)
def test_screened_sets_equal_the_all_triples_path(seed, near, scale):
    """float32, the dtype whose rounding dropped truths (float64 runs with ``-m slow``)."""
    f = _screened_equals_all_triples(seed, near, np.float32, scale)
    if scale == 0:
        assert not f.any()
    elif near:  # a triple within the rounding of a boundary is always flagged
        assert f.any()


def test_near_degenerate_triples_are_flagged_and_generic_ones_mostly_not():
    """Generic triples are mostly unflagged (at most one in ten); the near-degenerate ones are
    flagged; the sets equal the all-triples path."""
    rng = np.random.default_rng(5)
    b = jnp.asarray(_batch(rng, 4, np.float32, (1.0, 2 * np.pi)))
    tol = jnp.asarray(C.default_tolerance(np.float32), jnp.float32)
    screened, full, flags = _get(np.float32)
    f = np.asarray(flags(b, tol))
    assert f[4:].mean() <= 0.1
    assert f[:4].sum() >= 3
    got, ref = screened(b, tol), full(b, tol)
    _assert_same_sets(got, ref)


def test_chunks_when_the_buffer_overflows(monkeypatch):
    """More flagged triples than the buffer holds: they take the full tolerant decision in
    as many buffer-sized chunks as they fill (forced with a 1-triple buffer: one chunk per
    flagged triple); same sets as the all-triples path."""
    monkeypatch.setattr(X, "SCREEN_MIN", 1)
    monkeypatch.setattr(X, "SCREEN_SHARE", 0.0)
    assert X.screen_buffer(T) == 1
    rng = np.random.default_rng(9)
    b = jnp.asarray(_batch(rng, 12, np.float32))
    tol = jnp.asarray(C.default_tolerance(np.float32), jnp.float32)
    f = np.asarray(jax.jit(lambda b, t: X.tolerant_flags(SPEC, b, t))(b, tol))
    assert f.sum() > 1
    got = jax.jit(lambda b, t: X.exact_sets(SPEC, b, t))(b, tol)  # traced with the patch
    ref = _get(np.float32)[1](b, tol)
    _assert_same_sets(got, ref)


def test_several_chunks_of_the_shipped_buffer():
    """More flagged triples than the shipped buffer holds (a wide tolerance, no patch): they
    go through the decision in several chunks of the one compiled buffer size; same sets as
    the all-triples path."""
    rng = np.random.default_rng(5)
    b = jnp.asarray(_batch(rng, 12, np.float32))
    tol = jnp.asarray(3000 * C.default_tolerance(np.float32), jnp.float32)
    screened, full, flags = _get(np.float32)
    f = np.asarray(flags(b, tol))
    assert f.sum() > 2 * X.screen_buffer(T)  # at least three chunks
    _assert_same_sets(screened(b, tol), full(b, tol))


def test_the_tolerant_decision_is_traced_once(monkeypatch):
    """The screened kernel holds the full tolerant decision once (one buffer size): two
    sizes put it twice into every program with a measurement, ~30 % of its compile time."""
    calls = []
    inner = X._tolerant_edge_atoms  # noqa: SLF001 (counting the traces of the decision)

    def counted(*a, **k):
        calls.append(a[2].t.shape[-1])  # the batch of triples it was traced for
        return inner(*a, **k)

    monkeypatch.setattr(X, "_tolerant_edge_atoms", counted)
    b = jnp.zeros((816, 3), jnp.float32)
    jax.jit(lambda b, t: X.exact_sets(SPEC, b, t)).lower(b, jnp.float32(0))
    assert calls == [X.screen_buffer(816)]


@pytest.mark.parametrize("n", [3, 20, 816, 4060])
def test_screen_buffer_size(n):
    """One static size, ``min(T, max(6, ⌈T/48⌉))``: 17 on the traverse's 816 triples, the
    smaller of the two buffers before 2026-12-06."""
    assert 1 <= X.screen_buffer(n) <= n
    assert X.screen_buffer(n) == min(n, max(6, -(-n // 48)))
    assert X.screen_buffer(816) == 17


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 9), min_size=2, max_size=4), st.data(), st.booleans(),
       st.integers(0, 2**32 - 1))
def test_fold_equals_the_plain_reduction(shape, data, big, seed):
    """The halving OR (arrays from ``_FOLD_MIN`` elements) and the plain reduce give the
    same bits as NumPy's, over any axes, odd and even lengths, bool and uint32."""
    shape = list(shape)
    if big:  # past the threshold: the halving path
        shape[-1] = -(-X._FOLD_MIN // int(np.prod(shape[:-1])))
    axes = tuple(sorted(data.draw(st.sets(st.integers(0, len(shape) - 1), min_size=1,
                                          max_size=len(shape) - 1))))
    rng = np.random.default_rng(seed)
    u = rng.integers(0, 2**32, shape, dtype=np.uint64).astype(np.uint32)
    u &= rng.integers(0, 2**32, shape, dtype=np.uint64).astype(np.uint32)  # sparser bits
    b = rng.random(shape) < 0.02
    # one program a drawn shape (eager, each halving step compiled apart for every shape)
    got_or, got_any = jax.jit(lambda u, b: (X._or(u, axes), X._any(b, axes)))(
        jnp.asarray(u), jnp.asarray(b))
    np.testing.assert_array_equal(np.asarray(got_or), np.bitwise_or.reduce(u, axis=axes))
    np.testing.assert_array_equal(np.asarray(got_any), b.any(axis=axes))
