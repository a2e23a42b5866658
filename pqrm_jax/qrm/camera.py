"""Camera measurement of qualitative states (M§IV, Table III; M§V feasibility).

Turns one image — the bearings of the visible landmarks and the order of their ranges — into
the set of feasible EDC states of every visible triple and each of its three cyclic
relations, batched over triples by one kernel without search: the exact decision of
:mod:`pqrm_jax.qrm.exact_camera` (the boundary of the range cone in the normalised plane).
A state is kept only with a witness range assignment or when near-degenerate input leaves it
undecided (counted); it is removed only when infeasible, so the true state is never dropped
(docs/decisions.md §4). How it works and why it is exact: docs/qrm.md §camera.
"""

from __future__ import annotations

import itertools
from functools import cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi import Calculus
from .exact_camera import exact_sets
from .spec import CYCLIC, QRMSpec, qrm_spec

__all__ = ["TripleMeasurement", "ImageMeasurement", "measure_triples", "measure_image",
           "select_nearest", "slot_triples", "CYCLIC", "BEARING_ULPS", "default_tolerance",
           "resolve_tolerance"]

#: default bearing tolerance in units of the machine epsilon of the bearings' dtype: the
#: bearings a float32/float64 camera computes (rotation, arctan2, the heading subtraction)
#: are within a few eps of the exact bearings of the scene (measured:
#: benchmarks/bench_qrm_tolerance.py; docs/qrm.md §camera)
BEARING_ULPS = 16.0


def default_tolerance(dtype) -> float:
    """Default bearing tolerance (radians) for bearings of ``dtype``: ``BEARING_ULPS · eps``
    (float32: 1.9e-6 rad, float64: 3.6e-15 rad); a user adds their sensor's noise."""
    return float(BEARING_ULPS * np.finfo(np.dtype(dtype)).eps)


def resolve_tolerance(tol, dtype) -> float:
    """``tol`` checked (a finite float in [0, π/4)), or the default of ``dtype`` for None."""
    if tol is None:
        return default_tolerance(dtype)
    if isinstance(tol, bool) or not isinstance(tol, int | float | np.floating | np.integer):
        raise ValueError(f"tol (bearing tolerance, radians) must be a float or None, got {tol!r}")
    tol = float(tol)
    if not (np.isfinite(tol) and 0 <= tol < np.pi / 4):
        raise ValueError(f"tol (bearing tolerance, radians) must be finite and in [0, π/4), "
                         f"got {tol!r}")
    return tol


class TripleMeasurement(NamedTuple):
    """Kernel output for T triples (slot order near, mid, far).

    Attributes:
        sets: [T, 3] uint32 state masks of the cyclic relations (0,1:2), (1,2:0), (2,0:1).
        undecided: [T, 3] uint32 states kept without a witness (neither proven nor excluded);
            all zero after the exact stage.
        exact_decisions: number of states the exact stage (z3) decided.
    """

    sets: jax.Array
    undecided: jax.Array
    exact_decisions: int = 0


class ImageMeasurement(NamedTuple):
    """One image's measurement (M§IV) of the ``n`` nearest visible landmarks.

    Attributes:
        ids: [S] int32 landmark id of each slot, nearest first; −1 for empty slots.
        triples: [T, 3] int32 landmark ids (near, mid, far) of every slot triple s0 < s1 < s2.
        sets: [T, 3] uint32 measured state masks of ``ids[t0] ids[t1] : ids[t2]``,
            ``ids[t1] ids[t2] : ids[t0]`` and ``ids[t2] ids[t0] : ids[t1]``.
        valid: [T] bool, all three slots hold a visible landmark.
        undecided: [T, 3] uint32 states kept undecided (only near-degenerate input;
            docs/qrm.md §camera).
    """

    ids: jax.Array
    triples: jax.Array
    sets: jax.Array
    valid: jax.Array
    undecided: jax.Array


# --------------------------------------------------------------------------------------
# the batched kernel
# --------------------------------------------------------------------------------------
def _atom_masks_to_states(atom_mask, atom_state):
    """[...] uint32 atom masks → state masks."""
    bits = (atom_mask[..., None] >> jnp.arange(atom_state.shape[0], dtype=jnp.uint32)) & 1
    vals = jnp.where(bits.astype(bool), jnp.uint32(1) << atom_state.astype(jnp.uint32),
                     jnp.uint32(0))
    return jax.lax.reduce(vals, np.uint32(0), jax.lax.bitwise_or, (vals.ndim - 1,))


