"""Re-localisation at a revisit: the current LPM matched against the place's stored LPM (B §9.2).

At a loop closure the layout needs the rover's pose relative to the place's frame, and B
re-localises in the stored local map ``m_p`` of the place: the LPMs are aligned first by
corresponding gateways, then refined on obstacles (B §9.2). Without it the springs assume the
rover stands exactly at the first visit's dividing pose turned by the arrival bearing,
``X_i = χ_p ⊕ (0, 0, δ_i)`` (:mod:`~pqrm_jax.hssh_global.layout`); in the simulator the dividing
pose re-read at a revisit strays from that by a fraction of a corridor width, more than the
odometry error of a travel, so relaxation made layouts worse.

Here, for visit ``i`` of place ``p`` first seen at visit ``j`` in a hypothesis:

1. **Gateway alignment** (the hypothesis's star isomorphism): the initial relative pose of the
   two dividing poses is ``c₀ = (0, 0, δ_i − δ_j)``, which is what the layout assumed.
2. **Refinement on obstacles**: the occupied cells of LPM snapshot ``i`` (points in its dividing
   pose's frame) are moved by a candidate ``c`` into snapshot ``j``'s frame and scored with the
   likelihood field of ``j`` (mean ``exp(−d² / 2σ²)``, ``d`` the distance in cells to the nearest
   occupied cell of ``j``, bilinear); a coarse-to-fine grid search over a small window around
   ``c₀`` (``levels`` levels of ``steps³`` candidates, each level ``1 / zoom`` of the last) keeps
   the best. All pairs are matched in one jitted call (``lax.map`` over pairs, ``vmap`` over
   the candidates, the points padded with a mask).
3. **Corrected displacements**: with the offset ``r_i = (0, 0, δ_j − δ_i) ⊕ c`` of the real
   dividing pose from the assumed one (``r = 0`` at first visits) the travel ``λ_i`` between real
   dividing poses becomes ``λ'_i = r_{i−1} ⊕ λ_i ⊖ r_i`` between the assumed poses, so the
   unchanged spring model of :func:`~pqrm_jax.hssh_global.layout.pack` uses it directly
   (``odometry`` of shape ``[H, N, 3]``, one row per hypothesis).

The window is in corridor widths and radians and the field's σ in LPM cells, so the result is
scale-free. A pair whose best score stays below ``min_score`` (too little overlap, or the wrong
place in a wrong hypothesis) keeps ``c₀`` (no correction).

>>> import numpy as np
>>> n = 21
>>> grid = np.zeros((n, n)); grid[5, 3:18] = 3.0; grid[3:18, 5] = 3.0    # an L of walls
>>> # the same walls seen from a dividing pose (0.4, -0.3, 0.03) off the stored one
>>> pts, mask = occupied_points(grid[None], np.zeros((1, 2)), np.array([[0.4, -0.3, 0.03]]),
...                             1.0, 1.0)
>>> c, score = match_pairs(pts, mask, field(grid[None], 1.0, 1.0), np.zeros((1, 2)),
...                        np.zeros((1, 3)), np.zeros((1, 3)), 1.0, 1.0,
...                        RelocParams(window_xy=1.0))
>>> [round(float(v), 2) for v in c[0]], bool(score[0] > 0.9)
([0.4, -0.3, 0.03], True)
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import hssh

from .layout import se2_compose, se2_compose_host, se2_inverse_host

__all__ = ["RelocParams", "Relocalization", "occupied_points", "field", "match_pairs",
           "visit_offsets"]


class RelocParams(NamedTuple):
    """Re-localisation settings (lengths in corridor widths ``w``, angles in radians).

    window_xy, window_theta: half-widths of the search window around ``c₀`` (the revisit jitter
        measured in the simulator is about 0.1 w and 0.024 rad on average, but single revisits
        stray up to 0.8 w where the core centre of a place is re-estimated elsewhere).
    steps: candidates per axis and level (odd, so ``c₀`` itself is a candidate).
    levels: coarse-to-fine levels; ``zoom``: window shrink factor per level.
    sigma_cells: σ of the likelihood field in LPM cells.
    threshold: log-odds above which a snapshot cell is an obstacle (the LPM's occupied
        threshold).
    min_score: least best score (mean field value) for a correction to be used.
    max_points: obstacle points kept per snapshot (padding; the densest LPM has fewer).
    """

    window_xy: float = 0.8
    window_theta: float = 0.12
    steps: int = 9
    levels: int = 4
    zoom: float = 3.0
    sigma_cells: float = 1.0
    threshold: float = 0.4
    min_score: float = 0.3
    max_points: int = 512


def occupied_points(snapshots, origins, poses, resolution: float,
                    threshold: float = 0.4, max_points: int = 512):
    """Obstacle cells of LPM snapshots as points in their dividing pose's frame.

    Args:
        snapshots: ``[S, N, N]`` log-odds (rows along y).
        origins: ``[S, 2]`` odometry-frame corner of cell ``(0, 0)``.
        poses: ``[S, 3]`` odometry dividing poses.
        resolution: LPM cell size.
        threshold: log-odds above which a cell is an obstacle.
        max_points: padded point count.

    Returns:
        ``(points [S, P, 2], mask [S, P])``.
    """
    snaps = np.asarray(snapshots, float)
    s_n = snaps.shape[0]
    pts = np.zeros((s_n, max_points, 2))
    mask = np.zeros((s_n, max_points), bool)
    for s in range(s_n):
        rows, cols = np.nonzero(snaps[s] > threshold)
        if len(rows) > max_points:       # keep an even subsample (deterministic)
            keep = np.linspace(0, len(rows) - 1, max_points).astype(int)
            rows, cols = rows[keep], cols[keep]
        xy = np.asarray(origins[s], float)[None, :] + (np.stack([cols, rows], 1) + 0.5) \
            * resolution
        rel = se2_compose_host(se2_inverse_host(poses[s]),
                               np.concatenate([xy, np.zeros((len(xy), 1))], 1))
        pts[s, :len(rows)] = rel[:, :2].reshape(-1, 2)
        mask[s, :len(rows)] = True
    return pts, mask


def field(snapshots, sigma_cells: float = 1.0, threshold: float = 0.4) -> np.ndarray:
    """Likelihood fields ``[S, N, N]``: ``exp(−d² / 2σ²)``, ``d`` cells to the nearest obstacle.

    ``d²`` is the local level's exact squared distance transform
    (:func:`~pqrm_jax.hssh.cellular.squared_distance_transform`, all snapshots in one call). A
    snapshot without an obstacle gives a zero field.
    """
    occ = np.asarray(snapshots, float) > threshold
    d2 = np.asarray(hssh.squared_distance_transform(jnp.asarray(occ)), float)
    return np.where(occ.any(axis=(1, 2))[:, None, None], np.exp(-d2 / (2 * sigma_cells ** 2)),
                    0.0)


def _bilinear(fld, r, c):
    """Bilinear lookup of ``fld [N, N]`` at fractional ``(row, col)``; 0 outside the grid."""
    n0, n1 = fld.shape
    r0, c0 = jnp.floor(r), jnp.floor(c)
    fr, fc = r - r0, c - c0
    r0, c0 = r0.astype(jnp.int32), c0.astype(jnp.int32)

    def at(i, j):
        ok = (i >= 0) & (i < n0) & (j >= 0) & (j < n1)
        return jnp.where(ok, fld[jnp.clip(i, 0, n0 - 1), jnp.clip(j, 0, n1 - 1)], 0.0)

    return ((1 - fr) * (1 - fc) * at(r0, c0) + (1 - fr) * fc * at(r0, c0 + 1)
            + fr * (1 - fc) * at(r0 + 1, c0) + fr * fc * at(r0 + 1, c0 + 1))


def _score(c, pts, mask, fld, origin, pose, resolution):
    """Mean field value of snapshot-i points moved by ``c`` into snapshot j's grid."""
    moved = se2_compose(c, jnp.concatenate([pts, jnp.zeros_like(pts[:, :1])], 1))
    xy = se2_compose(pose, moved)[:, :2]
    cr = (xy - origin) / resolution - 0.5                       # (col, row) fractional
    vals = _bilinear(fld, cr[:, 1], cr[:, 0])
    return jnp.sum(vals * mask) / jnp.maximum(jnp.sum(mask), 1)


