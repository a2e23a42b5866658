"""Initial cells ``C_init`` and the SERGE problem (Padgett §3.3, §3.4.1).

Offers the initial contiguous regions of a belief set on a grid (one per belief, by highest
saliency) and the SERGE problem built from them or from a given partition. A belief the grid
cannot separate raises ``ValueError`` by default, or is attached to a neighbouring region.

The decisions where the paper is open: docs/serge.md §cells.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .beliefs import GaussianBeliefs, SampleBeliefs
from .grid import Grid, connected_components


@dataclass(frozen=True)
class Problem:
    """A SERGE problem on R0 initial regions (all arrays static-shaped).

    Attributes:
        grid: the fine grid of cells.
        cell_region: [N] initial region of every fine cell.
        mass: [K, R0] ``∫_{C_r} B_k`` for belief k and initial region r.
        adj: [R0, R0] bool, 4-adjacency of initial regions.
        belief_region: [K] initial region of each belief (``L^B_init``).
        cell_mass: [K, N] the fine cell masses (for plotting and diagnostics).
    """

    grid: Grid
    cell_region: np.ndarray
    mass: jax.Array
    adj: jax.Array
    belief_region: jax.Array
    cell_mass: jax.Array = field(repr=False)

    @property
    def k(self) -> int:
        return int(self.mass.shape[0])

    @property
    def n_init(self) -> int:
        return int(self.mass.shape[1])

    def arrays(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        return self.mass, self.adj, self.belief_region


def _fill(label: np.ndarray, score: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Grow labelled regions into unlabelled (−1) cells until none is left."""
    lab = label.reshape(shape).copy()
    sc = score.reshape(score.shape[0], *shape)
    if (lab < 0).all():
        raise ValueError("initial_cells: no grid cell carries any belief mass")
    while (lab < 0).any():
        best = np.full(shape, -np.inf)
        pick = np.full(shape, -1)
        for axis, step in ((0, 1), (0, -1), (1, 1), (1, -1)):
            nb = np.roll(lab, step, axis=axis)
            edge = [slice(None)] * 2
            edge[axis] = 0 if step == 1 else -1
            nb[tuple(edge)] = -1                                      # no wrap-around
            cand = (lab < 0) & (nb >= 0)
            s = np.where(cand, np.take_along_axis(sc, np.maximum(nb, 0)[None], 0)[0], -np.inf)
            s = np.where(np.isnan(s), -np.inf, s)
            better = cand & ((s > best) | (pick < 0))
            best = np.where(better, s, best)
            pick = np.where(better, nb, pick)
        lab = np.where(pick >= 0, pick, lab)
    return lab.ravel()


