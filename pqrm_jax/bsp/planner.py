"""Belief-tree planner over qualitative and link actions (Z §4.1.2, §4.2, eqs. 4.3–4.14, 4.29–4.30).

The objective of eq. 4.3 has no goal term and links depend on the observed β, so an open-loop
sequence is ill-defined (docs/bsp.md §Z-11). The planner is an expectimax tree to depth ``L``:

    V(F, p, ℓ) = h(F)                                                   if ℓ = L
    V(F, p, ℓ) = min_{a ∈ Acts} [ c(p, a) + Σ_β w_β · ( 0 if β = τ* else
                                   min_{F' ∈ {F, (i,k), (j,k)}} V(F', ψ(p, a, β, ẑ, F'), ℓ+1) ) ]

* ``Acts`` — the ``n_actions`` target states with the smallest one-step proxy
  ``c(p, a) + Σ_β w_β(a) · min_{F'} h(F')`` (goal branches 0), computed for all Q actions
  (leaf values need no ẑ, so this costs one contraction per action);
* β — the ``n_beta`` observable candidates containing F (Z §4.2.3 heuristic) with the largest
  ``P(β | a)``, renormalised over those kept (the thesis renormalises over the available
  candidates, eq. 4.14; docs/bsp.md §Z-24);
* ẑ — ``n_z = 1`` draw per (node, a, β) from ``P(ẑ | β, a)`` (plain average, docs/bsp.md §Z-6); the
  key is a function of (level, frame, a, β) only, so pruned and full trees and any chunking of
  lanes draw the same measurement for the same branch; (b, s_x, s_τ) are drawn one after the
  other from their conditionals (nb, Q, Q cells) and ẑ from ``AZ[s_x, s_τ, b]``;
* ``c`` — eq. 4.29 (``cost = 1``: expected neighbour distance of the traversed states) or
  eq. 4.30 (``cost = 2``: expected displacement ``D2`` times the frame scale); neither depends
  on ẑ (law of total expectation);
* ``h(F) = c̄ · (1 + ρ) · (hops(F) + 1)`` from the frame graph, ``λ = 10⁵ c̄`` when no path.
  A first plan had ρ = 0; then a link of progress is worth about one step's cost and the
  eq. 4.29 planner (where staying costs 0) dithers. ρ = 10 makes each remaining link cost
  ten mean steps (docs/bsp.md §Z-11), so the tree maximises progress towards the goal
  first and minimises cost second ("the plan that most likely achieves the task's goal while
  minimizing the cost", Z abstract).

All levels are arrays of fixed width ``(n_actions · n_beta · 3)^ℓ`` evaluated level by level
(no Python recursion over nodes), and the whole planner is ``vmap``-able over environments.
What depends on a node's frame only (the proxy's expectation, the value of each candidate
at a leaf) is computed once per distinct frame of a level (the candidate weights per node,
for its chosen actions only); at the last
level a branch's value is the frame's leaf value of its candidate, so no child frame is built
there. Short contractions are written as fused sums and ``top_k`` as comparison counts
(XLA:CPU runs a reduction over a 6-long axis or a sort-based TopK as slow library calls;
docs/bsp.md §benchmark), and a branch's keys and uniforms come from :mod:`.draws`
(``jax.random``'s bits, with the threefry hash unrolled into one fusion).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from . import draws
from .belief import LINK_K, QBelief
from .graph import INF, FrameGraph, frame_graph
from .models import Models


class PlannerParams(NamedTuple):
    """Static planner settings (module docstring)."""

    depth: int = 2
    n_actions: int = 4
    n_beta: int = 3
    cost: int = 1
    lam: float = 1.0e5
    rho: float = 10.0
    #: EXTENSION beyond Z, off by default (docs/bsp.md §nothing-seen): a "nothing seen"
    #: branch with weight 1 − P(some candidate seen | a), valued as staying in the frame
    #: (h(F) + c̄), instead of renormalising the candidate weights to 1 (§Z-24).
    nothing_seen: bool = False


DEFAULT = PlannerParams()


class Plan(NamedTuple):
    """Planner output: root value, the first action, whether a plan exists, first-level info.

    ``ks`` (n_actions, n_beta) candidates kept for each first-level action, ``links``
    (n_actions, n_beta) their best link option, ``q`` (n_actions,) action values.
    """

    value: jax.Array
    action: jax.Array
    exists: jax.Array
    actions: jax.Array
    ks: jax.Array
    links: jax.Array
    q: jax.Array


def cbar(models: Models, D1, cost) -> jax.Array:
    """Mean one-step cost used by the leaf heuristic (``cost`` 1 or 2, may be traced)."""
    return jnp.where(cost == 1, jnp.mean(D1),
                     jnp.mean(models.D2) * models.mid[models.num_bins // 2])


def step_costs(models: Models, D1, sf, p, cost) -> jax.Array:
    """(Q,) eq. 4.29 (cost 1) or eq. 4.30 (cost 2) for every action from robot belief ``p``.

    ``cost`` may be traced, so lanes of both costs share one compiled program.
    """
    Tf = jnp.einsum("b,bas->as", sf, models.T)
    c1 = Tf @ (D1.T @ p)
    c2 = jnp.einsum("b,b,bas,s->a", sf, models.mid, models.T, models.D2.T @ p)
    return jnp.where(cost == 1, c1, c2)


class _Level(NamedTuple):
    cost: jax.Array  # [N, na]
    acts: jax.Array  # [N, na]
    ks: jax.Array  # [N, na, nb]
    w: jax.Array  # [N, na, nb]
    goal: jax.Array  # [N, na, nb]
    anyobs: jax.Array  # [N, na]
    seen: jax.Array  # [N, na] P(some observable candidate seen | a): 1 without nothing_seen
    stuck: jax.Array  # [N] h(F) + c̄: the value of a node whose action sees nothing
    frames: jax.Array | None  # [N, na, nb, 3, 2]; None at the last level
    robots: jax.Array | None  # [N, na, nb, 3, Q]; None at the last level
    vb: jax.Array | None  # [N, na, nb] branch values at the last level (else None)
    links: jax.Array | None  # [N, na, nb] their best link at the last level (else None)


class _FramePart(NamedTuple):
    """What a node's expansion needs that depends on its frame only (not on its robot
    belief): computed once per distinct frame of a level."""

    E: jax.Array  # [Q] the proxy's expectation over candidates (leaf values after a)
    seen: jax.Array  # [Q] P(some candidate seen | a): 1 without nothing_seen
    hk: jax.Array  # [L] leaf value of seeing candidate k: min over links, 0 at the goal
    link: jax.Array  # [L] the link option attaining it (0 stay, 1 (i, k), 2 (j, k))
    stuck: jax.Array  # [] h(F) + c̄


def transition_association(models: Models) -> jax.Array:
    """[nb, Q, Q] ``TA[b, a, s_τ] = Σ_{s_x} T[b, a, s_x] A[s_x, s_τ, b]``: the chance of
    seeing a candidate in state s_τ after action ``a`` at scale bin ``b`` (``models.TA``,
    computed once when the models are built).

    With it a frame's candidate weights ``P(β | a) = Σ_{s_τ} (Σ_b P_F(b) TA[b, a, s_τ])
    P(ij:k = s_τ)`` cost nb·Q² + Q²·L multiply-adds instead of the Q²·nb·L of contracting
    the frame graph's ``Ab`` (docs/bsp.md §benchmark).

    Args:
        models: the offline tables (``T`` [nb, Q, Q], ``A`` [Q, Q, nb]).

    Returns:
        [nb, Q, Q] the table.
    """
    if models.TA is not None:
        return models.TA
    return jnp.einsum("bax,xtb->bat", models.T, models.A)


def _frame_part(models, D1, TA, scale, trip, fg: FrameGraph, goal, frame, pp: PlannerParams,
                cost) -> _FramePart:
    L = fg.obs.shape[0]
    i, j = frame[0], frame[1]
    sf = scale[i, j]
    tobs = _observable_rows(fg, trip, i, j)
    idx = jnp.arange(L)
    third = goal.sum() - i - j
    isg = fg.goal_obs[i, j] & (idx == third)
    cb = cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    # one-step proxy for every action: c + E_β[min over links of h(F')] (h needs no ẑ)
    h_f = leaf_values(fg, frame, cb, lam, pp.rho)
    h3 = jnp.stack([jnp.broadcast_to(h_f, (L,)),
                    leaf_values(fg, jnp.stack([jnp.full(L, i), idx], -1), cb, lam, pp.rho),
                    leaf_values(fg, jnp.stack([jnp.full(L, j), idx], -1), cb, lam, pp.rho)])
    hk = jnp.where(isg, 0.0, h3.min(0))
    # Σ_k P(β_k | a) [h_k, 1] = Σ_b sf_b TA[b] (tobsᵀ [h, 1]): the product with TA is one
    # matrix for every frame of the level (a CPU multiplies that at full speed)
    y = jnp.stack([_sum_first(tobs * hk[:, None]), _sum_first(tobs)])  # [2, Q]
    nb, Q = TA.shape[0], TA.shape[1]
    Z = (y @ TA.transpose(2, 0, 1).reshape(Q, nb * Q)).reshape(2, nb, Q)
    ew = _sum_first([sf[b] * Z[:, b] for b in range(nb)])  # [2, Q]
    wsum = ew[1]
    # P(some candidate seen | a): 1 in the thesis model (the candidate weights renormalised,
    # §Z-24); the nothing-seen EXTENSION clips the sum at 1 (the events may overlap)
    ps = jnp.clip(wsum, 0.0, 1.0) if pp.nothing_seen else jnp.ones_like(wsum)
    E = jnp.where(wsum > 0, ps * ew[0] / jnp.where(wsum > 0, wsum, 1.0)
                  + (1.0 - ps) * (h_f + cb), h_f + cb)
    return _FramePart(E=E, seen=ps, hk=hk,
                      link=h3.argmin(0), stuck=h_f + cb)


def node_costs(models, D1, sfs, robots, cost) -> jax.Array:
    """[N, Q] eq. 4.29 / 4.30 step costs of every action for N nodes (frame scales ``sfs``
    [N, nb], robot beliefs ``robots`` [N, Q]); the same as :func:`step_costs` per node.

    ``Σ_b sf_b m_b Σ_s T[b, a, s] (Dᵀ p)_s`` with ``(m, D) = (1, D1)`` (eq. 4.29) or
    ``(mid, D2)`` (eq. 4.30): one [N, Q] × [Q, nb·Q] product with the node-independent
    ``D T`` (one matrix for all nodes, which a CPU multiplies at full speed), then the
    nb-term sum over the scale bins."""
    nb, Q = models.T.shape[0], models.T.shape[1]
    D = jnp.where(cost == 1, D1, models.D2)
    DT = D @ models.T.transpose(2, 0, 1).reshape(Q, nb * Q)  # [Q, nb·Q]: (D T)[s, (b, a)]
    V = (robots @ DT).reshape(-1, nb, Q)
    sfm = sfs * jnp.where(cost == 1, jnp.ones_like(models.mid), models.mid)
    return _sum_first([sfm[:, b, None] * V[:, b] for b in range(nb)])


def top_k(x, k: int) -> tuple[jax.Array, jax.Array]:
    """``jax.lax.top_k`` for short rows: values and indices of the ``k`` largest of ``x``
    [..., n], largest first, equal values in index order.

    Each entry's rank is counted from n² comparisons, written as a sum of n elementwise
    comparisons that XLA fuses (on CPU the library's sort-based TopK call took 1.5 of 12.5 ms
    of 64 batched plans, and the same count as a reduction over a trailing n-long axis was
    the largest single operation left: docs/bsp.md §benchmark). Values must not be NaN.

    >>> v, i = top_k(jnp.array([1.0, 3.0, 3.0, 2.0]), 2)
    >>> i.tolist(), v.tolist()
    ([1, 2], [3.0, 3.0])
    """
    n = x.shape[-1]
    col = jnp.arange(n)
    rank = _sum_first([((x[..., j, None] > x) | ((x[..., j, None] == x) & (j < col))
                        ).astype(jnp.int32) for j in range(n)])  # [..., n]
    hit = rank[..., None, :] == jnp.arange(k)[:, None]  # [..., k, n]
    idx = (hit * jnp.arange(n)).sum(-1)
    return jnp.take_along_axis(x, idx, -1), idx


def _branch(models, KL, trip, fg: FrameGraph, base, frame, sf, a, k):
    """[3, Q] robot states after action ``a`` with candidate ``k`` seen and one drawn ẑ, for
    the three link options (stay, (i, k), (j, k)); the draw's key is ``base`` (a function of
    the level and the frame) folded with a, then k."""
    i, j = frame[0], frame[1]
    # jax.random's fold_in, split and uniform, bit for bit, as one fusion (bsp.draws)
    kk = draws.fold_in(draws.fold_in(base, a), k)
    k1, k2 = draws.split(kk, 0), draws.split(kk, 1)
    u = [draws.uniform(q) for q in (draws.split(k1, 0), draws.split(k1, 1), draws.split(k1, 2),
                                    k2)]
    # b, then x | b, then t | x, b, then ẑ | x, t, b: nb + Q + Q + Q² cells
    g = sf[:, None] * models.T[:, a]  # [nb, Q]: P_F(b) T[b, a, x]
    tab = g * fg.Ab[i, j, k].T  # [nb, Q]: ... · Ab[x, b]
    b = _pick(u[0], jnp.cumsum(tab.sum(-1)))
    x = _pick(u[1], jnp.cumsum(tab[b]))
    t = _pick(u[2], jnp.cumsum(trip[i, j, k] * models.A[x, :, b]))
    z = _pick(u[3], models.AZ_cdf[x, t, b])
    # J[x, t] ∝ Σ_b P_F(b) T[b, a, x] P(ij:k = t) AZ[x, t, b, ẑ], as one fused multiply-reduce
    az = models.AZ_by_z[z]  # [nb, Q, Q]: contiguous per bin (models.Models.with_derived)
    J = _sum_first([g[b][:, None] * az[b] for b in range(g.shape[0])]) * trip[i, j, k]
    # [stay, (i, k), (j, k)] = J @ KL / Σ J: one [Q², 3Q] product (KL: :func:`link_operators`);
    # Σ J is the sum of the stay option's row (J's marginal over s_τ), so J is formed once
    r = (J.reshape(-1) @ KL).reshape(3, -1)
    s = r[0].sum()
    return r / jnp.where(s > 0, s, 1.0)


def link_operators(models: Models) -> jax.Array:
    """[Q², 3 Q] the robot state after each link option from the joint (s_x, s_τ): staying
    keeps s_x, the links to (i, k) and (j, k) apply ``K[LINK_K]`` (Z eq. 4.24)."""
    Q = models.T.shape[1]
    stay = jnp.repeat(jnp.eye(Q, dtype=models.K.dtype), Q, axis=0)  # [(x, t), s] = δ(x, s)
    return jnp.concatenate([stay, models.K[LINK_K[0]].reshape(Q * Q, Q),
                            models.K[LINK_K[1]].reshape(Q * Q, Q)], 1)


def _sum_first(xs) -> jax.Array:
    """Σ over the first axis (static, short) of ``xs`` as a chain of adds: XLA fuses it with
    the producers, where a reduction over a short axis became a separate library call that
    took most of a batched plan on CPU (docs/bsp.md §benchmark)."""
    out = xs[0]
    for x in xs[1:]:
        out = out + x
    return out


def _children(frame, ks, w):
    """[na, nb, 3, 2] frames after each kept candidate and link; a branch of weight 0 (fewer
    observable candidates than ``n_beta``) stays in ``frame`` (its value is multiplied by 0),
    so a level has at most 1 + 2 (L − 2) distinct frames below one frame."""
    i, j = frame[0], frame[1]
    fi = jnp.stack([jnp.broadcast_to(i, ks.shape), ks], -1)
    fj = jnp.stack([jnp.broadcast_to(j, ks.shape), ks], -1)
    out = jnp.stack([jnp.broadcast_to(frame, fi.shape), fi, fj], -2)
    return jnp.where((w > 0)[..., None, None], out, frame)


def _expand_level(models, D1, TA, trip, scale, fg: FrameGraph, goal, key, level, frames,
                  robots, slots: int, last: bool, pp: PlannerParams, cost, parent=None
                  ) -> _Level:
    """Expand the N nodes (``frames`` [N, 2], ``robots`` [N, Q]) of one level.

    What depends only on a node's frame (:class:`_FramePart`) is computed once per distinct
    frame: the level's frames are sorted into ``slots`` (static, at least the number of
    distinct frames) by ``jnp.unique``, or, for the children of one node (``parent``: its
    frame, kept candidates and weights), placed by :func:`_child_slots` without a sort. The
    candidate weights of a node's chosen actions are computed per node (n_actions rows, not
    all Q actions of every slot). At the ``last`` level a branch's value depends on
    the frame and the candidate only (``_FramePart.hk``), so no branch is sampled and no
    child frame is built.
    """
    L = trip.shape[0]
    n = frames.shape[0]
    i, j = frames[:, 0], frames[:, 1]
    codes = i * L + j
    fpart = partial(_frame_part, models, D1, TA, scale, trip, fg, goal, pp=pp, cost=cost)
    if parent is not None:
        slot, sframes = _child_slots(L, *parent)
        fp = jax.vmap(fpart)(sframes)
    elif slots < n:
        slot, sframes = _sorted_slots(frames, slots, L)
        fp = jax.vmap(fpart)(sframes)
    else:
        slot = jnp.arange(n)
        fp = jax.vmap(fpart)(frames)
    sfs = scale[i, j]  # [N, nb]
    cst = node_costs(models, D1, sfs, robots, cost)
    _, acts = top_k(-(cst + fp.E[slot]), pp.n_actions)  # [N, na]
    # [N, na, L] the candidate weights of the chosen actions (unnormalised P(β_k | a)):
    # Σ_s (Σ_b sf_b TA[b, a, s]) P(ij:k = s) over the observable candidates k
    nb, Q = TA.shape[0], TA.shape[1]
    tob = _observable_rows(fg, trip, i, j)  # [N, L, Q]
    ta = TA[:, acts]  # [nb, N, na, Q]
    mrow = _sum_first([sfs[:, b, None, None] * ta[b] for b in range(nb)])  # [N, na, Q]
    wt = _sum_first([mrow[..., q, None] * tob[:, None, :, q] for q in range(Q)])
    wk, ks = top_k(wt, pp.n_beta)  # [N, na, nb]
    tot = _sum_first([wk[..., c] for c in range(wk.shape[-1])])[..., None]
    w = wk / jnp.where(tot > 0, tot, 1.0)
    third = goal.sum() - i - j
    goal_n = fg.goal_obs[i, j][:, None, None] & (ks == third[:, None, None])
    common = dict(cost=jnp.take_along_axis(cst, acts, 1), acts=acts, ks=ks, w=w, goal=goal_n,
                  anyobs=tot[..., 0] > 0, seen=fp.seen[slot[:, None], acts],
                  stuck=fp.stuck[slot])
    if last:
        sl = slot[:, None, None]
        return _Level(**common, frames=None, robots=None, vb=fp.hk[sl, ks],
                      links=jnp.where(w > 0, fp.link[sl, ks], 0))
    # one key per (level, frame), the same as before issue 25's fourth session (so the same
    # draws); each branch folds in a, then k
    base = draws.fold_in(draws.fold_in(key, level), codes)  # [N, 2] key words

    def node(frame, base_n, acts_n, ks_n):
        sf = scale[frame[0], frame[1]]
        br = partial(_branch, models, link_operators(models), trip, fg, base_n, frame, sf)
        return jax.vmap(jax.vmap(br, (None, 0)), (0, 0))(acts_n, ks_n)
    return _Level(**common, frames=jax.vmap(_children)(frames, ks, w),
                  robots=jax.vmap(node)(frames, base, acts, ks), vb=None, links=None)


def _observable_rows(fg: FrameGraph, trip, i, j) -> jax.Array:
    """[..., L, Q] the triplet rows ``P(ij:k)`` of frame(s) (i, j), zero for the candidates k
    that are not observable from it (``fg.obs``)."""
    return jnp.where(fg.obs[i, j][..., None], trip[i, j], 0.0)


def _sorted_slots(frames, slots: int, L: int):
    """Slots of N frames (``frames`` [N, 2]) by sorting their codes ``i·L + j`` with
    ``jnp.unique`` into ``slots`` (static, at least the number of distinct frames). Returns
    the [N] slot of each frame and the [slots, 2] slot frames (unused slots hold a fill
    frame)."""
    codes = frames[:, 0] * L + frames[:, 1]
    uniq = jnp.unique(codes, size=slots, fill_value=L * L)
    slot = jnp.searchsorted(uniq, codes)
    uniq = jnp.minimum(uniq, L * L - 1)
    return slot, jnp.stack([uniq // L, uniq % L], -1)


def _child_slots(L: int, frame, ks, w):
    """Slots of the children of one node (``frame`` [2], its kept candidates ``ks`` and
    weights ``w`` [na, nb]) without sorting: slot 0 is ``frame`` (i, j), slot 1 + r is
    (i, k_r) and slot 1 + (L − 2) + r is (j, k_r), k_r the r-th landmark other than i and j.
    Returns the [na·nb·3] slot of each child (in :func:`_children`'s order) and the
    [1 + 2 (L − 2), 2] slot frames: the slots :func:`_sorted_slots` would give, in another
    order, without the sort."""
    i, j = frame[0], frame[1]
    lo, hi = jnp.minimum(i, j), jnp.maximum(i, j)
    r = jnp.arange(L - 2)
    kr = r + (r >= lo)
    kr = kr + (kr >= hi)
    sframes = jnp.concatenate([frame[None], jnp.stack([jnp.full_like(kr, i), kr], -1),
                               jnp.stack([jnp.full_like(kr, j), kr], -1)])
    rk = ks - (ks > lo) - (ks > hi)
    sl = jnp.stack([jnp.zeros_like(rk), 1 + rk, 1 + (L - 2) + rk], -1)
    return jnp.where((w > 0)[..., None], sl, 0).reshape(-1), sframes


def _slots(level: int, n: int, L: int, pp: PlannerParams) -> int:
    """Static bound on the distinct frames of a level's ``n`` nodes: 1 at the root; below
    one frame at most 1 + 2 min(L − 2, n_actions · n_beta) (:func:`_children`); else L(L − 1)."""
    if level == 0:
        return 1
    if level == 1:
        return min(n, 1 + 2 * min(L - 2, pp.n_actions * pp.n_beta))
    return min(n, L * (L - 1))


def sample_index(key, weights) -> jax.Array:
    """One index drawn with probability ∝ ``weights`` [n] (≥ 0) by the inverse CDF.

    One uniform per draw: ``jax.random.categorical`` draws a Gumbel variate (a threefry block
    and two logs) for every cell, which made sampling ẑ over the Q²·nb cells of the joint the
    largest cost of a plan on CPU (docs/bsp.md §benchmark). Zero-weight cells are never drawn
    unless all weights are 0 (then index 0: that branch has weight 0 in the tree).

    >>> int(sample_index(jax.random.key(0), jnp.array([0.0, 0.0, 1.0, 0.0])))
    2
    """
    return sample_cdf(key, jnp.cumsum(weights))


def sample_cdf(key, c) -> jax.Array:
    """:func:`sample_index` from the cumulative weights ``c`` [n] (non-decreasing, ≥ 0).

    >>> int(sample_cdf(jax.random.key(0), jnp.array([0.0, 0.0, 1.0, 1.0])))
    2
    """
    return _pick(jax.random.uniform(key, dtype=c.dtype), c)


def _pick(u, c) -> jax.Array:
    """The index of the uniform ``u`` ∈ [0, 1) under the cumulative weights ``c`` [n]."""
    idx = jnp.searchsorted(c, u * c[-1], side="right", method="compare_all")  # n is small
    return jnp.clip(jnp.where(c[-1] > 0, idx, 0), 0, c.shape[0] - 1)


def leaf_values(fg: FrameGraph, frames, cb, lam, rho: float = 10.0) -> jax.Array:
    """h(F) = c̄ (1 + ρ) (hops + 1) for frames [..., 2]; λ c̄ without a path."""
    h = fg.hops[frames[..., 0], frames[..., 1]]
    return jnp.where(h < INF, cb * (1.0 + rho) * (h + 1.0), lam * cb)


@partial(jax.jit, static_argnames=("pp",))
def plan(key: jax.Array, models: Models, D1, trip, scale, fg: FrameGraph, goal, frame, robot,
         pp: PlannerParams = DEFAULT, cost=None) -> Plan:
    """Plan from ``frame`` with robot belief ``robot`` (Z §4.2.1, module docstring); jit, vmap-able.

    Args:
        key: PRNG key of the session (the tree's sampled outcomes).
        models: offline tables.
        D1: [Q, Q] neighbour distance (eq. 4.29).
        trip: [L, L, L, Q] frozen triplet beliefs.
        scale: [L, L, nb] frame scales.
        fg: the session's :func:`~pqrm_jax.bsp.graph.frame_graph`.
        goal: [3] landmark ids.
        frame: [2] current frame.
        robot: [Q] robot belief.
        pp: static settings.
        cost: optional traced 1 or 2 overriding ``pp.cost``.

    Returns:
        The :class:`Plan` (root value, first action, plan exists, first-level details).

    Raises:
        ValueError: for ``pp.depth < 1``.
    """
    if pp.depth < 1:
        raise ValueError(f"planner depth must be >= 1, got {pp.depth}")
    cost = pp.cost if cost is None else cost
    key = draws.key_words(key)
    cb = cbar(models, D1, cost)
    lam = jnp.asarray(pp.lam, jnp.float32)
    L = trip.shape[0]
    TA = transition_association(models)
    frames, robots = frame[None], robot[None]
    levels = []
    parent = None
    for lv in range(pp.depth):
        last = lv == pp.depth - 1
        out = _expand_level(models, D1, TA, trip, scale, fg, goal, key, lv, frames, robots,
                            _slots(lv, frames.shape[0], L, pp), last, pp, cost, parent)
        levels.append(out)
        parent = ((frames[0], out.ks[0], out.w[0])
                  if lv == 0 and L - 2 <= pp.n_actions * pp.n_beta else None)
        if not last:
            frames = out.frames.reshape(-1, 2)
            robots = out.robots.reshape(-1, robot.shape[-1])
    q = values = links = None
    for out in reversed(levels):
        n = out.acts.shape[0]
        if out.vb is None:  # below the last level: children's values, min over the links
            v = values.reshape(n, pp.n_actions, pp.n_beta, 3)
            vb, links = jnp.where(out.goal, 0.0, v.min(-1)), v.argmin(-1)
        else:
            vb, links = out.vb, out.links
        stuck = out.stuck[:, None]
        # seen = 1 unless the nothing-seen EXTENSION is on (docs/bsp.md §nothing-seen)
        wv = _sum_first([out.w[..., c] * vb[..., c] for c in range(pp.n_beta)])
        q = out.cost + jnp.where(out.anyobs, out.seen * wv
                                 + (1.0 - out.seen) * stuck, stuck)
        values = q.min(-1)
    root = levels[0]
    best = jnp.argmin(q[0])
    value = values[0]
    return Plan(value=value, action=root.acts[0, best], exists=value < 0.5 * lam * cb,
                actions=root.acts[0], ks=root.ks[0], links=links[0], q=q[0])


@partial(jax.jit, static_argnames=("eps", "pp"))
def trees_exist(keys: jax.Array, models: Models, D1, beliefs: QBelief, goals, eps: float,
                pp: PlannerParams = DEFAULT, cost=1) -> jax.Array:
    """[E] bool: :attr:`Plan.exists` (root value < λ c̄) of E frozen beliefs, one compiled
    program — each belief's frame graph at ``eps`` and its :func:`plan` with its key.

    A ``lax.map`` over the environments: each answer is the single-belief program's, not a
    batched contraction's rounding (the qbsp sweep's depth panel).

    Args:
        keys: [E] PRNG keys, one per belief.
        models: the offline tables.
        D1: [Q, Q] neighbour distance (eq. 4.29).
        beliefs: a :class:`~pqrm_jax.bsp.belief.QBelief` with a leading ``[E]`` axis
            (:func:`~pqrm_jax.bsp.env.initial_beliefs`).
        goals: [E, 3] int goal triplets.
        eps: observability threshold ε_obs of the frame graphs.
        pp: static planner settings.
        cost: 1 (eq. 4.29) or 2 (eq. 4.30).

    Returns:
        [E] bool.
    """
    def one(a):
        key, b, goal = a
        fg = frame_graph(models, b.trip, b.trip_src, b.scale, b.lm_mask, goal, eps)
        return plan(key, models, D1, b.trip, b.scale, fg, goal, b.frame, b.robot, pp,
                    cost).exists

    return jax.lax.map(one, (keys, beliefs, jnp.asarray(goals)))