@partial(jax.jit, static_argnames=("steps", "levels"))
def _search(pts, mask, fld, origin, pose, c0, resolution, win, steps, levels, zoom):
    lin = jnp.linspace(-1.0, 1.0, steps)
    grid = jnp.stack(jnp.meshgrid(lin, lin, lin, indexing="ij"), -1).reshape(-1, 3)

    def one(pts, mask, fld, origin, pose, c0):
        score = jax.vmap(lambda c: _score(c, pts, mask, fld, origin, pose, resolution))

        def level(carry, _):
            best, s_best, w = carry
            cands = best + grid * w
            s = score(cands)
            k = jnp.argmax(s)
            better = s[k] > s_best
            return (jnp.where(better, cands[k], best), jnp.where(better, s[k], s_best),
                    w / zoom), None

        s0 = _score(c0, pts, mask, fld, origin, pose, resolution)
        (best, s_best, _), _ = jax.lax.scan(level, (c0, s0, win), None, length=levels)
        return best, s_best

    # lax.map, not vmap, over pairs: each pair's candidates x points already fill the vector
    # units, and a vmapped gather over [K, candidates, points] leaves the caches (on CPU it
    # measured 2-5x slower than a Python loop; benchmarks/bench_hssh_reloc.py)
    return jax.lax.map(lambda a: one(*a), (pts, mask, fld, origin, pose, c0))


