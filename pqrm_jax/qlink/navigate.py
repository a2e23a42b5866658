"""The Q-Link executive: one start/goal navigation as one ``lax.while_loop`` (P §4.3, §4.4.1).

A trial follows a planned Link Graph path ``M_1 … M_|P|`` on the simulated rover
(:func:`pqrm_jax.sim.step`), sensing after every step with range R′ and partial disc occlusion
(:func:`pqrm_jax.sim.target_visibility`). The state machine (decisions in the study config):

1. **Transition** M_i → M_j whenever two landmarks of L_j are visible at the same time
   (P §4.4.1: "L_j^ref ⊆ L^{vis_t} at some time t"); the visible pair (preferring one with the
   link) becomes the new references, measured with noise σ.
2. **QSR search** (step 1 of P §4.3.1) for the link e ∈ L_i ∩ L_j not among the references:
   the search POMDP (:mod:`.pomdp`) with the PQRM's ``{A, B : e}`` distribution and the
   robot's own measured quadrant gives up to τ commands; each is the quarter arc of radius R
   about the references' measured midpoint (:mod:`.trajectory`). After τ misses the transition
   fails (``LINK_NOT_FOUND``).
3. **Reference search** (step 2): once e is seen, one circle of radius R′ about ê; a full turn
   without a pair of L_j fails (``REFS_NOT_FOUND``). With β = 1 and the link already a
   reference, the robot goes to this step directly.
4. **Start**: at the start landmark s (+ an offset in a seeded direction), localised into M_1 by
   step 3 with e = s (``START_NOT_LOCALIZED`` on failure). **Goal**: once in M_|P|, success
   when the goal landmark is visible; otherwise step 2 with e = g (``GOAL_NOT_FOUND``).
5. Every trial has a step budget; exceeding it ends the trial with ``BUDGET``, never a hang.

Length is the distance driven. :func:`navigate` ``vmap``s the loop over trials; per-trial PRNG
keys make results independent of the batch size. Re-planning after a failure (P §4.4.2) is
:func:`replan_inputs` + a second :func:`navigate` call from the final poses.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from .. import sim as _sim
from . import pomdp as _pomdp
from . import trajectory as tr
from .checks import validate
from .elements import MapElements, ordering_index

__all__ = ["NavParams", "NavResult", "Trials", "NavMap", "nav_map", "navigate",
           "FAILURE_REASONS", "SUCCESS", "RUNNING",
           "step_budget", "replan_inputs", "UNREACHABLE", "COLLISION", "localize",
           "start_tables", "start_poses",
           "PairResult", "navigate_pairs", "qsr_plans", "where_tree"]

RUNNING, SUCCESS = 0, 1
LINK_NOT_FOUND, REFS_NOT_FOUND, START_NOT_LOCALIZED, GOAL_NOT_FOUND, BUDGET = 2, 3, 4, 5, 6
UNREACHABLE, COLLISION = 7, 8
FAILURE_REASONS = {RUNNING: "running", SUCCESS: "success", LINK_NOT_FOUND: "link_not_found",
                   REFS_NOT_FOUND: "refs_not_found", START_NOT_LOCALIZED: "start_not_localized",
                   GOAL_NOT_FOUND: "goal_not_found", BUDGET: "budget",
                   UNREACHABLE: "unreachable", COLLISION: "collision"}
"""Status codes of :class:`NavResult` and :class:`PairResult` (``unreachable``: localised,
but no Link Graph path leads from the elements in view to the goal; ``collision``: the in-vivo
executive's straight drive met a wall, :mod:`pqrm_jax.qlink.hybrid`)."""

SENSING = ("step", "epoch")
"""Sensing models (docs/qlink.md §sensing): ``step`` senses after every rover step; ``epoch``
senses during the QSR search only at its decision epochs (the plan step and the end of each
quarter arc), the circle searches still every step."""

PLAN, ARC, CIRCLE, LOOK = 0, 1, 2, 3


class NavParams(NamedTuple):
    """Navigation parameters (all lengths in the world's units; scale-free by construction).

    map_range: R, the mapping robot's range; the QSR arcs have radius R.
    nav_range: R′, the navigating robot's sensing range (circle-search radius).
    occluder_radius: landmark disc radius for partial occlusion (0 = none).
    sigma: std of the navigation measurement noise on landmark positions.
    ds: distance per rover step (``v_max·dt``). turn_per_step: ``ω_max·dt`` (radians).
    circle_margin: circle radius = ``circle_margin · R′`` (keeps the centre in range despite
        rounding).
    start_offset: start pose distance from the start landmark.
    circle_only: 1.0 = skip the QSR search and circle a reference that is a link landmark
        whenever there is one (the strategy of Prop. 2, P §4.3.4); 0.0 = Q-Link's QSR search.
    sense_epochs: 1.0 = the ``epoch`` sensing model (:data:`SENSING`): along a QSR arc the
        robot looks only at the arc's end; 0.0 = ``step`` (after every step).
    """

    map_range: float
    nav_range: float
    occluder_radius: float = 0.0
    sigma: float = 0.0
    ds: float = 0.5
    turn_per_step: float = 0.5
    circle_margin: float = 0.999
    start_offset: float = 1.0
    circle_only: float = 0.0
    sense_epochs: float = 0.0


class NavResult(NamedTuple):
    """Outcome of B trials (arrays ``[B]`` unless noted).

    status: :data:`FAILURE_REASONS` code. length: distance driven. steps: loop iterations.
    hops: transitions completed (localisation into M_1 counts as the first).
    k: index on the path of the element the robot is localised in (−1 = none).
    pose: ``[B, 3]`` final pose. refs: ``[B, 2]`` final references.
    trace: ``[B, T, 2]`` positions after each of the first T steps (NaN after the end; T = 0
        unless ``record`` is given).
    """

    status: jax.Array
    length: jax.Array
    steps: jax.Array
    hops: jax.Array
    k: jax.Array
    pose: jax.Array
    refs: jax.Array
    trace: jax.Array


class Trials(NamedTuple):
    """The trials bundle of :func:`navigate` and :func:`navigate_pairs` (arrays ``[B]``).

    keys: ``[B]`` per-trial PRNG keys (first: derive them from (world, setting, pair)).
    starts, goals: ``[B]`` start and goal landmark ids.
    paths: ``[B, L]`` planned element paths (``-1`` padded) and n_elements ``[B]`` ``|P|``
        (:func:`navigate` only; :func:`navigate_pairs` plans them itself).
    poses: optional ``[B, 3]`` start poses (default :func:`start_poses`).
    budget: optional ``[B]`` step budgets (default :func:`step_budget`; :func:`navigate`).
    """

    keys: jax.Array
    starts: np.ndarray
    goals: np.ndarray
    paths: np.ndarray | None = None
    n_elements: np.ndarray | None = None
    poses: jax.Array | None = None
    budget: np.ndarray | None = None


class NavMap(NamedTuple):
    """The map bundle a robot navigates on (build it with :func:`nav_map`).

    landmarks: ``[N, 2]`` true landmark positions. elements: the map elements.
    graph: the Link Graph; to_go: its :class:`~pqrm_jax.qlink.linkgraph.GoalTable` for every
        mapped landmark; goal_row: ``[N]`` the row of ``to_go`` of each landmark (−1 = none);
        tables: :func:`start_tables` (these four for :func:`navigate_pairs`).
    plans: optional :func:`qsr_plans` table (computed per call when not given).
    """

    landmarks: jax.Array
    elements: MapElements
    graph: object = None
    to_go: object = None
    goal_row: np.ndarray | None = None
    tables: tuple | None = None
    plans: jax.Array | None = None


def nav_map(landmarks, elements: MapElements, graph=None,
            model: _pomdp.SearchPOMDP | None = None) -> NavMap:
    """The map bundle a robot navigates on, with its tables computed once (P §4.3).

    Args:
        landmarks: ``[N, 2]`` true landmark positions.
        elements: the map elements (``E`` of them).
        graph: optional Link Graph: then the goal table (:func:`goal_distances` to every
            mapped landmark), goal rows ``[N]`` and :func:`start_tables` are computed
            (what :func:`navigate_pairs` needs).
        model: optional search POMDP: then the :func:`qsr_plans` table ``[E, 6, Q, τ]``.

    Returns:
        :class:`NavMap` (fields not computed are ``None``).

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) NaN/inf or coincident
            landmarks, malformed elements.
    """
    from .elements import incidence
    from .linkgraph import goal_distances

    validate(landmarks=np.asarray(landmarks), elements=elements)
    to_go = goal_row = tables = None
    if graph is not None:
        lms = np.flatnonzero(incidence(elements).any(1))
        goal_row = np.full(elements.num_landmarks, -1, np.int64)
        goal_row[lms] = np.arange(len(lms))
        to_go = goal_distances(graph, elements, lms)
        tables = start_tables(elements)
    plans = None if model is None else qsr_plans(elements, model)
    return NavMap(jnp.asarray(landmarks), elements, graph, to_go, goal_row, tables, plans)


class _S(NamedTuple):
    pose: jax.Array
    length: jax.Array
    steps: jax.Array
    k: jax.Array
    refs: jax.Array
    refs_xy: jax.Array
    phase: jax.Array
    seq: jax.Array
    c: jax.Array
    e: jax.Array
    e_xy: jax.Array
    motion: tr.Motion
    status: jax.Array
    hops: jax.Array
    trace: jax.Array


def qsr_plans(elements: MapElements, model: _pomdp.SearchPOMDP) -> jax.Array:
    """``[E, 6, Q, τ]`` the exact search-POMDP command sequence for every element, ordering
    (references A, B; link C) and robot state — solved once, batched over all of them
    (:func:`pqrm_jax.qlink.pomdp.open_loop_plan`), looked up by the executive."""
    probs = jnp.asarray(elements.probs)
    e, o, q = probs.shape
    b = jnp.repeat(probs.reshape(e * o, q), q, axis=0)
    qr = jnp.tile(jnp.arange(q, dtype=jnp.int32), e * o)
    _, seq = _pomdp.open_loop_plan(model, qr, b)
    return seq.reshape(e, o, q, -1).astype(jnp.int32)


def where_tree(cond: jax.Array, a, b):
    """``jnp.where(cond, ·, ·)`` leaf by leaf over two pytrees of one structure."""
    return jax.tree.map(lambda x, y: jnp.where(cond, x, y), a, b)


def step_budget(n_elements, params: NavParams, factor: float = 5.0, turns: int = 64):
    """Per-trial step budget: ``factor`` × the Prop. 2 bound ``(2π+1)R|P|`` in steps, plus
    ``turns`` in-place turning steps per element (P §4.3.4)."""
    n = np.maximum(np.asarray(n_elements), 1)
    return (np.ceil(factor * (2 * np.pi + 1) * params.map_range * n / params.ds)
            + turns * n).astype(np.int32)


def _sense(pos, landmarks, targets, occ_tab, params: NavParams, occlusion: bool):
    """Visibility ``[K]`` of ``targets`` from ``pos``: range only, or range + partial disc
    occlusion by the candidate occluders of :func:`pqrm_jax.sim.occluder_table` (the same
    result as testing every landmark; ``occlusion`` is static, one compile each)."""
    if occlusion:
        return _sim.local_target_visibility(pos, landmarks, targets,
                                            occ_tab[jnp.maximum(targets, 0)],
                                            params.nav_range, params.occluder_radius)
    d = jnp.linalg.norm(landmarks[jnp.maximum(targets, 0)] - pos, axis=-1)
    return (targets >= 0) & (d <= params.nav_range)


def _occ_inputs(landmarks, params: NavParams):
    """``(occluder table, occlusion flag)`` for :func:`_sense` (a dummy table without)."""
    if params.occluder_radius > 0:
        tab = _sim.occluder_table(np.asarray(landmarks), params.nav_range,
                                  params.occluder_radius)
        return jnp.asarray(tab), True
    return jnp.full((1, 1), -1, jnp.int32), False


class _Trial(NamedTuple):
    """One trial's inputs (a lane of the pool loads them when it takes the trial)."""

    key: jax.Array          # the noise key, ``fold_in(trial key, 1)``
    start: jax.Array
    goal: jax.Array
    path: jax.Array         # [L]
    n: jax.Array
    budget: jax.Array
    start_pose: jax.Array   # [3]


def _noisy(landmarks, sigma, key_noise, lm_id, step):
    """A noisy measurement ``[2]`` of landmark ``lm_id`` at step ``step`` (std ``sigma``;
    the same key, landmark and step always give the same draw)."""
    z = jax.random.normal(jax.random.fold_in(jax.random.fold_in(key_noise, step), lm_id),
                          (2,), landmarks.dtype)
    return landmarks[lm_id] + sigma * z


def _init(t: _Trial, landmarks, params: NavParams, tau: int, record: int) -> _S:
    """The state a trial starts in: circling the start landmark (measured) at R′."""
    fdt = landmarks.dtype
    start, start_pose = t.start, t.start_pose
    s_xy = _noisy(landmarks, params.sigma, t.key, start, 1 << 30)
    pos0 = start_pose[:2]
    return _S(pose=start_pose, length=jnp.zeros((), fdt), steps=jnp.int32(0),
              k=jnp.int32(-1), refs=jnp.full(2, -1, jnp.int32),
              refs_xy=jnp.zeros((2, 2), fdt), phase=jnp.int32(CIRCLE),
              seq=jnp.zeros(tau, jnp.int32), c=jnp.int32(0), e=start.astype(jnp.int32),
              e_xy=s_xy,
              motion=tr.circle_motion(pos0, s_xy, params.circle_margin * params.nav_range),
              status=jnp.int32(RUNNING), hops=jnp.int32(0),
              trace=jnp.full((record, 2), jnp.nan, fdt))


def _plan_step(s: _S, pos, goal, path, nxt, goal_stage, ids, plans, params: NavParams) -> _S:
    """PLAN (step 1 of P §4.3.1): choose the link and the QSR command sequence; the state
    that starts the first quarter arc, or (a reference that is the link) the circle."""
    quad = calculi.get("quadrant")
    cur = path[jnp.maximum(s.k, 0)]
    lc = ids[cur]
    in_next = (lc[:, None] == ids[jnp.maximum(nxt, 0)][None, :]).any(1)
    not_ref = (lc != s.refs[0]) & (lc != s.refs[1])
    cand = in_next & not_ref
    link_tr = jnp.where(jnp.any(cand), lc[jnp.argmax(cand)], lc[jnp.argmax(in_next)])
    link = jnp.where(goal_stage, goal, link_tr).astype(jnp.int32)
    # circle-only strategy (Prop. 2): circle a reference that is also in L_j (or any
    # reference at the goal: the goal lies within 2R of it)
    ref_in = jnp.where(goal_stage, jnp.array([True, True]),
                       (s.refs[:, None] == ids[jnp.maximum(nxt, 0)][None, :]).any(1))
    use_circle = (params.circle_only > 0.5) & jnp.any(ref_in)
    link = jnp.where(use_circle, s.refs[jnp.argmax(ref_in)], link).astype(jnp.int32)
    link_is_ref = (link == s.refs[0]) | (link == s.refs[1])
    order = ordering_index(lc, s.refs[0], s.refs[1])
    a_xy, b_xy = s.refs_xy[0], s.refs_xy[1]
    q_r = jnp.maximum(quad.classify(a_xy, b_xy, pos), 0).astype(jnp.int32)
    seq = plans[cur, order, q_r]          # the exact POMDP plan for this entry state
    centre, lo = tr.quadrant_wedge(a_xy, b_xy, seq[0])
    ref_pos = jnp.where(link == s.refs[0], a_xy, b_xy)
    s_plan_arc = s._replace(phase=jnp.int32(ARC), seq=seq.astype(jnp.int32),
                            c=jnp.int32(0), e=link,
                            motion=tr.arc_motion(pos, centre, params.map_range, lo))
    s_plan_circ = s._replace(phase=jnp.int32(CIRCLE), e=link, e_xy=ref_pos,
                             motion=tr.circle_motion(
                                 pos, ref_pos, params.circle_margin * params.nav_range))
    return where_tree(link_is_ref, s_plan_circ, s_plan_arc)


def _move_step(s: _S, pos, goal_stage, tau: int, params: NavParams) -> tuple[_S, _S]:
    """``(moved, look)``: one rover step along the current motion (an arc that ends: the
    next command, a LOOK in the epoch model, or failure; a circle that ends: failure), and
    the LOOK decision of the epoch model (nothing seen from the arc's end: next command or
    failure)."""
    dt = 1.0
    v_max, w_max = params.ds, params.turn_per_step
    fdt = s.length.dtype
    epochs = params.sense_epochs > 0.5
    u, mot = tr.motion_control(s.pose, s.motion, v_max, w_max, dt)
    new_pose = _sim.step(_sim.RoverState(s.pose, jnp.zeros((), fdt)), u,
                         _sim.RoverParams(dt=dt, max_speed=v_max, max_turn_rate=w_max)).pose
    mot, finished = tr.advance(mot, u, dt)
    s_move = s._replace(pose=new_pose, length=s.length + jnp.abs(u[0]) * dt, motion=mot)
    # arc finished without the link: next command or failure
    c2 = s.c + 1
    more = c2 < tau
    a_xy, b_xy = s.refs_xy[0], s.refs_xy[1]
    centre2, lo2 = tr.quadrant_wedge(a_xy, b_xy, s.seq[jnp.minimum(c2, tau - 1)])
    s_next_cmd = s_move._replace(c=c2, motion=tr.arc_motion(new_pose[:2], centre2,
                                                            params.map_range, lo2))
    arc_fail = jnp.where(goal_stage, GOAL_NOT_FOUND, LINK_NOT_FOUND)
    circ_fail = jnp.where(s.k < 0, START_NOT_LOCALIZED, REFS_NOT_FOUND)
    s_arc_end = where_tree(more, s_next_cmd, s_move._replace(status=jnp.int32(arc_fail)))
    s_circ_end = s_move._replace(status=jnp.int32(circ_fail))
    # epoch model: an arc that ends is followed by one look from its end point
    s_arc_end = where_tree(epochs, s_move._replace(phase=jnp.int32(LOOK)), s_arc_end)
    s_moved = where_tree(finished & (s.phase == ARC), s_arc_end,
                         where_tree(finished & (s.phase == CIRCLE), s_circ_end, s_move))
    # LOOK (epoch model): nothing seen from the arc's end: next command or failure
    s_look = where_tree(more, s._replace(c=c2, phase=jnp.int32(ARC),
                                         motion=tr.arc_motion(pos, centre2,
                                                              params.map_range, lo2)),
                        s._replace(status=jnp.int32(arc_fail)))
    return s_moved, s_look


def _machine(landmarks, ids, plans, model, params: NavParams, occ_tab, occlusion: bool,
             record: int = 0):
    """``(init, body)`` of one trial's state machine: ``init(t) -> _S`` and
    ``body(s, t) -> _S`` (one sensing + decision + rover step); a trial is ``body`` applied
    from ``init(t)`` while ``status == RUNNING``."""
    tau = int(model.horizon)

    def noisy(key_noise, lm_id, step):
        return _noisy(landmarks, params.sigma, key_noise, lm_id, step)

    def init(t: _Trial) -> _S:
        return _init(t, landmarks, params, tau, record)

    def body(s: _S, t: _Trial) -> _S:
        key_noise, goal, path, n, budget = t.key, t.goal, t.path, t.n, t.budget
        pos = s.pose[:2]
        goal_stage = s.k == n - 1
        nxt = path[jnp.clip(s.k + 1, 0, path.shape[0] - 1)]
        members = jnp.where(goal_stage, -1, ids[jnp.maximum(nxt, 0)])       # [3]
        targets = jnp.concatenate([members, jnp.stack([goal, s.e])])
        epochs = params.sense_epochs > 0.5
        look = ~epochs | (s.phase != ARC)      # epoch model: blind while driving an arc
        vis = _sense(pos, landmarks, targets, occ_tab, params, occlusion) & look
        vm, g_vis, e_vis = vis[:3], vis[3], vis[4]
        # --- event A: goal reached
        done_goal = goal_stage & g_vis
        # --- event B: transition into nxt (two of its landmarks in view at once)
        n_vis = jnp.sum(vm)
        trans = ~goal_stage & (n_vis >= 2)
        e_in = vm & (members == s.e)
        first = jnp.where(jnp.any(e_in), jnp.argmax(e_in), jnp.argmax(vm))
        other_mask = vm & (jnp.arange(3) != first)
        second = jnp.argmax(other_mask)
        new_refs = jnp.stack([members[first], members[second]]).astype(jnp.int32)
        new_xy = jnp.stack([noisy(key_noise, new_refs[0], s.steps),
                            noisy(key_noise, new_refs[1], s.steps)])
        s_trans = s._replace(k=s.k + 1, refs=new_refs, refs_xy=new_xy, phase=jnp.int32(PLAN),
                             hops=s.hops + 1)
        # --- event C: link seen during the QSR search -> circle of radius R' about it
        see_e = ((s.phase == ARC) | (s.phase == LOOK)) & e_vis
        e_xy = noisy(key_noise, s.e, s.steps)
        s_circ = s._replace(phase=jnp.int32(CIRCLE), e_xy=e_xy,
                            motion=tr.circle_motion(pos, e_xy,
                                                    params.circle_margin * params.nav_range))
        # --- PLAN, MOVE and LOOK
        s_plan = _plan_step(s, pos, goal, path, nxt, goal_stage, ids, plans, params)
        s_moved, s_look = _move_step(s, pos, goal_stage, tau, params)
        # --- priority: goal > transition > link seen > plan > move
        out = where_tree(done_goal, s._replace(status=jnp.int32(SUCCESS)),
                   where_tree(trans, s_trans,
                        where_tree(see_e, s_circ,
                             where_tree(s.phase == PLAN, s_plan,
                                        where_tree(s.phase == LOOK, s_look, s_moved)))))
        out = out._replace(steps=s.steps + 1)
        if record:
            out = out._replace(trace=out.trace.at[jnp.minimum(s.steps, record - 1)].set(
                jnp.where(s.steps < record, out.pose[:2], out.trace[record - 1])))
        over = (out.status == RUNNING) & (out.steps >= budget)
        return out._replace(status=jnp.where(over, BUDGET, out.status))

    return init, body


def _result(s: _S) -> NavResult:
    return NavResult(s.status, s.length, s.steps, s.hops, s.k, s.pose, s.refs, s.trace)


def _lane_sel(mask, a, b):
    """Per lane (leading axis) ``mask ? a : b`` over two pytrees of lane arrays."""
    return jax.tree.map(lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)),
                                               x, y), a, b)


