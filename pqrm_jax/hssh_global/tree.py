"""The tree of topological map hypotheses with star views (B Alg. 8.1, §3.2.3, §8.3).

Each leaf is a map hypothesis ``⟨M, q⟩``: places with their stars (``M^P``, the star stored at
first visit), the corridors known between gateways (``R`` restricted to travels: turns are fully
described by the star, B §8.1) and the current distinctive state ``q = (place, entry)``. After each
travel with observed view ``v`` (Alg. 8.1):

1. known territory (the gateway's corridor is in ``M``): the predicted view must match ``v``
   (star isomorphism mapping the arrival entries), otherwise the leaf is marked inconsistent;
2. new territory: one successor per known dstate ``q_j`` whose view matches ``v`` and whose
   arrival gateway is still unexplored (loop closure ``q' = q_j``), plus one new place;
3. successors violating the topological axioms are marked inconsistent and pruned;
4. consistent leaves are ordered by :func:`preference_order`.

Axioms checked (B §3.2.3): (3.1)/(3.5) every dstate is at one place on one directed local-path
(by construction: a dstate is a star entry), (3.2) turns stay at the place, (3.3)/(3.4) a travel
continues along the same global path (global paths are the chains of local paths joined by
corridors), (3.7)–(3.10) ``order`` along a path is a strict order: a global path is a simple
chain, never a cycle and never through the same place twice; and determinism of ``R`` (one
corridor per gateway; traversability ``α`` respected). The planarity constraint (Savelli &
Kuipers 2004) does not prune the tree; :func:`is_planar` checks it on a leaf, as an optional
filter on the final leaves.

Preference: the thesis ranks leaves by the *prioritized circumscription policy* of Remolina &
Kuipers 2004, which the thesis does not specify; we use **fewest places** (the minimality that
circumscription aims at), ties broken by the layout likelihood (the residual of the relaxed
global layout, :mod:`~pqrm_jax.hssh_global.layout`) — the probabilistic ranking the thesis names
as future work (B §10.1.2), not the thesis's policy.

Why host-side Python: the tree is a growing set of variable-size symbolic maps whose successors
differ in shape (a new place, a new corridor, a merge); a padded array form would fix a maximum
number of leaves and places and waste most of its lanes on the ≤ k+1 actual branches. The
per-step work is tiny (dictionaries of at most ``m·l`` gateways). What is array-shaped is batched:
the view matching against all known dstates (:func:`~pqrm_jax.hssh_global.star.match_matrix`)
and the scoring of all leaves by layout relaxation (``vmap`` over hypotheses).

>>> from pqrm_jax.hssh_global.world import grid_world, explore
>>> w = grid_world(3, 3, seed=0)
>>> t = build_tree(explore(w, 8, seed=1))
>>> any(is_true_map(h, explore(w, 8, seed=1)) for h in t.leaves)
True
"""

from __future__ import annotations

from typing import NamedTuple

import networkx as nx
import numpy as np

from .star import view_match
from .world import Experience


class MapHypothesis(NamedTuple):
    """One leaf ``⟨M, q⟩`` of the tree of maps.

    Attributes:
        stars: star of each hypothesised place (as first observed).
        bearings: entry bearings of each place at its first visit (rover frame of that visit).
        edges: ``{(p, e): (p', e')}`` known corridors between gateways (symmetric).
        visits: ``((place, arrival entry), ...)`` for every view so far.
    """

    stars: tuple
    bearings: tuple
    edges: dict
    visits: tuple

    @property
    def n_places(self) -> int:
        return len(self.stars)

    @property
    def q(self) -> tuple:
        """The current distinctive state ``(place, entry)``."""
        return self.visits[-1]


class TreeLog(NamedTuple):
    """The tree of maps after an experience, with its growth record (B §8.3).

    Attributes:
        leaves: consistent leaves.
        n_leaves: ``[n+1]`` consistent leaves after each view.
        n_inconsistent: ``[n]`` leaves/successors marked inconsistent at each travel.
        branching: ``[n]`` largest number of successors of one leaf at each travel.
        branch_events: travels at which some leaf branched (new territory with ``k ≥ 1``).
        k_max: largest number of matching known dstates at one branching (``k`` of §8.3).
    """

    leaves: list
    n_leaves: np.ndarray
    n_inconsistent: np.ndarray
    branching: np.ndarray
    branch_events: int
    k_max: int


