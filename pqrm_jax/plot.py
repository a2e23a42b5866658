"""Figures of the maps every system builds (matplotlib; each function returns its ``Axes``).

* :func:`draw_relational_map` — a PQRM ``MapState`` or a QRM ``QRMMap`` over its landmarks: one
  mark per landmark triple at the centroid of its triangle (outlined in light grey), coloured
  by the uncertainty of its relation (PQRM: entropy of the row in bits; QRM: log2 of the size
  of the state set), a circle where the most likely state equals the true one, a red-edged
  diamond where it does not (P §2.4 map accuracy, M §VIII.A). Triangles of a dense map share
  their edges, so a per-triple mark, not an edge style or an overlapping fill, carries it.
* :func:`draw_link_graph` — a Q-Link Link Graph over its landmarks (P §4.3.2): elements at the
  centroid of their landmarks, edges, a planned element path and a driven trajectory.
* :func:`draw_local_topology` — an HSSH local topology over its occupancy grid (B ch. 5–6):
  occupied / free / unknown cells, the pruned skeleton, gateways with outward normals.
* :func:`draw_topological_map` — an HSSH map hypothesis (B ch. 8–9) drawn at its layout (place
  poses ``[m, 3]`` from ``hssh_global.relax`` or ``true_layout``), or a spring layout.

>>> import matplotlib; matplotlib.use("Agg")
>>> import numpy as np
>>> from pqrm_jax import plot, qrm
>>> lm = np.array([[0., 0.], [4., 0.], [1., 3.], [5., 4.]])
>>> ax = plot.draw_relational_map(lm, qrm.true_map(lm), calculus="edc")
>>> ax.get_xlabel()
'x'
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection

__all__ = ["draw_relational_map", "draw_link_graph", "draw_local_topology",
           "draw_topological_map", "CORRECT", "WRONG", "NO_STATE"]

#: legend labels of :func:`draw_relational_map`'s three kinds of triple mark
CORRECT = "ML state = true state"
WRONG = "ML state wrong or not unique"
NO_STATE = "layout on a boundary (no true state)"


def _axes(ax: Axes | None, size=(6, 5)) -> Axes:
    if ax is None:
        _, ax = plt.subplots(figsize=size, constrained_layout=True)
    return ax


def _landmarks(ax: Axes, lm: np.ndarray, labels: bool = True) -> None:
    ax.scatter(lm[:, 0], lm[:, 1], s=36, c="k", zorder=5, label="landmark")
    if labels:
        for i, (x, y) in enumerate(lm):
            ax.annotate(str(i), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8,
                        zorder=6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x")
    ax.set_ylabel("y")


def _map_rows(state, calculus: str, n: int, triplets):
    """(triplets [T, 3], ml state [T] (-1 unmapped), uncertainty [T] bits, max bits)."""
    from .calculi import get
    calc = get(calculus)
    q = calc.num_states
    if hasattr(state, "rel"):  # QRMMap: uint32 masks of ij:k
        rel = np.asarray(state.rel)
        i, j, k = np.asarray(triplets).T
        masks = rel[i, j, k].astype(np.int64)
        bits = (masks[:, None] >> np.arange(q)) & 1
        size = bits.sum(1)
        ml = np.where(size == 1, bits.argmax(1), -1)
        unc = np.log2(np.maximum(size, 1)).astype(float)
        unc[size == 0] = np.nan
        return ml, unc, math.log2(q)
    probs = state.probs[calculus] if isinstance(state.probs, dict) else state.probs
    p = np.asarray(probs, float)
    mapped = np.asarray(state.mapped, bool) & (p.sum(1) > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(np.where(p > 0, p * np.log2(p), 0.0)).sum(1)
    ml = np.where(mapped, p.argmax(1), -1)
    return ml, np.where(mapped, h, np.nan), math.log2(q)


def draw_relational_map(landmarks, state, *, calculus: str = "edc", triplets=None,
                        ax: Axes | None = None, max_triangles: int = 60,
                        title: str | None = None) -> Axes:
    """A PQRM or QRM map over its landmarks ``[N, 2]``.

    For each unordered triple ``{i < j < k}`` the relation ``ij:k`` is shown by one mark at
    the centroid of the triangle ``ijk`` (the triangle itself is outlined in light grey),
    coloured by its uncertainty (bits; 0 = certain): a circle where the most likely state
    (PQRM: arg max of the row; QRM: the single state of a singleton set) is the true state of
    the landmark layout, a red-edged diamond where it is not or is not unique, a grey square
    where the layout itself lies on a boundary of an open calculus and has no state. At most
    ``max_triangles`` triples, the most certain first (unmapped triples are skipped).

    Args:
        landmarks: ``[N, 2]`` positions.
        state: a PQRM ``MapState`` (rows over ``triplets``, default every ordered triplet)
            or a QRM ``QRMMap``.
        calculus: the representation to show (a key of ``state.probs`` for PQRM).
        triplets: ``[T, 3]`` rows of a sparse PQRM map (default: all ordered triplets).
        ax: axes to draw into (a new figure when None).
        max_triangles: cap on the triples drawn.
        title: axes title (default: map kind, calculus, accuracy).

    Returns:
        The ``Axes``; its marks are the collections labelled :data:`CORRECT`,
        :data:`WRONG` and :data:`NO_STATE` (one point per triple).
    """
    from .calculi import get
    from .triplets import ordered_triplets

    lm = np.asarray(landmarks, float)
    n = lm.shape[0]
    trip = ordered_triplets(n) if triplets is None else np.asarray(triplets, np.int32)
    ml, unc, hmax = _map_rows(state, calculus, n, trip)
    calc = get(calculus)
    true = np.asarray(calc.classify(lm[trip[:, 0]], lm[trip[:, 1]], lm[trip[:, 2]]))
    keep = (trip[:, 0] < trip[:, 1]) & (trip[:, 1] < trip[:, 2]) & np.isfinite(unc)
    idx = np.flatnonzero(keep)
    idx = idx[np.argsort(unc[idx], kind="stable")][:max_triangles]
    ax = _axes(ax)
    tri = lm[trip[idx]]                                        # [K, 3, 2]
    ax.add_collection(LineCollection(np.concatenate([tri, tri[:, :1]], 1), colors="0.8",
                                     linewidths=0.5, zorder=1))
    cen = tri.mean(axis=1) if len(idx) else np.zeros((0, 2))
    cmap, norm = plt.get_cmap("viridis_r"), plt.Normalize(0, hmax)
    ok = (ml[idx] >= 0) & (ml[idx] == true[idx])
    none = true[idx] < 0
    for sel, marker, edge, label in ((ok & ~none, "o", "k", CORRECT),
                                     (~ok & ~none, "D", "tab:red", WRONG),
                                     (none, "s", "0.5", NO_STATE)):
        if sel.any():
            ax.scatter(cen[sel, 0], cen[sel, 1], c=unc[idx][sel], cmap=cmap, norm=norm,
                       marker=marker, s=48, edgecolors=edge, linewidths=1.2, zorder=4,
                       label=label)
    ax.figure.colorbar(plt.cm.ScalarMappable(cmap=cmap, norm=norm), ax=ax,
                       label="uncertainty of ij:k (bits)")
    _landmarks(ax, lm)
    ax.legend(loc="upper left", bbox_to_anchor=(0, -0.12), ncol=2, fontsize=7, frameon=False)
    judged = keep & (true >= 0)  # a layout on a boundary of an open calculus has no state
    acc = float(np.mean(ml[judged] == true[judged])) if judged.any() else float("nan")
    kind = "QRM" if hasattr(state, "rel") else "PQRM"
    ax.set_title(title or f"{kind} map ({calculus}): {int(keep.sum())} triples mapped, "
                 f"ML state correct {acc:.0%}", fontsize=10)
    return ax


def draw_link_graph(landmarks, elements, graph, *, planned=None, driven=None,
               ax: Axes | None = None, title: str | None = None) -> Axes:
    """A Link Graph (P §4.3.2) over its landmarks.

    Args:
        landmarks: ``[N, 2]``.
        elements: the ``MapElements`` (``ids [E, 3]``).
        graph: the ``LinkGraph`` (``cost [E, E]``, inf = no edge).
        planned: optional element path ``[L]`` (``-1`` padding allowed; a ``Plan.path`` row).
        driven: optional trajectory ``[K, 2]`` (NaN rows are skipped; a ``NavResult.trace``
            row).
        ax: the axes to draw into (None: a new figure).
        title: the axes title.

    Returns:
        The ``Axes``: elements at their landmarks' centroids, Link Graph edges, the planned
        element path and the driven trajectory, each with a legend label.
    """
    lm = np.asarray(landmarks, float)
    ids = np.asarray(elements.ids)
    cen = lm[ids].mean(axis=1)
    ax = _axes(ax)
    src, dst = np.nonzero(np.isfinite(np.asarray(graph.cost)))
    ax.add_collection(LineCollection(np.stack([cen[src], cen[dst]], 1), colors="0.75",
                                     lw=0.6, zorder=1, label="Link Graph edge"))
    ax.scatter(cen[:, 0], cen[:, 1], s=12, c="tab:blue", zorder=3, label="map element")
    if planned is not None:
        path = np.asarray(planned)
        path = path[path >= 0]
        if path.size:
            ax.plot(cen[path, 0], cen[path, 1], "-o", color="tab:orange", lw=2, ms=5, zorder=4,
                    label=f"planned path ({path.size} elements)")
            for e in path[[0, -1]]:
                tri = lm[ids[e]]
                ax.fill(tri[:, 0], tri[:, 1], color="tab:orange", alpha=0.15)
    if driven is not None:
        d = np.asarray(driven, float)
        d = d[np.isfinite(d).all(axis=1)]
        if len(d):
            ax.plot(d[:, 0], d[:, 1], color="tab:green", lw=1.5, zorder=4, label="driven path")
            ax.plot(*d[0], "g^", ms=8, zorder=6)
            ax.plot(*d[-1], "gs", ms=7, zorder=6)
    _landmarks(ax, lm)
    ax.legend(loc="upper left", bbox_to_anchor=(0, -0.12), ncol=2, fontsize=7, frameon=False)
    ax.set_title(title or f"Link Graph: {len(ids)} elements, {len(src)} edges "
                 f"(β = {graph.beta})", fontsize=10)
    return ax


def draw_local_topology(grid, topology, *, unknown=None, robot_cell=None, ax: Axes | None = None,
                   title: str | None = None) -> Axes:
    """An HSSH local topology over its grid (B ch. 5–6), in cell coordinates (row 0 on top).

    Args:
        grid: ``[H, W]`` bool occupancy (True = occupied) or uint8 grey image.
        topology: the ``LocalTopology``.
        unknown: optional ``[H, W]`` bool unknown cells (drawn grey).
        robot_cell: optional ``(row, col)`` of the robot.
        ax: the axes to draw into (None: a new figure).
        title: the axes title.

    Returns:
        The ``Axes``: the grid, the pruned skeleton, the numbered gateways with their
        outward directions, the core centre and the robot, each with a legend label.
    """
    from .hssh import occupancy_from_grid

    occ = occupancy_from_grid(np.asarray(grid))
    img = np.where(occ, 0.0, 1.0)
    if unknown is not None:
        img = np.where(np.asarray(unknown, bool), 0.7, img)
    ax = _axes(ax)
    ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    tree = topology.skeleton.tree
    if tree.number_of_edges():
        seg = np.array([[(u[1], u[0]), (v[1], v[0])] for u, v in tree.edges()], float)
        ax.add_collection(LineCollection(seg, colors="tab:blue", lw=1.2, label="skeleton"))
    for g, (ends, out) in enumerate(zip(topology.gateways, topology.outward, strict=True)):
        ends = np.asarray(ends, float)
        ax.plot(ends[:, 1], ends[:, 0], color="tab:red", lw=2.5,
                label="gateway" if g == 0 else None)
        mid = ends.mean(0)
        ax.annotate("", xy=(mid[1] + 3 * out[1], mid[0] + 3 * out[0]), xytext=(mid[1], mid[0]),
                    arrowprops={"arrowstyle": "->", "color": "tab:red"})
        ax.annotate(str(g), (mid[1], mid[0]), textcoords="offset points", xytext=(3, 3),
                    color="tab:red", fontsize=8)
    if topology.core is not None:
        c = np.asarray(topology.core.centre, float)
        ax.plot(c[1], c[0], "D", color="tab:purple", ms=6, label="core centre")
    if robot_cell is not None:
        ax.plot(robot_cell[1], robot_cell[0], "o", color="tab:green", ms=7, label="robot")
    ax.set_xlabel("column (cells)")
    ax.set_ylabel("row (cells)")
    ax.legend(loc="lower left", fontsize=7, framealpha=0.8)
    star = " ".join(f"{p}{'+' if d > 0 else '-'}{'' if a else '×'}"
                    for p, d, a in topology.star)
    ax.set_title(title or f"local topology: {topology.kind}, {topology.num_paths} paths, "
                 f"star ({star})", fontsize=10)
    return ax


def draw_topological_map(hypothesis, layout=None, *, ax: Axes | None = None,
                    title: str | None = None) -> Axes:
    """An HSSH map hypothesis (B ch. 8): places and corridors, drawn at ``layout`` ``[m, 3]``
    (x, y, heading of each place; e.g. a row of ``hssh_global.relax``'s ``chi``) or, when
    None, at a spring layout of its place graph (the topology alone).

    Args:
        hypothesis: the ``MapHypothesis`` (places, stars, corridor edges).
        layout: ``[m, 3]`` place poses (x, y, heading), or None for a spring layout.
        ax: the axes to draw into (None: a new figure).
        title: the axes title.

    Returns:
        The ``Axes``: places as numbered points, corridors as lines between them; the axis
        labels say whether the positions are metric (a layout) or not (spring layout).
    """
    import networkx as nx

    from .io import networkx_graph

    g = networkx_graph(hypothesis)
    m = hypothesis.n_places
    if layout is None:
        pos = nx.spring_layout(g, seed=0)
        xy = np.array([pos[i] for i in range(m)])
        xl, yl = "layout x (spring, no metric meaning)", "layout y"
    else:
        xy = np.asarray(layout, float)[:m, :2]
        xl, yl = "x", "y"
    ax = _axes(ax)
    seg = [(xy[u], xy[v]) for u, v in g.edges()]
    if seg:
        ax.add_collection(LineCollection(np.array(seg), colors="tab:blue", lw=1.5,
                                         label="corridor"))
    ax.scatter(xy[:, 0], xy[:, 1], s=120, c="w", edgecolors="k", zorder=3, label="place")
    for i, (x, y) in enumerate(xy):
        ax.annotate(str(i), (x, y), ha="center", va="center", fontsize=8, zorder=4)
    if layout is not None:
        th = np.asarray(layout, float)[:m, 2]
        span = np.ptp(xy, axis=0).max() if m > 1 else 1.0
        ax.quiver(xy[:, 0], xy[:, 1], np.cos(th), np.sin(th), angles="xy", scale_units="xy",
                  scale=10 / max(span, 1e-12), width=0.004, color="0.4", zorder=2)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.legend(loc="upper left", bbox_to_anchor=(0, -0.12), ncol=2, fontsize=7, frameon=False)
    ax.set_title(title or f"topological map: {m} places, {g.number_of_edges()} corridors",
                 fontsize=10)
    return ax
