"""The one input check of every public Q-Link entry point (docs/qlink.md §validation).

:func:`validate` is called by :func:`~pqrm_jax.qlink.elements.exact_elements`,
:func:`~pqrm_jax.qlink.elements.from_mapping_run`, :func:`~pqrm_jax.qlink.linkgraph.link_graph`,
:func:`~pqrm_jax.qlink.costs.edge_costs`, :func:`~pqrm_jax.qlink.linkgraph.plan_pairs`,
:func:`~pqrm_jax.qlink.linkgraph.goal_distances`, :func:`~pqrm_jax.qlink.navigate.navigate`,
:func:`~pqrm_jax.qlink.navigate.navigate_pairs` and the hybrid map
(:func:`~pqrm_jax.qlink.hybrid.hybrid_elements`, :func:`~pqrm_jax.qlink.hybrid.drive_hybrid`).
Every refusal is a ``ValueError`` naming the argument and the offending value:

* landmark positions: shape ``[N, 2]``, finite, pairwise distinct (coincident landmarks have
  no qualitative relation);
* map elements: ids ``[E, 3]`` integers in ``[0, N)``, no landmark twice in one element,
  probabilities ``[E, 6, Q]`` finite, non-negative, no all-zero row;
* landmark id lists (starts, goals): non-empty, integers (a non-integral value is refused,
  never truncated), in ``[0, N)`` (a negative id never wraps), and in the map;
* ranges and step sizes: finite and positive (or non-negative where zero means "none").
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["validate"]


def _ids(name: str, value, num_landmarks: int | None, *, allow_empty=False) -> np.ndarray:
    a = np.asarray(value)
    if a.size == 0 and not allow_empty:
        raise ValueError(f"{name} is empty: at least one landmark id is needed")
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer)
                               or np.issubdtype(a.dtype, np.floating)):
        raise ValueError(f"{name} must hold integer landmark ids, got dtype {a.dtype}")
    if np.issubdtype(a.dtype, np.floating):
        bad = ~np.isfinite(a) | (a != np.round(a))
        if bad.any():
            raise ValueError(f"{name} must hold integer landmark ids, got {a[bad].flat[0]!r}")
    a = a.astype(np.int64)
    if num_landmarks is not None:
        bad = (a < 0) | (a >= num_landmarks)
        if bad.any():
            raise ValueError(f"{name} holds id {int(a[bad].flat[0])}, outside "
                             f"[0, {num_landmarks}): not in the map")
    return a


def _landmarks(name: str, value) -> None:
    lm = np.asarray(value)
    if lm.ndim != 2 or lm.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {lm.shape}")
    if not np.issubdtype(lm.dtype, np.number) or lm.dtype == bool:
        raise ValueError(f"{name} must hold real coordinates, got dtype {lm.dtype}")
    bad = ~np.isfinite(lm).all(1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name}[{i}] is not finite: {lm[i].tolist()}")
    _, first, counts = np.unique(lm, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        p = lm[first[counts > 1][0]]
        same = np.flatnonzero((lm == p).all(1)).tolist()
        raise ValueError(f"{name} {same} coincide at {p.tolist()}: landmarks must be distinct")


def _elements(name: str, elements, probs_used: bool) -> None:
    idn = name if name == "ids" else f"{name}.ids"
    ids = np.asarray(elements.ids)
    if ids.ndim != 2 or ids.shape[1] != 3:
        raise ValueError(f"{idn} must have shape (E, 3), got {ids.shape}")
    if ids.shape[0] == 0:
        raise ValueError(f"{name} is empty: the map has no map elements")
    n = elements.num_landmarks
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 3:
        raise ValueError(f"{name}.num_landmarks must be an integer >= 3, got {n!r}")
    ids = _ids(idn, ids, int(n))
    srt = np.sort(ids, axis=1)
    rep = (srt[:, 1:] == srt[:, :-1]).any(1)
    if rep.any():
        e = int(np.flatnonzero(rep)[0])
        raise ValueError(f"{idn}[{e}] = {ids[e].tolist()} repeats a landmark")
    probs = np.asarray(elements.probs)
    if probs.ndim != 3 or probs.shape[:2] != (ids.shape[0], 6):
        raise ValueError(f"{name}.probs must have shape ({ids.shape[0]}, 6, Q), "
                         f"got {probs.shape}")
    if not np.isfinite(probs).all() or (probs < 0).any():
        e = int(np.flatnonzero(~(np.isfinite(probs) & (probs >= 0)).all((1, 2)))[0])
        raise ValueError(f"{name}.probs[{e}] holds a negative or non-finite value")
    zero = ~(probs.sum(-1) > 0)
    if probs_used and zero.any():
        e, k = (int(x) for x in np.argwhere(zero)[0])
        raise ValueError(f"{name}.probs[{e}, {k}] is all zero (element {ids[e].tolist()}): "
                         "no qualitative state; a landmark on a dividing line is split "
                         "exactly by exact_elements (docs/qlink.md §boundary)")


def _paths(paths: np.ndarray, n: np.ndarray, num_elements: int, trials: int) -> None:
    """``paths [B, L]`` element ids (−1 padded) with ``n [B]`` valid entries each."""
    if paths.ndim != 2 or paths.shape[0] != trials or n.shape != (trials,):
        raise ValueError(f"paths must have shape ({trials}, L) and n_elements ({trials},), "
                         f"got {paths.shape} and {n.shape}")
    if not np.issubdtype(n.dtype, np.integer) or not np.issubdtype(paths.dtype, np.integer):
        raise ValueError(f"paths and n_elements must be integers, got {paths.dtype}, {n.dtype}")
    if np.any(n < 1):
        raise ValueError(f"n_elements holds {int(n[n < 1][0])}: every trial needs a planned "
                         "path (|P| >= 1); unreachable pairs are reported by the planner, not "
                         "navigated")
    if np.any(n > paths.shape[1]):
        raise ValueError(f"n_elements holds {int(n.max())}, longer than paths "
                         f"({paths.shape[1]} columns)")
    valid = np.arange(paths.shape[1])[None, :] < n[:, None]
    bad = valid & ((paths < 0) | (paths >= num_elements))
    if bad.any():
        b, k = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(f"paths[{b}, {k}] = {int(paths[b, k])} is not a map element "
                         f"(0 <= id < {num_elements})")


def _beta(beta) -> int:
    if isinstance(beta, bool) or not isinstance(beta, (int, np.integer)) or beta < 1:
        raise ValueError(f"beta must be an integer >= 1, got {beta!r}")
    if beta > 3:
        raise ValueError(f"beta must be <= 3 for triplet elements, got {beta}")
    return int(beta)


def validate(*, landmarks=None, elements=None, landmark_ids: Mapping | None = None,
             positive: Mapping | None = None, nonnegative: Mapping | None = None,
             finite: Mapping | None = None, num_landmarks: int | None = None,
             landmarks_name: str = "landmarks", elements_name: str = "elements",
             probs_used: bool = True, beta=None, paths: tuple | None = None
             ) -> dict[str, np.ndarray]:
    """Check Q-Link inputs; raise ``ValueError`` naming the argument and the value.

    Args:
        landmarks: ``[N, 2]`` landmark positions (finite, pairwise distinct).
        elements: a :class:`~pqrm_jax.qlink.elements.MapElements` (ids, probabilities).
        landmark_ids: ``{name: ids}`` landmark id lists (starts, goals): non-empty integers in
            ``[0, N)``; with ``elements`` each must also belong to some map element.
        positive: ``{name: value}`` scalars that must be finite and > 0.
        nonnegative: ``{name: value}`` scalars that must be finite and >= 0.
        finite: ``{name: array}`` arrays that must be finite (poses, positions).
        num_landmarks: N when neither ``landmarks`` nor ``elements`` gives it.
        landmarks_name, elements_name: the argument names used in messages.
        beta: the Link Graph threshold β (an integer in 1..3).
        paths: ``(paths [B, L], n_elements [B], num_elements E, B)``: planned paths whose
            first ``n_elements`` entries are element ids in ``[0, E)``, ``|P| >= 1``.
        probs_used: the caller reads ``elements.probs`` (the QSR level, costs, the
            executive): an all-zero row is refused; graph-only callers pass False.

    Returns:
        ``{name: int64 array}`` the checked landmark id lists (shapes as given).

    Raises:
        ValueError: naming the argument and the offending value — NaN/inf or coincident
            landmarks, an empty id list, a negative, out-of-range (≥ N), non-integer or
            unmapped id, a landmark twice in one element, an all-zero probability row
            (``probs_used``), a scalar that is not finite and positive (non-negative), a
            non-finite array, β outside 1..3, a path entry that is not an element.

    >>> validate(landmark_ids={"goals": [1, 2]}, num_landmarks=3)["goals"].tolist()
    [1, 2]
    >>> validate(landmark_ids={"starts": [-4]}, num_landmarks=3)
    Traceback (most recent call last):
    ...
    ValueError: starts holds id -4, outside [0, 3): not in the map
    """
    if beta is not None:
        _beta(beta)
    if paths is not None:
        _paths(np.asarray(paths[0]), np.asarray(paths[1]), int(paths[2]), int(paths[3]))
    for name, v in (positive or {}).items():
        x = np.asarray(v, np.float64) if np.ndim(v) == 0 else None
        if x is None or not (np.isfinite(x) and x > 0):
            raise ValueError(f"{name} must be positive and finite, got {v!r}")
    for name, v in (nonnegative or {}).items():
        x = np.asarray(v, np.float64) if np.ndim(v) == 0 else None
        if x is None or not (np.isfinite(x) and x >= 0):
            raise ValueError(f"{name} must be non-negative and finite, got {v!r}")
    for name, v in (finite or {}).items():
        a = np.asarray(v, np.float64)
        if not np.isfinite(a).all():
            raise ValueError(f"{name} holds NaN or inf: {a[~np.isfinite(a)].flat[0]!r}")
    if landmarks is not None:
        _landmarks(landmarks_name, landmarks)
        num_landmarks = int(np.shape(landmarks)[0])
    if elements is not None:
        _elements(elements_name, elements, probs_used)
        if landmarks is not None and elements.num_landmarks != num_landmarks:
            raise ValueError(f"{elements_name}.num_landmarks = {elements.num_landmarks} but "
                             f"{landmarks_name} has {num_landmarks} rows")
        num_landmarks = int(elements.num_landmarks)
    out = {}
    member = None
    if elements is not None and landmark_ids:
        member = np.zeros(num_landmarks, bool)
        member[np.asarray(elements.ids).ravel()] = True
    for name, v in (landmark_ids or {}).items():
        a = _ids(name, v, num_landmarks)
        if member is not None and not member[a].all():
            lm = int(a[~member[a]].flat[0])
            raise ValueError(f"{name} holds landmark {lm}, which is not in the map (it "
                             "belongs to no map element)")
        out[name] = a
    return out
