"""Path-completion guarantees of Q-Link (P §4.3.4, Assumptions 1–4, Propositions 1–4).

Scope (P §4.3.4): point landmarks, no occlusion, perfect recognition, navigating range
R′ ≥ R (the mapping range).

* Assumption 1 (i): every element fits in a disc of radius R — :func:`mec_radius` ≤ R.
* Prop. 1, operative form: then every two members are ≤ 2R apart, so the circle of radius R
  about one member passes within R of each other member (at ``L_n + R (L_k − L_n)/|L_k − L_n|``),
  and the quarter arc of radius R about the reference midpoint in the link's quadrant passes
  within R of the link (:func:`pqrm_jax.qlink.trajectory.arc_min_distance`).
* Prop. 2: "the worst case trajectory length for one map element transition is (2π + 1)R, and
  ... for |P| transitions is (2π + 1)R|P|" (:func:`bound_prop2`), for the circle strategy.
* Assumption 3 / Prop. 3–4: members pairwise ≤ R; a straight drive between members keeps both
  in view and costs ≤ R per transition (:func:`bound_prop4`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["mec_radius", "assumption1", "assumption3", "bound_prop2", "bound_prop4"]


def mec_radius(points: np.ndarray) -> np.ndarray:
    """Minimum-enclosing-circle radius ``[E]`` of triangles ``points [E, 3, 2]``.

    Obtuse (or right) triangle: half the longest side; acute: the circumradius.

    >>> mec_radius(np.array([[[0., 0.], [2., 0.], [1., 0.1]], [[0., 0.], [2., 0.], [1., 3.]]]))
    array([1.        , 1.66666667])
    """
    p = np.asarray(points, np.float64)
    a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    b = np.linalg.norm(p[:, 0] - p[:, 2], axis=1)
    c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    s = np.sort(np.stack([a, b, c], 1), axis=1)
    obtuse = s[:, 2] ** 2 >= s[:, 0] ** 2 + s[:, 1] ** 2
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area2 = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    circ = a * b * c / np.maximum(2 * area2, 1e-300)
    return np.where(obtuse, s[:, 2] / 2, circ)


def assumption1(landmarks, ids, r) -> np.ndarray:
    """``[E]`` bool: element fits in a disc of radius ``r`` (Assumption 1 (i))."""
    return mec_radius(np.asarray(landmarks)[np.asarray(ids)]) <= r


def assumption3(landmarks, ids, r) -> np.ndarray:
    """``[E]`` bool: members pairwise within ``r`` (Assumption 3 (i))."""
    p = np.asarray(landmarks)[np.asarray(ids)]
    d = np.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1)
    return d.max(axis=(1, 2)) <= r


def bound_prop2(n_transitions, r):
    """Prop. 2 worst-case length ``(2π + 1) R |P|``.

    >>> round(float(bound_prop2(18, 20.0)), 1)
    2621.9
    """
    return (2 * np.pi + 1) * r * np.asarray(n_transitions)


def bound_prop4(n_transitions, r):
    """Prop. 4 worst-case length ``|P| R``."""
    return r * np.asarray(n_transitions)