def match_pairs(pts, mask, fields, origins, poses, c0, resolution: float, width: float,
                params: RelocParams | None = None):
    """Matches snapshot pairs: the current dividing pose ``c`` in the stored one's frame.

    Args:
        pts, mask: ``[K, P, 2]``, ``[K, P]`` obstacle points of the current snapshots
            (:func:`occupied_points`).
        fields: ``[K, N, N]`` likelihood fields of the stored snapshots (:func:`field`).
        origins, poses: ``[K, 2]``, ``[K, 3]`` origin and odometry dividing pose of the stored
            snapshots.
        c0: ``[K, 3]`` initial relative pose (the gateway alignment).
        resolution: LPM cell size; ``width``: corridor width (the window's unit).
        params: :class:`RelocParams` (default ``RelocParams()``).

    Returns:
        ``(c [K, 3], score [K])``: the best relative pose and its mean field value.
    """
    params = RelocParams() if params is None else params
    win = jnp.asarray([params.window_xy * width, params.window_xy * width,
                       params.window_theta], jnp.float32)
    return _search(jnp.asarray(pts, jnp.float32), jnp.asarray(mask),
                   jnp.asarray(fields, jnp.float32), jnp.asarray(origins, jnp.float32),
                   jnp.asarray(poses, jnp.float32), jnp.asarray(c0, jnp.float32),
                   jnp.float32(resolution), win, steps=int(params.steps),
                   levels=int(params.levels), zoom=jnp.float32(params.zoom))


def _pairs(hypotheses):
    """Unique ``(i, j, δ_i − δ_j)`` revisit pairs over hypotheses (keys, in first-seen order),
    and ``[H, n+1]`` each visit's pair index (-1 at first visits)."""
    keys: dict = {}
    idx = np.full((len(hypotheses), len(hypotheses[0].visits)), -1)
    for hk, h in enumerate(hypotheses):
        first: dict = {}
        for i, (p, e) in enumerate(h.visits):
            if p not in first:
                first[p] = (i, e)
                continue
            j, ej = first[p]
            key = (i, j, round(float(h.bearings[p][e] - h.bearings[p][ej]), 9))
            idx[hk, i] = keys.setdefault(key, len(keys))
    return list(keys), idx


