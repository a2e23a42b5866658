"""Image-by-image QRM mapping in the simulator, and the map metrics of M§VIII.A.

:func:`map_step` = camera image → measurement of the ``n`` nearest landmarks (only states
still open in the map are tested) → map update → metrics; :func:`run_sequence` scans it over
a sequence of imaging poses (one compiled program per run, ``vmap``-able over runs).

Metrics (M§VIII.A, Fig. 7): percentage of incorrect states removed (of all incorrect states
of the cyclic relations of every triple of the final map), percentage of fully constrained
edges (all three cyclic relations singletons), percentage of open states not adjacent to
(nor equal to) the true state, total RNG edge cost (Alg. 2).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import sim

from ..calculi import Calculus
from ..triplets import cyclic_mask
from .camera import measure_image_kernel, resolve_tolerance
from .hypergraph import QRMMap, apply_relations_kernel, check_max_sweeps, empty_map, true_relations
from .rng import rng_estimate_kernel
from .spec import QRMSpec, popcount, qrm_spec

__all__ = ["Metrics", "map_metrics", "map_step", "run_sequence"]


class Metrics(NamedTuple):
    removed_pct: jax.Array
    constrained_pct: jax.Array
    not_adjacent_pct: jax.Array
    rng_cost: jax.Array
    truth_kept: jax.Array
    n_known: jax.Array
    first_open: jax.Array  # (Q+1,) histogram of open-state counts of newly measured relations
    inconsistent: jax.Array
    undecided: jax.Array  # states kept without witness nor exclusion in this image
    first_proven: jax.Array  # (Q+1,) same histogram counting only states with a witness


@partial(jax.jit, static_argnames="spec")
def _metrics(spec: QRMSpec, m: QRMMap, truth):
    n = m.rel.shape[0]
    q = spec.num_states
    cyc = jnp.asarray(cyclic_mask(n))
    open_ = popcount(m.rel)
    n_rel = cyc.sum()
    removed = jnp.sum(jnp.where(cyc, q - open_, 0)) / (n_rel * (q - 1)) * 100
    single = (open_ == 1) | ~cyc
    i, j, k = np.ix_(np.arange(n), np.arange(n), np.arange(n))
    inc = jnp.asarray((i < j) & (j < k))
    edge_done = single & jnp.transpose(single, (1, 2, 0)) & jnp.transpose(single, (2, 0, 1))
    constrained = jnp.sum(inc & edge_done) / inc.sum() * 100
    known3 = m.known[:, None, None] & m.known[None, :, None] & m.known[None, None, :]
    t = jnp.maximum(truth, 0)
    near = jnp.asarray(spec.adjacency | np.eye(q, dtype=bool))[t]  # (n,n,n,Q)
    bits = ((m.rel[..., None] >> jnp.arange(q, dtype=jnp.uint32)) & 1).astype(bool)
    sel = cyc & known3
    far = jnp.sum(jnp.where(sel[..., None], bits & ~near, False))
    tot = jnp.sum(jnp.where(sel, open_, 0))
    not_adj = far / jnp.maximum(tot, 1) * 100
    kept = jnp.all(((m.rel >> t.astype(jnp.uint32)) & 1).astype(bool) | (truth < 0))
    cost = (rng_estimate_kernel(m.rel, m.known, lune=int(spec.lune)).total_cost if spec.lune
            else jnp.nan)
    return removed, constrained, not_adj, cost, kept, m.known.sum()


def map_metrics(m: QRMMap, landmarks, calc: Calculus | str | QRMSpec = "edc") -> dict:
    """The M§VIII.A metrics of a map against the true layout, as a dict of floats.

    Args:
        m: the map.
        landmarks: [N, 2] the true layout.
        calc: the calculus (name, object or its :class:`QRMSpec`).

    Returns:
        ``{removed_pct, constrained_pct, not_adjacent_pct, rng_cost, truth_kept, n_known}``
        as floats.
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    vals = _metrics(spec, m, true_relations(landmarks, spec))
    keys = ("removed_pct", "constrained_pct", "not_adjacent_pct", "rng_cost", "truth_kept",
            "n_known")
    return {k: float(v) for k, v in zip(keys, vals, strict=True)}


