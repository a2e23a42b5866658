"""Receding-horizon execution in the simulator with PQRM map updates (Z §4.3, Fig. 4.6).

One lane is one test (environment × mode × cost). Each step (``lax.scan`` over ``T_max``):

1. freeze the belief and build the frame graph; stop with "no plan" when the goal is
   unreachable (:func:`~pqrm_jax.bsp.graph.plan_exists`; recorded at the first step);
2. plan (:func:`~pqrm_jax.bsp.planner.plan`) and take its first qualitative action "go to
   state a": the true robot moves to the world image of the target point ``p_a`` in its true
   frame plus ``N(0, σ_m²)`` — the controller the transition model was sampled from
   (docs/bsp.md §Z-26);
3. ``pqrm_jax.sim.observe`` all landmarks within R (noise σ_z, 360°); success when the three
   goal landmarks are visible at once (docs/bsp.md §Z-16);
4. among the observed candidates ``frame:k`` in the belief, choose β and the link whose frame
   has the smallest leaf value ``h`` (goal first; ties keep the frame), compute ẑ from the
   real measurement and update the robot's state with ψ (eq. 4.25);
5. update the rows of every observed candidate triplet (all orderings) by PQRM (P eq. 2.9
   sampled inverse sensor model; eq. 2.10 by :func:`pqrm_jax.pqrm.fuse_rows`, the one row
   rule of the library: a zero product keeps the prior, leaves the row's source as it was
   and adds a conflict to ``QBelief.conflicts``) and recompute the frame scales
   (``ExecParams.scale_model``, docs/bsp.md §Z-10). Composed rows are kept from the initial
   session (decision: compositions once per episode).

Ground-truth executed costs (docs/bsp.md §Z-17): cost 1 sums the neighbour distance between the
true states before and after each move in the frame of that step; cost 2 sums the metric
displacement in units of R.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .. import calculi, sim
from ..pqrm import fuse_rows, state_probabilities
from ..triplets import ORDERINGS
from .belief import (
    MEASURED,
    QBelief,
    belief_scales,
    discretise,
    in_belief,
    non_detection,
    predict,
    update,
)
from .graph import frame_graph, plan_exists
from .models import Models
from .planner import PlannerParams, cbar, leaf_values, plan


class ExecParams(NamedTuple):
    """Static execution settings."""

    t_max: int = 12
    sigma_m: float = 0.05
    sigma_z: float = 0.05
    pqrm_samples: int = 64
    eps_obs: float = 0.01
    calculus: str = "edc"
    #: EXTENSION beyond Z, off by default (docs/bsp.md §non-detection): after each move,
    #: the rows of the frame's candidates that were not seen get the negative-information
    #: update :func:`~pqrm_jax.bsp.belief.non_detection`.
    nondetection: bool = False
    #: how frame scales are derived (docs/bsp.md §Z-10; ``bsp.belief.SCALE_MODELS``): from
    #: measured and composed rows in both modes (default) or from the mode's own belief.
    scale_model: str = "composed"
    #: what a lane does when a later frame graph says "no plan" (docs/bsp.md §execution):
    #: ``"continue"`` (default) takes the planner's action anyway and replans at the next
    #: step — measured: 4 of the 11 lanes a later "no plan" ended reach the goal when they go
    #: on; ``"stop"`` (the previous rule) ends the lane as a failure. The first session's
    #: "no plan" always ends it.
    on_no_plan: str = "continue"


class Outcome(NamedTuple):
    """Per-lane result (leading lane axis when batched); ``log_*`` have a ``t_max`` axis."""

    exists: jax.Array
    tree_exists: jax.Array
    reached: jax.Array
    cost1: jax.Array
    cost2: jax.Array
    steps: jax.Array
    conflicts: jax.Array
    root_value: jax.Array
    log_frame: jax.Array
    log_action: jax.Array
    log_beta: jax.Array
    log_pos: jax.Array


def _to_world(pa, pb, p):
    e = pb - pa
    right = jnp.stack([e[1], -e[0]])
    return pa + p[1] * e + p[0] * right


class LaneState(NamedTuple):
    """The carry of one lane's ``lax.scan`` (shapes for L landmarks)."""

    pos: jax.Array  # [2] the true robot position (units of R)
    belief: QBelief  # the belief (frame, robot state, map)
    done: jax.Array  # [] bool: the lane has ended (goal seen, or no plan)
    reached: jax.Array  # [] bool: the three goal landmarks were seen at once
    cost1: jax.Array  # [] executed cost 1 so far (eq. 4.29, ground truth)
    cost2: jax.Array  # [] executed cost 2 so far (displacement in R)
    steps: jax.Array  # [] int32 executed steps
    exists: jax.Array  # [] bool: the first session's frame graph has a plan
    tree_exists: jax.Array  # [] bool: the first session's tree root < λ
    root_value: jax.Array  # [] the first session's root value
    key: jax.Array  # the lane's PRNG key