@partial(jax.jit, static_argnames=("spec",))
def _kernel(spec: QRMSpec, bearings, target_states, tol=None):
    """(sets, undecided) [T, 3] state masks of every triple (exact_camera.exact_sets)."""
    tol = default_tolerance(bearings.dtype) if tol is None else tol
    atom_state = jnp.asarray(spec.atom_state)
    possible, undecided = exact_sets(spec, bearings, tol)
    sets = _atom_masks_to_states(possible, atom_state)
    und = _atom_masks_to_states(undecided, atom_state) & target_states
    # three equal bearings: collinear for every range assignment, no open state (exact);
    # with a tolerance, bearings within it of each other are ordinary input
    ray = (jnp.all(bearings == bearings[:, :1], -1) & (jnp.asarray(tol) == 0))[:, None]
    return jnp.where(ray, jnp.uint32(0), sets), jnp.where(ray, jnp.uint32(0), und)


def measure_triples(
    bearings: jax.Array,
    calc: Calculus | str | QRMSpec = "edc",
    target: jax.Array | None = None,
    *,
    exact: bool = True,
    tol: float | None = None,
) -> TripleMeasurement:
    """Feasible states of the three cyclic relations of each triple (M§IV–V), batched.

    Args:
        bearings: [T, 3] bearings of each triple's landmarks in *range order* (nearest first;
            ties allowed), float32 or float64.
        calc: the calculus (object, name or prepared spec).
        target: [T, 3] uint32 state masks of the states still open in the map; only those
            are reported as ``undecided`` (the sets are exact for every state); default all.
        exact: settle the undecided states with z3 (concrete input, ``tol = 0`` only).
        tol: bearing tolerance τ in radians: the sets hold every state feasible for *some*
            bearings within τ of the given ones (each independently) and ranges in the
            given order — sound for a scene whose computed bearings are within τ of its
            exact ones. None: :func:`default_tolerance` of the bearings' dtype (their
            rounding; add a real sensor's noise yourself). 0: the sets of the given bearings
            exactly (equal to the z3 oracle with ``exact=True``).

    Returns:
        A :class:`TripleMeasurement`: state masks of ``01:2, 12:0, 20:1`` (slots 0 = near,
        1 = mid, 2 = far) and the states left undecided.

    Raises:
        ValueError: for an empty batch (T = 0), bearings of the wrong shape or with NaN/inf,
            a ``target`` of the wrong shape, a ``tol`` outside [0, π/4), or (``tol = 0``)
            three equal bearings.

    The kernel (:func:`pqrm_jax.qrm.exact_camera.exact_sets`) decides every state from the
    boundary of the range cone: a kept state has a witness range assignment, a removed one
    is infeasible. States that only near-degenerate input leaves open (a sample within the
    rounding band of a constraint; in float64 none were seen in 61 440 random relations, in
    float32 0.6–4.5 % of relations at bearing spreads ≥ 0.3 rad) are kept and counted in
    ``undecided``. At ``tol = 0``, ``exact=True`` decides those with z3 on the exact
    polynomial systems (:func:`pqrm_jax.qrm.camera_oracle.settle_undecided`), so the sets
    are exactly the feasible sets; ``exact_decisions`` counts the z3 calls. ``exact=False``,
    any traced call and ``tol > 0`` return the kernel's sets with the undecided states kept
    (sound; with a tolerance every kept state not counted undecided has a witness at the
    given bearings, and the undecided ones are those the kernel can neither witness nor
    exclude; docs/qrm.md §camera).

    Bearings all equal (three landmarks on one ray): the points are collinear for every
    range assignment, which no (open) EDC state admits — ``ValueError`` (in a traced call
    the row's sets are empty, which the map update reports as inconsistent). Two equal
    bearings and ties in the ranges are ordinary input (the cone is closed; ties add no
    state: a state is open, and an open set meets the closed cone iff it meets its
    interior). A camera on a landmark: that landmark's range is 0 and its bearing
    arbitrary; ``d_near = 0`` lies in the closed cone, so the sets still contain the true
    states (they are the sets of the reported bearing).

    >>> import numpy as np
    >>> from pqrm_jax.qrm.spec import states_of
    >>> P = np.array([[2.0, 0.5], [1.0, 3.0], [-4.0, 1.5]])   # near, mid, far; truth: 1
    >>> m = measure_triples(np.arctan2(P[:, 1], P[:, 0])[None].astype(np.float32))
    >>> states_of("edc", int(m.sets[0, 0]))                    # 20 states → 3
    ['1', '5', '11']
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    bearings = jnp.asarray(bearings)
    if jnp.issubdtype(bearings.dtype, jnp.complexfloating):
        raise TypeError(f"bearings are complex ({bearings.dtype}); bearings must be real")
    if bearings.ndim != 2 or bearings.shape[-1] != 3:
        raise ValueError(f"bearings must have shape (T, 3), got {bearings.shape}")
    if bearings.shape[0] == 0:
        raise ValueError("measure_triples: bearings holds no triple (shape (0, 3)); an image "
                         "with fewer than three landmarks has nothing to measure")
    if not jnp.issubdtype(bearings.dtype, jnp.floating):
        bearings = bearings.astype(jnp.float32)
    if not isinstance(bearings, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(bearings))):
        raise ValueError("bearings contain NaN or inf values")
    if target is None:
        target = jnp.full(bearings.shape[:1] + (3,), spec.full, jnp.uint32)
    target = jnp.asarray(target, jnp.uint32)
    if target.shape != bearings.shape[:1] + (3,):
        raise ValueError(f"target must have shape {bearings.shape[:1] + (3,)}, got {target.shape}")
    tol = resolve_tolerance(tol, bearings.dtype)
    concrete = not any(isinstance(x, jax.core.Tracer) for x in (bearings, target))
    if concrete and tol == 0:
        b = np.asarray(bearings, np.float64)
        same = (np.remainder(b - b[:, :1] + np.pi, 2 * np.pi) - np.pi == 0).all(-1)
        if same.any():
            raise ValueError(f"bearings of triple(s) {np.flatnonzero(same).tolist()} are all "
                             "equal: three landmarks on one ray are collinear, no open EDC "
                             "state fits")
    sets, und = _kernel(spec, bearings, target, jnp.asarray(tol, bearings.dtype))
    if exact and concrete and tol == 0 and bool(jnp.any(und != 0)):
        from .camera_oracle import settle_undecided

        sets, n = settle_undecided(spec, bearings, sets, und)
        return TripleMeasurement(jnp.asarray(sets), jnp.zeros_like(und), n)
    return TripleMeasurement(sets, und)


# --------------------------------------------------------------------------------------
# images
# --------------------------------------------------------------------------------------
@cache
def slot_triples(n_slots: int) -> np.ndarray:
    """(C(S, 3), 3) int32 slot triples s0 < s1 < s2 (range order: s0 nearest)."""
    if n_slots < 3:
        return np.zeros((0, 3), np.int32)
    return np.asarray(list(itertools.combinations(range(n_slots), 3)), np.int32)


def select_nearest(range_rank: jax.Array, visible: jax.Array, n: int) -> jax.Array:
    """(n,) landmark ids of the ``n`` nearest visible landmarks, nearest first (−1 = none)."""
    N = range_rank.shape[0]
    key = jnp.where(visible & (range_rank >= 0), range_rank, N + jnp.arange(N))
    order = jnp.argsort(key)[:n]
    ok = jnp.take(visible & (range_rank >= 0), order)
    ids = jnp.where(ok, order, -1).astype(jnp.int32)
    if n > N:
        ids = jnp.concatenate([ids, jnp.full((n - N,), -1, jnp.int32)])
    return ids


def _check_observation(bearings, range_rank, visible):
    bearings = np.asarray(bearings)
    rank = np.asarray(range_rank)
    vis = np.asarray(visible, bool)
    if bearings.ndim != 1 or rank.shape != bearings.shape or vis.shape != bearings.shape:
        raise ValueError("bearings, range_rank and visible must be 1-D arrays of equal length, "
                         f"got {bearings.shape}, {rank.shape}, {vis.shape}")
    if not np.all(np.isfinite(bearings[vis])):
        raise ValueError("non-finite bearing for a visible landmark: "
                         f"ids {np.flatnonzero(vis & ~np.isfinite(bearings)).tolist()}")
    r = rank[vis]
    if np.any(r < 0):
        raise ValueError("a visible landmark has no range rank (−1)")
    if len(np.unique(r)) != len(r):
        raise ValueError("ties in the range ordering: range_rank must give distinct ranks to "
                         "visible landmarks (break ties first; a tie is a valid configuration "
                         "on the boundary of both orders, so either order is sound)")
    if vis.sum() < 3:
        raise ValueError(f"fewer than three visible landmarks ({int(vis.sum())}): no triple "
                         "to measure")


@partial(jax.jit, static_argnames=("spec", "n"))
def _measure_image(spec, bearings, range_rank, visible, target_map, tol=None, *, n):
    ids = select_nearest(range_rank, visible, n)
    tri = jnp.asarray(slot_triples(n))
    lid = ids[tri]  # (T, 3)
    valid = jnp.all(lid >= 0, -1)
    safe = jnp.maximum(lid, 0)
    b = bearings[safe]
    if target_map is None:
        target = jnp.full(lid.shape, spec.full, jnp.uint32)
    else:
        target = jnp.stack([target_map[safe[:, X], safe[:, Y], safe[:, Z]]
                            for X, Y, Z in CYCLIC], -1)
    sets, und = _kernel(spec, b, target, tol)
    full = jnp.uint32(spec.full)
    sets = jnp.where(valid[:, None], sets, full)
    und = jnp.where(valid[:, None], und, jnp.uint32(0))
    return ImageMeasurement(ids, lid, sets, valid, und)


#: The raw jit-compiled image measurement (no host-side checks), for callers that trace it.
measure_image_kernel = _measure_image


def measure_image(
    bearings: jax.Array,
    range_rank: jax.Array,
    visible: jax.Array,
    n: int,
    calc: Calculus | str | QRMSpec = "edc",
    target_map: jax.Array | None = None,
    *,
    check: bool = True,
    tol: float | None = None,
) -> ImageMeasurement:
    """Measure every triple of the ``n`` nearest visible landmarks of one image (M§IV).

    Args:
        bearings: [N] bearings of a :class:`~pqrm_jax.sim.sensors.CameraObservation`.
        range_rank: [N] its range ranks.
        visible: [N] its visibility.
        n: landmarks used per image (an int ≥ 3).
        calc: the calculus (object, name or prepared spec).
        target_map: [N, N, N] uint32, the current map relations (only their open states are
            tested).
        check: check the observation when it is concrete.
        tol: bearing tolerance in radians (:func:`measure_triples`; None: the default of
            the bearings' dtype, 0: exact for the given bearings).

    Returns:
        The :class:`ImageMeasurement` of the image.

    Raises:
        ValueError: for ``n < 3``, and (when concrete, ``check=True``) arrays of unequal
            length, non-finite bearings of visible landmarks, a visible landmark without a
            rank, repeated ranks or fewer than three visible landmarks; a ``tol`` outside
            [0, π/4).

    >>> import jax
    >>> from pqrm_jax import sim
    >>> lm = sim.uniform_landmarks(jax.random.key(0), 6)
    >>> cam = sim.camera(jax.numpy.array([50.0, 50.0, 0.0]), lm, sim.SensorParams(200.0))
    >>> m = measure_image(cam.bearings, cam.range_rank, cam.visible, n=6)
    >>> m.sets.shape, bool(m.valid.all())
    ((20, 3), True)
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    if not isinstance(n, int) or n < 3:
        raise ValueError(f"n (landmarks per image) must be an int >= 3, got {n!r}")
    if check and not any(isinstance(x, jax.core.Tracer) for x in (bearings, range_rank, visible)):
        _check_observation(bearings, range_rank, visible)
    bearings = jnp.asarray(bearings)
    tol = resolve_tolerance(tol, bearings.dtype)
    return _measure_image(spec, bearings, jnp.asarray(range_rank),
                          jnp.asarray(visible), target_map, jnp.asarray(tol, bearings.dtype), n=n)
