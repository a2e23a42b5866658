"""Topological navigation: routes over places and turn commands from the star (B §7.1.3, §5.1).

A route is a shortest path over the places of a map hypothesis (networkx, corridor length =
mean odometry distance of that corridor). At each place the exit gateway is named relative to
the arrival entry ``a`` by the star's qualitative left/right (B §5.1): ``Forward`` (exit ``a``
itself), ``TurnAround`` (exit ``opp(a)``), ``Right`` (entries strictly clockwise between ``a``
and ``opp(a)``) or ``Left`` (the others); with several exits on one side the command carries
their order from ``a``. Commands are relative, so they can be executed in the world without
knowing the map's labels: :func:`execute` replays them on the ground truth.

>>> from pqrm_jax.hssh_global.world import grid_world, explore
>>> from pqrm_jax.hssh_global.tree import build_tree
>>> w = grid_world(3, 3, seed=1); e = explore(w, 20, seed=0)
>>> h = build_tree(e).leaves[0]
>>> route, cmds = plan_route(h, e.odometry, h.q, h.visits[0][0])
>>> route[0] == h.q[0], route[-1] == h.visits[0][0], len(cmds) == len(route) - 1
(True, True, True)
"""

from __future__ import annotations

import networkx as nx
import numpy as np

from .star import Star
from .tree import MapHypothesis
from .world import CorridorWorld


class NavigationError(ValueError):
    """A goal or start that is not in the map, or no route."""


def map_graph(h: MapHypothesis, odometry) -> nx.DiGraph:
    """Directed place graph of a hypothesis; edge attributes ``gate``, ``arrive``, ``length``.

    Args:
        h: a map hypothesis.
        odometry: ``[n, 3]`` displacements (edge lengths from their norms).

    Returns:
        The ``networkx.DiGraph`` over places (B §7.1.3).
    """
    odo = np.asarray(odometry, float).reshape(-1, 3)
    lengths: dict = {}
    for i in range(len(h.visits) - 1):
        (p, _), (q, _) = h.visits[i], h.visits[i + 1]
        d = float(np.linalg.norm(odo[i, :2]))
        if np.isfinite(d):
            lengths.setdefault(frozenset((p, q)), []).append(d)
    g = nx.DiGraph()
    g.add_nodes_from(range(h.n_places))
    for (p, e), (q, f) in h.edges.items():
        ln = float(np.mean(lengths.get(frozenset((p, q)), [1.0])))
        if not g.has_edge(p, q) or g.edges[p, q]["length"] > ln:
            g.add_edge(p, q, gate=e, arrive=h.stars[q].opp[f], length=ln)
    return g


def command(star: Star, arrival: int, exit_: int) -> tuple[str, int]:
    """Turn command from arrival entry to exit entry (B §5.1 left/right of a directed path).

    Args:
        star: the place's star.
        arrival: the arrival entry index.
        exit_: the exit entry index (traversable).

    Returns:
        ``(kind, n)``: ``("Forward", 0)`` when the exit is the arrival entry,
        ``("TurnAround", 0)`` when it is its opposite, else ``"Right"``/``"Left"`` with the
        0-based rank ``n`` of the exit among the entries on that side, counted from the
        arrival entry (B §7.1.3).
    """
    n, o = len(star), star.opp[arrival]
    if exit_ == arrival:
        return ("Forward", 0)
    if exit_ == o:
        return ("TurnAround", 0)
    right = [(arrival + k) % n for k in range(1, (o - arrival) % n)]
    left = [(arrival - k) % n for k in range(1, (arrival - o) % n)]
    if exit_ in right:
        return ("Right", right.index(exit_))
    return ("Left", left.index(exit_))


def apply_command(star: Star, arrival: int, cmd: tuple[str, int]) -> int | None:
    """The exit entry a command names at a place, or ``None`` when the star has none.

    Args:
        star: the observed star at the place.
        arrival: the arrival entry index.
        cmd: ``(kind, n)`` as :func:`command` returns it (B §7.1.3).

    Returns:
        The exit entry index, or ``None``.
    """
    n, o = len(star), star.opp[arrival]
    name, k = cmd
    if name == "Forward":
        e = arrival
    elif name == "TurnAround":
        e = o
    else:
        side = ([(arrival + j) % n for j in range(1, (o - arrival) % n)] if name == "Right"
                else [(arrival - j) % n for j in range(1, (arrival - o) % n)])
        if k >= len(side):
            return None
        e = side[k]
    return e if star.alpha[e] else None


