"""The QRM map as a pair of pure functions, the shape of :func:`pqrm_jax.pqrm.mapper` (M§VI).

``qrm.mapper(calc, num_landmarks, n)`` resolves the static configuration once and returns
``Mapper(init, update, metrics)``: ``init()`` is the empty map, ``update(map, key, image)`` fuses
one camera image (a :class:`pqrm_jax.sim.CameraObservation`: measurement of the ``n`` nearest
visible landmarks, M§IV, then path consistency, M§VI.B) and returns ``(map, UpdateReport)``.
The map is deterministic: ``key`` is accepted for the step convention of
:mod:`pqrm_jax.protocols` and unused, so a sequence of images is
``protocols.run(mapper, key, mapper.init(), images)``; ``metrics(map, landmarks)`` gives the
M§VIII.A metrics against the true layout.

>>> import jax
>>> from pqrm_jax import qrm, sim
>>> lm = sim.uniform_landmarks(jax.random.key(0), 6)
>>> poses = sim.random_imaging_points(jax.random.key(1), 3)
>>> images = jax.vmap(lambda p: sim.camera(p, lm, sim.SensorParams(max_range=1e6)))(poses)
>>> from pqrm_jax.protocols import run
>>> qm = qrm.mapper("edc", 6, n=6)
>>> m, reports = run(qm, jax.random.key(2), qm.init(), images)
>>> reports.inconsistent.shape, bool(qm.metrics(m, lm)["truth_kept"])
((3,), True)
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import jax

from ..calculi import Calculus
from .camera import measure_image_kernel, resolve_tolerance
from .hypergraph import QRMMap, UpdateReport, apply_relations_kernel, check_max_sweeps, empty_map
from .pipeline import map_metrics
from .spec import QRMSpec, qrm_spec

__all__ = ["Mapper", "mapper"]


class Mapper(NamedTuple):
    """A QRM mapper: pure functions over a :class:`~pqrm_jax.qrm.QRMMap` plus its setup.

    ``init() -> QRMMap``; ``update(map, key, image) -> (QRMMap, UpdateReport)`` (jitted; the
    ``key`` is unused, the step convention of :mod:`pqrm_jax.protocols`; ``image`` is a
    :class:`~pqrm_jax.sim.CameraObservation` with ``[N]`` fields);
    ``metrics(map, landmarks [N, 2]) -> dict`` (M§VIII.A, host side).
    """

    init: Callable[[], QRMMap]
    update: Callable[[QRMMap, jax.Array, object], tuple[QRMMap, UpdateReport]]
    metrics: Callable[[QRMMap, jax.Array], dict]
    spec: QRMSpec
    num_landmarks: int
    n: int


def _update(spec: QRMSpec, m: QRMMap, key, image, *, n: int, max_sweeps: int, tol=None):
    del key  # deterministic (accepted for the step convention)
    meas = measure_image_kernel(spec, image.bearings, image.range_rank, image.visible, m.rel,
                                tol, n=n)
    return apply_relations_kernel(spec, m, meas.triples, meas.sets, meas.valid,
                                  max_sweeps=max_sweeps)


def mapper(calc: Calculus | str | QRMSpec = "edc", num_landmarks: int = 10, n: int = 18, *,
           max_sweeps: int = 64, tol: float | None = None) -> Mapper:
    """A QRM mapper over ``num_landmarks`` landmarks, ``n`` nearest measured per image (M§VI).

    Args:
        calc: the calculus (or a prepared :class:`~pqrm_jax.qrm.QRMSpec`).
        num_landmarks: N, the map capacity (landmark ids 0..N−1).
        n: landmarks measured per image (the nearest visible ones; capped at N).
        max_sweeps: path-consistency sweeps per update (M§VI.B; an integer ≥ 0, 0: no
            propagation, the map is the intersection of the measured sets).
        tol: bearing tolerance of the measurement in radians (None: the default of the
            images' dtype, :func:`pqrm_jax.qrm.camera.default_tolerance`; 0: exact for the
            given bearings; docs/qrm.md §camera).

    Returns:
        ``Mapper(init, update, metrics, spec, num_landmarks, n)``; the same map as
        :func:`~pqrm_jax.qrm.run_sequence` for the images of the same poses.
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    if not isinstance(num_landmarks, int) or num_landmarks < 3:
        raise ValueError(f"num_landmarks must be an int >= 3, got {num_landmarks!r}")
    if not isinstance(n, int) or n < 3:
        raise ValueError(f"n must be an int >= 3, got {n!r}")
    n = min(n, num_landmarks)
    max_sweeps = check_max_sweeps(max_sweeps, minimum=0)
    if tol is not None:
        tol = resolve_tolerance(tol, "float64")

    def init() -> QRMMap:
        return empty_map(num_landmarks, spec)

    update = jax.jit(partial(_update, spec, n=n,
                             max_sweeps=max_sweeps, tol=tol))

    def metrics(m: QRMMap, landmarks) -> dict:
        return map_metrics(m, landmarks, spec)

    return Mapper(init, update, metrics, spec, int(num_landmarks), n)
