"""The fine grid of cells on which salient regions are built (Padgett §3.2.2, §3.4.1).

A :class:`Grid` is an ``nx × ny`` tessellation of an axis-aligned box. Cells are indexed
``flat = ix * ny + iy`` (``ix`` along x). Adjacency is **4-neighbour** (cells sharing an edge),
which is the connectivity used for the contiguity potential ψ2 (eq. 3.6).

Points outside the box belong to the nearest border cell (coordinates are clipped), so the
cells — and hence every region map — partition the whole plane ℝ². This is the documented
handling of beliefs whose tails leave the domain and of ``classify`` queries outside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

MAX_CELLS = 2**31 - 1  # cell ids are int32 inside the jitted kernels


@dataclass(frozen=True)
class Grid:
    """Axis-aligned grid ``[lo, hi]`` split into ``shape = (nx, ny)`` cells.

    >>> g = Grid((0.0, 0.0), (4.0, 2.0), (4, 2))
    >>> g.n_cells, g.cell_size
    (8, (1.0, 1.0))
    >>> int(g.cell_of(np.array([[3.5, 0.2]]))[0])   # ix=3, iy=0
    6
    """

    lo: tuple[float, float]
    hi: tuple[float, float]
    shape: tuple[int, int]

    def __post_init__(self):
        lo = tuple(float(x) for x in self.lo)
        hi = tuple(float(x) for x in self.hi)
        shape = tuple(int(n) for n in self.shape)
        if len(lo) != 2 or len(hi) != 2 or len(shape) != 2:
            raise ValueError("Grid: lo, hi and shape must have two entries each")
        if not all(np.isfinite(lo + hi)):
            raise ValueError(f"Grid: bounds must be finite, got lo={lo}, hi={hi}")
        if not (hi[0] > lo[0] and hi[1] > lo[1]):
            raise ValueError(f"Grid: need hi > lo in both axes, got lo={lo}, hi={hi}")
        if min(shape) < 1:
            raise ValueError(f"Grid: shape must be positive, got {shape}")
        if shape[0] * shape[1] > MAX_CELLS:
            raise ValueError(f"Grid: {shape[0]}×{shape[1]} = {shape[0] * shape[1]} cells is more "
                             f"than the {MAX_CELLS} (2³¹ − 1) that int32 cell indices address")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "shape", shape)

    # construction -----------------------------------------------------------------------
    @classmethod
    def covering(cls, points, shape: tuple[int, int] = (96, 96), margin: float = 0.05,
                 quantile: float | None = None) -> Grid:
        """A grid covering ``points`` [..., 2] with a relative ``margin``.

        With ``quantile`` (e.g. 0.005) the box covers the [q, 1−q] quantiles instead of the
        extremes (far outliers then fall into border cells, which extend to infinity).
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) == 0:
            raise ValueError("Grid.covering: no finite points")
        if quantile:
            lo, hi = np.quantile(pts, quantile, axis=0), np.quantile(pts, 1 - quantile, axis=0)
        else:
            lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = np.maximum(hi - lo, 1e-6 * max(1.0, float(np.abs(pts).max())))
        lo, hi = lo - margin * span, hi + margin * span
        return cls(tuple(lo), tuple(hi), shape)

    # geometry ---------------------------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def cell_size(self) -> tuple[float, float]:
        return ((self.hi[0] - self.lo[0]) / self.shape[0],
                (self.hi[1] - self.lo[1]) / self.shape[1])

    def centers(self) -> np.ndarray:
        """(n_cells, 2) cell centres in flat order."""
        xs = self.lo[0] + (np.arange(self.shape[0]) + 0.5) * self.cell_size[0]
        ys = self.lo[1] + (np.arange(self.shape[1]) + 0.5) * self.cell_size[1]
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        return np.stack([gx.ravel(), gy.ravel()], axis=1)

    def cell_of(self, points):
        """Flat cell index of points [..., 2], clipped to the border cells; jit-able.

        Works on NumPy and JAX arrays (returns the same kind)."""
        xp = jnp if not isinstance(points, np.ndarray) else np
        p = xp.asarray(points)
        ix = xp.floor((p[..., 0] - self.lo[0]) / self.cell_size[0])
        iy = xp.floor((p[..., 1] - self.lo[1]) / self.cell_size[1])
        ix = xp.clip(ix, 0, self.shape[0] - 1).astype(xp.int32)
        iy = xp.clip(iy, 0, self.shape[1] - 1).astype(xp.int32)
        return ix * self.shape[1] + iy

    def edges(self) -> np.ndarray:
        """[E, 2] pairs of 4-adjacent flat cell indices (each pair once)."""
        idx = np.arange(self.n_cells).reshape(self.shape)
        right = np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], axis=1)
        up = np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], axis=1)
        return np.concatenate([right, up], axis=0)

    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` for ``imshow(labels.reshape(shape).T, origin='lower')``."""
        return (self.lo[0], self.hi[0], self.lo[1], self.hi[1])


def connected_components(labels: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """4-connected components of a flat label array (negative labels are background; P §3.2).

    Args:
        labels: ``[H·W]`` int labels.
        shape: ``(H, W)``.

    Returns:
        ``[H·W]`` component ids ``0..n−1`` (−1 for background).

    >>> lab = np.array([0, 1, 0, 0, 1, 0, 0, 0, 0])    # 3x3, label 1 splits nothing
    >>> int(connected_components(lab, (3, 3)).max()) + 1
    2
    """
    lab = np.asarray(labels).reshape(shape)
    comp = np.where(lab >= 0, np.arange(lab.size).reshape(shape), -1)
    big = lab.size + 1
    while True:
        c = np.where(comp >= 0, comp, big)
        new = c.copy()
        same_x = lab[1:, :] == lab[:-1, :]
        same_y = lab[:, 1:] == lab[:, :-1]
        new[:-1, :] = np.where(same_x, np.minimum(new[:-1, :], c[1:, :]), new[:-1, :])
        new[1:, :] = np.where(same_x, np.minimum(new[1:, :], c[:-1, :]), new[1:, :])
        new[:, :-1] = np.where(same_y, np.minimum(new[:, :-1], c[:, 1:]), new[:, :-1])
        new[:, 1:] = np.where(same_y, np.minimum(new[:, 1:], c[:, :-1]), new[:, 1:])
        new = np.where(lab >= 0, new, big)
        if np.array_equal(new, c):
            break
        comp = np.where(lab >= 0, new, -1)
    flat = np.where(lab >= 0, comp, -1).ravel()
    _, inv = np.unique(flat[flat >= 0], return_inverse=True)
    out = np.full(flat.shape, -1, dtype=np.int64)
    out[flat >= 0] = inv
    return out


def components_per_label(labels: np.ndarray, shape: tuple[int, int]) -> dict[int, int]:
    """Ω of P eq. (3.6): the number of 4-connected components of every label present.

    Args:
        labels: ``[H·W]`` int labels (negative: background).
        shape: ``(H, W)``.

    Returns:
        ``label -> number of components``.

    >>> components_per_label(np.array([0, 1, 0, 1, 0, 1, 0, 1, 0]), (3, 3))
    {0: 5, 1: 4}
    """
    lab = np.asarray(labels).ravel()
    comp = connected_components(lab, shape)
    out: dict[int, int] = {}
    for lbl in np.unique(lab[lab >= 0]):
        out[int(lbl)] = len(np.unique(comp[lab == lbl]))
    return out