def _pool(trials: _Trial, n_valid, init, body, width: int, refill_at: int) -> NavResult:
    """Run the trials ``[Q]`` (the first ``n_valid``) on ``width`` lanes that refill.

    One ``while_loop`` steps every lane (``vmap`` of ``body``); a lane whose trial has ended
    idles until at least ``refill_at`` lanes have ended (or every lane that is still busy has),
    then every ended lane writes its result and takes the next trial of the queue. So no lane
    waits for the slowest trial of a fixed batch; each trial still runs ``init`` then ``body``
    until it ends, exactly as alone (results do not depend on ``width`` or the order).
    """
    q = trials.start.shape[0]
    lanes = jnp.arange(width)

    def load(idx):
        t = jax.tree.map(lambda x: x[idx], trials)
        return t, jax.vmap(init)(t)

    idx0 = jnp.minimum(lanes, q - 1)
    act0 = lanes < n_valid
    t0, s0 = load(idx0)
    s0 = s0._replace(status=jnp.where(act0, s0.status, SUCCESS))       # empty lanes idle
    out0 = jax.tree.map(lambda x: jnp.zeros((q,) + x.shape[1:], x.dtype), _result(s0))

    def step_lane(s, t):
        return where_tree(s.status == RUNNING, body(s, t), s)

    def refill(c):
        t, s, idx, act, nxt, out = c
        fin = act & (s.status != RUNNING)
        dest = jnp.where(fin, idx, q)                                   # q: dropped
        out = jax.tree.map(lambda o, r: o.at[dest].set(r, mode="drop"), out, _result(s))
        new = nxt + jnp.cumsum(fin) - 1
        has = fin & (new < n_valid)
        tn, sn = load(jnp.minimum(new, q - 1))
        t, s = _lane_sel(has, tn, t), _lane_sel(has, sn, s)
        return (t, s, jnp.where(has, new, idx), (act & ~fin) | has,
                nxt + jnp.sum(has).astype(nxt.dtype), out)

    def loop(c):
        t, s, idx, act, nxt, out = c
        s = jax.vmap(step_lane)(s, t)
        fin = act & (s.status != RUNNING)
        nfin = jnp.sum(fin)
        go = (nfin >= refill_at) | ((nfin > 0) & (nfin == jnp.sum(act)))
        return jax.lax.cond(go, refill, lambda c: c, (t, s, idx, act, nxt, out))

    c = jax.lax.while_loop(lambda c: jnp.any(c[3]), loop,
                           (t0, s0, idx0, act0, jnp.minimum(n_valid, width).astype(jnp.int32),
                            out0))
    return c[5]


