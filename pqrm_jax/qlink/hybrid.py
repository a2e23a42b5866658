"""Q-Link on a hybrid map: LR point triplets and wall–wall–point bands (P §4.4.2).

Padgett's in-vivo map mixes two ternary QSRs (P §4.4.2): the flip-flop (left/right, ``lr``) on
point-landmark triplets, and a three-state calculus on *two oriented, extended landmarks and one
point landmark* — "in front", "between", "behind" — whose references are the two extended
landmarks only. Here the extended landmarks are two facing wall segments; with A, B their
midpoints and the walls perpendicular to AB the three states are exactly the three bands of the
Double Cross (β > 1, 0 < β < 1, β < 0 along AB), so :func:`bands_calculus` is a merge of
``double_cross`` (docs/qlink.md §invivo).

* :func:`hybrid_elements` maps a run: a wall is seen when any point of it is in range
  (:func:`pqrm_jax.sim.segment_visibility`) and measured at its midpoint; every co-observed
  triplet is an element; a triplet holding both walls is a **bands** element (``kind`` 1),
  any other an **LR** element (``kind`` 0; a wall in it acts as a point at its midpoint —
  decision, so that bands and point elements can share two landmarks and link at β = 2).
* :func:`hybrid_costs` gives −log p edge costs (P eq. 4.4) from the search POMDP of each kind.
* :func:`drive` is the in-vivo executive: at every stop a 360° scan (each landmark missed
  with probability ``p_miss``); the QSR commands drive to the centre of the reference segment
  and sweep the commanded state; a transition needs two landmarks of the next element in view
  at once (both walls for a bands element); at the goal element, a drive to the centroid of
  its landmarks. Sensing happens at stops only, so a trial is a short ``lax.while_loop`` over
  stops (straight drives between them), ``vmap``ped over trials.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi, pqrm
from .. import sim as _sim
from . import pomdp as _pomdp
from .checks import validate
from .elements import ORDERINGS, MapElements, co_observed_triplets, fuse, ordering_index
from .navigate import (
    BUDGET,
    COLLISION,
    GOAL_NOT_FOUND,
    LINK_NOT_FOUND,
    REFS_NOT_FOUND,
    RUNNING,
    SUCCESS,
    where_tree,
)

__all__ = ["bands_calculus", "HybridMap", "hybrid_elements", "search_models", "hybrid_costs",
           "HybridParams", "HybridResult", "drive", "LR", "BANDS", "reference_rule",
           "qsr_tables", "uniform_sequence", "landmark_distances", "visible_references",
           "wall_contact"]

LR, BANDS = 0, 1
ENTER, SEARCH = 0, 1


def bands_calculus() -> calculi.Calculus:
    """Front / between / behind along AB: the three bands of the Double Cross merged.

    >>> import jax.numpy as jnp
    >>> b = bands_calculus()
    >>> [b.states[int(b.classify(jnp.array([0., 0.]), jnp.array([10., 0.]), jnp.array([x, 3.])))]
    ...  for x in (-5., 5., 15.)]
    ['behind', 'between', 'front']
    """
    return calculi.get("double_cross").merge(
        "bands", {"front": ["lf", "rf"], "between": ["lm", "rm"], "behind": ["lb", "rb"]},
        "front of B / between / behind A (3), the in-vivo extended-landmark QSR (P §4.4.2)")


class HybridMap(NamedTuple):
    """A hybrid qualitative map.

    elements: ids ``[E, 3]`` sorted; probs ``[E, 6, 3]`` (LR rows use states 0–1, state 2 is 0).
    kind: ``[E]`` int, :data:`LR` or :data:`BANDS`.
    walls: ``(2,)`` the landmark ids of the two walls (the last two ids).
    """

    elements: MapElements
    kind: np.ndarray
    walls: tuple[int, int]


def hybrid_elements(key: jax.Array, points, walls, poses, max_range: float, sigma: float,
                    num_samples: int = 64, max_obs: int = 6, floor: float = 1e-3,
                    max_side: float | None = None) -> tuple[HybridMap, jax.Array, np.ndarray]:
    """Map a hybrid world from a mapping run (P §2.2, §4.4.2).

    Args:
        key: PRNG key. points: ``[N, 2]`` point landmarks. walls: ``[2, 2, 2]`` segments.
        poses: ``[P, 3]`` mapping poses. max_range, sigma: the sensor (P: 60 m, σ = 0.7 m).
        num_samples, max_obs, floor: as :func:`pqrm_jax.qlink.from_mapping_run`.
        max_side: keep only triplets whose measured pairwise distances (first
            co-observation) are at most this (Assumption 3 of P §4.3.4 with ``max_range``);
            ``None`` keeps every co-observed triplet.

    Returns:
        ``(map, landmarks [N + 2, 2] (walls at their midpoints), visible [P, N + 2])``.
    """
    if np.shape(walls) != (2, 2, 2):
        raise ValueError(f"walls must have shape (2, 2, 2), got {np.shape(walls)}")
    validate(landmarks=np.concatenate([np.asarray(points, np.float64),
                                       np.asarray(walls, np.float64).mean(1)]),
             landmarks_name="points and wall midpoints",
             finite={"walls": np.asarray(walls), "poses": np.asarray(poses)},
             positive={"max_range": max_range, "num_samples": num_samples,
                       "max_obs": max_obs},
             nonnegative={"sigma": sigma, "floor": floor})
    if max_side is not None:
        validate(positive={"max_side": max_side})
    points, walls = jnp.asarray(points), jnp.asarray(walls)
    n = points.shape[0]
    lm = jnp.concatenate([points, walls.mean(1)])
    k_obs, k_map = jax.random.split(key)
    sensor = _sim.SensorParams(max_range=float(max_range), sigma=float(sigma))
    obs = jax.vmap(_sim.observe, (0, 0, None, None))(jax.random.split(k_obs, poses.shape[0]),
                                                      poses, lm, sensor)
    wall_vis = jax.vmap(lambda p: _sim.segment_visibility(p[:2], walls, max_range))(poses)
    visible = np.concatenate([np.asarray(obs.visible)[:, :n], np.asarray(wall_vis)], 1)
    ids, which = co_observed_triplets(visible, max_obs)
    if ids.shape[0] == 0:
        raise ValueError("the mapping run observed no landmark triplet: the map would be empty")
    if max_side is not None:
        first = np.asarray(obs.rel)[which[:, 0][:, None], ids]              # [E, 3, 2]
        side = np.linalg.norm(first[:, [0, 0, 1]] - first[:, [1, 2, 2]], axis=-1)
        keep = (side <= max_side).all(1)
        ids, which = ids[keep], which[keep]
        if ids.shape[0] == 0:
            raise ValueError(f"no co-observed triplet has all sides <= {max_side}: empty map")
    kind = np.where((ids == n).any(1) & (ids == n + 1).any(1), BANDS, LR).astype(np.int32)
    trip = jnp.asarray(ids)[:, ORDERINGS]
    pose_idx = jnp.maximum(jnp.asarray(which), 0)
    means = obs.rel[pose_idx[:, :, None, None], trip[:, None, :, :]]       # [E, K, 6, 3, 2]
    e, k = which.shape
    flat = means.reshape(e * k * 6, 3, 2)
    mask = jnp.asarray(which >= 0, jnp.float32)
    out = np.zeros((e, 6, 3), np.float32)
    for kd, calc, q in ((LR, calculi.get("lr"), 2), (BANDS, bands_calculus(), 3)):
        sel = kind == kd
        if not sel.any():
            continue
        rows = flat.reshape(e, k * 6, 3, 2)[sel].reshape(-1, 3, 2)
        p = pqrm.state_probabilities(jax.random.fold_in(k_map, kd), calc, rows, float(sigma),
                                     num_samples).reshape(-1, k, 6, q)
        out[sel, :, :q] = np.asarray(fuse(p, mask[sel], floor))
    el = MapElements(jnp.asarray(ids), jnp.asarray(out), n + 2)
    return HybridMap(el, kind, (n, n + 1)), lm, visible


def search_models(horizon: int = 4, detect_same: float = 0.9):
    """``(lr, bands)`` search POMDPs with direct transitions (P §4.4.2) and one detection
    table for all elements (P L1165): ``detect_same`` when the swept state holds the link,
    0 otherwise (a sweep sees only its own state)."""
    out = []
    for q in (2, 3):
        det = np.eye(q, dtype=np.float32) * detect_same
        out.append(_pomdp.SearchPOMDP(jnp.ones((q, q), bool), jnp.asarray(det), 1.0,
                                      int(horizon)))
    return tuple(out)


def _first(mask):
    """Index of the first True per row (``[K, 3]``) and whether there is one."""
    return np.argmax(mask, 1), mask.any(1)


def reference_rule(ids_i, kind_i, ids_j, walls):
    """``(refs [K, 2], target [K], order [K])`` for transitions M_i → M_j (host side, batched).

    Bands elements use the two walls as references; LR elements the two members other than
    the link (the first shared member that is not a wall, else the first shared one). The
    target is what the robot must find: the first member of L_i ∩ L_j that is not a
    reference, else the first member of L_j not a reference (then it is not in L_i and the
    search belief is uniform); ``target = -1`` when the references already give two members
    of L_j. ``order`` is the :data:`~pqrm_jax.qlink.elements.ORDERINGS` row of
    ``(refs, target)`` in L_i, −1 when the target is not in L_i.

    >>> refs, t, o = reference_rule([[0, 1, 2]], [LR], [[1, 2, 3]], (8, 9))
    >>> refs.tolist(), t.tolist(), o.tolist()
    ([[0, 2]], [1], [1])
    """
    ids_i, ids_j = np.atleast_2d(ids_i), np.atleast_2d(ids_j)
    kind_i = np.asarray(kind_i)
    rows = np.arange(ids_i.shape[0])
    shared = (ids_i[:, :, None] == ids_j[:, None, :]).any(-1)           # [K, 3]
    is_wall = np.isin(ids_i, walls)
    li, has = _first(shared & ~is_wall)
    li = np.where(has, li, _first(shared)[0])
    keep = np.arange(3)[None, :] != li[:, None]
    pos_lr = np.sort(np.where(keep, np.arange(3)[None, :], 9), 1)[:, :2]
    pos = np.where((kind_i == BANDS)[:, None], np.array([[1, 2]]), pos_lr)
    refs = ids_i[rows[:, None], pos]
    is_ref_i = (ids_i[:, :, None] == refs[:, None, :]).any(-1)
    t_i, has_i = _first(shared & ~is_ref_i)
    is_ref_j = (ids_j[:, :, None] == refs[:, None, :]).any(-1)
    t_j, has_j = _first(~is_ref_j)
    target = np.where(has_i, ids_i[rows, t_i], np.where(has_j, ids_j[rows, t_j], -1))
    target = np.where(is_ref_j.sum(1) >= 2, -1, target)
    order = np.asarray(jax.vmap(ordering_index)(ids_i, refs[:, 0], refs[:, 1]))
    order = np.where(has_i & (target >= 0), order, -1)
    return refs.astype(np.int32), target.astype(np.int32), order.astype(np.int32)


def uniform_sequence(q: int, horizon: int) -> np.ndarray:
    """``[τ]`` the sweep order for a target whose state is unknown (uniform belief): the
    states in turn, ``0, 1, …, q − 1, 0, …`` (with one detection table for every state, any
    order of distinct states has the same success probability)."""
    return (np.arange(horizon) % q).astype(np.int32)


def hybrid_costs(hmap: HybridMap, beta: int, models, tables=None):
    """``[E, E]`` −log p edge costs (P eqs. 4.2–4.4), ``inf`` where no edge.

    p is eq. 4.3's success probability of the command sequence the executive would sweep for
    the target of :func:`reference_rule` (1 when no search is needed), clamped to
    [1e-12, 1]: the exact open-loop plan of :func:`qsr_tables` (``tables``, computed when not
    given) for a target in L_i, :func:`uniform_sequence` for one outside it.
    """
    from .linkgraph import shared_counts

    validate(elements=hmap.elements, elements_name="hmap.elements", beta=beta)
    ids = np.asarray(hmap.elements.ids)
    probs = np.asarray(hmap.elements.probs)
    tables = qsr_tables(hmap, models) if tables is None else tables
    adj = shared_counts(hmap.elements) >= beta
    np.fill_diagonal(adj, False)
    src, dst = np.nonzero(adj)
    cost = np.full(adj.shape, np.inf)
    for kd in (LR, BANDS):
        m = models[kd]
        q, tau = m.detect.shape[0], int(m.horizon)
        sel = np.flatnonzero(hmap.kind[src] == kd)
        if sel.size == 0:
            continue
        _, t, o = reference_rule(ids[src[sel]], hmap.kind[src[sel]], ids[dst[sel]],
                                 hmap.walls)
        b = np.where((o >= 0)[:, None], probs[src[sel], np.maximum(o, 0), :q], 1.0 / q)
        b = b / np.maximum(b.sum(-1, keepdims=True), 1e-30)
        seq = np.where((o >= 0)[:, None], np.asarray(tables[kd])[src[sel], np.maximum(o, 0)],
                       uniform_sequence(q, tau)[None, :])
        width = 1 << max(0, int(sel.size - 1).bit_length())           # few compiles
        pad = width - sel.size
        b = jnp.asarray(np.concatenate([b, np.full((pad, q), 1.0 / q)]), jnp.float32)
        seq = jnp.asarray(np.concatenate([seq, np.zeros((pad, tau), np.int32)]))
        h = jax.vmap(lambda bb, s, m=m: _pomdp.hazards(m, bb, s, True))(b, seq)
        p = np.clip(np.asarray(jax.vmap(_pomdp.success_probability)(h))[:sel.size],
                    1e-12, 1.0)
        p = np.where(t < 0, 1.0, p)
        cost[src[sel], dst[sel]] = -np.log(p.astype(np.float64))
    return cost


class HybridParams(NamedTuple):
    """In-vivo executive parameters.

    nav_range: sensing range (P: 60 m). sigma: measurement noise std. p_miss: probability
    that a scan misses a landmark in range (injected; each scan and landmark independent).
    """

    nav_range: float
    sigma: float
    p_miss: float = 0.0


class HybridResult(NamedTuple):
    """Outcome of B trials (``[B]`` unless noted): status (codes of
    :data:`pqrm_jax.qlink.FAILURE_REASONS`), length driven, stops (loop iterations), hops,
    k (index on the path of the last element entered), pose ``[B, 2]`` final position,
    refs ``[B, 2]``, failed ``[B, 2]`` the edge (element ids) that failed (−1 if none),
    trace ``[B, 2T − 1, 2]`` the driven polyline: the start, then per stop the waypoint round a
    wall (the stop itself when the drive was straight) and the stop (NaN after the end)."""

    status: jax.Array
    length: jax.Array
    stops: jax.Array
    hops: jax.Array
    k: jax.Array
    pose: jax.Array
    refs: jax.Array
    failed: jax.Array
    trace: jax.Array


class _S(NamedTuple):
    pos: jax.Array
    length: jax.Array
    stops: jax.Array
    k: jax.Array
    refs: jax.Array
    refs_xy: jax.Array
    phase: jax.Array
    c: jax.Array
    e: jax.Array
    seq: jax.Array
    status: jax.Array
    hops: jax.Array
    trace: jax.Array
    gseen: jax.Array        # [3] goal-element members measured so far (goal stage)
    gxy: jax.Array          # [3, 2] their measured positions


def wall_contact(p: jax.Array, q: jax.Array, walls: jax.Array, tol) -> tuple:
    """Does the straight drive ``p [2] → q [2]`` meet a wall segment of ``walls [S, 2, 2]``?

    Returns ``(hit, t, near_end, first)``: ``t`` ∈ [0, 1] the first contact along the drive
    (1 when none), ``near_end`` whether ``q`` lies within ``tol`` of the wall met first, and
    ``first`` that wall's index.

    >>> w = jnp.array([[[5., -1.], [5., 1.]]])
    >>> h, t, near, i = wall_contact(jnp.zeros(2), jnp.array([10., 0.]), w, 0.5)
    >>> bool(h), float(t), bool(near), int(i)
    (True, 0.5, False, 0)
    """
    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    a, b = walls[:, 0], walls[:, 1]
    d = q - p
    den = cross(d[None, :], b - a)                                    # [S]
    t = cross(a - p, b - a) / jnp.where(den == 0, 1.0, den)
    u = cross(a - p, d[None, :]) / jnp.where(den == 0, 1.0, den)
    hit = (den != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    t = jnp.where(hit, t, 1.0)
    first = jnp.argmin(t)
    near_end = _sim.segment_distance(q, walls)[first] <= tol
    return jnp.any(hit), t[first], near_end, first


def _detour(p, q, walls, first, standoff):
    """``(via [2], length, blocked)``: round wall ``first`` by the end (``standoff`` beyond it
    along the wall) that gives the shorter drive ``p → via → q``; ``blocked`` when a leg of
    it meets a wall."""
    a, b = walls[first, 0], walls[first, 1]
    u = (b - a) / jnp.maximum(jnp.linalg.norm(b - a), 1e-30)
    ends = jnp.stack([a - standoff * u, b + standoff * u])                 # [2, 2]
    lens = jnp.linalg.norm(ends - p, axis=-1) + jnp.linalg.norm(q - ends, axis=-1)
    via = ends[jnp.argmin(lens)]
    blocked = (wall_contact(p, via, walls, 0.0)[0]
               | wall_contact(via, q, walls, 0.0)[0])
    return via, jnp.min(lens), blocked


def landmark_distances(pos: jax.Array, landmarks: jax.Array, walls: jax.Array) -> jax.Array:
    """``[N + 2]`` distances from ``pos [2]`` to every landmark of a hybrid world: the points
    to their positions, the two walls (the last two ids) to their nearest point
    (:func:`pqrm_jax.sim.segment_distance`; a wall is in range when any point of it is).

    >>> lm = jnp.array([[3., 4.], [0., 0.], [0., 0.]])      # one point + two wall midpoints
    >>> walls = jnp.array([[[1., -1.], [1., 1.]], [[-2., 5.], [2., 5.]]])
    >>> landmark_distances(jnp.zeros(2), lm, walls).tolist()
    [5.0, 1.0, 5.0]
    """
    n = landmarks.shape[0] - 2
    return jnp.concatenate([jnp.linalg.norm(landmarks[:n] - pos, axis=-1),
                            _sim.segment_distance(pos, walls)])


def _pair(mem, kind_j, vis_j):
    """(ok, refs [2]) of entering an element with members ``mem [3]`` and visibility
    ``vis_j [3]``: both walls for a bands element, the first two members seen for LR."""
    is_bd = kind_j == BANDS
    ok_bd = vis_j[1] & vis_j[2]               # walls are the two largest ids
    ok_lr = jnp.sum(vis_j) >= 2
    first = jnp.argmax(vis_j)
    second = jnp.argmax(vis_j & (jnp.arange(3) != first))
    r_lr = jnp.stack([mem[first], mem[second]])
    return jnp.where(is_bd, ok_bd, ok_lr), jnp.where(is_bd, mem[1:], r_lr)


def visible_references(hmap: HybridMap, landmarks, walls, pos,
                       nav_range: float) -> tuple[np.ndarray, np.ndarray]:
    """``(ok [E], refs [E, 2])``: the elements whose references a robot at ``pos [2]`` has in
    range (exact range test, no misses) and those references — the executive's entry rule
    (both walls for a bands element, two members for an LR one), for every element at once.
    """
    lm = jnp.asarray(landmarks)
    ok, refs = _visible_references(jnp.asarray(hmap.elements.ids), jnp.asarray(hmap.kind), lm,
                                   jnp.asarray(walls, lm.dtype), jnp.asarray(pos, lm.dtype),
                                   float(nav_range))
    return np.asarray(ok), np.asarray(refs)


@jax.jit
def _visible_references(ids, kind, lm, walls, pos, nav_range):
    d = landmark_distances(pos, lm, walls)
    return jax.vmap(_pair)(ids, kind, d[ids] <= nav_range)


def _goal_stage(s: _S, mem_g, vis_g, meas_g, tau: int) -> _S:
    """The goal element's step (docs/qlink.md §invivo, the goal rule): the centroid of L_goal
    from what the robot has measured — the references (at entry) and the members a scan sees
    (``vis_g [3]``, measured ``meas_g [3, 2]``); a member still unseen: drive to the
    references' measured midpoint (with sides ≤ R every member is in range there) and scan
    again, at most ``tau`` scans there, else ``GOAL_NOT_FOUND``."""
    ref_of = mem_g[:, None] == s.refs[None, :]                       # [3, 2]
    is_ref = ref_of.any(1)
    ref_xy = jnp.where(ref_of[:, :1], s.refs_xy[0], s.refs_xy[1])
    seen_g = s.gseen | is_ref | vis_g
    gxy = jnp.where(s.gseen[:, None], s.gxy, jnp.where(is_ref[:, None], ref_xy, meas_g))
    cen = jnp.mean(gxy, axis=0)
    s_ok = s._replace(pos=cen, length=s.length + jnp.linalg.norm(cen - s.pos),
                      status=jnp.int32(SUCCESS), gseen=seen_g, gxy=gxy)
    centre = jnp.where(s.c == 0, jnp.mean(s.refs_xy, axis=0), s.pos)
    s_wait = s._replace(c=s.c + 1, gseen=seen_g, gxy=gxy, pos=centre,
                        length=s.length + jnp.linalg.norm(centre - s.pos),
                        status=jnp.where(s.c < tau, RUNNING, GOAL_NOT_FOUND).astype(jnp.int32))
    return where_tree(seen_g.all(), s_ok, s_wait)


def _around_walls(s: _S, out: _S, walls, params: HybridParams, scan) -> _S:
    """The drive ``s.pos → out.pos`` with walls as obstacles (docs/qlink.md §invivo): a
    straight line that meets a wall goes round the wall's nearer end (one waypoint,
    ``standoff`` beyond it); a drive up to a wall stops at it; if the way round is blocked too,
    the robot stops at the wall and the trial ends with ``COLLISION``. Writes the waypoint and
    the stop into the trace (``2·scan − 1``, ``2·scan``)."""
    standoff = jnp.maximum(params.sigma, 1e-3 * params.nav_range)
    hit, t_hit, near_end, first = wall_contact(s.pos, out.pos, walls, 3 * standoff)
    seg = out.pos - s.pos
    d_seg = jnp.linalg.norm(seg)
    back = jnp.maximum(t_hit * d_seg - standoff, 0.0)
    contact = s.pos + seg * back / jnp.maximum(d_seg, 1e-30)
    via, d_via, blocked = _detour(s.pos, out.pos, walls, first, standoff)
    s_hit = s._replace(pos=contact, length=s.length + back, status=jnp.int32(COLLISION))
    s_round = out._replace(length=s.length + d_via)
    s_stop = out._replace(pos=contact, length=s.length + back)
    out = where_tree(hit & near_end, s_stop,
                     where_tree(hit & ~blocked, s_round, where_tree(hit, s_hit, out)))
    via = jnp.where(hit & ~near_end & ~blocked, via, out.pos)
    t2 = out.trace.shape[0]
    i_via, i_pos = 2 * scan - 1, 2 * scan
    tr_ = out.trace.at[jnp.minimum(i_via, t2 - 1)].set(
        jnp.where(i_via < t2, via, out.trace[t2 - 1]))
    tr_ = tr_.at[jnp.minimum(i_pos, t2 - 1)].set(jnp.where(i_pos < t2, out.pos, tr_[t2 - 1]))
    return out._replace(stops=scan, trace=tr_)


def _visible(key, scan, pos, who, lm, walls, params: HybridParams) -> jax.Array:
    """``[K]``: which of ``who`` (landmark ids, −1 = none) are in range of ``pos`` (path
    length round the walls) and not missed (probability ``p_miss``, one draw per key, scan
    and landmark)."""
    w = jnp.maximum(who, 0)
    d = landmark_distances(pos, lm, walls)[w]
    u = jax.vmap(lambda x: jax.random.uniform(
        jax.random.fold_in(jax.random.fold_in(key, scan), x)))(w)
    return (who >= 0) & (d <= params.nav_range) & (u >= params.p_miss)


def _measure(key, scan, who, lm, sigma) -> jax.Array:
    """``[K, 2]`` noisy positions (std ``sigma``) of the landmarks ``who`` at scan ``scan``."""
    z = jax.vmap(lambda x: jax.random.normal(
        jax.random.fold_in(jax.random.fold_in(key, scan), x), (2,), lm.dtype))(who)
    return lm[jnp.maximum(who, 0)] + sigma * z


def _search_plan(refs, cur, mem_n, ids, kind, plans_lr, plans_bd) -> tuple:
    """``(target, commands [τ])`` of the QSR search from element ``cur`` (references
    ``refs [2]``) for the next element's members ``mem_n [3]``: the target by the host rule
    (:func:`reference_rule`, mirrored), the exact plan of its ordering, or the uniform
    sequence when the target is not in ``cur`` (its state is unknown)."""
    tau = plans_lr.shape[-1]
    mem_c = ids[cur]
    in_n = (mem_c[:, None] == mem_n[None, :]).any(1)
    not_ref = (mem_c != refs[0]) & (mem_c != refs[1])
    cand_c = in_n & not_ref
    n_not_ref = (mem_n != refs[0]) & (mem_n != refs[1])
    tgt = jnp.where(jnp.any(cand_c), mem_c[jnp.argmax(cand_c)],
                    mem_n[jnp.argmax(n_not_ref)]).astype(jnp.int32)
    in_c = jnp.any(mem_c == tgt)
    order = ordering_index(mem_c, refs[0], refs[1])
    seq = jnp.where(kind[cur] == BANDS, plans_bd[cur, order], plans_lr[cur, order])
    q_uni = jnp.where(kind[cur] == BANDS, jnp.arange(tau) % 3, jnp.arange(tau) % 2)
    return tgt, jnp.where(in_c, seq, q_uni)   # uniform_sequence: the state is unknown


@partial(jax.jit, static_argnames=("trace_len",))
def _drive(keys, paths, n, refs0, pos0, lm, walls, ids, kind, probs, plans_lr, plans_bd,
           params, *, trace_len):
    """The hybrid executive (:func:`drive`) over B trials, ``vmap``ped: per trial one
    ``while_loop`` of scans (ENTER, SEARCH, goal stage) until it ends."""
    lr, bd = calculi.get("lr"), bands_calculus()
    tau = plans_lr.shape[-1]
    fdt = lm.dtype

    def visible(key, scan, pos, who):
        return _visible(key, scan, pos, who, lm, walls, params)

    def measure(key, scan, who):
        return _measure(key, scan, who, lm, params.sigma)

    def one(key, path, n, refs0, pos0):
        k_miss, k_noise = jax.random.split(key)
        s0 = _S(pos0, jnp.zeros((), fdt), jnp.int32(0), jnp.int32(0), refs0,
                measure(k_noise, 0, refs0), jnp.int32(ENTER), jnp.int32(0), jnp.int32(-1),
                jnp.zeros(tau, jnp.int32), jnp.int32(RUNNING), jnp.int32(1),
                jnp.full((2 * trace_len - 1, 2), jnp.nan, fdt).at[0].set(pos0),
                jnp.zeros(3, bool), jnp.zeros((3, 2), fdt))
        budget = 3 * (tau + 2) * n + 4

        def pair_of(j, vis_j):
            """(ok, refs [2]) of entering element j with members' visibility vis_j [3]."""
            return _pair(ids[j], kind[j], vis_j)

        def body(s):
            scan = s.stops + 1
            goal_stage = s.k == n - 1
            cur = path[s.k]
            nxt = path[jnp.minimum(s.k + 1, path.shape[0] - 1)]
            mem_n = ids[nxt]
            # ---- goal: drive to the centroid of L_goal as measured (_goal_stage)
            mem_g = ids[cur]
            s_goal = _goal_stage(s, mem_g, visible(k_miss, scan, s.pos, mem_g),
                                 measure(k_noise, scan, mem_g), tau)
            # ---- ENTER: 360° scan for the next element
            vis_full = visible(k_miss, scan, s.pos, mem_n)
            ok, new_refs = pair_of(nxt, vis_full)

            def enter_next(st, refs):
                return st._replace(k=st.k + 1, refs=refs.astype(jnp.int32),
                                   refs_xy=measure(k_noise, scan, refs), phase=jnp.int32(ENTER),
                                   hops=st.hops + 1, c=jnp.int32(0), e=jnp.int32(-1))
            s_trans = enter_next(s, new_refs)
            tgt, seq = _search_plan(s.refs, cur, mem_n, ids, kind, plans_lr, plans_bd)
            centre = jnp.mean(s.refs_xy, axis=0)
            s_search = s._replace(pos=centre, length=s.length + jnp.linalg.norm(centre - s.pos),
                                  phase=jnp.int32(SEARCH), c=jnp.int32(0), e=tgt, seq=seq)
            s_enter = where_tree(ok, s_trans, s_search)
            # ---- SEARCH: sweep the commanded state from the centre
            cmd = s.seq[jnp.minimum(s.c, tau - 1)]
            a, b = s.refs_xy[0], s.refs_xy[1]
            who = jnp.concatenate([mem_n, s.e[None]])
            true_xy = lm[jnp.maximum(who, 0)]
            cls = jnp.where(kind[cur] == BANDS,
                            jax.vmap(lambda x: bd.classify(a, b, x))(true_xy),
                            jax.vmap(lambda x: lr.classify(a, b, x))(true_xy))
            is_ref = (who[:, None] == s.refs[None, :]).any(1)
            vis_sw = visible(k_miss, scan, s.pos, who) & ((cls == cmd) | is_ref)
            ok_sw, refs_sw = pair_of(nxt, vis_sw[:3])
            e_seen = vis_sw[3]
            # seen the target alone: drive to it and scan all round
            e_xy = measure(k_noise, scan, s.e[None])[0]
            vis_at_e = visible(k_miss, scan + (1 << 20), e_xy, mem_n)
            ok_e, refs_e = pair_of(nxt, vis_at_e)
            s_at_e = s._replace(pos=e_xy, length=s.length + jnp.linalg.norm(e_xy - s.pos))
            s_e = where_tree(ok_e, enter_next(s_at_e, refs_e),
                       s_at_e._replace(status=jnp.int32(REFS_NOT_FOUND)))
            c2 = s.c + 1
            s_miss = where_tree(c2 < tau, s._replace(c=c2),
                          s._replace(status=jnp.int32(LINK_NOT_FOUND)))
            s_sweep = where_tree(ok_sw, enter_next(s, refs_sw), where_tree(e_seen, s_e, s_miss))
            out = where_tree(goal_stage, s_goal, where_tree(s.phase == ENTER, s_enter, s_sweep))
            out = _around_walls(s, out, walls, params, scan)
            over = (out.status == RUNNING) & (scan >= budget)
            return out._replace(status=jnp.where(over, BUDGET, out.status))

        s = jax.lax.while_loop(lambda s: s.status == RUNNING, body, s0)
        fail = s.status != SUCCESS
        edge = jnp.where(fail, jnp.stack([path[s.k], path[jnp.minimum(s.k + 1,
                                                                      path.shape[0] - 1)]]),
                         -1)
        return HybridResult(s.status, s.length, s.stops, s.hops, s.k, s.pos, s.refs,
                            edge.astype(jnp.int32), s.trace)

    return jax.vmap(one)(keys, paths, n, refs0, pos0)


