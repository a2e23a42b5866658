"""The QSR-level controller: a search POMDP per map element (P §4.3.3, eqs. 4.2–4.3).

Padgett's POMDP ``Ω_i = (U_i, O_i, ψ_i, X_i, Γ_i, γ_i, Π_i, τ_i)`` is "formulated as a search
problem where the goal is to localize L^α_{i,j}": states ``X_i = Q_i × Q_i`` (robot state,
link state), controls "direct a robot into any qualitative state" and are "feasible only if the
qualitative state that the robot is directed towards is adjacent to the current qualitative
state", the observation is whether the link is seen "and an observation about the current robot
qualitative state", with "a small cost, such as −1" per control and "high reward, such as 100"
when the link is found (P §4.3.2–4.3.3). The concrete model here:

* states ``(q_r, q_l)``; ``q_l`` (the link's state w.r.t. the references) is static; controls
  ``go(q)``, feasible for ``q ∈ {q_r} ∪ adj(q_r)``;
* ``q_r' = q`` with probability ``p_move``, else ``q_r' = q_r``; ``q_r'`` is observed exactly;
* after reaching ``q_r'`` the link is seen with probability ``detect[q_r', q_l]``;
* reward −1 per control, +100 and the episode ends when the link is seen (search semantics:
  the literal per-step +100 would reward staying forever); horizon τ, no discount.

**Exact solution.** Because seeing the link ends the episode and ``q_r`` is observed, the only
continuing branches are "not seen yet" at each observed ``q_r'``; working with the
*unnormalised* probability mass ``m(q_l)`` of a branch makes the value linear in ``m``, so
``W(q_r, m, h) = max_a [ −Σm + Σ_{q'} T(q' | q_r, a) (100·m·d[q'] + W(q', m∘(1 − d[q']), h−1)) ]``
is the exact finite-horizon value (:func:`solve_exact`; the recursion branches only over
``q'``, ``|Q|^τ`` leaves). With ``p_move = 1`` the belief is a function of the command sequence
and the optimum is the best *open-loop* sequence (:func:`open_loop_plan`, ``|Q|^τ`` sequences);
a test checks the two agree and both against a brute-force belief-tree enumeration.

**Finite-state controller variant** (P §4.3.2, "Any finite state controller may be used"):
:func:`greedy_sequence` — always go to the feasible state with the highest immediate detection
probability under the current belief.

**eqs. 4.2–4.3.** :func:`hazards` gives ``p^t`` (literal eq. 4.2: detections in goal states
``q_r = q_l`` only; ``full=True`` counts detections from any state), with the belief conditioned
on no detection so far; :func:`success_probability` is the eq. 4.3 recursion with
``p^{τ:τ} = 0``; :func:`expected_commands` the expected number of commands issued.
"""

from __future__ import annotations

import itertools
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi

__all__ = ["SearchPOMDP", "search_model", "edge_adjacency", "solve_exact", "open_loop_plan",
           "greedy_sequence", "open_loop_best", "hazards", "success_probability",
           "expected_commands", "sequence_value", "DEFAULT_DETECTION", "estimate_detection"]

DEFAULT_DETECTION = (0.95, 0.2, 0.02)
"""Detection probability (same state, adjacent state, opposite state) when none is estimated."""


class SearchPOMDP(NamedTuple):
    """The search POMDP of one calculus, shared by all map elements (P §4.3.3).

    feasible: ``[Q, Q]`` bool, ``feasible[q_r, a]``: control ``go(a)`` allowed in ``q_r``.
    detect: ``[Q, Q]`` float, ``detect[q_r, q_l]``: P(link seen | robot searched ``q_r``,
        link in ``q_l``).
    p_move: probability that ``go(a)`` reaches ``a``.
    horizon: τ, the number of controls (Python int, ≥ 1).
    step_cost: reward per control (−1). found_reward: reward when the link is seen (100).
    """

    feasible: jax.Array
    detect: jax.Array
    p_move: float
    horizon: int
    step_cost: float = -1.0
    found_reward: float = 100.0