@partial(jax.jit, static_argnames=("horizon", "record", "occlusion", "width"))
def _navigate(keys, starts, goals, paths, n, budget, start_poses, n_valid, landmarks, ids,
              plans, feasible, detect, params, occ_tab, *, horizon, occlusion, width,
              record=0):
    model = _pomdp.SearchPOMDP(feasible, detect, 1.0, horizon)
    init, body = _machine(landmarks, ids, plans, model, params, occ_tab, occlusion, record)
    noise_keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    trials = _Trial(noise_keys, starts, goals, paths, n, budget, start_poses)
    return _pool(trials, n_valid, init, body, width, max(1, width // 8))


def _check_params(params: NavParams) -> None:
    """Ranges and steps of :class:`NavParams` (one message per argument, naming the value)."""
    validate(positive={"params.nav_range (R')": params.nav_range,
                       "params.map_range (R)": params.map_range, "params.ds": params.ds,
                       "params.turn_per_step": params.turn_per_step,
                       "params.circle_margin": params.circle_margin},
             nonnegative={"params.occluder_radius": params.occluder_radius,
                          "params.sigma": params.sigma, "params.start_offset":
                          params.start_offset})
    for name in ("circle_only", "sense_epochs"):
        if getattr(params, name) not in (0.0, 1.0):
            raise ValueError(f"params.{name} must be 0 or 1, got {getattr(params, name)!r}")


def start_poses(keys, landmarks, starts, offset):
    """Start poses ``[B, 3]``: the start landmark + ``offset`` in a seeded direction, seeded
    heading (P §4.4.1 start landmark; docs/qlink.md §Q20)."""
    def one(k, s):
        a, h = jax.random.uniform(jax.random.fold_in(k, 2), (2,), minval=-jnp.pi,
                                  maxval=jnp.pi)
        p = landmarks[s] + offset * jnp.stack([jnp.cos(a), jnp.sin(a)])
        return jnp.concatenate([p, h[None]])
    return jax.vmap(one)(keys, jnp.asarray(starts))


def navigate(trials: Trials, world: NavMap, params: NavParams,
             model: _pomdp.SearchPOMDP | None = None, *, chunk: int = 64, record: int = 0,
             compile_only: bool = False) -> NavResult:
    """Drive B planned Link Graph paths on the simulated rover (P §4.3, §4.4.1).

    One ``while_loop`` per trial (the state machine of this module's docstring) on a pool
    of ``chunk`` lanes.

    Args:
        trials: :class:`Trials` — keys ``[B]`` (first), starts, goals, ``paths [B, L]``
            (element indices, ``-1`` padded, e.g. from
            :func:`pqrm_jax.qlink.linkgraph.plan_pairs`), ``n_elements [B]`` ``|P|`` (≥ 1),
            optional start poses ``[B, 3]`` and step budgets ``[B]``.
        world: :class:`NavMap` — landmarks ``[N, 2]`` (true positions), the map elements the
            paths refer to, optional :func:`qsr_plans` table.
        params: :class:`NavParams`.
        model: the search POMDP (``p_move = 1``); default :func:`pomdp.search_model`.
        chunk: lanes of the pool (``vmap`` width; a lane takes the next trial as soon as its
            own ends); results do not depend on it.
        record: keep the first ``record`` positions of every trial (for plots).
        compile_only: return the pool program compiled for these inputs instead of running
            it (its XLA memory analysis sizes ``chunk``; nothing is driven).

    Returns:
        :class:`NavResult` of ``[B]`` arrays (``pose [B, 3]``, ``refs [B, 2]``,
        ``trace [B, record, 2]``), in the order of ``trials``; with ``compile_only`` the
        compiled program instead.

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) NaN/inf or coincident
            landmarks, bad ids, malformed elements, NaN/inf poses, a range or step that is
            not positive and finite, a trial without a path (``|P| < 1``), a path entry that
            is not an element.
    """
    keys, starts, goals, paths, n_elements, poses, budget = trials
    landmarks, elements, plans = world.landmarks, world.elements, world.plans
    if paths is None or n_elements is None:
        raise ValueError("navigate drives planned trials: trials.paths and trials.n_elements "
                         "are needed (navigate_pairs plans them)")
    model = model or _pomdp.search_model(horizon=4)
    if model.p_move != 1.0:
        raise ValueError("the executive needs p_move = 1 (the open-loop plan is exact then)")
    _check_params(params)
    validate(landmarks=np.asarray(landmarks), elements=elements,
             landmark_ids={"starts": starts, "goals": goals})
    landmarks = jnp.asarray(landmarks)
    n_elements = np.asarray(n_elements)
    paths = np.asarray(paths)
    validate(paths=(paths, n_elements, np.asarray(elements.ids).shape[0],
                    len(np.ravel(starts))))
    n_elements = n_elements.astype(np.int32)
    keys = jnp.asarray(keys)
    if poses is None:
        poses = start_poses(keys, landmarks, starts, params.start_offset)
    validate(finite={"poses": np.asarray(poses)})
    poses = jnp.asarray(poses, landmarks.dtype)
    budget = step_budget(n_elements, params) if budget is None else np.asarray(budget)
    p = NavParams(*(float(x) for x in params))
    paths = np.asarray(paths, np.int32)
    width = max(16, -(-paths.shape[1] // 16) * 16)        # fixed widths: fewer recompiles
    paths = np.pad(paths, ((0, 0), (0, width - paths.shape[1])), constant_values=-1)
    # longest plans first, so the pool's last lanes to finish hold short trials; the order is
    # undone below, and no result depends on it
    order = np.argsort(-n_elements, kind="stable")
    inv = np.argsort(order)
    b = len(order)
    q = max(4 * chunk, 1 << int(np.ceil(np.log2(max(b, 1)))))   # queue: few compiles
    pad = np.concatenate([order, np.full(q - b, order[0] if b else 0)])
    args = [keys, jnp.asarray(starts, jnp.int32), jnp.asarray(goals, jnp.int32),
            jnp.asarray(paths), jnp.asarray(n_elements), jnp.asarray(budget, jnp.int32), poses]
    args = _take(args, jnp.asarray(pad, jnp.int32))
    if plans is None:
        plans = qsr_plans(elements, model)
    occ_tab, occlusion = _occ_inputs(landmarks, p)
    call = (*args, jnp.int32(b), landmarks, jnp.asarray(elements.ids), jnp.asarray(plans),
            model.feasible, model.detect, p, occ_tab)
    kw = dict(horizon=int(model.horizon), occlusion=occlusion, width=int(chunk),
              record=int(record))
    if compile_only:
        return _navigate.lower(*call, **kw).compile()
    return _take(_navigate(*call, **kw), jnp.asarray(inv, jnp.int32))


@jax.jit
def _take(tree, idx):
    """Every leaf's rows ``idx`` (one compiled gather per tree layout, not one per leaf)."""
    return jax.tree.map(lambda x: x[idx], tree)


def _chunked(fn, args, chunk):
    """Run ``fn`` over fixed-size chunks of the leading axis (the last one padded), so every
    batch size reuses one compiled program and results do not depend on the batch."""
    b = args[0].shape[0]
    outs = []
    for i in range(0, b, chunk):
        part = [a[i:i + chunk] for a in args]
        m = part[0].shape[0]
        if m < chunk:
            part = [jnp.concatenate([x, jnp.repeat(x[:1], chunk - m, axis=0)]) for x in part]
        outs.append(jax.tree.map(lambda x, m=m: x[:m], fn(*part)))
    return jax.tree.map(lambda *x: jnp.concatenate(x), *outs)


def replan_inputs(result: NavResult, landmarks, elements: MapElements, graph, goals, paths,
                  params: NavParams):
    """Contingency re-planning (P §4.4.2): for each failed trial whose final view holds two
    landmarks of some element, drop the failed edge and plan from those elements to the goal.

    Returns ``(trial indices [M], paths [M, L'], n_elements [M])`` for the trials that can
    continue (host side, networkx on the Link Graph with the failed edge removed); resume them
    with :func:`navigate` (``Trials(..., poses=result.pose[idx])``; the start landmark is any
    visible reference of the new first element).
    """
    import networkx as nx

    from .linkgraph import to_networkx

    ids = np.asarray(elements.ids)
    status, k = np.asarray(result.status), np.asarray(result.k)
    paths = np.asarray(paths)
    base = to_networkx(graph)
    out_idx, out_paths = [], []
    for t in np.flatnonzero((status == LINK_NOT_FOUND) | (status == REFS_NOT_FOUND)):
        pos = jnp.asarray(result.pose[t, :2])
        vis = np.asarray(_sim.disc_visibility(pos, landmarks, params.nav_range,
                                              params.occluder_radius))
        srcs = np.flatnonzero(vis[ids].sum(1) >= 2)
        if srcs.size == 0:
            continue   # "cannot re-plan ... insufficient environmental features in view"
        g = base.copy()
        cur, nxt = paths[t, max(k[t], 0)], paths[t, k[t] + 1]
        if g.has_edge(cur, nxt):
            g.remove_edge(cur, nxt)
        goal_el = set(np.flatnonzero((ids == goals[t]).any(1)).tolist())
        try:
            _, p = nx.multi_source_dijkstra(g, set(srcs.tolist()),
                                            target=None, weight="weight")
        except nx.NetworkXNoPath:
            continue
        reach = [v for v in goal_el if v in p]
        if not reach:
            continue
        best = min(reach, key=lambda v: len(p[v]))
        out_idx.append(int(t))
        out_paths.append(p[best])
    width = max([len(p) for p in out_paths], default=1)
    arr = np.full((len(out_paths), width), -1, np.int32)
    for i, p in enumerate(out_paths):
        arr[i, :len(p)] = p
    return np.array(out_idx, np.int64), arr, np.array([len(p) for p in out_paths], np.int32)


def start_tables(elements: MapElements) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-landmark tables for the initial localisation (P §4.3.2) of :func:`localize`.

    Args:
        elements: the map elements (``ids [E, 3]`` over N_L landmarks).

    Returns:
        ``(elements [N_L, C], members [N_L, K], membership [N_L, C, K])``: each landmark's
        elements, the members of those elements and which member belongs to which element
        (``-1`` / ``False`` padded) — what :func:`localize` needs to recognise a reference
        pair of any element holding the start landmark.
    """
    ids = np.asarray(elements.ids)
    n = elements.num_landmarks
    els = [np.flatnonzero((ids == lm).any(1)) for lm in range(n)]
    c = max(1, max(len(e) for e in els))
    nb = [np.unique(ids[e]) if len(e) else np.array([lm]) for lm, e in enumerate(els)]
    k = max(len(x) for x in nb)
    cand = np.full((n, c), -1, np.int32)
    nbrs = np.full((n, k), -1, np.int32)
    memb = np.zeros((n, c, k), bool)
    for lm in range(n):
        cand[lm, :len(els[lm])] = els[lm]
        nbrs[lm, :len(nb[lm])] = nb[lm]
        for i, e in enumerate(els[lm]):
            memb[lm, i, :len(nb[lm])] = np.isin(nb[lm], ids[e])
    return cand, nbrs, memb


def _localize_one(key, start, pose0, nbrs, memb, budget, landmarks, params: NavParams, occ_tab,
                  occlusion: bool):
    fdt = landmarks.dtype
    z = jax.random.normal(jax.random.fold_in(key, 3), (2,), fdt)
    s_xy = landmarks[start] + params.sigma * z
    mot0 = tr.circle_motion(pose0[:2], s_xy, params.circle_margin * params.nav_range)
    rp = _sim.RoverParams(dt=1.0, max_speed=params.ds, max_turn_rate=params.turn_per_step)

    def seen(pose):
        vis = _sense(pose[:2], landmarks, nbrs, occ_tab, params, occlusion)
        return (memb.astype(fdt) @ vis.astype(fdt)) >= 2

    def body(c):
        pose, length, steps, status, mot = c
        u, mot = tr.motion_control(pose, mot, params.ds, params.turn_per_step, 1.0)
        pose = _sim.step(_sim.RoverState(pose, jnp.zeros((), fdt)), u, rp).pose
        mot, finished = tr.advance(mot, u, 1.0)
        ok = jnp.any(seen(pose))
        status = jnp.where(ok, SUCCESS, jnp.where(finished, START_NOT_LOCALIZED,
                                                   jnp.where(steps + 1 >= budget, BUDGET,
                                                             RUNNING)))
        return pose, length + jnp.abs(u[0]), steps + 1, status.astype(jnp.int32), mot

    st0 = jnp.where(jnp.any(seen(pose0)), SUCCESS, RUNNING).astype(jnp.int32)
    pose, length, steps, status, _ = jax.lax.while_loop(
        lambda c: c[3] == RUNNING, body,
        (pose0, jnp.zeros((), fdt), jnp.int32(0), st0, mot0))
    return pose, length, steps, status, seen(pose)


@partial(jax.jit, static_argnames=("occlusion",))
def _localize(keys, starts, poses, nbrs, memb, budget, landmarks, params, occ_tab, *,
              occlusion):
    return jax.vmap(lambda k, s, p, nb, m, b: _localize_one(k, s, p, nb, m, b, landmarks,
                                                            params, occ_tab, occlusion))(
        keys, starts, poses, nbrs, memb, budget)


def localize(keys, landmarks, starts, poses, tables, params: NavParams, budget=None,
             chunk: int = 64):
    """Initial localisation (P §4.3.2): from the start pose, circle the start landmark at R′
    until two landmarks of an element holding it are in view at once.

    Returns ``(pose [B, 3], length [B], steps [B], status [B], in_view [B, C])`` where
    ``in_view`` marks the start landmark's elements (``tables[0][starts]``) with a reference
    pair in view.
    """
    cand, nbrs, memb = tables
    starts = np.asarray(starts)
    if budget is None:
        budget = np.full(starts.shape, int(np.ceil(4 * (2 * np.pi + 1) * params.nav_range
                                                   / params.ds)) + 256, np.int32)
    p = NavParams(*(float(x) for x in params))
    lm = jnp.asarray(landmarks)
    args = [jnp.asarray(keys), jnp.asarray(starts, jnp.int32), jnp.asarray(poses),
            jnp.asarray(nbrs[starts]), jnp.asarray(memb[starts]), jnp.asarray(budget, jnp.int32)]
    occ_tab, occlusion = _occ_inputs(lm, p)
    return _chunked(lambda *a: _localize(*a, lm, p, occ_tab, occlusion=occlusion), args, chunk)


class PairResult(NamedTuple):
    """One row per start/goal trial (arrays ``[B]``).

    reachable: a Link Graph path exists from the localised start (False: reported as
        unreachable, not as a controller failure). status: :data:`FAILURE_REASONS` code
        (``SUCCESS`` or the failure; unreachable trials keep the localisation status).
    n_elements: ``|P|`` of the driven plan (0 if none). length: total distance driven.
    nav: the :class:`NavResult` of the driven trials (``[B]``, meaningless where not reachable).
    """

    reachable: np.ndarray
    status: np.ndarray
    n_elements: np.ndarray
    length: np.ndarray
    nav: NavResult


def navigate_pairs(trials: Trials, world: NavMap, params: NavParams,
                   model: _pomdp.SearchPOMDP | None = None, *, chunk: int = 64,
                   record: int = 0) -> PairResult:
    """Localise, plan from the elements in view, and drive B start/goal trials (P §4.3, §4.4.1).

    The whole planned path is driven on any Link Graph (unit, −log p, zero costs): plans
    follow the successors recorded in ``world.to_go`` and the path buffer is sized from its
    hop counts. A trial localised in the start element but with no path from the elements in
    view gets the status ``UNREACHABLE``.

    Args:
        trials: :class:`Trials` — keys ``[B]`` (first), starts and goals ``[B]`` landmark ids
            (paths, poses and budgets are not used: the trial plans from where it localises).
        world: :class:`NavMap` with the Link Graph, its goal table, goal rows and start tables
            (:func:`nav_map`) and optionally the :func:`qsr_plans` table (pass it when driving
            many batches on one map).
        params: :class:`NavParams`; model: the search POMDP; chunk: lanes per compiled batch.
        record: keep the first ``record`` positions of every trial (for plots).

    Returns:
        :class:`PairResult` of ``[B]`` arrays: ``reachable``, ``status``
        (:data:`FAILURE_REASONS`), ``n_elements`` ``|P|``, ``length`` (distance driven,
        localisation included) and the :class:`NavResult` ``nav`` of the drives.

    Raises:
        ValueError: (:func:`~pqrm_jax.qlink.checks.validate`) as :func:`navigate`, and a goal
            without a row of ``world.to_go``.

    >>> import jax, numpy as np
    >>> from pqrm_jax import qlink
    >>> lm = jax.numpy.array([[0., 0.], [10., 0.], [5., 6.], [14., 7.], [20., 0.]])
    >>> el = qlink.exact_elements(lm, np.array([[0, 1, 2], [1, 2, 3], [1, 3, 4]]))
    >>> world = qlink.nav_map(lm, el, qlink.link_graph(el, 2), qlink.search_model())
    >>> keys = jax.random.split(jax.random.key(0), 2)
    >>> r = navigate_pairs(Trials(keys, [0, 4], [4, 0]), world,
    ...                    NavParams(map_range=20.0, nav_range=20.0), chunk=2)
    >>> [FAILURE_REASONS[int(s)] for s in r.status], r.n_elements.tolist()
    (['success', 'success'], [3, 3])
    """
    keys, starts, goals = trials.keys, trials.starts, trials.goals
    landmarks, elements, graph, to_go, goal_row, tables, plans = world
    from .linkgraph import GoalTable, plan_from

    if not isinstance(to_go, GoalTable):
        raise ValueError("world.to_go must be the GoalTable of linkgraph.goal_distances, got "
                         f"{type(to_go).__name__}")
    _check_params(params)
    got = validate(landmarks=np.asarray(landmarks), elements=elements,
                   landmark_ids={"starts": starts, "goals": goals})
    starts, goals = got["starts"].astype(np.int32), got["goals"].astype(np.int32)
    if starts.shape != goals.shape or starts.ndim != 1:
        raise ValueError(f"starts and goals must be [B] of one length, got {starts.shape} "
                         f"and {goals.shape}")
    goal_row = np.asarray(goal_row)
    if goal_row.shape != (elements.num_landmarks,):
        raise ValueError(f"goal_row must have shape ({elements.num_landmarks},), got "
                         f"{goal_row.shape}")
    rows = goal_row[goals]
    if np.any((rows < 0) | (rows >= np.shape(to_go.cost)[0])):
        g = int(goals[(rows < 0) | (rows >= np.shape(to_go.cost)[0])][0])
        raise ValueError(f"goal_row[{g}] = {int(goal_row[g])}: to_go has no row for goal {g}")
    cand = tables[0]
    keys = jnp.asarray(keys)
    poses = start_poses(keys, jnp.asarray(landmarks), starts, params.start_offset)
    validate(finite={"start poses": np.asarray(poses)})
    pose1, len1, _, st1, in_view = localize(keys, landmarks, starts, poses, tables, params,
                                            chunk=chunk)
    cands = np.where(np.asarray(in_view), cand[starts], -1)
    # path buffer from hop counts (the longest path of the table: one width per world)
    max_len = int(np.max(np.asarray(to_go.hops), initial=0)) + 1
    plan = plan_from(graph, to_go, rows, cands, max_len)
    st1 = np.asarray(st1)
    reach = np.asarray(plan.reachable) & (st1 == SUCCESS)
    n = np.where(reach, np.asarray(plan.n_elements), 1)
    # a trial without a plan rides along on a one-element placeholder (its start element);
    # its result is masked below and no other trial depends on it
    path = np.asarray(plan.path).copy()
    path[~reach, 0] = cand[starts[~reach], 0]
    res = navigate(Trials(jax.vmap(lambda k: jax.random.fold_in(k, 7))(keys), starts, goals,
                          path, n, pose1), world, params, model, chunk=chunk, record=record)
    status = np.where(reach, np.asarray(res.status), np.where(st1 == SUCCESS, UNREACHABLE, st1))
    length = np.asarray(len1) + np.where(reach, np.asarray(res.length), 0.0)
    return PairResult(reach, status, np.where(reach, n, 0), length, res)
