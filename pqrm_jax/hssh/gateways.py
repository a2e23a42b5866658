"""Base points, core, search spaces and gateways on a pruned skeleton (B §6.1.2--6.3.2).

Host-side geometry over the pruned tree of :mod:`pqrm_jax.hssh.skeleton` (a few hundred
nodes; per-branch crawling, counting and small arg-min searches):

* :func:`core` -- junctions, base points ``F`` and core ``Q`` (B Alg. 6.1).
* :func:`search_spaces` -- one branch per core-edge point ``e`` and its search space ``S_e``
  (B Alg. 6.2, first half).
* :func:`find_gateways` -- gateway location hypotheses by anchors (B Alg. 6.4--6.5) or by
  constrictions (B Alg. 6.2, the baseline), then the gateway segment (B Alg. 6.3).

Grid readings of the set definitions (decisions, all documented in ``docs/hssh.md``):

* Distances are between cell centres; the Voronoi radius ``r_p`` is the exact Euclidean
  distance transform at ``p``. A core-edge point (``dist(f, e) = r_f`` in B) is the last core
  node on each tree edge that leaves the core.
* A branch is the tree path through ``e`` that stops at junctions, at ``c`` and at leaves;
  ``S_e`` is its part within ``r_e`` of ``e``. "Inside" (toward the core) and "outside" are the
  two sides of ``e`` on it.
* Left/right of the branch at ``s`` uses one consistent direction, outward (core → frontier),
  from a tangent over +-2 branch nodes; obstacles are searched within ``r_s + sqrt 2`` (B
  §6.3.3, footnote 4). Ties between equally near obstacles go to the lowest ``(row, col)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import networkx as nx
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["Core", "Branch", "Gateway", "core", "search_spaces", "find_gateways",
           "obstacle_index", "SIDE_SLACK", "SIDE_CONE"]

_SQRT2 = math.sqrt(2.0)

SIDE_SLACK = 0.5
"""Relative slack of the side-obstacle search radius, ``r (1 + SIDE_SLACK) + sqrt 2``.

B searches within ``r + sqrt 2`` (§6.3.3, fn. 4); a thinned skeleton on rotated corridors
sits cells off the medial axis near junctions, so the far wall falls outside that radius
and the point is wrongly taken as coastal (one-sided), which tilts its gateway. Points of a
true coastal (EVG rim) branch have no obstacle on one side within ``M``, far beyond this."""


SIDE_CONE = 45.0
"""Half-angle (degrees) about the branch normal within which an obstacle counts as a *side*
obstacle of a skeleton point (left or right); obstacles nearer the branch direction are ahead
or behind, not on a side.

B's ``left_of`` (Alg. 6.4) splits the plane by the branch line only, so an obstacle straight
behind a point counts as "left" or "right" by a hair. In a wide junction aligned with the grid
the wall facing a branch across the junction (the T's top wall seen from its stem, the L's
outer wall seen from the other arm) is then the nearest "side" obstacle of the branch points
inside the core; Alg. 6.5 takes the first of them as the location hypothesis, and Alg. 6.3
lays the gateway across the junction centre. With the quadrant rule (45°: more lateral than
longitudinal) those walls are ahead, and the hypothesis stays at the arm's mouth. Every corner
of a + or T seen from a point inside its junction square lies at least 45° off the branch, so
those keep their role. 90 gives B's half-plane rule."""


class Core(NamedTuple):
    """Result of B Alg. 6.1.

    junctions: tree nodes of degree >= 3.
    base_points: ``F`` (junctions near ``c`` and their neighbours, or ``[c]``).
    core: ``Q``, the set of tree nodes within ``r_f`` of some base point.
    centre: mean of the base points, float ``[2]`` (row, col).
    """

    junctions: list[tuple[int, int]]
    base_points: list[tuple[int, int]]
    core: set[tuple[int, int]]
    centre: np.ndarray


class Branch(NamedTuple):
    """A skeleton branch through a core-edge point (B Alg. 6.2).

    nodes: ``[L, 2]`` int cells ordered from the core outward.
    edge_index: position of ``e`` in ``nodes``.
    pos: ``[L]`` signed skeleton distance from ``e`` (negative inside the core).
    search: ``[L]`` bool, membership of ``S_e``.
    """

    nodes: np.ndarray
    edge_index: int
    pos: np.ndarray
    search: np.ndarray