class TreeTooLarge(RuntimeError):
    """Raised instead of silently dropping leaves when the tree exceeds ``max_leaves``."""


def _path_chain_ok(h_stars, edges, p, e) -> bool:
    """Global path through local path of ``(p, e)`` is a simple chain (B eqs. 3.7–3.10)."""
    start = (p, h_stars[p].path[e])
    seen_places = {p}
    seen_nodes = {start}
    for first in (e, h_stars[p].opp[e]):
        cp, ce = p, first
        while (cp, ce) in edges:
            np_, ne = edges[(cp, ce)]
            node = (np_, h_stars[np_].path[ne])
            if node == start:
                return False  # the path closes into a cycle: order(π, d, p, p)
            if node in seen_nodes or np_ in seen_places:
                return False  # the path passes twice through a place
            seen_nodes.add(node)
            seen_places.add(np_)
            cp, ce = np_, h_stars[np_].opp[ne]
    return True


def root(experience: Experience) -> MapHypothesis:
    """The root ``⟨M0, q0⟩`` of Alg. 8.1 step 0: one place with the first view.

    Args:
        experience: the exploration.

    Returns:
        The root :class:`MapHypothesis`.

    Raises:
        ValueError: for an empty exploration.
    """
    if len(experience.views) == 0:
        raise ValueError("an empty exploration has no view: the tree of maps has no root")
    star, arr = experience.views[0]
    return MapHypothesis((star,), (experience.bearings[0],), {}, ((0, arr),))


def extend(h: MapHypothesis, turn: int, view) -> tuple[list, int, int]:
    """Successors of one leaf after ``turn`` then a travel observing ``view`` (Alg. 8.1 1–3).

    Args:
        h: the leaf.
        turn: clockwise steps from the arrival entry to the exit entry.
        view: observed ``(star, arrival entry)``; its bearings are attached by the caller.

    Returns:
        ``(successors, n_inconsistent, k)``: consistent successors (each still to get its
        bearings if it is a new place), the number marked inconsistent, and ``k`` (matching
        known dstates; ``-1`` in known territory).
    """
    p, a = h.q
    star = h.stars[p]
    e = (a + int(turn)) % len(star)
    if not star.alpha[e]:
        return [], 1, -1  # travel through a wall of the hypothesised star
    if (p, e) in h.edges:
        q, f = h.edges[(p, e)]
        arr = h.stars[q].opp[f]
        if view_match(view, (h.stars[q], arr)):
            return [h._replace(visits=h.visits + ((q, arr),))], 0, -1
        return [], 1, -1
    out, bad, k = [], 0, 0
    for qj in range(h.n_places):
        sq = h.stars[qj]
        for aj in range(len(sq)):
            g = sq.opp[aj]
            if not sq.alpha[g] or not view_match(view, (sq, aj)):
                continue
            k += 1
            if (qj, g) in h.edges or (qj == p and g == e):
                bad += 1  # that gateway already leads elsewhere (determinism of R)
                continue
            edges = dict(h.edges)
            edges[(p, e)] = (qj, g)
            edges[(qj, g)] = (p, e)
            if not _path_chain_ok(h.stars, edges, p, e):
                bad += 1
                continue
            out.append(h._replace(edges=edges, visits=h.visits + ((qj, aj),)))
    vstar, varr = view
    new = h.n_places
    edges = dict(h.edges)
    g = vstar.opp[varr]
    if not vstar.alpha[g]:
        return out, bad + 1, k  # arrived through a wall: the view itself is impossible
    edges[(p, e)] = (new, g)
    edges[(new, g)] = (p, e)
    stars = h.stars + (vstar,)
    if _path_chain_ok(stars, edges, p, e):
        out.append(MapHypothesis(stars, h.bearings, edges, h.visits + ((new, varr),)))
    else:
        bad += 1
    return out, bad, k


