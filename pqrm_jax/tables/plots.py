"""Figures of calculi and their tables (matplotlib)."""

from __future__ import annotations

import numpy as np

from ..calculi.calculus import Calculus


def _axis(extent: float, n: int, shift: float) -> np.ndarray:
    """``n``-ish grid coordinates in ``[shift - extent, shift + extent]`` on a binary-fraction
    step, so that 0, 1/2 and 1 (the lines through A and B) are sample points exactly."""
    step = 2.0 ** np.floor(np.log2(2 * extent / n))
    k = int(np.ceil(extent / step))
    return shift + step * np.arange(-k, k + 1)


def region_image(calc: Calculus, extent: float = 2.5, n: int = 400) -> np.ndarray:
    """State index of C over a grid of the canonical frame (A=(0,0), B=(0,1)), ``[ny, nx]``.

    The grid step is a power of two and the grid holds x = 0 and y = 0, 1/2, 1 exactly, so
    the line and point relations of a boundary-inclusive calculus (dcc, lr_full) get their
    cells (classification is exact there).
    """
    xs = _axis(extent, n, 0.0)
    ys = _axis(extent, n, 0.5)
    X, Y = np.meshgrid(xs, ys)
    pts = np.stack([X, Y], -1)
    return np.asarray(calc.classify(np.zeros(2), np.array([0.0, 1.0]), pts))


def plot_regions(calc: Calculus, ax=None, extent: float = 2.5, n: int = 400, labels=True):
    """Draw the relations AB:C with A=(0,0), B=(0,1), every one that this frame can show.

    Area relations are filled; line relations (a set of zero area: C on the line AB or on a
    perpendicular) are drawn as thick coloured lines and point relations (C = A, C = B) as
    markers, each labelled, so a boundary-inclusive calculus shows all its relations with
    A ≠ B. Relations that need A = B (dou, tri) cannot occur in this frame; the axes name them.
    Unlabelled white is where an open calculus has no relation (a boundary).
    """
    import matplotlib.pyplot as plt

    ax = ax or plt.gca()
    xs = _axis(extent, n, 0.0)
    ys = _axis(extent, n, 0.5)
    raw = region_image(calc, extent, n)
    counts = np.bincount(raw[raw >= 0].ravel(), minlength=calc.num_states)
    thin = counts < 0.004 * raw.size  # line / point relations (zero area)
    img = raw.astype(float)
    img[(raw < 0) | thin[np.maximum(raw, 0)]] = np.nan
    cmap = plt.get_cmap("tab20")
    ext = (xs[0], xs[-1], ys[0], ys[-1])
    ax.imshow(img, origin="lower", cmap=cmap, vmin=0, vmax=19, interpolation="nearest",
              extent=ext, alpha=0.85)
    placed = []
    for i in np.flatnonzero(thin & (counts > 0)):
        yy, xx = np.nonzero(raw == i)
        col = cmap(i % 20)
        if counts[i] <= 4:  # a point relation
            ax.plot(xs[xx].mean(), ys[yy].mean(), "o", ms=9, mfc=col, mec="k", zorder=5)
        else:
            ax.scatter(xs[xx], ys[yy], s=14, color=col, edgecolors="none", zorder=4)
        placed.append(i)
    ax.plot([0, 0], [0, 1], "k-", lw=0.8, zorder=3)
    ax.text(-0.12, -0.05, "A", va="top", ha="right", fontweight="bold", zorder=6)
    ax.text(-0.12, 1.05, "B", va="bottom", ha="right", fontweight="bold", zorder=6)
    if labels:
        for i, lab in enumerate(calc.states):
            yy, xx = np.nonzero(raw == i)
            if not len(xx):
                continue
            k = np.argmin((xx - xx.mean()) ** 2 + (yy - yy.mean()) ** 2)
            dx = 0.16 if thin[i] else 0.0
            ax.text(xs[xx[k]] + dx, ys[yy[k]] + (0.12 if counts[i] <= 4 else 0.0), lab,
                    fontsize=7, ha="left" if thin[i] else "center", va="center", zorder=7,
                    bbox={"boxstyle": "round,pad=0.1", "fc": "w", "ec": "none", "alpha": 0.7}
                    if thin[i] else None)
    absent = [calc.states[i] for i in np.flatnonzero(counts == 0)]
    shown = int((counts > 0).sum())
    ax.set_title(f"{calc.name}: {shown} of {calc.num_states} relations"
                 + (f" ({', '.join(absent)}: A = B)" if absent else ""), fontsize=9)
    ax.set_xlabel("x of C (A = (0, 0), B = (0, 1))", fontsize=8)
    ax.set_ylabel("y of C", fontsize=8)
    ax.set_aspect("equal")
    return ax


def plot_compose_sizes(tables, ax=None):
    """Heat map of |COMPOSE(s1, s2)| over all state pairs."""
    import matplotlib.pyplot as plt

    ax = ax or plt.gca()
    sizes = tables.compose.sum(-1)
    im = ax.imshow(sizes, cmap="viridis")
    Q = len(tables.states)
    ax.set_xticks(range(Q), tables.states, fontsize=6, rotation=90)
    ax.set_yticks(range(Q), tables.states, fontsize=6)
    ax.set_xlabel("BC:D")
    ax.set_ylabel("AB:C")
    ax.set_title(f"|COMPOSE| for {tables.calculus}")
    plt.colorbar(im, ax=ax, shrink=0.7)
    return ax
