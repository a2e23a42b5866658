"""Figures of calculi and their tables (matplotlib)."""

from __future__ import annotations

import numpy as np

from ..calculi.calculus import Calculus


def region_image(calc: Calculus, extent: float = 2.5, n: int = 400) -> np.ndarray:
    """State index of C over an n×n grid of the canonical frame (A=(0,0), B=(0,1))."""
    xs = np.linspace(-extent, extent, n)
    ys = np.linspace(-extent + 0.5, extent + 0.5, n)
    X, Y = np.meshgrid(xs, ys)
    pts = np.stack([X, Y], -1)
    return np.asarray(calc.classify(np.zeros(2), np.array([0.0, 1.0]), pts))


def plot_regions(calc: Calculus, ax=None, extent: float = 2.5, n: int = 400, labels=True):
    """Draw the regions of AB:C with A=(0,0), B=(0,1); boundaries show as white."""
    import matplotlib.pyplot as plt

    ax = ax or plt.gca()
    img = region_image(calc, extent, n).astype(float)
    img[img < 0] = np.nan
    ax.imshow(img, origin="lower", cmap="tab20", interpolation="nearest",
              extent=(-extent, extent, -extent + 0.5, extent + 0.5))
    ax.plot([0, 0], [0, 1], "k.-", ms=8)
    ax.text(0.05, -0.05, "A", va="top")
    ax.text(0.05, 1.05, "B", va="bottom")
    if labels:
        raw = region_image(calc, extent, n)
        xs = np.linspace(-extent, extent, n)
        ys = np.linspace(-extent + 0.5, extent + 0.5, n)
        for i, lab in enumerate(calc.states):
            yy, xx = np.nonzero(raw == i)
            if len(xx):
                k = np.argmin((xx - xx.mean()) ** 2 + (yy - yy.mean()) ** 2)
                ax.text(xs[xx[k]], ys[yy[k]], lab, fontsize=7, ha="center", va="center")
    ax.set_title(f"{calc.name} ({calc.num_states} states)")
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