class _TreeStats:
    """Per-step bookkeeping shared by the tree builders (leaves, inconsistent, branching)."""

    def __init__(self):
        self.n_leaves, self.n_bad, self.branching = [1], [], []
        self.events, self.k_max = 0, 0

    def step(self, leaves: list, bad: int, br: int, branched: bool) -> None:
        self.events += int(branched)
        self.n_leaves.append(len(leaves))
        self.n_bad.append(bad)
        self.branching.append(br)

    def log(self, leaves: list) -> TreeLog:
        return TreeLog(leaves, np.array(self.n_leaves), np.array(self.n_bad, int),
                       np.array(self.branching, int), self.events, self.k_max)


def build_tree(experience: Experience, max_leaves: int = 200_000) -> TreeLog:
    """Runs Alg. 8.1 over a whole experience (breadth-first, all consistent leaves kept).

    Args:
        experience: views, turns (and bearings) of an exploration.
        max_leaves: a :class:`TreeTooLarge` is raised beyond this many leaves (never a silent
            truncation, which could discard the correct map).

    Returns:
        A :class:`TreeLog`; ``leaves`` is empty when the experience is inconsistent with every map
        (e.g. a view that contradicts known territory in every hypothesis).

    Raises:
        ValueError: for an empty exploration; TreeTooLarge: beyond ``max_leaves`` leaves.

    >>> from pqrm_jax.hssh_global import explore, is_true_map, minimal_models, office_world
    >>> e = explore(office_world(), 14, seed=0)                  # 15 views of the §8.3 office
    >>> t = build_tree(e)
    >>> len(t.leaves), len(minimal_models(t.leaves)), sum(is_true_map(h, e) for h in t.leaves)
    (8, 1, 1)
    """
    leaves = [root(experience)]
    stats = _TreeStats()
    for i, turn in enumerate(np.asarray(experience.turns)):
        view = experience.views[i + 1]
        nxt, bad_i, br, branched = [], 0, 0, False
        for h in leaves:
            succ, bad, k = extend(h, int(turn), view)
            succ = [s if s.n_places == len(s.bearings)
                    else s._replace(bearings=s.bearings + (experience.bearings[i + 1],))
                    for s in succ]
            nxt.extend(succ)
            bad_i += bad
            br = max(br, len(succ))
            if k >= 1 and len(succ) > 1:
                branched = True
            stats.k_max = max(stats.k_max, k)
            if len(nxt) > max_leaves:
                raise TreeTooLarge(f"more than {max_leaves} leaves after travel {i + 1}")
        leaves = nxt
        stats.step(leaves, bad_i, br, branched)
    return stats.log(leaves)


def canonical_places(places) -> tuple:
    """Relabels a place sequence by order of first appearance (for comparing maps).

    Args:
        places: a sequence of place labels.

    Returns:
        The labels renumbered 0, 1, ... by first appearance.
    """
    lab: dict = {}
    return tuple(lab.setdefault(int(p), len(lab)) for p in places)


def is_true_map(h: MapHypothesis, experience: Experience) -> bool:
    """Whether the hypothesis is the true map of the explored part of the world.

    The views must be assigned to the true places (up to relabelling), and at each place the
    map's dstates must correspond to the true ones by one fixed rotation of the star (a map that
    closes a loop onto the right place but the wrong gateway is another map).

    Args:
        h: a map hypothesis of ``experience``.
        experience: the exploration, with its ground truth.

    Returns:
        True for the true map.
    """
    if (canonical_places([v[0] for v in h.visits])
            != canonical_places(experience.true_places)):
        return False
    offset: dict = {}
    for (p, e), t in zip(h.visits, experience.true_arrivals, strict=True):
        d = (int(e) - int(t)) % len(h.stars[p])
        if offset.setdefault(p, d) != d:
            return False
    return True