def qsr_tables(hmap: HybridMap, models) -> tuple[jax.Array, jax.Array]:
    """``([E, 6, τ], [E, 6, τ])`` exact open-loop command sequences of every element and
    ordering under the LR and the bands search POMDP (robot state irrelevant: direct
    transitions)."""
    probs = jnp.asarray(hmap.elements.probs)
    e = probs.shape[0]
    out = []
    for kd in (LR, BANDS):
        m = models[kd]
        q = m.detect.shape[0]
        b = probs[:, :, :q].reshape(e * 6, q)
        b = b / jnp.maximum(b.sum(-1, keepdims=True), 1e-30)
        b = jnp.where(jnp.sum(b, -1, keepdims=True) > 0, b, 1.0 / q)
        _, seq = _pomdp.open_loop_plan(m, jnp.zeros(e * 6, jnp.int32), b)
        out.append(seq.reshape(e, 6, -1).astype(jnp.int32))
    return out[0], out[1]


def drive(keys, hmap: HybridMap, landmarks, walls, paths, n_elements, refs, positions,
          params: HybridParams, tables, trace_len: int = 32) -> HybridResult:
    """Drive B planned trials with the in-vivo executive (one ``while_loop`` each, ``vmap``).

    Args:
        keys: ``[B]`` per-trial keys. hmap: the map. landmarks: ``[N + 2, 2]`` true positions
            (walls at their midpoints); walls: ``[2, 2, 2]`` segments.
        paths: ``[B, L]`` element ids (−1 padded); n_elements: ``[B]`` ≥ 1.
        refs: ``[B, 2]`` the references the robot is localised with in ``paths[:, 0]``.
        positions: ``[B, 2]`` start positions. params: :class:`HybridParams`.
        tables: :func:`qsr_tables`. trace_len: stops kept for plots.

    Raises:
        ValueError: ``nav_range <= 0``, ``p_miss`` outside [0, 1], a trial without a path,
            NaN positions.
    """
    validate(positive={"params.nav_range": params.nav_range},
             nonnegative={"params.sigma": params.sigma, "params.p_miss": params.p_miss},
             finite={"positions": np.asarray(positions)},
             landmarks=np.asarray(landmarks), elements=hmap.elements,
             elements_name="hmap.elements")
    if not params.p_miss <= 1.0:
        raise ValueError(f"params.p_miss must lie in [0, 1], got {params.p_miss!r}")
    n_elements = np.asarray(n_elements)
    validate(paths=(np.asarray(paths), n_elements, np.asarray(hmap.elements.ids).shape[0],
                    len(n_elements)))
    n_elements = n_elements.astype(np.int32)
    p = HybridParams(*(float(x) for x in params))
    lm = jnp.asarray(landmarks, jnp.float32)
    # pad the batch to a power of two and the path width to a multiple of 8 (few compiles;
    # every trial runs alone in its lane, so results do not depend on the padding)
    paths = np.asarray(paths, np.int32)
    b = paths.shape[0]
    bp = 1 << max(3, int(b - 1).bit_length())
    width = -(-paths.shape[1] // 8) * 8
    paths = np.pad(paths, ((0, bp - b), (0, width - paths.shape[1])), constant_values=-1)
    paths[b:, 0] = paths[0, 0]
    rep = np.concatenate([np.arange(b), np.zeros(bp - b, np.int64)])
    keys = jnp.asarray(keys)[rep]
    res = _drive(keys, jnp.asarray(paths), jnp.asarray(n_elements[rep]),
                 jnp.asarray(np.asarray(refs, np.int32)[rep]),
                 jnp.asarray(np.asarray(positions)[rep], lm.dtype), lm,
                 jnp.asarray(walls, lm.dtype), jnp.asarray(hmap.elements.ids),
                 jnp.asarray(hmap.kind), jnp.asarray(hmap.elements.probs), tables[0],
                 tables[1], p, trace_len=int(trace_len))
    return jax.tree.map(lambda x: x[:b], res)
