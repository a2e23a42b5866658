"""Link Graph edge costs: unit, expected length, −log success (P §4.3.2–4.3.3, eqs. 4.2–4.4).

"Edge costs are assigned using one of several metrics: unit cost, expected path length to
complete a transition, or the negative log probability of success for the transition"
(P §4.3.2). The success probability of a transition M_i → M_j is eq. 4.3's
``p^{0:τ}`` of the search POMDP run in M_i for the link landmark; the cost is
``C_ij = −log p^{0:τ}`` and a path's success probability is eq. 4.4,
``p_success = exp(−Σ C_ij) = Π p_ij`` (edges independent).

Planning-time entry conditions are unknown, so (decision) the link is the smallest shared
landmark, the references are the two other members of L_i, and the robot's state is uniform
over Q (each state with its own optimal command sequence). The expected-length cost is the
expected number of QSR commands (P: "the expected number of qualitative state transitions"),
truncated at τ. p is clamped to ``[1e-12, 1]``.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import pomdp as _pomdp
from .checks import validate
from .elements import MapElements, ordering_index
from .linkgraph import link_graph, shared_counts

__all__ = ["edge_success", "edge_costs", "path_success"]


@partial(jax.jit, static_argnames=("horizon", "full"))
def _edge_success(ids, probs, feasible, detect, step_cost, reward, src, dst, *, horizon, full):
    model = _pomdp.SearchPOMDP(feasible, detect, 1.0, horizon, step_cost, reward)
    li, lj = ids[src], ids[dst]
    in_j = (li[:, :, None] == lj[:, None, :]).any(-1)            # [K, 3]
    link_pos = jnp.argmax(in_j, axis=1)
    others = jnp.stack([jnp.where(link_pos == 0, li[:, 1], li[:, 0]),
                        jnp.where(link_pos == 2, li[:, 1], li[:, 2])], axis=1)
    order = jax.vmap(ordering_index)(li, others[:, 0], others[:, 1])
    belief = probs[src, order]                                   # [K, Q]
    q = belief.shape[-1]
    qr = jnp.tile(jnp.arange(q, dtype=jnp.int32), belief.shape[0])
    b = jnp.repeat(belief, q, axis=0)
    _, seq = jax.vmap(lambda r, bb: _pomdp.open_loop_best(model, r, bb))(qr, b)
    h = jax.vmap(lambda bb, s: _pomdp.hazards(model, bb, s, full))(b, seq)
    p = jax.vmap(_pomdp.success_probability)(h).reshape(-1, q).mean(1)
    n = jax.vmap(_pomdp.expected_commands)(h).reshape(-1, q).mean(1)
    return jnp.clip(p, 1e-12, 1.0), n


def edge_success(elements: MapElements, model: _pomdp.SearchPOMDP, src, dst,
                 full: bool = False) -> tuple[jax.Array, jax.Array]:
    """Success probability and expected commands of Link Graph transitions (P §4.3.3, eq. 4.3).

    The search POMDP's exact open-loop plan from each transition's PQRM entry (the link's
    distribution), averaged over the robot's entry state.

    Args:
        elements: the map elements (``ids [E, 3]``, ``probs [E, 6, Q]``).
        model: the search POMDP; needs ``model.p_move = 1`` (the open-loop plan is then the
            exact POMDP policy).
        src, dst: ``[K]`` element indices of the transitions ``src[k] → dst[k]``.
        full: count every command of the horizon (``True``) or stop at detection.

    Returns:
        ``(p [K], n [K])``: ``p^{0:τ}`` the probability of finding the link within τ
        commands (clipped to ``[1e-12, 1]``) and the expected number of commands.

    Raises:
        ValueError: ``model.p_move != 1``.
    """
    if model.p_move != 1.0:
        raise ValueError("edge_success needs p_move = 1 (exact open-loop policy)")
    src, dst = np.asarray(src), np.asarray(dst)
    k = src.size
    width = 1 << max(0, int(k - 1).bit_length())                 # bucket: fewer recompiles
    pad = np.zeros(width - k, src.dtype)
    p, n = _edge_success(jnp.asarray(elements.ids), jnp.asarray(elements.probs),
                         model.feasible, model.detect, model.step_cost, model.found_reward,
                         jnp.asarray(np.concatenate([src, pad + src[0]])),
                         jnp.asarray(np.concatenate([dst, pad + dst[0]])),
                         horizon=int(model.horizon), full=bool(full))
    return p[:k], n[:k]


def edge_costs(elements: MapElements, beta: int, kind: str = "unit",
               model: _pomdp.SearchPOMDP | None = None):
    """The Link Graph of ``elements`` with edge costs of one kind (P §4.3.2, eqs. 4.2–4.4).

    Args:
        elements: the map elements (``E`` of them).
        beta: the edge threshold β (``|L_i ∩ L_j| ≥ β``).
        kind: ``"unit"`` (1 per edge), ``"expected_length"`` (expected commands, eq. 4.2)
            or ``"neg_log_success"`` (``−log p^{0:τ}``, eqs. 4.3–4.4; 0 where p = 1).
        model: the search POMDP of the costs (default :func:`~.pomdp.search_model`, τ = 4).

    Returns:
        :class:`~pqrm_jax.qlink.linkgraph.LinkGraph` with ``cost [E, E]`` (``inf`` = no
        edge).

    Raises:
        ValueError: an unknown ``kind``, malformed elements, β outside 1..3, an all-zero
            probability row (non-unit costs).

    >>> import jax.numpy as jnp
    >>> from pqrm_jax.qlink.elements import exact_elements
    >>> lm = jnp.array([[0., 0.], [10., 0.], [5., 5.], [12., 6.]])
    >>> el = exact_elements(lm, np.array([[0, 1, 2], [1, 2, 3]]))
    >>> g = edge_costs(el, 2, "neg_log_success")
    >>> bool(np.all(g.cost[g.adjacency] > 0))
    True
    """
    if kind not in ("unit", "expected_length", "neg_log_success"):
        raise ValueError(f"kind must be 'unit', 'expected_length' or 'neg_log_success', "
                         f"got {kind!r}")
    validate(elements=elements, beta=beta, probs_used=kind != "unit")
    graph = link_graph(elements, beta)
    if kind == "unit":
        return graph
    model = model or _pomdp.search_model(horizon=4)
    src, dst = np.nonzero(graph.adjacency)
    cost = np.full(graph.cost.shape, np.inf)
    if src.size:
        p, n = edge_success(elements, model, src, dst)
        cost[src, dst] = -np.log(np.asarray(p, np.float64)) if kind == "neg_log_success" \
            else np.asarray(n, np.float64)
    return link_graph(elements, beta, cost=np.where(np.isfinite(cost), cost, 1.0)) \
        ._replace(cost=np.where(shared_counts(elements) >= beta, cost, np.inf))


def path_success(graph, path) -> float:
    """The success probability of a path of a −log-success graph (P §4.3.2, eq. 4.4).

    Args:
        graph: a Link Graph with ``kind="neg_log_success"`` costs (:func:`edge_costs`).
        path: ``[L]`` element indices (``-1`` padded).

    Returns:
        ``exp(−Σ C_ij)`` along the path (0.0 if a step is not an edge).
    """
    p = [int(x) for x in np.asarray(path) if x >= 0]
    return float(np.exp(-sum(graph.cost[a, b] for a, b in zip(p[:-1], p[1:], strict=True))))