def preference_order(leaves: list, layout_cost=None, supported=None) -> list[int]:
    """Indices of leaves, most preferred first: fewest places, then lowest layout cost (B).

    Args:
        leaves: consistent leaves.
        layout_cost: optional ``[len(leaves)]`` costs (e.g. from
            :func:`~pqrm_jax.hssh_global.layout.score_hypotheses`); NaN ranks last.
        supported: optional bool ``[len(leaves)]`` from the declared geometric test
            (:func:`~pqrm_jax.hssh_global.layout.layout_supported`, beyond B): maps the layout
            cannot support are demoted behind every supported one (kept, not discarded).

    Returns:
        Every leaf index, most preferred first.

    Raises:
        ValueError: for a ``supported`` of the wrong length.
    """
    cost = np.zeros(len(leaves)) if layout_cost is None else np.asarray(layout_cost, float)
    cost = np.where(np.isnan(cost), np.inf, cost)
    ok = np.ones(len(leaves), bool) if supported is None else np.asarray(supported, bool)
    if ok.shape != (len(leaves),):
        raise ValueError(f"supported must be [{len(leaves)}], got shape {ok.shape}")
    return sorted(range(len(leaves)), key=lambda i: (not ok[i], leaves[i].n_places, cost[i]))


def minimal_models(leaves: list) -> list[int]:
    """Indices of the leaves with the fewest places (our stand-in for the minimal models).

    Args:
        leaves: consistent leaves (:class:`MapHypothesis`).

    Returns:
        The indices of the leaves with the fewest places (B §8.3).
    """
    if not leaves:
        return []
    m = min(h.n_places for h in leaves)
    return [i for i, h in enumerate(leaves) if h.n_places == m]


def is_planar(h: MapHypothesis) -> bool:
    """Whether a map's corridors embed in the plane with the stars' clockwise orders (B §8.3).

    The stars give a rotation system: at each place its gateways (traversable entries) in
    clockwise order. Every gateway is a dart; a known corridor pairs two darts, a gateway not
    explored yet gets a stub vertex of its own (a pendant edge never changes the genus). The
    faces are the orbits of "cross the corridor, then turn to the next gateway clockwise";
    the embedding is planar iff ``V − E + F = 2 C`` (Euler, ``C`` connected components).
    Used as the optional consistency filter behind B's "46 → 1 with planarity" figure.
    (``networkx.check_planarity`` asks whether *some* embedding is planar, ignoring the stars'
    orders, and ``networkx.PlanarEmbedding`` holds neither parallel corridors nor loops, so the
    faces are traced here.)

    Args:
        h: a map hypothesis.

    Returns:
        True when the rotation system embeds in the plane.

    >>> from pqrm_jax.hssh_global.world import office_world, explore
    >>> w = office_world()
    >>> e = explore(w, 14, seed=0)
    >>> all(is_planar(h) for h in build_tree(e).leaves if is_true_map(h, e))
    True
    """
    darts = [(p, e) for p, star in enumerate(h.stars) for e in range(len(star))
             if star.alpha[e]]
    if not darts:
        return True
    nxt = {}
    for p, star in enumerate(h.stars):
        gs = [e for e in range(len(star)) if star.alpha[e]]
        for k, e in enumerate(gs):
            nxt[(p, e)] = (p, gs[(k + 1) % len(gs)])
    partner = {d: h.edges.get(d, ("stub", d)) for d in darts}
    for d in darts:
        if partner[d][0] == "stub":
            partner[partner[d]] = d
            nxt[partner[d]] = partner[d]
    n_stub = sum(1 for d in darts if d not in h.edges)
    v = h.n_places + n_stub
    # each known corridor pairs two darts; each stub edge pairs a dart with its stub dart
    e_n = (len(darts) - n_stub) // 2 + n_stub
    seen: set = set()
    faces = 0
    for d0 in partner:
        if d0 in seen:
            continue
        faces += 1
        d = d0
        while d not in seen:
            seen.add(d)
            d = nxt[partner[d]]
    # connected components over places (stubs hang on their place)
    g = nx.Graph()
    g.add_nodes_from(range(h.n_places))
    g.add_edges_from((p, q) for (p, _), (q, _) in h.edges.items())
    comps = nx.number_connected_components(g)
    return v - e_n + faces == 2 * comps


