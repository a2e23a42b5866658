"""Localizing in the LPM while it is being built (B §4.1, §4.3).

B's robot keeps its local perceptual map in its own frame of reference: every lidar scan is
first *localized* against the LPM built so far (from the previous pose estimate and the
odometry increment, with one of the adaptive proposals of :mod:`pqrm_jax.hssh.localization`),
then added to the LPM at the localized pose. The LPM therefore stays consistent with the
robot's pose estimate, not with raw odometry.

:func:`lpm_tracker` returns a :class:`Tracker` of two pure functions (``init`` / ``update``,
the step convention of :mod:`pqrm_jax.protocols`) over a :class:`TrackState`; equal trackers
are equal static values and share one compiled program. :func:`track_run` runs a whole log in
one ``lax.scan`` (one jitted program: per step the capped distance transform of the LPM's
occupied cells -- the likelihood field --, the localization step, the scan update with
scrolling). Batched runs: ``jax.vmap`` over :func:`track_run`.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax.hssh.cellular import squared_distance_transform
from pqrm_jax.hssh.localization import (
    DEFAULT_PARAMS,
    METHODS,
    LocalizeParams,
    localize_with_count,
)
from pqrm_jax.hssh.lpm import DEFAULT, LPMParams, LPMState, lpm_classify, lpm_init, lpm_update
from pqrm_jax.protocols import run
from pqrm_jax.sim.lidar import LidarScan

__all__ = ["TrackState", "TrackStep", "Tracker", "lpm_tracker", "track_run"]


class TrackState(NamedTuple):
    """lpm: the :class:`~pqrm_jax.hssh.lpm.LPMState`; pose: ``[3]`` the estimate at the last
    scan; odom: ``[3]`` the odometry reading at the last scan (float64 NumPy when the run was
    given float64 NumPy poses, see :func:`track_run`)."""

    lpm: LPMState
    pose: jax.Array
    odom: jax.Array


class TrackStep(NamedTuple):
    """Per-step output: the localized pose ``[3]``, its scan likelihood against the LPM
    before the update, and the number of particles scored."""

    pose: jax.Array
    likelihood: jax.Array
    particles: jax.Array


class Tracker(NamedTuple):
    """Localize-then-map in the LPM, an :class:`~pqrm_jax.protocols.Estimator`.

    ``init(pose, odom, scan) -> TrackState``; ``update(state, key, odom, scan) ->
    (TrackState, TrackStep)`` (the step convention of :mod:`pqrm_jax.protocols`).

    The tracker *is* its static parameters (hashable, compared by value), so equal trackers
    are one static argument of :func:`track_run` and share one compiled program.

    Attributes:
        c: the ``21`` action-model coefficients, Python floats (float32 values).
        method: the localization method.
        lpm_params: static LPM parameters.
        loc_params: static localization parameters.
        field_cap_cells: distance-transform cap of the likelihood field, in cells.
    """

    c: tuple[float, ...]
    method: str
    lpm_params: LPMParams
    loc_params: LocalizeParams
    field_cap_cells: int

    def init(self, pose: jax.Array, odom: jax.Array, scan: LidarScan) -> TrackState:
        """The LPM built from the first scan at ``pose`` [3] (its frame); ``odom`` [3].

        Concrete float64 NumPy poses stay float64 (UTM-sized coordinates, issue 26)."""
        pose, odom = _keep64(pose), _keep64(odom)
        lpm = lpm_update(lpm_init(pose, self.lpm_params), pose, scan, self.lpm_params)
        return TrackState(lpm, pose, odom)

    def update(self, state: TrackState, key: jax.Array, odom: jax.Array,
               scan: LidarScan) -> tuple[TrackState, TrackStep]:
        """Localize ``scan`` against the LPM (odometry ``odom`` [3]), then add it there.

        With a float64 NumPy state (from :meth:`init` on float64 poses) the localization and
        the map update take their differences in float64 on the host (issue 26)."""
        lpm_params = self.lpm_params
        occ, _ = lpm_classify(state.lpm, lpm_params)
        d2 = squared_distance_transform(occ[None], cap=self.field_cap_cells)[0]
        odom = _keep64(odom)
        origin = state.lpm.origin
        if _is64(state.pose):   # the LPM origin to float64: origin + origin_lo
            origin = (np.asarray(origin, np.float64)
                      + np.asarray(state.lpm.origin_lo, np.float64))
            odom = np.asarray(odom, np.float64)
        pose, lik, n = localize_with_count(key, state.pose, state.odom, odom, scan, d2,
                                           origin, lpm_params.resolution,
                                           jnp.asarray(self.c, jnp.float32),
                                           method=self.method, params=self.loc_params)
        lpm = lpm_update(state.lpm, pose, scan, lpm_params)
        return TrackState(lpm, pose, odom), TrackStep(pose, lik, n)


def _is64(x) -> bool:
    return isinstance(x, np.ndarray) and x.dtype == np.float64


def _keep64(x):
    """A concrete float64 NumPy ``[3]`` stays float64; anything else becomes float32."""
    return x if _is64(x) else jnp.asarray(x, jnp.float32)


def lpm_tracker(c: jax.Array, *, method: str = "shrink_and_grow",
                lpm_params: LPMParams = DEFAULT,
                loc_params: LocalizeParams = DEFAULT_PARAMS,
                field_cap_cells: int = 20) -> Tracker:
    """Localize-then-map in the LPM (B §4.1, §4.3.2).

    Args:
        c: ``[21]`` action model (:data:`pqrm_jax.hssh.motion.ACTION_MODELS`), concrete (it
            becomes part of the tracker's static identity).
        method: a localization method (:data:`pqrm_jax.hssh.localization.METHODS`).
        lpm_params: static LPM parameters.
        loc_params: static localization parameters (``kld`` for KLD-sampling).
        field_cap_cells: distance-transform cap of the likelihood field, in cells (the
            field is ``exp(-d**2 / 2 sigma**2)``, flat beyond a few sigma).

    Returns:
        :class:`Tracker`; equal arguments give equal trackers (one compiled
        :func:`track_run`).

    Raises:
        ValueError: for ``field_cap_cells < 1``, an unknown ``method`` or ``c`` not of
            shape ``[21]``.
    """
    cap = int(field_cap_cells)
    if cap < 1:
        raise ValueError(f"field_cap_cells must be >= 1, got {field_cap_cells}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    c = np.asarray(c, np.float32)
    if c.shape != (21,):
        raise ValueError(f"c must be the [21] action model, got shape {c.shape}")
    return Tracker(tuple(float(v) for v in c), method, lpm_params, loc_params, cap)


def track_run(tracker: Tracker, key: jax.Array, pose0: jax.Array, odoms: jax.Array,
              scans: LidarScan) -> tuple[TrackState, TrackStep]:
    """Run a log through a tracker in one ``lax.scan``.

    World coordinates: with float64 NumPy ``pose0`` and ``odoms`` the run is taken in a local
    frame (the differences from ``pose0`` and ``odoms[0]``, in float64 on the host), and the
    poses, the odometry and the LPM origin (``origin + origin_lo``) come back in the world
    frame, poses as float64 NumPy; so at UTM-sized coordinates (5e5, 4.2e6 m) the run equals
    the one at the origin, shifted (issue 26). Other input runs in float32 as given.

    Args:
        tracker: from :func:`lpm_tracker`.
        key: PRNG key (one subkey per step).
        pose0: ``[3]`` the pose at the first scan (the LPM's frame).
        odoms: ``[T + 1, 3]`` odometry readings at the scans.
        scans: :class:`~pqrm_jax.sim.lidar.LidarScan` with leading axis ``T + 1``.

    Returns:
        ``(final TrackState, TrackStep with leading axis T)`` (steps 1..T).
    """
    odoms_a = odoms if isinstance(odoms, jax.core.Tracer) else np.asarray(odoms)
    if odoms_a.ndim != 2 or odoms_a.shape[1] != 3:
        raise ValueError(f"odoms must be [T + 1, 3], got shape {odoms_a.shape}")
    if scans.ranges.shape[0] != odoms_a.shape[0]:
        raise ValueError(f"need one scan per odometry reading: {scans.ranges.shape[0]} scans, "
                         f"{odoms_a.shape[0]} readings")
    if not (_is64(pose0) and _is64(odoms_a)):
        return _track_run(tracker, key, pose0, odoms, scans)
    # a local origin on the world's lattice of cells, so an offset by whole cells (e.g. whole
    # metres) moves the local frame by exactly that offset
    r = float(tracker.lpm_params.resolution)
    ref = np.concatenate([np.floor(np.asarray(pose0[:2], np.float64) / r) * r, [0.0]])
    oref = np.concatenate([odoms_a[0, :2], [0.0]])
    state, steps = _track_run(tracker, key, jnp.asarray(pose0 - ref, jnp.float32),
                              jnp.asarray(odoms_a - oref, jnp.float32), scans)
    origin = (np.asarray(state.lpm.origin, np.float64)
              + np.asarray(state.lpm.origin_lo, np.float64) + ref[:2])
    o_hi = origin.astype(np.float32)
    o_lo = (origin - o_hi.astype(np.float64)).astype(np.float32)
    lpm = state.lpm._replace(origin=jnp.asarray(o_hi), origin_lo=jnp.asarray(o_lo))
    state = TrackState(lpm, np.asarray(state.pose, np.float64) + ref,
                       np.asarray(state.odom, np.float64) + oref)
    return state, steps._replace(pose=np.asarray(steps.pose, np.float64) + ref)


@partial(jax.jit, static_argnames="tracker")
def _track_run(tracker: Tracker, key: jax.Array, pose0: jax.Array, odoms: jax.Array,
               scans: LidarScan) -> tuple[TrackState, TrackStep]:
    """:func:`track_run` in float32, one jitted ``lax.scan``."""
    odoms = jnp.asarray(odoms, jnp.float32)
    first = jax.tree.map(lambda x: x[0], scans)
    rest = jax.tree.map(lambda x: x[1:], scans)
    state = tracker.init(jnp.asarray(pose0, jnp.float32), odoms[0], first)
    return run(tracker, key, state, odoms[1:], rest)