def map_update(key, models: Models, before: QBelief, after: QBelief, rel, cand, ref, ref_scale,
               ep: ExecParams) -> QBelief:
    """PQRM update of the rows of every observed candidate triplet (step 5 of the module).

    For each landmark ``k`` with ``cand[k]``, the six orderings of the triplet (i, j, k) of the
    frame (i, j) are measured by P eq. 2.9 from ``rel`` and fused into the rows of ``before``
    (the belief before this observation: ψ's marginal of the same observation is replaced,
    not counted twice) by :func:`pqrm_jax.pqrm.fuse_rows` (P eq. 2.10, the library's one row
    rule): a zero product keeps the prior row and its source and adds one conflict per row to
    ``conflicts``; otherwise the row becomes the posterior and is marked measured. Then the
    frame scales are recomputed (``ep.scale_model``, docs/bsp.md §Z-10).

    Args:
        key: PRNG key of the eq. 2.9 samples.
        models: the offline tables.
        before: the belief before the observation (its frame is the observing frame).
        after: the belief after ψ (its other fields are kept).
        rel: [L, 2] measured landmark positions relative to the robot.
        cand: [L] bool, landmarks k whose triplet with the frame was observed.
        ref: [2] reference frame; ref_scale: [nb] its scale.
        ep: execution settings (``calculus``, ``sigma_z``, ``pqrm_samples``, ``scale_model``).

    Returns:
        ``after`` with the fused rows, their sources, the scales and the conflict count.
    """
    calc = calculi.get(ep.calculus)
    L = rel.shape[0]
    i, j = before.frame[0], before.frame[1]
    idx = jnp.arange(L)
    ids = jnp.stack([jnp.full(L, i), jnp.full(L, j), idx], -1)  # (L, 3)
    pid = ids[:, jnp.asarray(ORDERINGS)]  # (L, 6, 3)
    sel = (pid[..., 0], pid[..., 1], pid[..., 2])
    meas = state_probabilities(key, calc, rel[pid].reshape(-1, 3, 2), ep.sigma_z,
                               ep.pqrm_samples).reshape(L, 6, -1)
    okm = cand[:, None] & (meas.sum(-1) > 0)
    srcv = after.trip_src[sel]
    fused, conflict = fuse_rows(before.trip[sel], meas, in_belief(srcv), okm)
    rows = jnp.where(okm[..., None], fused, after.trip[sel])
    trip = after.trip.at[sel].set(rows)
    src = after.trip_src.at[sel].set(jnp.where(okm & ~conflict, jnp.int8(MEASURED), srcv))
    scale = belief_scales(models, trip, src, ref, ref_scale, before.lm_mask, ep.scale_model)
    return after._replace(trip=trip, trip_src=src, scale=scale,
                          conflicts=after.conflicts + conflict.sum().astype(jnp.int32))


class Lane(NamedTuple):
    """The inputs of one lane (one test: environment × mode × cost), shapes for L landmarks.

    Batched by :func:`run_lanes` with a leading lane axis on every field.
    """

    pos: jax.Array  # [L, 2] landmark positions (units of R; padding landmarks far away)
    lm_mask: jax.Array  # [L] bool: real (not padding) landmarks
    goal: jax.Array  # [3] int32 the goal triplet's landmark ids
    start: jax.Array  # [2] the true start position of the robot
    belief: QBelief  # the initial belief (its mode: with or without compositions)
    ref: jax.Array  # [2] int32 the reference frame F_1 (its scale is known)
    ref_scale: jax.Array  # [nb] one-hot scale bin of ``ref``
    cost: jax.Array  # [] int32 the cost the planner minimises: 1 (eq. 4.29) or 2 (eq. 4.30)


