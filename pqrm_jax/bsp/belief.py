"""The qualitative belief and its update ψ (Z §4.1.1, eqs. 4.1–4.2, 4.18–4.25).

The belief is the factorised product of eq. 4.2, held as a pytree of static shapes padded to
``L`` landmarks (a landmark mask marks the real ones):

* ``frame`` (2,) int32 — the current ordered frame (i, j): i at (0, 0), j at (0, 1);
* ``robot`` (Q,) — ``P(S_frame^X)``, the robot's state in its frame;
* ``trip`` (L, L, L, Q) — ``P(ij:k)`` for every ordering (P §2.3 layout);
* ``trip_src`` (L, L, L) int8 — 0 unknown, 1 measured, 2 composed (Z eq. 4.26), 3 composed
  for the frame scales only (not a candidate: the without-compositions mode of the
  ``"composed"`` scale model, docs/bsp.md §Z-10);
* ``ncomp`` (L, L, L) int8 — compositions in the tree that produced a composed row;
* ``scale`` (L, L, nb) — ``P(S^{ij})`` global frame-scale bins, symmetric (Z §4.2.5);
* ``lm_mask`` (L,) bool; ``conflicts`` () int32 — updates whose evidence had zero likelihood
  (ψ with η = 0, and PQRM row fusions whose product was zero, :func:`pqrm_jax.pqrm.fuse_rows`).

The update ψ (eq. 4.25) for action ``a`` (go to state a), observed triplet ``β = ij:k``,
discrete measurement ``ẑ`` and link option ``link`` (0 stay, 1 → frame (i, k), 2 → (j, k),
the landmark shared with the old frame as the new origin) is, with ``P_F`` the scale of the
current frame (docs/bsp.md §Z-8: association and measurement condition on the scale of F_{t−1}):

    J(s_x, s_τ) ∝ Σ_b P_F(b) · T[b, a, s_x] · P(ij:k = s_τ) · AZ[s_x, s_τ, b, ẑ]
    robot'(s') = Σ_{s_x, s_τ} K[link][s_x, s_τ, s'] · J(s_x, s_τ)         (eq. 4.20, joint J)

normalised by η = ``P(ẑ, β | H⁻)`` (a division, docs/bsp.md §Z-7). Evidence with η = 0 keeps the
prediction ``Σ_b P_F(b) T[b, a]``, keeps the frame, and increments ``conflicts``: never NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .models import Models

#: link option → index into ``Models.K`` (the link types "AC" and "BC").
LINK_K = (1, 3)

#: ``QBelief.trip_src`` codes.
UNKNOWN, MEASURED, COMPOSED, SCALE_ONLY = 0, 1, 2, 3

#: Scale models (docs/bsp.md §Z-10). ``"composed"`` (default): the frame scales of both modes
#: are derived from the measured and the composed rows (Z §4.2.5 eq. 4.24 with §4.2.6), so
#: "without compositions" changes only the candidate set. ``"belief"`` (the previous model,
#: kept as a declared option): the scales come from the rows of the mode's own belief, and a
#: pair inside a measured triplet keeps its measured-only scale (uniform over the observable
#: bins when not derivable from measured rows).
SCALE_MODELS = ("composed", "belief")


def in_belief(trip_src) -> jax.Array:
    """Which rows are candidates: measured or composed, not ``SCALE_ONLY`` (Z §4.2.6, §Z-10).

    Args:
        trip_src: int8 source codes of triplet rows, any shape (e.g. [L, L, L]).

    Returns:
        bool array of the same shape.
    """
    return (trip_src == MEASURED) | (trip_src == COMPOSED)


def check_scale_model(scale_model: str) -> str:
    """``ValueError`` naming ``scale_model`` unless it is one of :data:`SCALE_MODELS`."""
    if scale_model not in SCALE_MODELS:
        raise ValueError(f"scale_model must be one of {SCALE_MODELS}, got {scale_model!r}")
    return scale_model


def belief_scales(models: Models, trip, trip_src, ref, ref_scale, lm_mask,
                  scale_model: str = "composed") -> jax.Array:
    """[L, L, nb] frame scales of a belief under ``scale_model`` (Z eqs. 4.22–4.24, §Z-10).

    Args:
        models: the offline tables (``G2``, ``GA``, ``GB``).
        trip: [L, L, L, Q] triplet rows.
        trip_src: [L, L, L] int8 source codes (module docstring).
        ref: [2] the reference frame.
        ref_scale: [nb] its known scale.
        lm_mask: [L] bool, real landmarks.
        scale_model: ``"composed"`` or ``"belief"`` (:data:`SCALE_MODELS`), static.

    Returns:
        [L, L, nb] the scale distribution of every frame.
    """
    check_scale_model(scale_model)
    if scale_model == "composed":
        return scale_posteriors(models, trip, trip_src > 0, ref, ref_scale, lm_mask)
    return scale_posteriors(models, trip, in_belief(trip_src), ref, ref_scale, lm_mask,
                            measured=trip_src == MEASURED)


class QBelief(NamedTuple):
    """Qualitative belief (module docstring); shapes for L landmarks, Q states, nb bins."""

    frame: jax.Array
    robot: jax.Array
    trip: jax.Array
    trip_src: jax.Array
    ncomp: jax.Array
    scale: jax.Array
    lm_mask: jax.Array
    conflicts: jax.Array


def check_distribution(name: str, p, axis: int = -1, atol: float = 1e-3) -> np.ndarray:
    """Check that ``p`` is a probability distribution along ``axis`` (host, NumPy).

    Args:
        name: what ``p`` is, for the error message.
        p: array of probabilities, any shape.
        axis: the axis that must sum to 1.
        atol: tolerance of the sum.

    Returns:
        ``p`` as a float64 NumPy array.

    Raises:
        ValueError: naming ``name`` when ``p`` has a NaN or infinite, a negative entry, or does
            not sum to 1 within ``atol``.
    """
    p = np.asarray(p, np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name} contains NaN or infinite probabilities")
    if np.any(p < 0):
        raise ValueError(f"{name} contains negative probabilities")
    s = p.sum(axis)
    if not np.allclose(s, 1.0, atol=atol):
        bad = float(np.max(np.abs(s - 1)))
        raise ValueError(f"{name} does not sum to 1 (off by up to {bad:.3g})")
    return p


def scale_posteriors(models: Models, trip, known, ref, ref_scale, lm_mask,
                     measured=None) -> jax.Array:
    """[L, L, nb] frame-scale beliefs from the reference frame (Z eqs. 4.22–4.24).

    Decisions: docs/bsp.md §Z-9–Z-10.

    With ``measured`` (the measured subset of ``known``), a pair whose scale can be derived
    from measured rows, or that lies inside a measured triplet, gets the same scale as without
    the other (composed) rows; composed rows only serve the remaining pairs. Compositions then
    never change what measured triplets say (plan existence is monotone in the belief).

    ``ref`` = (a, b) is the frame whose scale ``ref_scale`` (nb,) is known. The scale of
    ``{a, l}`` comes from ``GA`` and ``P(ab:l)``, of ``{b, l}`` from ``GB``, of ``{l1, l2}``
    from ``G2`` with ``P(ab:l1)``, ``P(ab:l2)``, when those rows are ``known`` (measured or
    composed). Otherwise (docs/bsp.md §Z-10) a pair inside a known triplet gets the uniform
    distribution over the observable bins (an observed triplet has pairwise distances ≤ 2R)
    and any other pair the uniform distribution over all bins.

    Args:
        models: the offline tables (``G2``, ``GA``, ``GB``).
        trip: [L, L, L, Q] triplet rows.
        known: [L, L, L] bool, rows that may serve the scales (measured or composed).
        ref: [2] the reference frame (a, b).
        ref_scale: [nb] its known scale.
        lm_mask: [L] bool, real landmarks.
        measured: optional [L, L, L] bool, the measured subset of ``known``.

    Returns:
        [L, L, nb] the scale distribution of every frame (symmetric in the pair).
    """
    if measured is not None:
        s_m, has_m, in_m = _scales(models, trip, measured, ref, ref_scale, lm_mask)
        s_k, _, _ = _scales(models, trip, known, ref, ref_scale, lm_mask)
        return jnp.where((has_m | in_m)[..., None], s_m, s_k)
    return _scales(models, trip, known, ref, ref_scale, lm_mask)[0]


def _scales(models, trip, known, ref, ref_scale, lm_mask):
    trip = jnp.asarray(trip, jnp.float32)
    known = jnp.asarray(known, bool)
    L, nb = trip.shape[0], models.num_bins
    a, b = ref[0], ref[1]
    pa = trip[a, b]  # (L, Q): P(ab:l)
    ka = known[a, b] & lm_mask
    g2 = jnp.einsum("iq,jr,qrcs,c->ijs", pa, pa, models.G2, ref_scale)
    ga = jnp.einsum("jq,qcs,c->js", pa, models.GA, ref_scale)
    gb = jnp.einsum("jq,qcs,c->js", pa, models.GB, ref_scale)
    idx = jnp.arange(L)
    out = jnp.where((ka[:, None] & ka[None, :])[..., None], g2, 0.0)
    has = ka[:, None] & ka[None, :]
    rowa = (idx[:, None] == a) & ka[None, :]  # pair (a, j)
    out = jnp.where(rowa[..., None], ga[None], out)
    out = jnp.where(rowa.T[..., None], ga[:, None], out)
    rowb = (idx[:, None] == b) & ka[None, :]
    out = jnp.where(rowb[..., None], gb[None], out)
    out = jnp.where(rowb.T[..., None], gb[:, None], out)
    has = has | rowa | rowa.T | rowb | rowb.T
    isref = (((idx[:, None] == a) & (idx[None, :] == b))
             | ((idx[:, None] == b) & (idx[None, :] == a)))
    out = jnp.where(isref[..., None], ref_scale, out)
    has = has | isref
    in_trip = jnp.any(known, axis=2) | jnp.any(known, axis=1) | jnp.any(known, axis=0)
    in_trip = in_trip | in_trip.T
    obs_uniform = jnp.where(jnp.arange(nb) < nb - 1, 1.0 / (nb - 1), 0.0)
    fallback = jnp.where(in_trip[..., None], obs_uniform, 1.0 / nb)
    s = out.sum(-1, keepdims=True)
    good = has[..., None] & (s > 0)
    return (jnp.where(good, out / jnp.where(s > 0, s, 1.0), fallback), good[..., 0], in_trip)


def predict(models: Models, scale_f, action) -> jax.Array:
    """(Q,) predicted robot state after "go to state ``action``" (eq. 4.5, scale-averaged)."""
    return jnp.einsum("b,bq->q", scale_f, models.T[:, action])


def joint(models: Models, scale_f, action, trip_row, zhat) -> jax.Array:
    """(Q, Q) unnormalised J(s_x, s_τ) of the module docstring; ``sum`` is η."""
    return jnp.einsum("b,bx,t,xtb->xt", scale_f, models.T[:, action], trip_row,
                      models.AZ[:, :, :, zhat])


def link_state(models: Models, J, link) -> jax.Array:
    """(Q,) robot state after the link ``link`` (0 stay, 1 AC, 2 BC) from the joint J."""
    stay = J.sum(1)
    k = jnp.asarray(LINK_K)[jnp.clip(link - 1, 0, 1)]
    moved = jnp.einsum("xt,xts->s", J, models.K[k])
    return jnp.where(link == 0, stay, moved)


def new_frame(frame, k, link) -> jax.Array:
    """The frame after link option ``link`` through landmark ``k``: (i, j), (i, k) or (j, k)."""
    i, j = frame[0], frame[1]
    return jnp.where(link == 0, frame, jnp.where(link == 1, jnp.stack([i, k]),
                                                 jnp.stack([j, k])))


@jax.jit
def update(models: Models, belief: QBelief, action, k, zhat, link) -> tuple[QBelief, jax.Array]:
    """ψ (Z eq. 4.25): the belief after an action, an observation of ``frame:k`` and a link.

    The triplet row ``frame:k`` becomes the marginal of J (its other orderings and the rest of
    the map are unchanged; the execution loop updates the map by PQRM). With η = 0 (impossible
    evidence) see the module docstring.

    Args:
        models: the offline tables.
        belief: the belief before the step (its frame is the acting frame).
        action: [] int, the qualitative action "go to state a".
        k: [] int, the observed third landmark β.
        zhat: [] int, the measured joint state ẑ = ẑ_x·Q + ẑ_τ.
        link: [] int, the link option (0: keep the frame, 1: (i, k), 2: (j, k)).

    Returns:
        ``(belief', η)``: the updated :class:`QBelief` and the [] evidence η.
    """
    i, j = belief.frame[0], belief.frame[1]
    sf = belief.scale[i, j]
    Jr = joint(models, sf, action, belief.trip[i, j, k], zhat)
    eta = Jr.sum()
    ok = eta > 0
    J = Jr / jnp.where(ok, eta, 1.0)
    robot = jnp.where(ok, link_state(models, J, link), predict(models, sf, action))
    frame = jnp.where(ok, new_frame(belief.frame, k, link), belief.frame)
    row = jnp.where(ok, J.sum(0), belief.trip[i, j, k])
    trip = belief.trip.at[i, j, k].set(row)
    return belief._replace(frame=frame.astype(jnp.int32), robot=robot, trip=trip,
                           conflicts=belief.conflicts + (~ok).astype(jnp.int32)), eta


def non_detection(models: Models, scale_f, robot, rows, unseen) -> tuple[jax.Array, jax.Array]:
    """Rows ``P(ij:k)`` after *not* seeing the candidates ``unseen`` (EXTENSION beyond Z).

    Off by default (``ExecParams.nondetection``; docs/bsp.md §non-detection). The thesis's
    ψ (Z eq. 4.25) conditions only on an observed candidate, so a candidate that should be
    visible and is not seen changes nothing. This is the negative-information update with the
    association model ``A`` (Z eq. 4.12) of the current frame:

        ℓ(s_τ)    = Σ_{s_x, b} robot(s_x) · P_F(b) · (1 − A[s_x, s_τ, b])
        row'(s_τ) ∝ row(s_τ) · ℓ(s_τ)

    (the same ℓ for every candidate of the frame: it depends on the candidate only through
    its row). A row whose posterior mass is 0 (the model says it must have been seen) is
    kept and counted as a conflict: never NaN.

    Args:
        models: the offline tables.
        scale_f: [nb] scale belief of the current frame.
        robot: [Q] the robot's state in the frame when it looked (the prediction).
        rows: [K, Q] the candidates' rows in the current ordering.
        unseen: [K] bool, the candidates that were not seen (the others are returned as is).

    Returns:
        ``(rows', conflicts)``: [K, Q] and the number of unseen rows with zero evidence.

    Only ``models.A`` is read. With a stand-in whose robot state 0 sees state 1 of the
    triplet for sure and state 0 with probability ½:

    >>> from types import SimpleNamespace
    >>> A = jnp.zeros((2, 2, 1)).at[0, 1].set(1.0).at[0, 0].set(0.5)
    >>> rows = jnp.array([[0.5, 0.5], [0.5, 0.5], [0.0, 1.0]])
    >>> new, bad = non_detection(SimpleNamespace(A=A), jnp.ones(1), jnp.array([1.0, 0.0]),
    ...                          rows, jnp.array([True, False, True]))
    >>> new.tolist(), int(bad)
    ([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]], 1)
    """
    like = jnp.einsum("x,b,xtb->t", robot, scale_f, 1.0 - models.A)
    post = rows * like
    s = post.sum(-1, keepdims=True)
    ok = s[..., 0] > 0
    new = jnp.where((unseen & ok)[:, None], post / jnp.where(s > 0, s, 1.0), rows)
    return new, jnp.sum(unseen & ~ok).astype(jnp.int32)


def discretise(rel_a, rel_b, rel_c, num_states: int, calc) -> jax.Array:
    """Discrete measurement ẑ = ẑ_x·Q + ẑ_τ from measured positions relative to the robot
    (docs/bsp.md §Z-5); ``-1`` when a state is undefined (boundary, degenerate or non-finite)."""
    zx = calc.classify(rel_a, rel_b, jnp.zeros_like(rel_a))
    zt = calc.classify(rel_a, rel_b, rel_c)
    return jnp.where((zx >= 0) & (zt >= 0), zx * num_states + zt, -1)