def view_symbol(view) -> tuple:
    """A view as a symbol: the star read clockwise from the arrival entry (``match`` ⇔ equal).

    Args:
        view: ``(star, arrival entry)``.

    Returns:
        ``(alpha, opp offsets)``: two tuples read clockwise from the arrival entry, the
        traversabilities and each entry's opposite as an offset from the arrival (B §8.2).
    """
    star, a = view
    n, opp = len(star), star.opp
    return (tuple(star.alpha[(a + i) % n] for i in range(n)),
            tuple((opp[(a + i) % n] - a) % n for i in range(n)))


def build_basic_tree(experience: Experience, max_leaves: int = 200_000) -> TreeLog:
    """The basic-SSH tree of maps (B Alg. 3.1): symbol views, branching on turns and travels.

    The experience is replayed as ``v0 Turn_k v0' Travel v1 Turn_k v1' …``: each turn is its own
    action ``Turn_k`` (``k`` clockwise steps) and reaches a dstate whose view symbol is the star
    read from the exit entry (:func:`view_symbol`, the same information as the HSSH view, so
    only the branching differs). A leaf is the schema set ``R`` over dstates, their views and the
    current dstate; new territory branches over every known dstate with an equal symbol plus a
    new dstate; a turn closure merges the two dstates' places (axiom 3.2), and a dstate keeps one
    place. Unlike the HSSH, nothing tells the basic SSH that ``Turn_j ∘ Turn_k = Turn_{j+k}``.
    Its leaves are partitions of the experienced dstates, while HSSH leaves also fix place
    identities and gateway correspondences, so "star leaves ≤ basic leaves" is an empirical
    comparison here, not a theorem (the hssh-maps study reports a counterexample).

    Returns:
        A :class:`TreeLog` whose ``leaves`` are ``(R, views, places, q)`` tuples and whose
        ``n_leaves`` has one entry per view *and* per turn.

    Args:
        experience: the exploration.
        max_leaves: a :class:`TreeTooLarge` is raised beyond this many leaves.

    Raises:
        ValueError: for an empty exploration; TreeTooLarge: beyond ``max_leaves`` leaves.
    """
    if len(experience.views) == 0:
        raise ValueError("an empty exploration has no view: the tree of maps has no root")
    v0 = view_symbol(experience.views[0])
    leaves = [({}, (v0,), (0,), 0)]
    stats = _TreeStats()
    for i, turn in enumerate(np.asarray(experience.turns)):
        star, a = experience.views[i]
        steps = []
        if int(turn) % len(star):
            steps.append((("turn", int(turn)), view_symbol((star, (a + int(turn)) % len(star)))))
        steps.append((("travel", 0), view_symbol(experience.views[i + 1])))
        for act, v in steps:
            nxt, bad_i, br, branched = [], 0, 0, False
            for r, views, places, q in leaves:
                if (q, act) in r:
                    q2 = r[(q, act)]
                    if views[q2] == v:
                        nxt.append((r, views, places, q2))
                    else:
                        bad_i += 1
                    continue
                succ, k = [], 0
                for qj, vj in enumerate(views):
                    if vj != v:
                        continue
                    k += 1
                    r2 = dict(r)
                    r2[(q, act)] = qj
                    pl = places
                    if act[0] == "turn" and places[qj] != places[q]:
                        old, new = places[qj], places[q]
                        pl = tuple(new if x == old else x for x in places)
                    succ.append((r2, views, pl, qj))
                r2 = dict(r)
                nq = len(views)
                r2[(q, act)] = nq
                place = places[q] if act[0] == "turn" else max(places) + 1
                succ.append((r2, (*views, v), (*places, place), nq))
                nxt.extend(succ)
                stats.k_max = max(stats.k_max, k)
                br = max(br, len(succ))
                branched |= len(succ) > 1
                if len(nxt) > max_leaves:
                    raise TreeTooLarge(f"more than {max_leaves} basic-SSH leaves")
            leaves = nxt
            stats.step(leaves, bad_i, br, branched)
    return stats.log(leaves)