def map_step_kernel(spec, m, pose, landmarks, truth, sensor, n, tol=None, max_sweeps=64):
    return _step(spec, m, False, pose, landmarks, truth, sensor, n, tol, max_sweeps)[:2]


def _step(spec, m, closed, pose, landmarks, truth, sensor, n, tol, max_sweeps):
    """One image → (map, metrics, whether the map is a fixed point of the propagation).

    ``closed``: the input map is one (the first sweep then visits only the fourth landmarks
    the image's relations touch; the fixed point is the same, docs/qrm.md §hypergraph)."""
    cam = sim.sensors.camera_kernel(pose, landmarks, sensor)
    meas = measure_image_kernel(spec, cam.bearings, cam.range_rank, cam.visible, m.rel, tol,
                                n=n)
    # histogram of open counts of relations measured for the first time
    tri = jnp.maximum(meas.triples, 0)
    first = meas.valid & ~(m.known[tri[:, 0]] & m.known[tri[:, 1]] & m.known[tri[:, 2]])
    cnt = popcount(meas.sets)
    hist = jnp.zeros(spec.num_states + 1, jnp.int32).at[cnt.ravel()].add(
        jnp.repeat(first, 3).astype(jnp.int32))
    undecided = jnp.sum(jnp.where(meas.valid[:, None], popcount(meas.undecided), 0))
    cnt_p = popcount(meas.sets & ~meas.undecided)
    hist_p = jnp.zeros(spec.num_states + 1, jnp.int32).at[cnt_p.ravel()].add(
        jnp.repeat(first, 3).astype(jnp.int32))
    m, rep = apply_relations_kernel(spec, m, meas.triples, meas.sets, meas.valid,
                                    max_sweeps=max_sweeps, closed=closed)
    vals = _metrics(spec, m, truth)
    # a rejected update keeps the map it was given
    closed = jnp.where(rep.inconsistent, closed, rep.converged)
    return m, Metrics(*vals, hist, rep.inconsistent, undecided, hist_p), closed


@partial(jax.jit, static_argnames=("spec", "n", "max_sweeps"))
def _map_step(spec, m, pose, landmarks, truth, sensor, tol, *, n, max_sweeps):
    return map_step_kernel(spec, m, pose, landmarks, truth, sensor, n, tol, max_sweeps)


def _real(x):
    """float32, or float64 when the input is float64 (with ``jax_enable_x64`` on)."""
    x = jnp.asarray(x)
    return x.astype(jnp.float64 if x.dtype == jnp.float64 else jnp.float32)


def resolve_sensor(sensor):
    sensor = sim.SensorParams(max_range=1e6) if sensor is None else sensor
    return sim.SensorParams(*(jnp.asarray(v, jnp.float32) for v in sensor))