class Gateway(NamedTuple):
    """One gateway (B §5.2.1): a segment with an outward direction.

    ends: float ``[2, 2]`` end points (row, col); ``ends[0]`` is on the left looking out.
    centre: float ``[2]`` the skeleton point ``n_e`` it is centred on.
    outward: float ``[2]`` unit vector (row, col) pointing away from the place.
    radius: Voronoi radius at the centre (half the segment length).
    anchor: the anchor obstacle cell (None for the constriction method).
    coastal: True when the segment came from the coastal rule of B Alg. 6.5.
    """

    ends: np.ndarray
    centre: np.ndarray
    outward: np.ndarray
    radius: float
    anchor: tuple[int, int] | None
    coastal: bool


def _radius(dist2: np.ndarray, node) -> float:
    return math.sqrt(float(dist2[node]))


def core(tree: nx.Graph, closest: tuple[int, int], dist2: np.ndarray) -> Core:
    """Base points and core of a pruned skeleton (B Alg. 6.1).

    Args:
        tree: pruned skeleton tree (nodes ``(row, col)``).
        closest: ``c``, the tree node closest to the robot.
        dist2: squared distance transform ``[H, W]``.

    Returns:
        :class:`Core`.
    """
    nodes = list(tree.nodes)
    xy = np.array(nodes, float).reshape(-1, 2)
    r = np.sqrt(dist2[xy[:, 0].astype(int), xy[:, 1].astype(int)].astype(float))
    junctions = sorted(v for v in nodes if tree.degree(v) >= 3)
    c = np.array(closest, float)
    rj = {j: _radius(dist2, j) for j in junctions}
    frontier = [j for j in junctions if np.hypot(*(np.array(j) - c)) <= rj[j]]
    base = set(frontier)
    while frontier:
        j = frontier.pop()
        for k in junctions:
            if k not in base and math.dist(j, k) <= max(rj[j], rj[k]):
                base.add(k)
                frontier.append(k)
    base_points = sorted(base) if base else [closest]
    inside = np.zeros(len(nodes), bool)
    for f in base_points:
        rf = _radius(dist2, f)
        inside |= np.hypot(xy[:, 0] - f[0], xy[:, 1] - f[1]) <= rf + 1e-9
    del r
    q = {nodes[i] for i in np.nonzero(inside)[0]}
    centre = np.mean(np.array(base_points, float), axis=0)
    return Core(junctions, base_points, q, centre)


def _walk(tree, start, prev, stop):
    """Nodes from ``start`` away from ``prev`` until a node in ``stop`` or a leaf/fork."""
    out = []
    u, p = start, prev
    while True:
        if u in stop:
            return out
        out.append(u)
        nxt = [v for v in tree.neighbors(u) if v != p]
        if len(nxt) != 1:
            return out
        p, u = u, nxt[0]


def search_spaces(tree: nx.Graph, closest: tuple[int, int], cr: Core,
                  dist2: np.ndarray, stops=()) -> list[Branch]:
    """Branches leaving the core and their search spaces ``S_e`` (B Alg. 6.2).

    Args:
        tree: the pruned skeleton tree (:func:`~pqrm_jax.hssh.skeleton.prune_skeleton`).
        closest: ``(row, col)`` skeleton cell closest to the robot.
        cr: the core (:class:`Core`).
        dist2: ``[H, W]`` squared distance transform.
        stops: more nodes where branches stop, as at junctions (the pruned skeleton's
            ``forks``).

    Returns:
        one :class:`Branch` per tree edge ``(e, o)`` with ``e`` in the core, ``o`` outside.
    """
    stop = set(cr.junctions) | {closest} | set(stops)
    out = []
    for e in sorted(cr.core):
        for o in sorted(tree.neighbors(e)):
            if o in cr.core:
                continue
            outside = _walk(tree, o, e, stop)
            ins = [v for v in tree.neighbors(e) if v != o]
            inside = _walk(tree, ins[0], e, stop) if len(ins) == 1 and e not in stop else []
            nodes = np.array(inside[::-1] + [e] + outside, int).reshape(-1, 2)
            k = len(inside)
            steps = np.hypot(*np.diff(nodes, axis=0).T) if len(nodes) > 1 else np.zeros(0)
            cum = np.concatenate([[0.0], np.cumsum(steps)])
            pos = cum - cum[k]
            re = _radius(dist2, e)
            search = np.hypot(nodes[:, 0] - e[0], nodes[:, 1] - e[1]) <= re + 1e-9
            out.append(Branch(nodes, k, pos, search))
    return out


