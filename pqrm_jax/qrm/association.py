"""Data-association candidate filter (M§VI.C).

A landmark of uncertain identity is measured "as though previously unobserved": the camera
measurement of every triple it forms with two well-associated visible landmarks (all states
tested). A map landmark L remains a candidate only if, for every such triple, each measured
relation overlaps the map's relation with L substituted: the rest are inconsistent with the
image. If no candidate remains the landmark can be added as a new node.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi import Calculus
from .camera import CYCLIC, measure_image_kernel
from .hypergraph import QRMMap
from .spec import QRMSpec, qrm_spec

__all__ = ["association_candidates"]


@partial(jax.jit, static_argnames=("spec", "n"))
def _candidates(spec, m: QRMMap, bearings, range_rank, visible, unknown, *, n):
    meas = measure_image_kernel(spec, bearings, range_rank, visible, None, n=n)
    N = m.rel.shape[0]
    involved = meas.valid & jnp.any(meas.triples == unknown, -1)

    def consistent(cand):
        tri = jnp.where(meas.triples == unknown, cand, meas.triples)
        clash = jnp.any((tri == cand).sum(-1) > 1)  # cand is also a visible landmark
        ok = jnp.stack([(m.rel[tri[:, X], tri[:, Y], tri[:, Z]] & meas.sets[:, o]) != 0
                        for o, (X, Y, Z) in enumerate(CYCLIC)], -1).all(-1)
        return jnp.all(ok | ~involved) & ~clash & m.known[cand]

    return jax.vmap(consistent)(jnp.arange(N))


def association_candidates(
    m: QRMMap,
    bearings: jax.Array,
    range_rank: jax.Array,
    visible: jax.Array,
    unknown: int,
    n: int,
    calc: Calculus | str | QRMSpec = "edc",
) -> jax.Array:
    """[N] bool: map landmarks that the uncertain observation ``unknown`` may be (M§VI.C).

    Args:
        m: the current map.
        bearings: [N] bearings of the camera observation.
        range_rank: [N] range ranks of the observation.
        visible: [N] visibility of the observation.
        unknown: index, in the observation arrays, of the landmark whose identity is uncertain
            (it must be visible and among the ``n`` nearest); the other visible landmarks'
            indices are their (trusted) map ids.
        n: landmarks used per image.
        calc: the calculus (object, name or prepared spec).

    Returns:
        [N] bool, True for every map landmark consistent with the image.

    Raises:
        ValueError: when ``unknown`` is not a visible observation or fewer than three landmarks
            are visible.
    """
    spec = calc if isinstance(calc, QRMSpec) else qrm_spec(calc)
    vis = np.asarray(visible, bool)
    if not 0 <= int(unknown) < vis.shape[0] or not vis[int(unknown)]:
        raise ValueError(f"unknown={unknown} is not a visible observation index")
    if vis.sum() < 3:
        raise ValueError("fewer than three visible landmarks: nothing to compare")
    if np.asarray(range_rank)[int(unknown)] >= n:
        raise ValueError(f"the uncertain landmark is not among the {n} nearest used")
    return _candidates(spec, m, jnp.asarray(bearings), jnp.asarray(range_rank),
                       jnp.asarray(visible), jnp.int32(unknown), n=n)