def _choose_candidate(fg, frame, cand, goal, cb, lam, rho: float):
    """Step 4 of the module docstring: among the candidates ``cand`` [L], the landmark ``k``
    whose best link (frame, (i, k) or (j, k)) has the smallest leaf value (the goal landmark
    first, ties keep the frame); returns (k, link) as int32 scalars."""
    L = cand.shape[0]
    idx = jnp.arange(L)
    i, j = frame[0], frame[1]
    isg = fg.goal_obs[i, j] & (idx == goal.sum() - i - j)
    h_f = leaf_values(fg, frame, cb, lam, rho)
    h_ik = leaf_values(fg, jnp.stack([jnp.full(L, i), idx], -1), cb, lam, rho)
    h_jk = leaf_values(fg, jnp.stack([jnp.full(L, j), idx], -1), cb, lam, rho)
    hs = jnp.stack([jnp.full(L, h_f), h_ik, h_jk], -1)  # (L, 3)
    kval = jnp.where(isg, -1.0, hs.min(-1))
    kval = jnp.where(cand, kval, jnp.inf)
    k = jnp.argmin(kval)
    return k, jnp.argmin(hs[k])


def _nondetection_step(models: Models, sf, pred, bel: QBelief, unseen, i, j) -> QBelief:
    """EXTENSION (docs/bsp.md §non-detection): the negative-information update of the rows
    (i, j, k) and (j, i, k) of the landmarks ``unseen`` [L] from the robot's predicted state
    ``pred`` [Q] in a frame of scale ``sf`` [nb]."""
    rows_ij, bad = non_detection(models, sf, pred, bel.trip[i, j], unseen)
    # the reversed ordering ji:k is INVERSE of ij:k, an exact permutation P = U[2]
    # (P = Pᵀ = P⁻¹): update it in the ij order with the same likelihood
    P = models.U[2]
    rows_ji, _ = non_detection(models, sf, pred, bel.trip[j, i] @ P, unseen)
    nd_trip = bel.trip.at[i, j].set(rows_ij).at[j, i].set(rows_ji @ P)
    return bel._replace(trip=nd_trip, conflicts=bel.conflicts + bad)