def plan_route(h: MapHypothesis, odometry, start: tuple[int, int], goal: int):
    """Shortest route from dstate ``start = (place, arrival entry)`` to place ``goal``.

    Returns:
        ``(places, commands)``: the place sequence and one command per travel.

    Raises:
        NavigationError: the start or goal place is not in the map, or no route exists.

    Args:
        h: the map hypothesis.
        odometry: ``[n, 3]`` displacements (edge lengths, B §7.1.3).
        start: the dstate ``(place, arrival entry)``.
        goal: the goal place.
    """
    g = map_graph(h, odometry)
    if goal not in g or start[0] not in g:
        raise NavigationError(f"place {goal if goal not in g else start[0]} is not in the map "
                              f"(places 0..{h.n_places - 1})")
    try:
        route = nx.shortest_path(g, start[0], goal, weight="length")
    except nx.NetworkXNoPath as exc:
        raise NavigationError(f"no route from place {start[0]} to {goal}") from exc
    cmds, arr = [], start[1]
    for p, q in zip(route[:-1], route[1:], strict=True):
        ed = g.edges[p, q]
        cmds.append(command(h.stars[p], arr, ed["gate"]))
        arr = ed["arrive"]
    return route, cmds


def execute(world: CorridorWorld, start: tuple[int, int], commands) -> tuple[list, float, bool]:
    """Executes turn commands in the ground-truth world from true dstate ``start``.

    Returns:
        ``(true places visited, distance travelled, all commands executable)``.

    Args:
        world: the ground-truth world.
        start: the true dstate ``(place, arrival entry)``.
        commands: the turn commands, one per travel (B §7.1.3).
    """
    p, arr = start
    places, dist = [p], 0.0
    for c in commands:
        e = apply_command(world.stars[p], arr, c)
        if e is None:
            return places, dist, False
        q, f, d = world.edges[(p, e)]
        p, arr, dist = q, world.stars[q].opp[f], dist + d
        places.append(p)
    return places, dist, True


def shortest_distance(world: CorridorWorld, a: int, b: int) -> float:
    """Ground-truth shortest corridor distance between two places (networkx Dijkstra).

    Args:
        world: the ground-truth world.
        a: a place.
        b: a place.

    Returns:
        The distance in world units.

    Raises:
        networkx.NetworkXNoPath: when the places are not connected.
    """
    return float(nx.shortest_path_length(world.graph(), a, b, weight="length"))


def evaluate_navigation(world: CorridorWorld, experience, h: MapHypothesis, n_pairs: int = 20,
                        seed: int = 0) -> dict:
    """Success rate and path-length ratio over random start/goal pairs using map ``h``.

    A start is a random visit of the experience (its map dstate and its true dstate are known);
    a goal is a random other map place, whose true place is the one of its first visit. Success:
    the commands are executable and end at the true goal place. ``length_ratio``: mean of
    distance travelled / shortest true distance over successes.

    Args:
        world: the ground-truth world.
        experience: the exploration ``h`` was built from.
        h: the map hypothesis navigated with.
        n_pairs: random start/goal pairs.
        seed: NumPy seed of the pairs.

    Returns:
        ``{"success": rate, "length_ratio": mean, "pairs": n_pairs}`` (NaN rates when the
        map has no usable pair).
    """
    rng = np.random.default_rng(seed)
    first = {}
    for i, (p, _) in enumerate(h.visits):
        first.setdefault(p, int(experience.true_places[i]))
    if h.n_places < 2:
        return {"success": float("nan"), "length_ratio": float("nan"), "pairs": 0}
    ok, ratios = 0, []
    for _ in range(n_pairs):
        i = int(rng.integers(len(h.visits)))
        ms = h.visits[i]
        goal = int(rng.choice([p for p in range(h.n_places) if p != ms[0]]))
        _, cmds = plan_route(h, experience.odometry, ms, goal)
        ts = (int(experience.true_places[i]), int(experience.true_arrivals[i]))
        places, dist, done = execute(world, ts, cmds)
        if done and places[-1] == first[goal]:
            ok += 1
            sd = shortest_distance(world, ts[0], first[goal])
            if sd > 0:
                ratios.append(dist / sd)
    return {"success": ok / n_pairs, "length_ratio": float(np.mean(ratios)) if ratios
            else float("nan"), "pairs": n_pairs}