def edge_adjacency(calculus: str = "quadrant") -> np.ndarray:
    """``[Q, Q]`` bool: states whose names differ in exactly one ``-``-separated component.

    For the quadrant QSR this is the cycle FL–FR–BR–BL (P §4.3.2: diagonal moves must "pass
    through at least one additional qualitative state"); the library's ``adjacency`` table
    counts corners and is complete for quadrants.

    >>> edge_adjacency("quadrant").astype(int).tolist()
    [[0, 1, 1, 0], [1, 0, 0, 1], [1, 0, 0, 1], [0, 1, 1, 0]]
    """
    names = [s.split("-") for s in calculi.get(calculus).states]
    q = len(names)
    adj = np.zeros((q, q), bool)
    for i, j in itertools.product(range(q), repeat=2):
        if len(names[i]) == len(names[j]):
            adj[i, j] = sum(a != b for a, b in zip(names[i], names[j], strict=True)) == 1
    return adj


def search_model(calculus: str = "quadrant", horizon: int = 4, p_move: float = 1.0,
                 detect=None, direct: bool = False) -> SearchPOMDP:
    """The QSR-level search POMDP of one calculus (P §4.3.3).

    Args:
        calculus: the element's QSR.
        horizon: τ ≥ 1 (the in-vivo value is 4, P §4.4.2).
        p_move: success probability of a control.
        detect: ``[Q, Q]`` detection table; default from :data:`DEFAULT_DETECTION` by
            adjacency (same / edge-adjacent / other).
        direct: allow every control from every state ("Direct transitions are allowed",
            P §4.4.2) instead of edge-adjacent ones.

    Returns:
        :class:`SearchPOMDP` with ``feasible [Q, Q]`` bool controls, ``detect [Q, Q]``,
        ``p_move`` and ``horizon``.

    Raises:
        ValueError: ``horizon`` not an integer ≥ 1, ``p_move`` outside [0, 1], a
            ``detect`` table that is not ``[Q, Q]`` probabilities.

    >>> m = search_model(horizon=2)
    >>> m.feasible.astype(int).tolist()[0], [round(x, 2) for x in m.detect.tolist()[0]]
    ([1, 1, 1, 0], [0.95, 0.2, 0.2, 0.02])
    """
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise ValueError(f"the POMDP horizon must be an integer >= 1, got {horizon!r}")
    if not 0.0 <= float(p_move) <= 1.0:
        raise ValueError(f"p_move must lie in [0, 1], got {p_move}")
    adj = edge_adjacency(calculus)
    q = adj.shape[0]
    feasible = np.ones((q, q), bool) if direct else adj | np.eye(q, dtype=bool)
    if detect is None:
        same, near, far = DEFAULT_DETECTION
        detect = np.where(np.eye(q, dtype=bool), same, np.where(adj, near, far))
    detect = np.asarray(detect, np.float32)
    if detect.shape != (q, q) or np.any(detect < 0) or np.any(detect > 1):
        raise ValueError(f"detect must be a ({q}, {q}) table of probabilities")
    return SearchPOMDP(jnp.asarray(feasible), jnp.asarray(detect), float(p_move), int(horizon))


def _transition(model: SearchPOMDP, q_r):
    """``[Q(a), Q(q')]`` T(q' | q_r, a)."""
    q = model.detect.shape[0]
    eye = jnp.eye(q, dtype=model.detect.dtype)
    return model.p_move * eye + (1.0 - model.p_move) * eye[q_r][None, :]


def _w(model, q_r, mass, h):
    """Exact value (unnormalised mass) and best first control; recursion unrolled over h."""
    q = model.detect.shape[0]
    d = model.detect
    seen = mass @ d.T                                      # [Q'] mass seen after reaching q'
    if h == 1:
        cont = jnp.zeros(q, mass.dtype)
    else:
        rest = mass[None, :] * (1.0 - d)                   # [Q', Q]
        cont = jax.vmap(lambda qq, m: _w(model, qq, m, h - 1)[0])(jnp.arange(q), rest)
    t = _transition(model, q_r)                            # [A, Q']
    val = model.step_cost * jnp.sum(mass) + t @ (model.found_reward * seen + cont)
    val = jnp.where(model.feasible[q_r], val, -jnp.inf)
    a = jnp.argmax(val)
    return val[a], a


@partial(jax.jit, static_argnames=("horizon",))
def _solve_exact(feasible, detect, p_move, step_cost, reward, q_r, belief, *, horizon):
    model = SearchPOMDP(feasible, detect, p_move, horizon, step_cost, reward)
    return jax.vmap(lambda qr, b: _w(model, qr, b, horizon))(q_r, belief)