def initial_cells(
    key: jax.Array | None,
    beliefs: GaussianBeliefs | SampleBeliefs,
    grid: Grid,
    *,
    n_mc: int = 20000,
    unseparated: str = "error",
    min_saliency: float = 0.01,
) -> Problem:
    """Build ``C_init`` (one contiguous region per belief) and the SERGE problem.

    Args:
        key: PRNG key of the quasi-samples of Gaussian cell masses (``None``: the fixed key
            ``PRNGKey(0)``; sample-set beliefs use no key).
        beliefs: the K beliefs (Gaussian or sample sets).
        grid: the fine grid of cells.
        n_mc: quasi-samples per Gaussian belief.
        unseparated: ``"error"`` raises for a belief the grid cannot separate; ``"attach"``
            assigns it to the region holding most of its mass (the map then starts with fewer
            than K regions).
        min_saliency: the share of a belief's mass its own cells must hold for it to count as
            separated.

    Returns:
        The :class:`Problem` on the initial regions (decisions: docs/serge.md §cells).

    Raises:
        ValueError: for an unknown ``unseparated`` mode, or (with ``"error"``) beliefs that win
            no grid cell holding at least ``min_saliency`` of their mass.

    >>> import jax, numpy as np
    >>> from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells
    >>> b = GaussianBeliefs(np.array([[0., 0.], [4., 0.]]), np.tile(np.eye(2) * .1, (2, 1, 1)))
    >>> p = initial_cells(jax.random.PRNGKey(0), b, Grid((-2., -2.), (6., 2.), (16, 8)))
    >>> p.n_init, np.asarray(p.mass).round(3).tolist()
    (2, [[1.0, 0.0], [0.0, 1.0]])
    """
    if unseparated not in ("error", "attach"):
        raise ValueError(f"initial_cells: unseparated must be 'error' or 'attach', "
                         f"got {unseparated!r}")
    k = beliefs.k
    cell_mass = beliefs.cell_masses(grid, key=key, n_mc=n_mc)
    pm = np.asarray(cell_mass, np.float64)
    score = np.asarray(beliefs.cell_scores(grid), np.float64)
    score = np.where(np.isnan(score), -np.inf, score)
    win = np.argmax(score, axis=0)
    top = np.max(score, axis=0)
    # ties (two beliefs with the same score) are broken towards the lower index
    label = np.where(np.isfinite(top), win, -1)

    # keep, per belief, the connected patch holding most of its mass
    comp = connected_components(label, grid.shape)
    valid = comp >= 0
    ncomp = int(comp.max()) + 1 if valid.any() else 0
    if ncomp:
        comp_label = np.zeros(ncomp, dtype=np.int64)
        comp_label[comp[valid]] = label[valid]
        comp_mass = np.bincount(comp[valid], weights=pm[label[valid], np.flatnonzero(valid)],
                                minlength=ncomp)
        keep = np.zeros(ncomp, dtype=bool)
        for lbl in np.unique(comp_label):
            ids = np.flatnonzero(comp_label == lbl)
            keep[ids[np.argmax(comp_mass[ids])]] = True
        label = np.where(valid & keep[np.maximum(comp, 0)], label, -1)

    # a belief is separated when it wins cells holding at least ``min_saliency`` of its mass
    # (a density argmax can hand a belief cells that carry none of its mass: e.g. two beliefs
    # inside one coarse cell)
    pre_fill = label
    while True:
        winners = np.unique(pre_fill[pre_fill >= 0])
        filled = _fill(pre_fill, score, grid.shape)
        own = np.array([pm[i, filled == i].sum() for i in range(k)])
        weak = winners[own[winners] < min_saliency]
        if len(weak) == 0 or len(weak) == len(winners):
            break
        pre_fill = np.where(np.isin(pre_fill, weak), -1, pre_fill)
    label = filled
    losers = np.setdiff1d(np.arange(k), winners)
    if len(losers) and unseparated == "error":
        raise ValueError(
            f"initial_cells: beliefs {losers.tolist()} have the highest saliency in no grid cell "
            f"holding ≥ {min_saliency:g} of their mass (grid {grid.shape} too coarse to "
            "separate them, or they coincide with other beliefs); use a finer grid or "
            "unseparated='attach'")

    # regions numbered in belief order
    remap = np.full(k, -1, dtype=np.int64)
    remap[winners] = np.arange(len(winners))
    cell_region = remap[label]
    r0 = len(winners)
    onehot = np.zeros((grid.n_cells, r0))
    onehot[np.arange(grid.n_cells), cell_region] = 1.0
    mass = pm @ onehot                                                # (K, R0)
    belief_region = np.where(remap >= 0, remap, np.argmax(mass, axis=1))
    adj = _region_adjacency(grid, cell_region, r0)
    return Problem(grid, cell_region.astype(np.int32), jnp.asarray(mass, jnp.float32),
                   jnp.asarray(adj), jnp.asarray(belief_region, jnp.int32),
                   jnp.asarray(cell_mass, jnp.float32))


def _region_adjacency(grid: Grid, cell_region: np.ndarray, r0: int) -> np.ndarray:
    """[R0, R0] bool: regions sharing a grid edge (no self-adjacency)."""
    e = grid.edges()
    a, b = cell_region[e[:, 0]], cell_region[e[:, 1]]
    adj = np.zeros((r0, r0), dtype=bool)
    adj[a, b] = True
    adj[b, a] = True
    np.fill_diagonal(adj, False)
    return adj


def problem_from_partition(cell_mass, grid: Grid, cell_region, belief_region) -> Problem:
    """A problem from an explicit contiguous partition of the grid (e.g. a calculus's regions).

    The start of a search from given regions instead of one region per cell (P §3.3.2).

    Args:
        cell_mass: ``[K, N]`` belief mass of each of the N grid cells.
        grid: the grid.
        cell_region: ``[N]`` region ids ``0..R0−1`` (each region contiguous).
        belief_region: ``[K]`` the region of each belief.

    Returns:
        :class:`Problem`.
    """
    cell_region = np.asarray(cell_region, dtype=np.int64)
    r0 = int(cell_region.max()) + 1
    onehot = np.zeros((grid.n_cells, r0))
    onehot[np.arange(grid.n_cells), cell_region] = 1.0
    mass = np.asarray(cell_mass, np.float64) @ onehot
    adj = _region_adjacency(grid, cell_region, r0)
    return Problem(grid, cell_region.astype(np.int32), jnp.asarray(mass, jnp.float32),
                   jnp.asarray(adj), jnp.asarray(np.asarray(belief_region), jnp.int32),
                   jnp.asarray(cell_mass, jnp.float32))
