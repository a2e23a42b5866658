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
   sampled inverse sensor model, eq. 2.10 Bayes product) and recompute the frame scales.
   Composed rows are kept from the initial session (decision: compositions once per episode).

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
from ..pqrm import state_probabilities
from ..triplets import ORDERINGS
from .belief import QBelief, discretise, non_detection, predict, scale_posteriors, update
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


def run_lane(models: Models, D1, pos, lm_mask, goal, start, belief: QBelief, ref, ref_scale,
             key, cost, pp: PlannerParams, ep: ExecParams) -> Outcome:
    """Execute one test (module docstring) with cost ``cost`` (1 or 2, traced); pure and
    ``vmap``-able over lanes (``pp.cost`` is ignored)."""
    calc = calculi.get(ep.calculus)
    L = pos.shape[0]
    idx = jnp.arange(L)
    cb = cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    sensor = sim.SensorParams(max_range=1.0, sigma=ep.sigma_z)
    perms = jnp.asarray(ORDERINGS)

    def step(carry, t):
        x, bel, done, reached, c1, c2, nst, ex0, tex0, v0, key = carry
        key, kp, km, ko, kq = jax.random.split(key, 5)
        fg = frame_graph(models, bel.trip, bel.trip_src, bel.scale, lm_mask, goal, ep.eps_obs)
        pl = plan(models, D1, bel.trip, bel.scale, fg, goal, bel.frame, bel.robot, kp, pp, cost)
        exists = plan_exists(fg, bel.frame)
        ex0 = jnp.where(t == 0, exists, ex0)
        tex0 = jnp.where(t == 0, pl.exists, tex0)
        v0 = jnp.where(t == 0, pl.value, v0)
        active = (~done) & exists
        a = pl.action
        i, j = bel.frame[0], bel.frame[1]
        tgt = _to_world(pos[i], pos[j], models.targets[a])
        xn = tgt + ep.sigma_m * jax.random.normal(km, (2,))
        xn = jnp.where(active, xn, x)
        s0 = calc.classify(pos[i], pos[j], x)
        s1 = calc.classify(pos[i], pos[j], xn)
        d1 = D1[jnp.clip(s0, 0), jnp.clip(s1, 0)]
        c1 = c1 + jnp.where(active, d1, 0.0)
        c2 = c2 + jnp.where(active, jnp.linalg.norm(xn - x), 0.0)
        ob = sim.observe(ko, jnp.concatenate([xn, jnp.zeros(1)]), pos, sensor)
        vis = ob.visible & lm_mask
        got = active & vis[goal].all()
        avail = bel.trip_src[i, j] > 0
        cand = vis & vis[i] & vis[j] & (idx != i) & (idx != j) & avail
        isg = fg.goal_obs[i, j] & (idx == goal.sum() - i - j)
        h_f = leaf_values(fg, bel.frame, cb, lam, pp.rho)
        h_ik = leaf_values(fg, jnp.stack([jnp.full(L, i), idx], -1), cb, lam, pp.rho)
        h_jk = leaf_values(fg, jnp.stack([jnp.full(L, j), idx], -1), cb, lam, pp.rho)
        hs = jnp.stack([jnp.full(L, h_f), h_ik, h_jk], -1)  # (L, 3)
        kval = jnp.where(isg, -1.0, hs.min(-1))
        kval = jnp.where(cand, kval, jnp.inf)
        k = jnp.argmin(kval)
        link = jnp.argmin(hs[k])
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
            pred = nothing.robot  # the prediction (the robot's state when it looked)
            rows_ij, bad = non_detection(models, sf, pred, nb_.trip[i, j], unseen)
            # the reversed ordering ji:k is INVERSE of ij:k, an exact permutation P = U[2]
            # (P = Pᵀ = P⁻¹): update it in the ij order with the same likelihood
            P = models.U[2]
            rows_ji, _ = non_detection(models, sf, pred, nb_.trip[j, i] @ P, unseen)
            nd_trip = nb_.trip.at[i, j].set(rows_ij).at[j, i].set(rows_ji @ P)
            nb_ = nb_._replace(trip=nd_trip, conflicts=nb_.conflicts + bad)
        # PQRM rows of every observed candidate triplet (i, j, k'), all orderings
        rel = ob.rel
        ids = jnp.stack([jnp.full(L, i), jnp.full(L, j), idx], -1)  # (L, 3)
        pid = ids[:, perms]  # (L, 6, 3)
        means = rel[pid]  # (L, 6, 3, 2)
        meas = state_probabilities(kq, calc, means.reshape(-1, 3, 2), ep.sigma_z,
                                   ep.pqrm_samples).reshape(L, 6, -1)
        prior = bel.trip[pid[..., 0], pid[..., 1], pid[..., 2]]  # (L, 6, Q)
        post = prior * meas
        s = post.sum(-1, keepdims=True)
        post = jnp.where(s > 0, post / jnp.where(s > 0, s, 1.0), meas)
        okm = cand[:, None] & (meas.sum(-1) > 0)
        cur = nb_.trip[pid[..., 0], pid[..., 1], pid[..., 2]]
        rows = jnp.where(okm[..., None], post, cur)
        trip = nb_.trip.at[pid[..., 0], pid[..., 1], pid[..., 2]].set(rows)
        srcv = nb_.trip_src[pid[..., 0], pid[..., 1], pid[..., 2]]
        src = nb_.trip_src.at[pid[..., 0], pid[..., 1], pid[..., 2]].set(
            jnp.where(okm, jnp.int8(1), srcv))
        scale = scale_posteriors(models, trip, src > 0, ref, ref_scale, lm_mask,
                                 measured=src == 1)
        nb_ = nb_._replace(trip=trip, trip_src=src, scale=scale)
        bel = jax.tree.map(lambda u, v: jnp.where(active, u, v), nb_, bel)
        x = xn
        reached = reached | got
        nst = nst + active.astype(jnp.int32)
        done = done | got | ~exists
        logs = (jnp.where(active, bel.frame, -1), jnp.where(active, a, -1),
                jnp.where(active & anyc, k, -1), x)
        return (x, bel, done, reached, c1, c2, nst, ex0, tex0, v0, key), logs

    f0 = jnp.zeros((), bool)
    z0 = jnp.zeros((), jnp.float32)
    init = (start, belief, f0, f0, z0, z0, jnp.zeros((), jnp.int32), f0, f0, z0, key)
    carry, logs = jax.lax.scan(step, init, jnp.arange(ep.t_max))
    _, bel, _, reached, c1, c2, nst, ex0, tex0, v0, _ = carry
    return Outcome(exists=ex0, tree_exists=tex0, reached=reached, cost1=c1, cost2=c2, steps=nst,
                   conflicts=bel.conflicts, root_value=v0, log_frame=logs[0], log_action=logs[1],
                   log_beta=logs[2], log_pos=logs[3])


@partial(jax.jit, static_argnames=("pp", "ep"))
def run_lanes(models: Models, D1, pos, lm_mask, goal, start, belief: QBelief, ref, ref_scale,
              keys, costs, pp: PlannerParams, ep: ExecParams) -> Outcome:
    """:func:`run_lane` ``vmap``-ed over a leading lane axis of every per-lane argument
    (``costs`` (lanes,) int: 1 or 2 per lane)."""
    f = partial(run_lane, pp=pp, ep=ep)
    return jax.vmap(f, (None, None, 0, 0, 0, 0, 0, 0, 0, 0, 0))(
        models, D1, pos, lm_mask, goal, start, belief, ref, ref_scale, keys, costs)
