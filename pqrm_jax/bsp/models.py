"""Offline models of qualitative BSP, sampled under uniform-within-state priors (Z §4.2.2–4.2.5).

All lengths are in units of the sensing range R (R = 1); positions of the robot and of a
third landmark are in the canonical frame of the current ordered pair (A = (0, 0),
B = (0, 1)), uniform over ``state ∩ [−W, W]²`` (W = ``window`` frame units; Z eq. 4.11 and
4.16 approximate the metric priors as uniform). The global scale of a frame (Z §4.1.1) is the
bin ``s`` of its metric length ``d``: bins ``[(s−1)·2R/n_F, s·2R/n_F)`` for ``s ≤ n_F`` and
``[2R, ∞)`` for ``s = n_F + 1`` (docs/bsp.md §Z-1; that bin is sampled on ``[2R, 3R]``). Indices
here are 0-based: scale bin ``b = s − 1``.

Tables (``Q`` EDC states, ``nb = n_F + 1`` scale bins):

* ``T[b, j, s']`` (nb, Q, Q) — transition model (Z eq. 4.5) of the qualitative action "go to
  state j": the controller drives to the target point ``p_j`` (:func:`target_points`) with
  additive Gaussian noise ``σ_m`` in metres, i.e. ``σ_m/d`` frame units (docs/bsp.md §Z-3–Z-4). The
  outcome does not depend on the previous state, so the table has no such axis.
* ``AZ[s_x, s_τ, b, ẑ]`` (Q, Q, nb, Q²) — joint association and measurement model
  (Z eqs. 4.11–4.13): ``P(β visible, ẑ | s_x, s_τ, b)``, ``ẑ = ẑ_x·Q + ẑ_τ`` the measured robot
  state and triplet state from one noisy relative-position measurement (noise ``σ_z`` in
  metres; docs/bsp.md §Z-5). ``A = AZ.sum(-1)`` is the association model (eq. 4.12); its last
  scale bin is exactly 0 (two landmarks farther than 2R are never both within R).
* ``K[k, s_x, s_τ, s']`` (5, Q, Q, Q) — link model (Z eqs. 4.15–4.17): from frame AB with
  ``AB:C = s_τ`` and ``AB:X = s_x``, the state of X in frame ``k`` ∈ (BA, AC, CA, BC, CB).
* ``G2[s1, s2, b_ref, b]``, ``GA[s, b_ref, b]``, ``GB[s, b_ref, b]`` — global-scale model
  (Z eqs. 4.22–4.24 with the reference scale factor, docs/bsp.md §Z-9): the scale bin of the frame
  ``L1 L2`` from the reference frame AB's bin and ``AB:L1 = s1``, ``AB:L2 = s2`` (G2), or of
  ``A L`` / ``B L`` from ``AB:L = s`` (GA / GB).
* ``U[op, s, s']`` (3, Q, Q) — probabilistic LEFT (BC:A), RIGHT (CA:B), INVERSE (BA:C) of
  ``AB:C = s`` (used to fill the orderings of composed triplets, Z eq. 4.28).
* ``D2[s1, s2]`` (Q, Q) — ``E‖x2 − x1‖`` in frame units for independent uniform x1, x2
  (Z eq. 4.30).

Every conditioning cell has ``n`` samples (``counts[name]``, the per-cell sample count); the
binomial standard error of each entry is :func:`stderr`. Tables are cached as ``.npz`` keyed by
a hash of their parameters (:func:`load_models`), written atomically (temp file + rename) and
checked on load: a corrupt or mismatching file raises :class:`~pqrm_jax.tables.CacheError`
naming the file and how to regenerate it — it is never silently used.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from ..tables import CacheError

FORMAT_VERSION = 2  # bump whenever the sampling code changes (part of the cache key)
LINK_TYPES = ("BA", "AC", "CA", "BC", "CB")
UNARY_TYPES = ("left", "right", "inverse")
TABLES = ("T", "AZ", "K", "G2", "GA", "GB", "U", "D2")


@dataclass(frozen=True)
class ModelParams:
    """Parameters of the offline models (every one enters the cache key).

    Attributes:
        calculus: calculus name (EDC in the thesis).
        n_f: frame-scale resolution ``n_F`` (Z §4.1.1: "typical values are 4 – 6").
        window: W, half-width of the uniform-within-state window in frame units.
        sigma_m: motion noise std in units of R (metres / R).
        sigma_z: measurement noise std in units of R.
        r_min: minimum frame length in units of R (lower clip of the first scale bin).
        samples: samples per conditioning cell.
        pool: uniform points in the window used to group samples by state.
        seed: PRNG seed.
        target_half_width: half-width of the box around the frame midpoint (0, ½) in which the
            controller's target points are chosen.
    """

    calculus: str = "edc"
    n_f: int = 5
    window: float = 3.0
    sigma_m: float = 0.05
    sigma_z: float = 0.05
    r_min: float = 0.05
    samples: int = 4000
    pool: int = 1 << 20
    seed: int = 0
    target_half_width: float = 1.5

    def __post_init__(self):
        # NumPy integers and floats are accepted and stored as Python numbers (the cache key
        # is JSON); booleans and non-numbers are refused naming the field (validate)
        for nm in ("n_f", "samples", "pool", "seed"):
            v = getattr(self, nm)
            if isinstance(v, np.integer) and not isinstance(v, np.bool_):
                object.__setattr__(self, nm, int(v))
        for nm in ("window", "sigma_m", "sigma_z", "r_min", "target_half_width"):
            v = getattr(self, nm)
            if isinstance(v, np.floating | np.integer) and not isinstance(v, np.bool_):
                object.__setattr__(self, nm, float(v))

    def validate(self) -> ModelParams:
        """Raise ``ValueError`` naming the first bad field; return self."""
        if not isinstance(self.calculus, str):
            raise ValueError(f"calculus must be a calculus name, got {self.calculus!r}")
        calculi.get(self.calculus)
        for nm, low in (("n_f", 1), ("samples", 1), ("pool", 1), ("seed", 0)):
            v = getattr(self, nm)
            if not isinstance(v, int) or isinstance(v, bool) or v < low:
                raise ValueError(f"{nm} must be an integer >= {low}, got {v!r}")
        for nm, positive in (("window", True), ("target_half_width", True), ("sigma_m", False),
                             ("sigma_z", False), ("r_min", False)):
            v = getattr(self, nm)
            if not isinstance(v, int | float) or isinstance(v, bool) or not np.isfinite(v) \
                    or v < 0 or (positive and v == 0):
                what = "positive" if positive else "non-negative"
                raise ValueError(f"{nm} must be {what} and finite, got {v!r}")
        if self.r_min >= 2.0 / self.n_f:
            raise ValueError("r_min must be below the first scale bin's upper edge 2R/n_f")
        return self

    def key(self) -> str:
        """Hash of the parameters and the calculus definition (the cache key)."""
        d = asdict(self) | {"format": FORMAT_VERSION,
                            "calculus_hash": calculi.get(self.calculus).definition_hash}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


class Models(NamedTuple):
    """The offline tables (module docstring) with per-cell sample counts.

    ``counts[name]`` has the shape of the table without its outcome axis (the conditioning
    cells); ``bin_edges`` (nb + 1,) are the scale-bin edges in units of R (last edge 3R caps
    the sampled unobservable bin); ``mid`` (nb,) the representative frame length per bin (the
    last capped at 2R, docs/bsp.md §Z-14).
    """

    T: jax.Array
    AZ: jax.Array
    K: jax.Array
    G2: jax.Array
    GA: jax.Array
    GB: jax.Array
    U: jax.Array
    D2: jax.Array
    targets: jax.Array
    bin_edges: jax.Array
    mid: jax.Array
    counts: dict
    A: jax.Array | None = None
    AZ_by_z: jax.Array | None = None
    AZ_cdf: jax.Array | None = None
    TA: jax.Array | None = None

    def with_derived(self) -> Models:
        """These tables with the derived fields filled (done by every constructor here).

        ``A`` (Q, Q, nb) = ``AZ.sum(-1)``, the association model P(β visible | s_x, s_τ, b)
        (Z eq. 4.12); ``AZ_by_z`` (Q², nb, Q, Q) = ``AZ`` with the measurement axis first and
        the scale bin second, so that the planner's ``AZ[..., ẑ]`` is one contiguous slice
        instead of a gather with stride Q² (a strided gather per tree branch was the largest
        single cost of a plan) and each bin's [Q, Q] block is contiguous for the sum over bins;
        ``AZ_cdf`` (Q, Q, nb, Q²) = ``cumsum(AZ, -1)``, so that a tree branch draws ẑ by one
        search instead of a 400-cell cumsum each; ``TA`` (nb, Q, Q) = ``Σ_{s_x} T[b, a, s_x]
        A[s_x, s_τ, b]``, the planner's candidate weights after action ``a``
        (:func:`~pqrm_jax.bsp.planner.transition_association`).
        """
        A = self.AZ.sum(-1)
        return self._replace(A=A, AZ_by_z=jnp.moveaxis(self.AZ, (-1, 2), (0, 1)),
                             AZ_cdf=jnp.cumsum(self.AZ, -1),
                             TA=jnp.einsum("bax,xtb->bat", self.T, A))

    @property
    def num_states(self) -> int:
        return int(self.T.shape[-1])

    @property
    def num_bins(self) -> int:
        return int(self.T.shape[0])


def stderr(models: Models, name: str) -> np.ndarray:
    """Binomial standard error of every entry of table ``name`` (Z §4.2; module docstring).

    Args:
        models: the tables with their per-cell counts.
        name: a table name (``"T"``, ``"AZ"``, ...).

    Returns:
        An array of the table's shape.
    """
    p = np.asarray(getattr(models, name), np.float64)
    n = np.asarray(models.counts[name], np.float64)
    n = n.reshape(n.shape + (1,) * (p.ndim - n.ndim))
    return np.sqrt(np.clip(p * (1 - p), 0, None) / np.maximum(n, 1))


# --------------------------------------------------------------------------- sampling
def state_pool(calc, key, n: int, window: float):
    """Uniform points of ``[−W, W]²`` sorted by EDC state: ``(points, starts, counts)``."""
    pts = jax.random.uniform(key, (n, 2), minval=-window, maxval=window)
    st = calc.classify(jnp.zeros(2), jnp.asarray([0.0, 1.0]), pts)
    order = jnp.argsort(st)
    sts = st[order]
    q = jnp.arange(calc.num_states)
    starts = jnp.searchsorted(sts, q)
    counts = jnp.searchsorted(sts, q, side="right") - starts
    return pts[order], starts, counts


def _draw(pool, key, state, n):
    pts, starts, counts = pool
    u = jax.random.uniform(key, (n,))
    idx = starts[state] + jnp.floor(u * counts[state]).astype(jnp.int32)
    return pts[jnp.clip(idx, 0, pts.shape[0] - 1)]


def _draw_scale(key, b, n, edges, r_min):
    lo, hi = edges[b], edges[b + 1]
    return jnp.maximum(jax.random.uniform(key, (n,), minval=lo, maxval=hi), r_min)


def _hist(idx, valid, size):
    return jnp.zeros(size, jnp.float32).at[jnp.where(valid, idx, 0)].add(
        valid.astype(jnp.float32))


def _bin_of(d, n_f):
    return jnp.clip(jnp.floor(d * n_f / 2.0).astype(jnp.int32), 0, n_f)


def target_points(calc, half_width: float = 1.5, resolution: int = 241) -> np.ndarray:
    """(Q, 2) controller target point of every state: the grid point of ``state ∩ box`` that
    survives the most erosions (an approximate centre of the largest inscribed disk; box =
    ``[−h, h] × [½ − h, ½ + h]``). Every point lies strictly inside its state.

    >>> from pqrm_jax import calculi
    >>> edc = calculi.get("edc")
    >>> p = target_points(edc)
    >>> bool((np.asarray(edc.classify([0., 0.], [0., 1.], p)) == np.arange(20)).all())
    True
    """
    xs = np.linspace(-half_width, half_width, resolution)
    ys = 0.5 + xs
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([X, Y], -1).reshape(-1, 2)
    st = np.asarray(calc.classify(np.zeros(2), np.array([0.0, 1.0]), pts)).reshape(X.shape)
    out = np.zeros((calc.num_states, 2))
    for q in range(calc.num_states):
        m = st == q
        if not m.any():
            raise ValueError(f"state {calc.states[q]} does not meet the target box")
        prev = m
        while m.any():
            prev = m
            e = m.copy()
            e[1:] &= m[:-1]
            e[:-1] &= m[1:]
            e[:, 1:] &= m[:, :-1]
            e[:, :-1] &= m[:, 1:]
            e[0, :] = e[-1, :] = e[:, 0] = e[:, -1] = False
            m = e
        cand = np.argwhere(prev)
        c = cand.mean(0)
        i, j = cand[np.argmin(((cand - c) ** 2).sum(1))]
        out[q] = (X[i, j], Y[i, j])
    return out


@partial(jax.jit, static_argnums=(0, 1, 5))
def _sample_all(calc, p: ModelParams, key, targets, edges, names, sigma):
    # every table has its own fixed key, so a subset (``names``) samples exactly the same
    # entries as the full build; the noise levels ``sigma`` = (σ_m, σ_z) are traced (``p``'s
    # are ignored), so builds that differ only in the noise share one compiled program
    Q, nb, n, W = calc.num_states, p.n_f + 1, p.samples, p.window
    keys = jax.random.split(key, 12)
    pool = state_pool(calc, keys[0], p.pool, W)
    A0, B0 = jnp.zeros(2), jnp.asarray([0.0, 1.0])
    out = {"pool": pool[2]}

    def cls(a, b, c):
        return calc.classify(*jnp.broadcast_arrays(a, b, c))

    # T[b, j, s']
    def t_cell(args):
        b, j, k = args
        k1, k2 = jax.random.split(k)
        d = _draw_scale(k1, b, n, edges, p.r_min)
        x = targets[j] + jax.random.normal(k2, (n, 2)) * (sigma[0] / d)[:, None]
        s = cls(A0, B0, x)
        return _hist(s, s >= 0, Q)

    if "T" in names:
        bb, jj = jnp.meshgrid(jnp.arange(nb), jnp.arange(Q), indexing="ij")
        T = jax.lax.map(t_cell, (bb.ravel(), jj.ravel(), jax.random.split(keys[1], nb * Q)))
        out["T"] = T.reshape(nb, Q, Q)

    # AZ[s_x, s_t, b, z]
    def az_cell(args):
        sx, st, b, k = args
        k1, k2, k3, k4 = jax.random.split(k, 4)
        x = _draw(pool, k1, sx, n)
        c = _draw(pool, k2, st, n)
        d = _draw_scale(k3, b, n, edges, p.r_min)[:, None]
        lms = jnp.stack([jnp.broadcast_to(A0, x.shape), jnp.broadcast_to(B0, x.shape), c], 1)
        rel = d[:, None] * (lms - x[:, None])
        vis = jnp.all(jnp.sum(rel**2, -1) <= 1.0, -1)
        m = rel + sigma[1] * jax.random.normal(k4, rel.shape)
        zx = cls(m[:, 0], m[:, 1], jnp.zeros(2))
        zt = cls(m[:, 0], m[:, 1], m[:, 2])
        ok = vis & (zx >= 0) & (zt >= 0)
        return _hist(zx * Q + zt, ok, Q * Q)

    if "AZ" in names:
        g = jnp.meshgrid(jnp.arange(Q), jnp.arange(Q), jnp.arange(nb), indexing="ij")
        AZ = jax.lax.map(az_cell, (g[0].ravel(), g[1].ravel(), g[2].ravel(),
                                   jax.random.split(keys[2], Q * Q * nb)))
        out["AZ"] = AZ.reshape(Q, Q, nb, Q * Q)

    # K[type, s_x, s_t, s']
    def k_cell(args):
        sx, st, k = args
        k1, k2 = jax.random.split(k)
        x = _draw(pool, k1, sx, n)
        c = _draw(pool, k2, st, n)
        outs = (cls(B0, A0, x), cls(A0, c, x), cls(c, A0, x), cls(B0, c, x), cls(c, B0, x))
        return jnp.stack([_hist(s, s >= 0, Q) for s in outs])

    g2 = jnp.meshgrid(jnp.arange(Q), jnp.arange(Q), indexing="ij")
    if "K" in names:
        K = jax.lax.map(k_cell, (g2[0].ravel(), g2[1].ravel(),
                                 jax.random.split(keys[3], Q * Q)))
        out["K"] = K.reshape(Q, Q, 5, Q).transpose(2, 0, 1, 3)

    # G2[s1, s2, b_ref, b], D2[s1, s2]
    def g2_cell(args):
        s1, s2, k = args
        ks = jax.random.split(k, 2 + nb)
        x1 = _draw(pool, ks[0], s1, n)
        x2 = _draw(pool, ks[1], s2, n)
        r = jnp.linalg.norm(x1 - x2, axis=-1)
        hists = jnp.stack([_hist(_bin_of(_draw_scale(ks[2 + b], b, n, edges, p.r_min) * r,
                                         p.n_f), r > 0, nb) for b in range(nb)])
        return hists, jnp.mean(r)

    if "G2" in names or "D2" in names:
        G2, D2 = jax.lax.map(g2_cell, (g2[0].ravel(), g2[1].ravel(),
                                       jax.random.split(keys[4], Q * Q)))
        out |= {"G2": G2.reshape(Q, Q, nb, nb), "D2": D2.reshape(Q, Q)}

    # GA, GB, U
    def g1_cell(args):
        s, k = args
        ks = jax.random.split(k, 1 + 2 * nb)
        x = _draw(pool, ks[0], s, n)
        ra, rb = jnp.linalg.norm(x, axis=-1), jnp.linalg.norm(x - B0, axis=-1)
        ga = jnp.stack([_hist(_bin_of(_draw_scale(ks[1 + b], b, n, edges, p.r_min) * ra,
                                      p.n_f), ra > 0, nb) for b in range(nb)])
        gb = jnp.stack([_hist(_bin_of(_draw_scale(ks[1 + nb + b], b, n, edges, p.r_min) * rb,
                                      p.n_f), rb > 0, nb) for b in range(nb)])
        u = jnp.stack([_hist(s_, s_ >= 0, Q) for s_ in
                       (cls(B0, x, A0), cls(x, A0, B0), cls(B0, A0, x))])
        return ga, gb, u

    if {"GA", "GB", "U"} & set(names):
        GA, GB, U = jax.lax.map(g1_cell, (jnp.arange(Q), jax.random.split(keys[5], Q)))
        out |= {"GA": GA, "GB": GB, "U": U.transpose(1, 0, 2)}
    return {k: v for k, v in out.items() if k in names or k == "pool"}


def _normalise(c):
    tot = c.sum(-1, keepdims=True)
    return np.divide(c, tot, out=np.zeros_like(c), where=tot > 0)


def sample_tables(params: ModelParams | None = None,
                  names: tuple[str, ...] = TABLES) -> dict[str, np.ndarray]:
    """The tables ``names`` (a subset of ``TABLES``) as :func:`build_models` samples them (Z §4.2).

    Each table has its own key, so a subset is bit-identical to the same tables of the full
    build: a cheap way to test one table (e.g. the σ → 0 limits of ``T`` and ``AZ``).

    Args:
        params: the sampling parameters (default :class:`ModelParams`).
        names: the tables to sample.

    Returns:
        ``{name: float64 NumPy array}``, normalised as in :class:`Models`.

    Raises:
        ValueError: for unknown table names or invalid ``params``.
    """
    p = (params or ModelParams()).validate()
    names = tuple(sorted(set(names)))
    if bad := set(names) - set(TABLES):
        raise ValueError(f"unknown tables {sorted(bad)}; choose from {TABLES}")
    calc = calculi.get(p.calculus)
    if calc.boundary_inclusive:
        raise ValueError(f"uniform-within-state priors need an open calculus, not {calc.name!r}")
    targets = target_points(calc, p.target_half_width)
    edges = bin_edges(p)
    static = replace(p, sigma_m=0.0, sigma_z=0.0)
    raw = jax.device_get(_sample_all(calc, static, jax.random.key(p.seed),
                                     jnp.asarray(targets, jnp.float32),
                                     jnp.asarray(edges, jnp.float32), names,
                                     jnp.asarray([p.sigma_m, p.sigma_z], jnp.float32)))
    pool = np.asarray(raw.pop("pool"))
    if np.any(pool == 0):
        raise ValueError(f"pool of {p.pool} points misses states "
                         f"{[calc.states[i] for i in np.flatnonzero(pool == 0)]}; raise pool")
    n = p.samples
    out = {}
    for k, v in raw.items():
        v = np.asarray(v, np.float64)
        if k == "D2":
            out[k] = 0.5 * (v + v.T)  # the same expectation both ways: average the two
        elif k == "AZ":
            out[k] = v / n  # P(visible & ẑ): denominator is every sample of the cell
        elif k == "G2":  # |X1 - X2| is symmetric in the two states: pool both orders
            out[k] = _normalise(v + v.transpose(1, 0, 2, 3))
        else:
            out[k] = _normalise(v)
    return out


def bin_edges(params: ModelParams) -> np.ndarray:
    """(nb + 1,) scale-bin edges in units of R (the last, 3R, caps the unobservable bin)."""
    w = 2.0 / params.n_f
    return np.append(np.arange(params.n_f + 1) * w, 3.0)


def build_models(params: ModelParams | None = None) -> Models:
    """Sample every table of Z §4.2.2–4.2.5 (module docstring); no cache, see :func:`load_models`.

    Args:
        params: the sampling parameters (default :class:`ModelParams`).

    Returns:
        The :class:`Models` with their per-cell counts and derived fields.

    Raises:
        ValueError: for invalid ``params``.
    """
    p = (params or ModelParams()).validate()
    calc = calculi.get(p.calculus)
    out = sample_tables(p)
    targets = target_points(calc, p.target_half_width)
    edges = bin_edges(p)
    w = 2.0 / p.n_f
    n = p.samples
    Q, nb = calc.num_states, p.n_f + 1
    counts = {"T": np.full((nb, Q), n), "AZ": np.full((Q, Q, nb), n),
              "K": np.full((5, Q, Q), n), "G2": np.full((Q, Q, nb), 2 * n),
              "GA": np.full((Q, nb), n), "GB": np.full((Q, nb), n), "U": np.full((3, Q), n),
              "D2": np.full((Q, Q), n)}
    mid = (np.arange(nb) + 0.5) * w
    mid[-1] = 2.0
    return Models(**{k: jnp.asarray(out[k], jnp.float32) for k in TABLES},
                  targets=jnp.asarray(targets, jnp.float32),
                  bin_edges=jnp.asarray(edges, jnp.float32), mid=jnp.asarray(mid, jnp.float32),
                  counts=counts).with_derived()


# ------------------------------------------------------------------------------ cache
def cache_dir() -> Path:
    """``$PQRM_JAX_CACHE/bsp`` (default ``~/.cache/pqrm-jax/bsp``)."""
    root = os.environ.get("PQRM_JAX_CACHE", str(Path.home() / ".cache" / "pqrm-jax"))
    return Path(root) / "bsp"


def _checksum(arrays: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(arrays):
        a = np.ascontiguousarray(arrays[k])
        h.update(k.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def save_models(models: Models, params: ModelParams, path: Path) -> Path:
    """Write ``models`` atomically to ``path`` (.npz with parameters and a checksum)."""
    arrays = {k: np.asarray(getattr(models, k)) for k in
              (*TABLES, "targets", "bin_edges", "mid")}
    arrays |= {f"n_{k}": np.asarray(v) for k, v in models.counts.items()}
    meta = {"params": asdict(params), "key": params.key(), "format": FORMAT_VERSION,
            "checksum": _checksum(arrays)}
    buf = io.BytesIO()
    np.savez_compressed(buf, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(buf.getvalue())
    os.replace(tmp, path)
    return path


def read_models(path: Path, params: ModelParams) -> Models:
    """Load a cached file; ``CacheError`` (naming the file) if corrupt or for other params."""
    fix = f"delete {path} (or call load_models(..., rebuild=True)) to regenerate it"
    try:
        with np.load(path) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(bytes(data.pop("meta")).decode())
    except Exception as e:  # noqa: BLE001 - any read failure means a corrupt file
        raise CacheError(f"BSP model cache {path} is corrupt ({type(e).__name__}: {e}); "
                         f"{fix}") from None
    if meta.get("key") != params.key() or meta.get("format") != FORMAT_VERSION:
        raise CacheError(f"BSP model cache {path} was built for other parameters; {fix}")
    if meta.get("checksum") != _checksum(data):
        raise CacheError(f"BSP model cache {path} fails its checksum (corrupt); {fix}")
    counts = {k[2:]: data.pop(k) for k in list(data) if k.startswith("n_")}
    return Models(**{k: jnp.asarray(data[k]) for k in (*TABLES, "targets", "bin_edges", "mid")},
                  counts=counts).with_derived()


def load_models(params: ModelParams | None = None, *, directory: Path | None = None,
                rebuild: bool = False) -> Models:
    """The models for ``params`` from the cache, sampling and caching them when missing (Z §4.2).

    Args:
        params: the sampling parameters (default :class:`ModelParams`).
        directory: the cache directory (default: the library's cache directory).
        rebuild: sample again even when a cached file exists.

    Returns:
        The :class:`Models`.

    Raises:
        ValueError: for invalid ``params``; ``CacheError`` for a corrupt or mismatching cache
            file (named, with how to regenerate it).

    >>> m = load_models(ModelParams(samples=8, pool=1 << 16))   # doctest: +SKIP
    """
    p = (params or ModelParams()).validate()
    path = Path(directory or cache_dir()) / f"bsp-{p.calculus}-{p.key()}.npz"
    if path.exists() and not rebuild:
        return read_models(path, p)
    m = build_models(p)
    save_models(m, p, path)
    return m
