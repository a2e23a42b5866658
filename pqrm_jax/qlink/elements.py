"""Q-Link map elements: landmark sets with their qualitative relations (P §4.2).

"Each QRM map entry, M_i = {L_i, Q_i}, is composed of a landmark set, L_i, and Q_i, the
qualitative states of the landmarks for all possible ordered sets L_i^ref ⊂ L_i" (P §4.2). For a
PQRM every entry of Q_i is a distribution over the calculus's states. Here an element is an
unordered landmark triplet (sorted ids) and ``probs[e, k]`` is ``p({A, B : C} = q)`` for the k-th
of the six orderings :data:`ORDERINGS` of ``ids[e]``.

**Which elements exist.** An element exists for every triplet measured together at least once
during the mapping run (P §2.2.3; Assumption 1 of P §4.3.4: "a robot recording a QRM entry for
all landmark sets it observes"). :func:`from_mapping_run` collects those triplets on the host
from the visibility masks and maps *only* them: each co-observation of an element contributes
six rows (its orderings) to one call of :func:`pqrm_jax.pqrm.state_probabilities`, and the rows
of an element are fused by Bayes' rule (P eq. 2.10, a product of the per-measurement
likelihoods, each floored at ``floor`` so one outlying measurement cannot zero a state). No dense
``M(M-1)(M-2)`` triplet array is built (7.9 M rows at M = 200).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi, pqrm
from .. import sim as _sim
from ..triplets import ORDERING_INDEX, ORDERINGS
from .checks import validate

__all__ = ["ORDERINGS", "MapElements", "co_observed_triplets", "from_mapping_run",
           "exact_elements", "ordering_index", "incidence", "check_elements", "fuse"]

# the six orderings (positions of A, B, C within the sorted ``ids`` row) and their index by
# the positions of A and B: the triplet vocabulary (pqrm_jax.triplets)
_ORDER_OF = ORDERING_INDEX


class MapElements(NamedTuple):
    """Map elements of a qualitative map (P §4.2).

    ids: ``[E, 3]`` int32 landmark ids of each element, sorted ascending.
    probs: ``[E, 6, Q]`` float, ``p({A, B : C} = q)`` for the orderings :data:`ORDERINGS`.
    num_landmarks: number of landmarks in the world (ids are ``0 .. num_landmarks - 1``).
    """

    ids: jax.Array
    probs: jax.Array
    num_landmarks: int


def check_elements(elements: MapElements) -> None:
    """Raise ``ValueError`` for an empty map or malformed element arrays
    (:func:`pqrm_jax.qlink.checks.validate`; the probabilities are not read here)."""
    validate(elements=elements, probs_used=False)


def ordering_index(ids_row: jax.Array, a, b) -> jax.Array:
    """Index into :data:`ORDERINGS` of the ordering ``(a, b, c)`` of an element's ``ids_row``.

    ``a`` and ``b`` are landmark ids in ``ids_row``; ``c`` is the remaining member.

    >>> int(ordering_index(jnp.array([3, 5, 9]), 9, 3))
    4
    """
    pa = jnp.argmax(ids_row == a)
    pb = jnp.argmax(ids_row == b)
    return jnp.asarray(_ORDER_OF)[pa, pb]


def incidence(elements: MapElements) -> np.ndarray:
    """The landmark–element incidence of a map (P §4.2: which elements hold a landmark).

    Args:
        elements: the map elements (``ids [E, 3]`` over ``num_landmarks`` = N_L landmarks).

    Returns:
        ``[N_L, E]`` bool, ``True`` where the landmark is a member of the element.

    >>> el = MapElements(jnp.array([[0, 1, 2], [1, 2, 3]]), jnp.zeros((2, 6, 4)), 4)
    >>> incidence(el).astype(int).tolist()
    [[1, 0], [1, 1], [1, 1], [0, 1]]
    """
    ids = np.asarray(elements.ids)
    inc = np.zeros((elements.num_landmarks, ids.shape[0]), bool)
    inc[ids, np.arange(ids.shape[0])[:, None]] = True
    return inc


def co_observed_triplets(visible: np.ndarray, max_obs: int) -> tuple[np.ndarray, np.ndarray]:
    """Triplets seen together at ≥ 1 pose, with up to ``max_obs`` of their poses (host side).

    Args:
        visible: ``[P, N]`` bool visibility per mapping pose.
        max_obs: observations kept per element (evenly spread over its co-observations).

    Returns:
        ``(ids [E, 3] int32 sorted, obs [E, max_obs] int32 pose indices, -1 = none)``.

    >>> v = np.array([[1, 1, 1, 0], [0, 1, 1, 1], [1, 1, 1, 1]], bool)
    >>> ids, obs = co_observed_triplets(v, 2)
    >>> ids.tolist(), obs.tolist()
    ([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], [[0, 2], [2, -1], [2, -1], [1, 2]])
    """
    if max_obs < 1:
        raise ValueError(f"max_obs must be >= 1, got {max_obs}")
    seen: dict[tuple[int, int, int], list[int]] = {}
    for p, row in enumerate(np.asarray(visible, bool)):
        for tri in itertools.combinations(np.flatnonzero(row).tolist(), 3):
            seen.setdefault(tri, []).append(p)
    keys = sorted(seen)
    ids = np.array(keys, np.int32).reshape(-1, 3)
    obs = np.full((len(keys), max_obs), -1, np.int32)
    for e, k in enumerate(keys):
        poses = seen[k]
        if len(poses) > max_obs:
            pick = np.linspace(0, len(poses) - 1, max_obs).round().astype(int)
            poses = [poses[i] for i in pick]
        obs[e, :len(poses)] = poses
    return ids, obs


def fuse(probs: jax.Array, mask: jax.Array, floor: float) -> jax.Array:
    """Bayes fusion (P eq. 2.10) of ``[E, K, 6, Q]`` measurement likelihoods under ``mask``
    ``[E, K]`` (each likelihood floored at ``floor``): the ``[E, 6, Q]`` posteriors."""
    logp = jnp.log(jnp.maximum(probs, floor)) * mask[:, :, None, None]
    return jax.nn.softmax(jnp.sum(logp, axis=1), axis=-1)


def from_mapping_run(key: jax.Array, landmarks: jax.Array, poses: jax.Array,
                     sensor: _sim.SensorParams, calculus: str = "quadrant",
                     num_samples: int = 64, max_obs: int = 6,
                     floor: float = 1e-3) -> tuple[MapElements, np.ndarray]:
    """Map elements from a simulated PQRM mapping run (P §2.2, §4.4.1).

    At every pose the robot measures the visible landmarks (``sim.observe``: range, noise σ);
    every triplet seen together becomes an element; its six orderings are mapped from (up to
    ``max_obs``) co-observations with eq. 2.9 and fused with eq. 2.10.

    Args:
        key: PRNG key (sensor noise and the eq. 2.9 sampling).
        landmarks: ``[N, 2]`` landmark positions.
        poses: ``[P, 3]`` mapping poses (e.g. :func:`pqrm_jax.sim.lawnmower`).
        sensor: the mapping robot's sensor (range R, noise σ).
        calculus: the QSR (default ``"quadrant"``, P Fig. 4.5).
        num_samples: samples per row for eq. 2.9.
        max_obs: co-observations fused per element.
        floor: likelihood floor in the fusion.

    Returns:
        ``(elements, visible [P, N])``: the :class:`MapElements` (``ids [E, 3]``,
        ``probs [E, 6, Q]``) and the mapping run's bool visibility per pose.

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) NaN/inf or coincident
            landmarks, NaN/inf poses, fewer than 3 landmarks, ``poses`` not ``[P, 3]``, a
            run in which no triplet is seen together.

    >>> lm = jnp.array([[0., 0.], [6., 0.], [3., 4.], [40., 40.]])
    >>> el, vis = from_mapping_run(jax.random.key(0), lm, jnp.array([[3., 1., 0.]]),
    ...                            _sim.SensorParams(max_range=10.0, sigma=0.1))
    >>> el.ids.tolist(), el.probs.shape
    ([[0, 1, 2]], (1, 6, 4))
    """
    validate(landmarks=np.asarray(landmarks), finite={"poses": np.asarray(poses)},
             positive={"sensor.max_range": float(sensor.max_range),
                       "num_samples": num_samples, "max_obs": max_obs},
             nonnegative={"sensor.sigma": float(sensor.sigma), "floor": floor})
    landmarks = jnp.asarray(landmarks)
    if landmarks.shape[0] < 3:
        raise ValueError(f"landmarks must have at least 3 rows, got {landmarks.shape[0]}")
    poses = jnp.asarray(poses)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (P, 3), got {poses.shape}")
    calc = calculi.get(calculus)
    k_obs, k_map = jax.random.split(key)
    keys = jax.random.split(k_obs, poses.shape[0])
    obs = jax.vmap(_sim.observe, (0, 0, None, None))(keys, poses, landmarks, sensor)
    visible = np.asarray(obs.visible)
    ids, which = co_observed_triplets(visible, max_obs)
    if ids.shape[0] == 0:
        raise ValueError("the mapping run observed no landmark triplet: the map would be empty")
    rel = obs.rel                                           # [P, N, 2]
    trip = jnp.asarray(ids)[:, ORDERINGS]                   # [E, 6, 3] ordered landmark ids
    pose_idx = jnp.maximum(jnp.asarray(which), 0)           # [E, K]
    means = rel[pose_idx[:, :, None, None], trip[:, None, :, :]]  # [E, K, 6, 3, 2]
    e, k = which.shape
    flat = means.reshape(e * k * 6, 3, 2)
    p = pqrm.state_probabilities(k_map, calc, flat, float(sensor.sigma), num_samples)
    p = p.reshape(e, k, 6, calc.num_states)
    probs = fuse(p, jnp.asarray(which >= 0, p.dtype), floor)
    return MapElements(jnp.asarray(ids), probs, int(landmarks.shape[0])), visible


def _exact_probs(lm: np.ndarray, trip: np.ndarray, calculus: str) -> np.ndarray | None:
    """``[..., Q]`` noise-free distributions of ``{A, B : C}`` for ``trip [..., 3]`` with a
    landmark on a dividing line split exactly (quadrant and lr; ``None`` for other calculi).

    The two signs (left of AB: ``cross(B − A, C − A)``; in front of the mid-perpendicular:
    ``(B − A)·(C − M)``) are computed in float64. A zero sign gives ½ to each side: the
    σ → 0 limit of the PQRM (eq. 2.9) under symmetric noise (docs/qlink.md §boundary).
    """
    a, b, c = (lm[trip[..., i]] for i in range(3))
    ab = b - a
    left = np.sign(ab[..., 0] * (c - a)[..., 1] - ab[..., 1] * (c - a)[..., 0])
    pl = np.where(left > 0, 1.0, np.where(left < 0, 0.0, 0.5))
    if calculus == "lr":
        return np.stack([pl, 1 - pl], -1)
    if calculus != "quadrant":
        return None
    front = np.sign((ab * (c - (a + b) / 2)).sum(-1))
    pf = np.where(front > 0, 1.0, np.where(front < 0, 0.0, 0.5))
    return np.stack([pf * pl, pf * (1 - pl), (1 - pf) * pl, (1 - pf) * (1 - pl)], -1)


def exact_elements(landmarks: jax.Array, ids: np.ndarray,
                   calculus: str = "quadrant") -> MapElements:
    """Map elements with the noise-free relations of the true landmark positions (P §4.2).

    One-hot except where a landmark lies exactly on a dividing line of its ordering: for the
    quadrant and lr calculi its probability is split evenly between the states the line
    separates (½ each; ¼ each at the midpoint M), the σ → 0 limit of the PQRM; another
    calculus refuses such an element (docs/qlink.md §boundary).

    Args:
        landmarks: ``[N, 2]`` landmark positions (any scale; the relations are scale-free).
        ids: ``[E, 3]`` integer landmark ids of each element (sorted in the result).
        calculus: the QSR of the relations (default ``"quadrant"``, P Fig. 4.5).

    Returns:
        :class:`MapElements` with ``ids [E, 3]`` int32 and ``probs [E, 6, Q]`` (one row per
        ordering of :data:`ORDERINGS`, dtype of ``landmarks``).

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) non-finite or coincident
            landmarks, ids not integers in ``[0, N)``, a landmark twice in one element,
            ``ids`` not ``[E, 3]`` or empty, a landmark on a dividing line of a calculus
            without an exact split.

    >>> lm = jnp.array([[0., 0.], [10., 0.], [8., 3.]])
    >>> exact_elements(lm, np.array([[0, 1, 2]])).probs[0, 0].tolist()   # {0, 1 : 2} = FL
    [1.0, 0.0, 0.0, 0.0]
    >>> lm = jnp.array([[0., 0.], [10., 0.], [5., 6.]])                  # 2 on the bisector
    >>> exact_elements(lm, np.array([[0, 1, 2]])).probs[0, 0].tolist()
    [0.5, 0.0, 0.5, 0.0]
    """
    calc = calculi.get(calculus)
    validate(landmarks=np.asarray(landmarks))
    n = int(np.shape(landmarks)[0])
    ids = np.asarray(ids)
    if ids.ndim != 2 or ids.shape[1] != 3:
        raise ValueError(f"ids must have shape (E, 3), got {ids.shape}")
    if ids.shape[0] == 0:
        raise ValueError("ids is empty: the map would have no map elements")
    check = MapElements(ids, np.ones((ids.shape[0], 6, 1)), n)
    validate(elements=check, elements_name="ids")
    ids = np.sort(ids.astype(np.int32), axis=1)
    trip = ids[:, ORDERINGS]
    lm64 = np.asarray(landmarks, np.float64)
    dtype = jnp.asarray(landmarks).dtype
    probs = _exact_probs(lm64, trip, calculus)
    if probs is None:
        lm = jnp.asarray(landmarks)
        st = calc.classify(lm[trip[..., 0]], lm[trip[..., 1]], lm[trip[..., 2]])
        if (np.asarray(st) < 0).any():
            e = int(np.argwhere(np.asarray(st) < 0)[0, 0])
            raise ValueError(f"ids[{e}] = {ids[e].tolist()}: a landmark lies on a dividing "
                             f"line of {calculus!r}, which has no exact split here")
        probs = np.asarray(jax.nn.one_hot(st, calc.num_states))
    return MapElements(jnp.asarray(ids), jnp.asarray(probs, dtype), n)