def _check_belief(q_r, belief, q):
    q_r = jnp.atleast_1d(jnp.asarray(q_r, jnp.int32))
    belief = jnp.atleast_2d(jnp.asarray(belief, jnp.float32))
    if belief.shape[-1] != q or belief.shape[0] != q_r.shape[0]:
        raise ValueError(f"belief must be (B, {q}) with one q_r per row, got {belief.shape}")
    return q_r, belief


def solve_exact(model: SearchPOMDP, q_r, belief) -> tuple[jax.Array, jax.Array]:
    """Exact optimal value and first control of the search POMDP for B beliefs (P §4.3.3).

    Args:
        model: the search POMDP.
        q_r: ``[B]`` int robot states (observed).
        belief: ``[B, Q]`` distributions of the link's state (the PQRM entry, P §4.3.3).

    Returns:
        ``(value [B], first control [B])``.

    >>> m = search_model(horizon=3)
    >>> v, a = solve_exact(m, [0], [[0.0, 0.0, 0.0, 1.0]])        # link back-right, from FL
    >>> a.tolist(), round(float(v[0]), 2)      # via FR, then BR twice
    ([1], 97.96)
    """
    q_r, belief = _check_belief(q_r, belief, model.detect.shape[0])
    return _solve_exact(model.feasible, model.detect, model.p_move, model.step_cost,
                        model.found_reward, q_r, belief, horizon=int(model.horizon))


def _sequences(q: int, horizon: int) -> np.ndarray:
    return np.array(list(itertools.product(range(q), repeat=horizon)), np.int32)


def sequence_value(model: SearchPOMDP, belief: jax.Array, seq: jax.Array) -> jax.Array:
    """Expected reward of the command sequence ``seq [τ]`` (``p_move = 1``) from ``belief``."""
    d = model.detect

    def body(m, a):
        r = model.step_cost * jnp.sum(m) + model.found_reward * (m @ d[a])
        return m * (1.0 - d[a]), r

    _, r = jax.lax.scan(body, belief, seq)
    return jnp.sum(r)


def _chain_ok(feasible, q_r, seqs):
    prev = jnp.concatenate([jnp.full((seqs.shape[0], 1), q_r), seqs[:, :-1]], axis=1)
    return jnp.all(feasible[prev, seqs], axis=1)


def open_loop_best(model: SearchPOMDP, q_r: jax.Array, belief: jax.Array):
    """Traceable single-belief :func:`open_loop_plan`: ``(value, seq [τ])`` (``p_move = 1``).

    For use inside ``jit``/``vmap``/``while_loop`` (the executive re-plans online with it).
    """
    seqs = jnp.asarray(_sequences(model.detect.shape[0], int(model.horizon)))
    return _open_loop(model, seqs, q_r, belief)


def _open_loop(model, seqs, q_r, belief):
    vals = jax.vmap(lambda s: sequence_value(model, belief, s))(seqs)
    vals = jnp.where(_chain_ok(model.feasible, q_r, seqs), vals, -jnp.inf)
    k = jnp.argmax(vals)
    return vals[k], seqs[k]


@partial(jax.jit, static_argnames=("horizon",))
def _open_loop_batch(feasible, detect, step_cost, reward, q_r, belief, *, horizon):
    model = SearchPOMDP(feasible, detect, 1.0, horizon, step_cost, reward)
    seqs = jnp.asarray(_sequences(detect.shape[0], horizon))
    return jax.vmap(lambda qr, b: _open_loop(model, seqs, qr, b))(q_r, belief)


def open_loop_plan(model: SearchPOMDP, q_r, belief) -> tuple[jax.Array, jax.Array]:
    """Best feasible command sequence of the search POMDP for B initial beliefs (P §4.3.3).

    Exact when ``p_move = 1`` (the robot state after each control is then known, so the
    best open-loop sequence is the optimal policy).

    Args:
        model: the search POMDP (``p_move = 1``).
        q_r: ``[B]`` int robot states (observed).
        belief: ``[B, Q]`` distributions of the link's state (the PQRM entry).

    Returns:
        ``(value [B], commands [B, τ])``: the expected value and the control sequence.

    Raises:
        ValueError: ``model.p_move != 1``, beliefs that are not ``[B, Q]`` distributions or
            states outside ``[0, Q)``.

    >>> v, seq = open_loop_plan(search_model(horizon=3), [0], [[0.0, 0.0, 0.0, 1.0]])
    >>> seq.tolist(), round(float(v[0]), 2)
    ([[1, 3, 3]], 97.96)
    """
    if model.p_move != 1.0:
        raise ValueError("open_loop_plan is exact only for p_move = 1; use solve_exact")
    q_r, belief = _check_belief(q_r, belief, model.detect.shape[0])
    return _open_loop_batch(model.feasible, model.detect, model.step_cost, model.found_reward,
                            q_r, belief, horizon=int(model.horizon))


