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
    scan; odom: ``[3]`` the odometry reading at the last scan."""

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
        """The LPM built from the first scan at ``pose`` [3] (its frame); ``odom`` [3]."""
        pose = jnp.asarray(pose, jnp.float32)
        lpm = lpm_update(lpm_init(pose, self.lpm_params), pose, scan, self.lpm_params)
        return TrackState(lpm, pose, jnp.asarray(odom, jnp.float32))

    def update(self, state: TrackState, key: jax.Array, odom: jax.Array,
               scan: LidarScan) -> tuple[TrackState, TrackStep]:
        """Localize ``scan`` against the LPM (odometry ``odom`` [3]), then add it there."""
        lpm_params = self.lpm_params
        occ, _ = lpm_classify(state.lpm, lpm_params)
        d2 = squared_distance_transform(occ[None], cap=self.field_cap_cells)[0]
        odom = jnp.asarray(odom, jnp.float32)
        pose, lik, n = localize_with_count(key, state.pose, state.odom, odom, scan, d2,
                                           state.lpm.origin, lpm_params.resolution,
                                           jnp.asarray(self.c, jnp.float32),
                                           method=self.method, params=self.loc_params)
        lpm = lpm_update(state.lpm, pose, scan, lpm_params)
        return TrackState(lpm, pose, odom), TrackStep(pose, lik, n)


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


@partial(jax.jit, static_argnames="tracker")
def track_run(tracker: Tracker, key: jax.Array, pose0: jax.Array, odoms: jax.Array,
              scans: LidarScan) -> tuple[TrackState, TrackStep]:
    """Run a log through a tracker in one ``lax.scan``.

    Args:
        tracker: from :func:`lpm_tracker`.
        key: PRNG key (one subkey per step).
        pose0: ``[3]`` the pose at the first scan (the LPM's frame).
        odoms: ``[T + 1, 3]`` odometry readings at the scans.
        scans: :class:`~pqrm_jax.sim.lidar.LidarScan` with leading axis ``T + 1``.

    Returns:
        ``(final TrackState, TrackStep with leading axis T)`` (steps 1..T).
    """
    odoms = jnp.asarray(odoms, jnp.float32)
    if odoms.ndim != 2 or odoms.shape[1] != 3:
        raise ValueError(f"odoms must be [T + 1, 3], got shape {odoms.shape}")
    if scans.ranges.shape[0] != odoms.shape[0]:
        raise ValueError(f"need one scan per odometry reading: {scans.ranges.shape[0]} scans, "
                         f"{odoms.shape[0]} readings")
    first = jax.tree.map(lambda x: x[0], scans)
    rest = jax.tree.map(lambda x: x[1:], scans)
    state = tracker.init(pose0, odoms[0], first)
    return run(tracker, key, state, odoms[1:], rest)
