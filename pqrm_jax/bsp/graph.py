"""The frame graph of a frozen belief: observability, link hops, "plan exists" (Z §4.2.3, §4.3).

With the map frozen during lookahead (docs/bsp.md §Z-12), the association weight of candidate
``β = ij:k`` seen from frame (i, j) factorises through

    Ab[i, j, k, s_x, b] = Σ_{s_τ} A[s_x, s_τ, b] · P(ij:k = s_τ),

and ``P(β | s_x) = Σ_b P(S^{ij} = b) · Ab[i, j, k, s_x, b]``. A candidate is *observable* from
(i, j) when it is in the (augmented) belief and ``max_{s_x} P(β | s_x) ≥ eps``. Frames are
ordered pairs; an observable ``ij:k`` links (i, j) to (i, k) and (j, k) (the landmark shared
with the old frame is the new origin). The goal τ* = {g1, g2, g3} is reached from a frame
inside it that observes its third landmark. :func:`hops` is the number of links from each
frame to such a goal frame (``INF`` when none); a plan exists iff the initial frame's hop
count is finite (docs/bsp.md §plan-exists: existence is topology and observability, and
therefore the same for both costs).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .belief import QBelief, in_belief
from .models import Models

INF = 10_000


class FrameGraph(NamedTuple):
    """Per-session frozen quantities (shapes for L landmarks, Q states, nb bins)."""

    Ab: jax.Array  # (L, L, L, Q, nb)
    obs: jax.Array  # (L, L, L) bool: ij:k observable from frame (i, j)
    hops: jax.Array  # (L, L) int32: links to a goal-observing frame (INF: none)
    goal_obs: jax.Array  # (L, L) bool: frame (i, j) ⊂ goal and observes the goal


def available(trip_src, lm_mask) -> jax.Array:
    """(L, L, L) bool: ordered triplets of distinct real landmarks that are candidates
    (measured or composed rows of the belief; not rows kept for the frame scales only)."""
    L = trip_src.shape[0]
    i, j, k = jnp.meshgrid(jnp.arange(L), jnp.arange(L), jnp.arange(L), indexing="ij")
    distinct = (i != j) & (j != k) & (i != k)
    real = lm_mask[:, None, None] & lm_mask[None, :, None] & lm_mask[None, None, :]
    return in_belief(trip_src) & distinct & real


def visibility(models: Models, trip, trip_src, scale, lm_mask) -> tuple[jax.Array, jax.Array]:
    """Association weights and the best-state visibility of every candidate (module docstring).

    Args:
        models: the offline tables.
        trip: [L, L, L, Q] triplet rows.
        trip_src: [L, L, L] int8 source codes.
        scale: [L, L, nb] frame scales.
        lm_mask: [L] bool, real landmarks.

    Returns:
        ``Ab`` [L, L, L, Q, nb] (0 for rows that are not candidates) and ``pvis`` [L, L, L]
        ``max_{s_x} P(ij:k seen | s_x)`` (0 for rows that are not candidates).
    """
    av = available(trip_src, lm_mask)
    Ab = jnp.einsum("xtb,ijkt->ijkxb", models.A, trip) * av[..., None, None]
    pbx = jnp.einsum("ijb,ijkxb->ijkx", scale, Ab)
    return Ab, pbx.max(-1)


def link_hops(obs, goal) -> tuple[jax.Array, jax.Array]:
    """Links from every frame to a goal-observing frame, given which candidates are observable.

    Args:
        obs: [L, L, L] bool, ``ij:k`` observable from frame (i, j).
        goal: [3] int, the goal triplet.

    Returns:
        ``hops`` [L, L] int32 (``INF`` when no path) and ``goal_obs`` [L, L] bool (the frame
        lies in the goal and observes its third landmark).
    """
    L = obs.shape[0]
    idx = jnp.arange(L)
    in_goal = jnp.any(idx[:, None] == goal[None, :], axis=1)  # (L,)
    frame_in_goal = in_goal[:, None] & in_goal[None, :] & (idx[:, None] != idx[None, :])
    third = jnp.where(frame_in_goal, (goal.sum() - idx[:, None] - idx[None, :]), 0)
    goal_obs = frame_in_goal & jnp.take_along_axis(obs, third[..., None], axis=2)[..., 0]
    # edges (i, j) -> (i, k) and (j, k) for observable ij:k
    hops0 = jnp.where(goal_obs, 0, INF).astype(jnp.int32)

    def relax(_, h):
        via_i = jnp.where(obs, h[:, None, :], INF)  # (i, j, k): hops of (i, k)
        via_j = jnp.where(obs, h[None, :, :], INF)  # hops of (j, k)
        best = jnp.minimum(via_i.min(-1), via_j.min(-1))
        return jnp.minimum(h, jnp.where(best < INF, best + 1, INF))

    return jax.lax.fori_loop(0, L * (L - 1), relax, hops0), goal_obs


@partial(jax.jit, static_argnames=("eps",))
def frame_graph(models: Models, trip, trip_src, scale, lm_mask, goal, eps: float = 0.01
                ) -> FrameGraph:
    """Observability and hop counts of the frozen belief (Z §4.2.6, module docstring); jit-able.

    Args:
        models: the offline tables.
        trip: [L, L, L, Q] triplet rows.
        trip_src: [L, L, L] int8 source codes.
        scale: [L, L, nb] frame scales.
        lm_mask: [L] bool, real landmarks.
        goal: [3] int, the goal triplet.
        eps: observability threshold ε_obs on P(β visible).

    Returns:
        The :class:`FrameGraph` (``Ab`` [L, L, L, Q, nb], ``obs`` [L, L, L], ``hops`` and
        ``goal_obs`` [L, L]).
    """
    Ab, pvis = visibility(models, trip, trip_src, scale, lm_mask)
    obs = available(trip_src, lm_mask) & (pvis >= eps)
    hops, goal_obs = link_hops(obs, goal)
    return FrameGraph(Ab=Ab, obs=obs, hops=hops, goal_obs=goal_obs)


def plan_exists(graph: FrameGraph, frame) -> jax.Array:
    """Whether some sequence of observable links from ``frame`` reaches the goal (Z §4.3).

    Args:
        graph: the session's :class:`FrameGraph`.
        frame: [2] int, the current frame.

    Returns:
        [] bool.
    """
    return graph.hops[frame[0], frame[1]] < INF


@partial(jax.jit, static_argnames=("eps",))
def plans_exist(models: Models, beliefs: QBelief, goals, eps: float = 0.01) -> jax.Array:
    """:func:`plan_exists` of the frame graph of each of E beliefs, one compiled program.

    A ``lax.map`` over the environments: each answer is the single-belief program's
    (``frame_graph`` then ``plan_exists``), not a batched contraction's rounding.

    Args:
        models: the offline tables.
        beliefs: a :class:`~pqrm_jax.bsp.belief.QBelief` with a leading ``[E]`` axis on every
            field (:func:`~pqrm_jax.bsp.env.initial_beliefs`).
        goals: [E, 3] int, each environment's goal triplet.
        eps: observability threshold ε_obs.

    Returns:
        [E] bool.
    """
    def one(a):
        b, goal = a
        fg = frame_graph(models, b.trip, b.trip_src, b.scale, b.lm_mask, goal, eps)
        return plan_exists(fg, b.frame)

    return jax.lax.map(one, (beliefs, jnp.asarray(goals)))