def obstacle_index(occupied: np.ndarray) -> tuple[cKDTree | None, np.ndarray]:
    """KD-tree over the boundary obstacle cells (occupied cells next to a non-occupied one).

    Returns:
        ``(tree, cells)`` with ``cells`` int ``[N, 2]``; ``tree`` is None without obstacles.
    """
    occ = np.asarray(occupied, bool)
    pad = np.pad(occ, 1, constant_values=True)
    interior = np.ones_like(occ)
    h, w = occ.shape
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            interior &= pad[1 + di:1 + di + h, 1 + dj:1 + dj + w]
    cells = np.argwhere(occ & ~interior)
    return (cKDTree(cells) if len(cells) else None), cells


def _tangents(nodes: np.ndarray, k: int = 2) -> np.ndarray:
    n = len(nodes)
    if n == 1:
        return np.zeros((1, 2))
    idx = np.arange(n)
    t = nodes[np.minimum(idx + k, n - 1)] - nodes[np.maximum(idx - k, 0)]
    return t.astype(float)


_K_NEAR = (32, 256)  # neighbours fetched per point by the rounds of _closest_sides


def _pick_sides_rows(cid, dd, inside, pts, tan, cells, cone=SIDE_CONE):
    """Per (point, side): the candidate with the least (distance, row, col); -1 if none.

    Candidates are rows ``cid [m, k]`` (one per point, ``inside`` marks the real ones, ``dd``
    their squared distances); the pick is one argmin of a combined integer key, without a
    sort. Also returns each pick's squared distance (-1 where none)."""
    v = cells[cid] - pts[:, None, :]
    cross = tan[:, None, 1] * (-v[..., 0]) - (-tan[:, None, 0]) * v[..., 1]
    if cone < 90.0:  # side obstacles only within +-cone of the normal (SIDE_CONE)
        along = tan[:, None, 0] * v[..., 0] + tan[:, None, 1] * v[..., 1]
        inside = inside & (np.abs(along) <= np.abs(cross) * math.tan(math.radians(cone)))
    w = int(cells[:, 1].max()) + 1
    hw = (int(cells[:, 0].max()) + 1) * w
    key = dd.astype(np.int64) * hw + cells[cid, 0].astype(np.int64) * w + cells[cid, 1]
    none = np.iinfo(np.int64).max
    rows = np.arange(len(cid))
    out = []
    for sel in (inside & (cross > 0), inside & (cross < 0)):  # left, right
        kk = np.where(sel, key, none)
        j = np.argmin(kk, axis=1)
        ok = kk[rows, j] < none
        out.append((np.where(ok, cid[rows, j], -1), np.where(ok, dd[rows, j], -1)))
    (left, dl), (right, dr) = out
    return left, right, dl, dr