def map_step(m: QRMMap, pose, landmarks, n: int, calc: Calculus | str | QRMSpec = "edc",
             sensor: sim.SensorParams | None = None, truth=None, *,
             tol: float | None = None, max_sweeps: int = 64) -> tuple[QRMMap, Metrics]:
    """One image: camera at ``pose``, measurement of the ``n`` nearest, update, metrics.

    ``tol``: bearing tolerance of the measurement in radians (None: the default of the
    dtype, :func:`pqrm_jax.qrm.camera.default_tolerance`; docs/qrm.md §camera).

    Args:
        m: the map before the image.
        pose: [3] camera pose (x, y, θ).
        landmarks: [N, 2] true landmark positions.
        n: landmarks measured (the nearest visible).
        calc: the calculus (name, object or its :class:`QRMSpec`).
        sensor: camera parameters.
        truth: optional [N, N, N] true states (computed when None).
        tol: bearing tolerance (above).
        max_sweeps: path-consistency sweeps of the update (M§VI.B), an integer ≥ 0; 0: no
            propagation (the map is the intersection of the measured sets; an ablation).

    Returns:
        ``(map', metrics)``: the updated map and this image's :class:`Metrics` (M§VIII.A).

    Raises:
        ValueError: for a bad ``max_sweeps``.
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    landmarks = _real(landmarks)
    tol = resolve_tolerance(tol, landmarks.dtype)
    truth = true_relations(landmarks, spec) if truth is None else truth
    max_sweeps = check_max_sweeps(max_sweeps, minimum=0)
    return _map_step(spec, m, _real(pose), landmarks, truth,
                     resolve_sensor(sensor), jnp.asarray(tol, landmarks.dtype), n=n,
                     max_sweeps=max_sweeps)


@partial(jax.jit, static_argnames=("spec", "n", "max_sweeps"))
def _run(spec, poses, landmarks, truth, sensor, tol, *, n, max_sweeps):
    m0 = empty_map(landmarks.shape[0], spec)

    def body(carry, pose):
        m, met, closed = _step(spec, *carry, pose, landmarks, truth, sensor, n, tol, max_sweeps)
        return (m, closed), met

    # the empty map is not assumed closed under a calculus's tables: the first image's first
    # sweep visits every fourth landmark
    (m, _), met = jax.lax.scan(body, (m0, jnp.asarray(False)), poses)
    return m, met


def run_sequence(
    landmarks: jax.Array,
    poses: jax.Array,
    n: int,
    calc: Calculus | str | QRMSpec = "edc",
    sensor: sim.SensorParams | None = None,
    *,
    tol: float | None = None,
    max_sweeps: int = 64,
) -> tuple[QRMMap, Metrics]:
    """Map a layout from a sequence of imaging poses [T, 3]; per-image metrics [T, ...].

    float32 by default; float64 ``landmarks`` and ``poses`` (with ``jax_enable_x64`` on) run
    the simulator and the measurement in float64. ``tol`` is the bearing tolerance of the
    measurement in radians (None: the dtype's default, which covers the simulator's
    rounding of the bearings, so the true state is never dropped; 0: exact for the computed
    bearings; docs/qrm.md §camera).

    Args:
        landmarks: [N, 2] true landmark positions.
        poses: [T, 3] imaging poses.
        n: landmarks measured per image.
        calc: the calculus (name, object or its :class:`QRMSpec`).
        sensor: camera parameters.
        tol: bearing tolerance (above).
        max_sweeps: path-consistency sweeps per update (M§VI.B), an integer ≥ 0; 0: no
            propagation, the map is the intersection of the measured sets (the ablation of
            docs/studies.md §mcclelland-mc).

    Returns:
        ``(map, metrics)``: the final map and the per-image :class:`Metrics` with a leading
        ``[T]`` axis (M§VIII.A).

    >>> import jax
    >>> from pqrm_jax import sim
    >>> lm = sim.uniform_landmarks(jax.random.key(0), 8)
    >>> poses = sim.random_imaging_points(jax.random.key(1), 4)
    >>> m, met = run_sequence(lm, poses, n=8)
    >>> bool(met.truth_kept.all()), met.removed_pct.shape
    (True, (4,))
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    if not isinstance(n, int) or n < 3:
        raise ValueError(f"n must be an int >= 3, got {n!r}")
    landmarks = _real(landmarks)
    if landmarks.ndim != 2 or landmarks.shape[1] != 2 or landmarks.shape[0] < 3:
        raise ValueError(f"landmarks must have shape (N >= 3, 2), got {landmarks.shape}")
    poses = _real(poses)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 1:
        raise ValueError(f"poses must have shape (T >= 1, 3), got {poses.shape}")
    for nm, x in (("landmarks", landmarks), ("poses", poses)):
        # a NaN would make every comparison false and the map look sound ("truth kept")
        if not isinstance(x, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(x))):
            raise ValueError(f"run_sequence: {nm} contain NaN or inf")
    tol = resolve_tolerance(tol, landmarks.dtype)
    max_sweeps = check_max_sweeps(max_sweeps, minimum=0)
    truth = true_relations(landmarks, spec)
    n = min(n, landmarks.shape[0])
    return _run(spec, poses, landmarks, truth, resolve_sensor(sensor),
                jnp.asarray(tol, landmarks.dtype), n=n, max_sweeps=max_sweeps)