def run_lane(key: jax.Array, models: Models, D1: jax.Array, lane: Lane, pp: PlannerParams,
             ep: ExecParams) -> Outcome:
    """Execute one test (module docstring, Z §4.3 / Fig. 4.6); pure and ``vmap``-able.

    Args:
        key: PRNG key of the lane (planner sessions, motion and sensor noise, PQRM samples).
        models: the offline tables (:func:`~pqrm_jax.bsp.models.build_models`).
        D1: [Q, Q] neighbour distance of cost 1 (eq. 4.29).
        lane: the lane's inputs (:class:`Lane`); ``lane.cost`` (1 or 2, traced) overrides
            ``pp.cost``.
        pp: static planner settings.
        ep: static execution settings.

    Returns:
        The lane's :class:`Outcome` (scalars; ``log_*`` with a leading ``[ep.t_max]`` axis).

    Raises:
        ValueError: if ``ep.on_no_plan`` is not ``"stop"`` or ``"continue"``.
    """
    if ep.on_no_plan not in ("stop", "continue"):
        raise ValueError(f"ExecParams.on_no_plan must be 'stop' or 'continue', got "
                         f"{ep.on_no_plan!r}")
    calc = calculi.get(ep.calculus)
    pos, lm_mask, goal, cost = lane.pos, lane.lm_mask, lane.goal, lane.cost
    L = pos.shape[0]
    idx = jnp.arange(L)
    cb = cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    sensor = sim.SensorParams(max_range=1.0, sigma=ep.sigma_z)

    def step(st: LaneState, t):
        bel, x = st.belief, st.pos
        key, kp, km, ko, kq = jax.random.split(st.key, 5)
        fg = frame_graph(models, bel.trip, bel.trip_src, bel.scale, lm_mask, goal, ep.eps_obs)
        pl = plan(kp, models, D1, bel.trip, bel.scale, fg, goal, bel.frame, bel.robot, pp, cost)
        exists = plan_exists(fg, bel.frame)
        go_on = exists if ep.on_no_plan == "stop" else (exists | (t > 0))
        active = (~st.done) & go_on
        a = pl.action
        i, j = bel.frame[0], bel.frame[1]
        tgt = _to_world(pos[i], pos[j], models.targets[a])
        xn = tgt + ep.sigma_m * jax.random.normal(km, (2,))
        xn = jnp.where(active, xn, x)
        s0 = calc.classify(pos[i], pos[j], x)
        s1 = calc.classify(pos[i], pos[j], xn)
        d1 = D1[jnp.clip(s0, 0), jnp.clip(s1, 0)]
        ob = sim.observe(ko, jnp.concatenate([xn, jnp.zeros(1)]), pos, sensor)
        vis = ob.visible & lm_mask
        got = active & vis[goal].all()
        avail = in_belief(bel.trip_src[i, j])
        cand = vis & vis[i] & vis[j] & (idx != i) & (idx != j) & avail
        k, link = _choose_candidate(fg, bel.frame, cand, goal, cb, lam, pp.rho)
        anyc = cand.any()
        z = discretise(ob.rel[i], ob.rel[j], ob.rel[k], models.num_states, calc)
        upd, _ = update(models, bel, a, k, jnp.clip(z, 0), link)
        sf = bel.scale[i, j]
        nothing = bel._replace(robot=predict(models, sf, a))
        use = anyc & (z >= 0)
        nb_ = jax.tree.map(lambda u, v: jnp.where(use, u, v), upd, nothing)
        if ep.nondetection:  # EXTENSION (docs/bsp.md §non-detection); off in the thesis model
            unseen = (avail & lm_mask & (idx != i) & (idx != j)
                      & ~(vis[i] & vis[j] & vis))
            nb_ = _nondetection_step(models, sf, nothing.robot, nb_, unseen, i, j)
        # PQRM rows of every observed candidate triplet (i, j, k'), all orderings
        nb_ = map_update(kq, models, bel, nb_, ob.rel, cand, lane.ref, lane.ref_scale, ep)
        bel = jax.tree.map(lambda u, v: jnp.where(active, u, v), nb_, bel)
        logs = (jnp.where(active, bel.frame, -1), jnp.where(active, a, -1),
                jnp.where(active & anyc, k, -1), xn)
        first = t == 0
        return LaneState(
            pos=xn, belief=bel, done=st.done | got | ~go_on, reached=st.reached | got,
            cost1=st.cost1 + jnp.where(active, d1, 0.0),
            cost2=st.cost2 + jnp.where(active, jnp.linalg.norm(xn - x), 0.0),
            steps=st.steps + active.astype(jnp.int32),
            exists=jnp.where(first, exists, st.exists),
            tree_exists=jnp.where(first, pl.exists, st.tree_exists),
            root_value=jnp.where(first, pl.value, st.root_value), key=key), logs

    f0 = jnp.zeros((), bool)
    z0 = jnp.zeros((), jnp.float32)
    init = LaneState(pos=lane.start, belief=lane.belief, done=f0, reached=f0, cost1=z0,
                     cost2=z0, steps=jnp.zeros((), jnp.int32), exists=f0, tree_exists=f0,
                     root_value=z0, key=key)
    st, logs = jax.lax.scan(step, init, jnp.arange(ep.t_max))
    return Outcome(exists=st.exists, tree_exists=st.tree_exists, reached=st.reached,
                   cost1=st.cost1, cost2=st.cost2, steps=st.steps,
                   conflicts=st.belief.conflicts, root_value=st.root_value, log_frame=logs[0],
                   log_action=logs[1], log_beta=logs[2], log_pos=logs[3])


@partial(jax.jit, static_argnames=("pp", "ep"))
def run_lanes(keys: jax.Array, models: Models, D1: jax.Array, lanes: Lane, pp: PlannerParams,
              ep: ExecParams) -> Outcome:
    """:func:`run_lane` ``vmap``-ed over lanes, one compiled program per lane layout.

    Args:
        keys: [N] PRNG keys, one per lane.
        models: the offline tables (shared by every lane).
        D1: [Q, Q] neighbour distance of cost 1 (eq. 4.29).
        lanes: a :class:`Lane` whose every field has a leading ``[N]`` lane axis
            (``lanes.cost`` [N] int32: 1 or 2 per lane).
        pp: static planner settings.
        ep: static execution settings.

    Returns:
        The :class:`Outcome` of every lane, each field with a leading ``[N]`` axis.

    Raises:
        ValueError: if ``ep.on_no_plan`` is not ``"stop"`` or ``"continue"``.

    """
    f = partial(run_lane, pp=pp, ep=ep)
    return jax.vmap(f, (0, None, None, 0))(keys, models, D1, lanes)