def _closest_sides(points, tangents, radii, kd, cells, slack, cone=SIDE_CONE):
    """Closest left and right obstacle (index into ``cells`` or -1) of each point, searched
    within ``R = r (1 + slack) + sqrt 2``; ties to the lowest (row, col).

    Rounds of ``k`` nearest obstacle cells (``_K_NEAR``; one vectorised KD query per round). A
    side's pick among them is the answer when every cell at least as close is in the list: the
    list's farthest cell is strictly farther, or the list holds the whole ball (fewer than
    ``k`` cells within ``R``). Points left after the last round take the exhaustive ball
    query (:func:`_closest_sides_ball`); the result is the same as the ball query for all.
    """
    n = len(points)
    left, right = np.full(n, -1), np.full(n, -1)
    if kd is None or n == 0:
        return left, right
    pts = np.asarray(points)
    tan = np.asarray(tangents, float)
    reach = np.asarray(radii, float) * (1.0 + slack) + _SQRT2 + 1e-9
    todo = np.arange(n)
    for k in _K_NEAR:
        k = min(k, len(cells))
        m = len(todo)
        _, idx = kd.query(pts[todo], k=k, distance_upper_bound=float(reach[todo].max()))
        idx = np.asarray(idx).reshape(m, k)
        have = idx < len(cells)
        cid = np.where(have, idx, 0)
        dd = ((cells[cid] - pts[todo][:, None, :]) ** 2).sum(axis=-1)
        inside = have & (np.sqrt(dd) <= reach[todo][:, None])
        lt, rt, dl, dr = _pick_sides_rows(cid, dd, inside, pts[todo], tan[todo], cells, cone)
        whole_ball = inside.sum(axis=1) < k
        far = np.where(inside[:, -1], dd[:, -1], -1)  # the list's farthest in-ball cell
        exact = whole_ball | ((dl >= 0) & (dr >= 0) & (far > dl) & (far > dr))
        left[todo[exact]], right[todo[exact]] = lt[exact], rt[exact]
        todo = todo[~exact]
        if len(todo) == 0:
            return left, right
    left[todo], right[todo] = _closest_sides_ball(pts[todo], tan[todo], reach[todo], kd, cells,
                                                  cone)
    return left, right


def _closest_sides_ball(pts, tan, reach, kd, cells, cone=SIDE_CONE):
    """Exhaustive form of :func:`_closest_sides`: every obstacle cell within ``reach``
    (one vectorised ball query, padded to rows of the largest ball)."""
    n = len(pts)
    cand = kd.query_ball_point(pts, reach)
    lens = np.fromiter((len(c) for c in cand), int, count=n)
    inside = np.arange(max(int(lens.max(initial=0)), 1))[None, :] < lens[:, None]
    cid = np.zeros(inside.shape, int)
    cid[inside] = np.fromiter((k for c in cand for k in c), int, count=int(lens.sum()))
    dd = ((cells[cid] - pts[:, None, :]) ** 2).sum(axis=-1)
    left, right, _, _ = _pick_sides_rows(cid, dd, inside, pts, tan, cells, cone)
    return left, right


def _segment_point(nodes, a, b):
    """Index of the branch node nearest to segment a-b (ties: nearest to its midpoint)."""
    ab = b - a
    L2 = float(ab @ ab)
    p = nodes.astype(float)
    t = np.clip(((p - a) @ ab) / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(p))
    d = np.hypot(*(p - (a + t[:, None] * ab)).T)
    m = np.hypot(*(p - 0.5 * (a + b)).T)
    return int(np.lexsort((m, np.round(d, 9)))[0])


def _segment(br: Branch, i: int, dist2, kd, cells, left, right):
    """B Alg. 6.3 from hypothesis index ``i``: returns (centre index, direction v inward)."""
    nodes = br.nodes
    seen = {i}
    for _ in range(16):
        if left[i] < 0 or right[i] < 0:
            break
        j = _segment_point(nodes, cells[left[i]].astype(float), cells[right[i]].astype(float))
        if j == i or j in seen:
            break
        seen.add(j)
        i = j
    n = nodes[i].astype(float)
    rn = _radius(dist2, tuple(nodes[i]))
    d = np.hypot(*(nodes - n).T)
    near = (d <= rn + 1e-9) & (d > 0)
    inner = near & (br.pos < br.pos[i])
    outer = near & (br.pos > br.pos[i])
    v = np.zeros(2)
    for mask, sign in ((inner, 1.0), (outer, -1.0)):
        if mask.any():
            vec = (nodes[mask] - n) * sign
            dist = d[mask]
            v += ((vec / dist[:, None]) * dist[:, None]).sum(axis=0)
    if not np.any(v):
        t = _tangents(nodes)[i]
        v = -t if np.any(t) else np.array([1.0, 0.0])
    return i, v / np.hypot(*v)


def _make(centre, inward, half, anchor, coastal):
    out = -inward
    # left of the outward direction (screen frame): rotate (x, y) = (col, -row) by +90 deg
    left_dir = np.array([-out[1], out[0]])
    ends = np.stack([centre + half * left_dir, centre - half * left_dir])
    return Gateway(ends, centre, out, half, anchor, coastal)