class Relocalization(NamedTuple):
    """Re-localisation of every revisit in a set of hypotheses.

    offsets: ``[H, n+1, 3]`` offset ``r_i`` of each real dividing pose from the assumed
        ``χ_p ⊕ (0, 0, δ_i)`` (zeros at first visits and for rejected matches).
    odometry: ``[H, n, 3]`` corrected displacements ``λ'_i`` (feed to
        :func:`~pqrm_jax.hssh_global.layout.pack`).
    score: ``[H, n+1]`` best match score of each revisit (NaN at first visits).
    used: ``[H, n+1]`` bool, the correction was applied (score ≥ ``min_score``).
    """

    offsets: np.ndarray
    odometry: np.ndarray
    score: np.ndarray
    used: np.ndarray


def visit_offsets(sw, se, hypotheses, params: RelocParams | None = None) -> Relocalization:
    """Re-localises every revisit of every hypothesis in its place's stored LPM (B §9.2).

    Args:
        sw: the :class:`~pqrm_jax.hssh_global.simulation.SimWorld` explored (corridor width
            and LPM resolution).
        se: a :class:`~pqrm_jax.hssh_global.simulation.SimExperience` (its LPM snapshots,
            their origins and odometry dividing poses, and the odometry).
        hypotheses: leaves of the tree of maps of ``se.experience``.
        params: :class:`RelocParams` (default ``RelocParams()``).

    Returns:
        :class:`Relocalization`. The unique (revisit, first visit, bearing difference) pairs
        over all hypotheses are matched once, in one batched call.
    """
    params = RelocParams() if params is None else params
    if not hypotheses:
        raise ValueError("no hypothesis to re-localise")
    n = len(se.experience.views)
    if any(len(h.visits) != n for h in hypotheses):
        raise ValueError("hypothesis and simulator experience come from different explorations")
    width = float(sw.width)
    res = width / sw.params.cells
    order, idx = _pairs(hypotheses)
    offsets = np.zeros((len(hypotheses), n, 3))
    score = np.full((len(hypotheses), n), np.nan)
    used = np.zeros((len(hypotheses), n), bool)
    if order:
        cur = np.array([k[0] for k in order])
        sto = np.array([k[1] for k in order])
        c0 = np.array([[0.0, 0.0, k[2]] for k in order])
        pts, mask = occupied_points(se.snapshots, se.snap_origins, se.snap_poses, res,
                                    params.threshold, params.max_points)
        fld = field(se.snapshots, params.sigma_cells, params.threshold)
        # pad the pair count to a power of two so explorations share compiled shapes
        k_n = len(order)
        pad = np.concatenate([np.arange(k_n), np.zeros((1 << (k_n - 1).bit_length()) - k_n,
                                                       int)])
        cur, sto, c0p = cur[pad], sto[pad], c0[pad]
        c, s = match_pairs(pts[cur], mask[cur], fld[sto], se.snap_origins[sto],
                           se.snap_poses[sto], c0p, res, width, params)
        c, s = np.asarray(c, float)[:k_n], np.asarray(s, float)[:k_n]
        ok = s >= params.min_score
        r = se2_compose_host(np.concatenate([np.zeros((len(order), 2)), -c0[:, 2:]], 1), c)
        r[~ok] = 0.0
        rev = idx >= 0
        offsets[rev], score[rev], used[rev] = r[idx[rev]], s[idx[rev]], ok[idx[rev]]
    odo = np.asarray(se.experience.odometry, float).reshape(-1, 3)
    lam = se2_compose_host(
        se2_compose_host(offsets[:, :-1], np.broadcast_to(odo, offsets[:, 1:].shape)),
        se2_inverse_host(offsets[:, 1:]))
    return Relocalization(offsets, lam.reshape(len(hypotheses), -1, 3), score, used)