def greedy_sequence(model: SearchPOMDP, q_r: jax.Array, belief: jax.Array) -> jax.Array:
    """Finite-state-controller variant: myopic best detection, ``[τ]`` commands (jit-able).

    >>> greedy_sequence(search_model(horizon=3), jnp.int32(0),
    ...                 jnp.array([0.1, 0.6, 0.0, 0.3])).tolist()
    [1, 3, 1]
    """
    d = model.detect

    def body(c, _):
        qr, m = c
        score = jnp.where(model.feasible[qr], d @ m, -jnp.inf)
        a = jnp.argmax(score).astype(jnp.int32)
        return (a, m * (1.0 - d[a])), a

    _, seq = jax.lax.scan(body, (jnp.asarray(q_r, jnp.int32), belief), None,
                          length=int(model.horizon))
    return seq


def hazards(model: SearchPOMDP, belief: jax.Array, seq: jax.Array,
            full: bool = False) -> jax.Array:
    """``[τ]`` p^t of eq. 4.2: P(reach a goal state and see the link at t | not seen before).

    ``full=False`` is eq. 4.2 as written (only states with ``q_r = q_l`` count); ``full=True``
    counts a detection from any link state. The belief is conditioned on no detection so far.
    """
    d = model.detect

    def body(b, a):
        b = b / jnp.maximum(jnp.sum(b), 1e-30)
        h = jnp.where(full, b @ d[a], b[a] * d[a, a])
        return b * (1.0 - d[a]), h

    _, h = jax.lax.scan(body, jnp.asarray(belief, d.dtype), seq)
    return h


def success_probability(h: jax.Array) -> jax.Array:
    """eq. 4.3: ``p^{t:τ} = p^t + (1 − p^t) p^{t+1:τ}`` with ``p^{τ:τ} = 0``; returns p^{0:τ}.

    >>> float(success_probability(jnp.array([0.5, 0.5])))
    0.75
    """
    def body(p_next, ht):
        return ht + (1.0 - ht) * p_next, None

    p, _ = jax.lax.scan(body, jnp.zeros((), h.dtype), h, reverse=True)
    return p


def expected_commands(h: jax.Array) -> jax.Array:
    """Expected number of commands issued, ``Σ_t Π_{k<t}(1 − h_k)`` (truncated at τ).

    >>> float(expected_commands(jnp.array([0.5, 0.5])))
    1.5
    """
    alive = jnp.concatenate([jnp.ones(1, h.dtype), jnp.cumprod(1.0 - h)[:-1]])
    return jnp.sum(alive)


def estimate_detection(landmarks, elements, r_map: float, r_nav: float) -> np.ndarray:
    """The search POMDP's detection table estimated from a world's geometry (P §4.3.3, §Q12).

    ``d[q_r, q_l]`` is the fraction of mapped orderings ``{A, B : C}`` in state ``q_l``
    whose C lies within ``r_nav`` of the radius-``r_map`` quarter arc of ``q_r``
    (docs/qlink.md §Q12).

    Args:
        landmarks: ``[N, 2]`` true landmark positions.
        elements: the map elements (``ids [E, 3]``).
        r_map: R, the arc radius.
        r_nav: the range within which C counts as seen.

    Returns:
        ``[Q, Q]`` float64, clipped to [0.01, 0.99].
    """
    from . import elements as qel
    from . import trajectory as tr

    lm = jnp.asarray(landmarks)
    trip = jnp.asarray(np.asarray(elements.ids)[:, qel.ORDERINGS]).reshape(-1, 3)
    a, b, c = lm[trip[:, 0]], lm[trip[:, 1]], lm[trip[:, 2]]
    ql = np.asarray(calculi.get("quadrant").classify(a, b, c))
    d = np.zeros((4, 4))
    for qr in range(4):
        centre, lo = jax.vmap(tr.quadrant_wedge, (0, 0, None))(a, b, qr)
        dist = np.asarray(jax.vmap(tr.arc_min_distance, (0, 0, None, 0))(c, centre, r_map, lo))
        for q in range(4):
            m = ql == q
            d[qr, q] = float((dist[m] <= r_nav).mean()) if m.any() else 0.0
    return np.clip(d, 0.01, 0.99)