def find_gateways(branches: list[Branch], dist2: np.ndarray, occupied: np.ndarray,
                  method: str = "anchor",
                  index: tuple[cKDTree | None, np.ndarray] | None = None,
                  side_slack: float = SIDE_SLACK,
                  side_cone: float = SIDE_CONE) -> list[Gateway]:
    """Gateways on each branch (B Alg. 6.4--6.5 for ``"anchor"``, Alg. 6.2 for
    ``"constriction"``; the segment by Alg. 6.3, or the coastal rule of Alg. 6.5).

    Args:
        branches: from :func:`search_spaces`.
        dist2: squared distance transform ``[H, W]``.
        occupied: bool ``[H, W]`` obstacles (after island removal and bleeding).
        method: ``"anchor"`` (B §6.3.2) or ``"constriction"`` (B §6.2, the baseline).
        index: a precomputed :func:`obstacle_index` of ``occupied``.
        side_slack: obstacles on each side are searched within ``r (1 + side_slack) +
            sqrt 2`` (see :data:`SIDE_SLACK`).
        side_cone: half-angle (degrees, in (0, 90]) about the branch normal of the side
            obstacles (see :data:`SIDE_CONE`; 90 is B's half-plane rule).

    Returns:
        list of :class:`Gateway`, one per branch that has a search space.
    """
    if method not in ("anchor", "constriction"):
        raise ValueError(f"method must be 'anchor' or 'constriction', got {method!r}")
    if not (0.0 < float(side_cone) <= 90.0):
        raise ValueError(f"side_cone must be in (0, 90] degrees, got {side_cone!r}")
    kd, cells = obstacle_index(occupied) if index is None else index
    gws = []
    for br in branches:
        nodes = br.nodes
        s_idx = np.nonzero(br.search)[0]
        if len(s_idx) == 0:
            continue
        radii = np.sqrt(dist2[nodes[:, 0], nodes[:, 1]].astype(float))
        tang = _tangents(nodes)
        e = br.edge_index
        # sides are needed in S_e and where Alg. 6.3 may move (a few radii of e)
        near = np.hypot(*(nodes - nodes[e]).T) <= 3.0 * radii[e] + 2.0
        left = np.full(len(nodes), -1)
        right = np.full(len(nodes), -1)
        left[near], right[near] = _closest_sides(nodes[near], tang[near], radii[near], kd,
                                                 cells, side_slack, float(side_cone))
        absd = np.abs(br.pos)
        anchor = None
        if method == "constriction":
            rs = radii[s_idx]
            cand = s_idx[np.isclose(rs, rs.min())]
            h = int(cand[np.argmin(absd[cand])])
        else:
            counts: dict[int, int] = {}
            for s in s_idx:
                for o in (left[s], right[s]):
                    if o >= 0:
                        counts[o] = counts.get(o, 0) + 1
            if not counts:
                h = e
            else:
                best = max(counts.values())
                tied = [o for o, k in counts.items() if k == best]
                a = min(tied, key=lambda o: (float(np.hypot(*(cells[o] - nodes[e]))),
                                             tuple(cells[o])))
                anchor = (int(cells[a, 0]), int(cells[a, 1]))
                has_a = (left == a) | (right == a)
                inside = s_idx[br.pos[s_idx] < 0]
                outside = s_idx[br.pos[s_idx] > 0]
                if has_a[e]:
                    pick = [inside[~has_a[inside]], outside[~has_a[outside]], np.array([e])]
                else:
                    pick = [inside[has_a[inside]], outside[has_a[outside]], np.array([e])]
                cand = next(p for p in pick if len(p))
                h = int(cand[np.argmin(absd[cand])])
        coastal = left[h] < 0 or right[h] < 0
        if method == "anchor" and coastal and anchor is not None:
            rh = radii[h]
            centre = nodes[h].astype(float)
            along = centre - np.array(anchor, float)
            if not np.any(along):
                along = np.array([1.0, 0.0])
            along /= np.hypot(*along)
            normal = np.array([along[1], -along[0]])
            t = tang[h]
            if np.dot(normal, t) > 0:
                normal = -normal
            gws.append(_make(centre, normal, rh, anchor, True))
            continue
        i, v = _segment(br, h, dist2, kd, cells, left, right)
        gws.append(_make(nodes[i].astype(float), v, radii[i], anchor, False))
    return gws
