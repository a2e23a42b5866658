"""SR maps as a learned ternary qualitative calculus (Padgett §3.3.2, eq. 3.11, Alg. 3).

Beliefs over the position of F in the frame D=(0,0), E=(0,1) of each landmark triplet
(:func:`triplet_beliefs`, eq. 3.11) are fed to SERGE; the resulting SRs are the states of a
calculus, :class:`SergeCalculus`, implementing :class:`pqrm_jax.calculi.TernaryCalculus`
(``name``, ``states``, ``num_states``, jit-able ``classify(a, b, c)``), so that once registered
it works in ``pqrm.state_probabilities`` and ``pqrm.mapper`` (sampled by its own ``classify``,
as a root calculus: ``parent`` is None). Its compose table is computed by Alg. 3.

The frame, the sentinels and how SERGE compose relates to the exact tables:
docs/serge.md §qsr.
"""

from __future__ import annotations

import hashlib
import json
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi.protocol import DEGENERATE, INVALID
from .beliefs import SampleBeliefs
from .grid import Grid
from .scenes import to_frame


def triplet_beliefs(d, e, f) -> SampleBeliefs:
    """Eq. (3.11): samples of D, E, F [K, S, 2] each → beliefs over F̂ in frame DE.

    >>> d = np.zeros((1, 4, 2)); e = d + [0., 2.]; f = d + [2., 2.]
    >>> triplet_beliefs(d, e, f).samples[0, 0].tolist()
    [1.0, 1.0]
    """
    d, e, f = (np.asarray(x, np.float64) for x in (d, e, f))
    if not (d.shape == e.shape == f.shape) or d.ndim != 3 or d.shape[2] != 2:
        raise ValueError(f"triplet_beliefs: d, e, f must be (K, S, 2) of one shape, got "
                         f"{d.shape}, {e.shape}, {f.shape}")
    n = np.sum((e - d) ** 2, axis=-1)
    bad = np.flatnonzero(np.any(n == 0, axis=1))
    if len(bad):
        raise ValueError(f"triplet_beliefs: triplets {bad.tolist()} have samples with D = E "
                         "(the frame DE does not exist)")
    return SampleBeliefs(to_frame(d, e, f))


class SergeCalculus:
    """A ternary calculus whose states are the SRs of an SR map on a grid (P§3.3.2).

    >>> import numpy as np
    >>> from pqrm_jax.serge import Grid
    >>> g = Grid((-2., -2.), (2., 3.), (4, 5))
    >>> lab = (g.centers()[:, 0] > 0).astype(int)         # two SRs: left / right of DE
    >>> c = SergeCalculus("lr_learned", g, lab)
    >>> int(c.classify([0., 0.], [0., 1.], [5., 0.3])), c.states
    (1, ('1', '2'))
    """

    def __init__(self, name: str, grid: Grid, cell_labels, states=None, description: str = ""):
        lab = np.asarray(cell_labels, np.int64).ravel()
        if lab.shape != (grid.n_cells,):
            raise ValueError(f"SergeCalculus: cell_labels must have {grid.n_cells} entries, "
                             f"got {lab.shape}")
        q = int(lab.max()) + 1
        if lab.min() < 0 or len(np.unique(lab)) != q:
            raise ValueError("SergeCalculus: cell labels must be 0..Q−1, each used")
        self.name = name
        self.grid = grid
        self.cell_labels = lab.astype(np.int32)
        self.states = tuple(states) if states is not None else tuple(str(i + 1) for i in range(q))
        if len(self.states) != q:
            raise ValueError(f"SergeCalculus: {q} regions but {len(self.states)} state labels")
        self.description = description or "SERGE salient regions (P§3.3.2)"
        self.parent = None  # a root calculus (no finer calculus it is a merge of)
        self.parent_map = None
        self._labels = jnp.asarray(self.cell_labels)
        self._jit_classify = jax.jit(self._classify)
        self._compose_counts: np.ndarray | None = None
        self.cell_labels.setflags(write=False)
        object.__setattr__(self, "_frozen", True)

    #: memo attributes that may still be set on a frozen calculus (derived, not definition)
    CACHES = frozenset({"_compose_counts", "_compose_stride"})

    def __setattr__(self, name: str, value) -> None:
        """Frozen once built, like :class:`~pqrm_jax.calculi.Calculus` (only the memo of
        :meth:`compose_counts` may be set)."""
        if getattr(self, "_frozen", False) and name not in self.CACHES:
            raise AttributeError(f"calculus {self.name!r} is frozen: cannot set {name!r}")
        object.__setattr__(self, name, value)

    @classmethod
    def from_result(cls, result, name: str = "serge") -> SergeCalculus:
        """From a :class:`~pqrm_jax.serge.search.SergeResult` learned in frame DE."""
        if np.any(result.cell_labels < 0):
            raise ValueError("SergeCalculus.from_result: the map has inactive cells")
        return cls(name, result.problem.grid, result.cell_labels,
                   description=f"SERGE SRs, mu={result.mu}, sigma={result.sigma}")

    @property
    def num_states(self) -> int:
        return len(self.states)

    @cached_property
    def definition_hash(self) -> str:
        """Hash of the grid, the cell labels and the state labels (the calculus's identity)."""
        spec = {"grid": [list(self.grid.lo), list(self.grid.hi), list(self.grid.shape)],
                "states": list(self.states)}
        h = hashlib.sha256(json.dumps(spec, sort_keys=True).encode())
        h.update(self.cell_labels.tobytes())
        return h.hexdigest()[:16]

    def __repr__(self) -> str:
        return f"SergeCalculus({self.name!r}, {self.num_states} states, grid {self.grid.shape})"

    # classification ---------------------------------------------------------------------
    def lookup(self, p) -> jax.Array:
        """State of frame coordinates p [..., 2]."""
        return self._labels[self.grid.cell_of(jnp.asarray(p))]

    def _classify(self, a, b, c):
        v = b - a
        n = v[..., 0] ** 2 + v[..., 1] ** 2
        safe_b = jnp.where((n == 0)[..., None], a + jnp.array([0.0, 1.0], a.dtype), b)
        state = self.lookup(to_frame(a, safe_b, c))
        state = jnp.where(n == 0, DEGENERATE, state)
        finite = jnp.all(jnp.isfinite(a) & jnp.isfinite(b) & jnp.isfinite(c), axis=-1)
        return jnp.where(finite, state, INVALID).astype(jnp.int32)

    def classify(self, a, b, c) -> jax.Array:
        """State index of ``AB:C`` for points [..., 2] (broadcast); jit-able; sentinels −2/−3."""
        a, b, c = (jnp.asarray(x, jnp.float32) for x in (a, b, c))
        for nm, x in (("a", a), ("b", b), ("c", c)):
            if x.ndim < 1 or x.shape[-1] != 2:
                raise ValueError(f"classify: {nm} must have shape (..., 2), got {x.shape}")
        a, b, c = jnp.broadcast_arrays(a, b, c)
        return self._jit_classify(a, b, c)

    # compose (Alg. 3) -----------------------------------------------------------------------
    def compose_counts(self, stride: int = 2, chunk: int = 256) -> np.ndarray:
        """[Q, Q, Q] counts of Alg. 3 over pairs of grid cells.

        For every cell c (F at its centre, state q1 = {DE:F}) and every cell d (G at its centre
        in frame EF, q2 = {EF:G}), the state q3 of G in frame DE is counted. Every
        ``stride``-th cell per axis is used (stride 1 = Alg. 3 exactly, O(N²) pairs).
        """
        if self._compose_counts is not None and self._compose_stride == stride:
            return self._compose_counts
        q = self.num_states
        idx = np.arange(self.grid.n_cells).reshape(self.grid.shape)[::stride, ::stride].ravel()
        centres = jnp.asarray(self.grid.centers()[idx], jnp.float32)
        labs = self._labels[jnp.asarray(idx)]
        e = jnp.array([0.0, 1.0], jnp.float32)

        @jax.jit
        def block(fc, fl, w):
            # F = fc (chunk, 2) in frame DE; G' = centres [M, 2] in frame EF
            v = fc - e                                               # EF direction
            right = jnp.stack([v[:, 1], -v[:, 0]], -1)
            g = (e + centres[None, :, 0:1] * right[:, None, :]
                 + centres[None, :, 1:2] * v[:, None, :])
            q3 = self.lookup(g)
            flat = (fl[:, None] * q + labs[None, :]) * q + q3
            wts = jnp.broadcast_to(w[:, None], flat.shape)
            return jnp.bincount(flat.ravel(), weights=wts.ravel(), length=q**3)

        counts = np.zeros(q**3, np.int64)
        m = len(idx)
        for s in range(0, m, chunk):
            fc, fl = centres[s:s + chunk], labs[s:s + chunk]
            w = jnp.ones(fc.shape[0], jnp.float32)
            pad = chunk - fc.shape[0]
            if pad:
                fc = jnp.concatenate([fc, jnp.repeat(fc[:1], pad, 0)])
                fl = jnp.concatenate([fl, jnp.repeat(fl[:1], pad, 0)])
                w = jnp.concatenate([w, jnp.zeros(pad, jnp.float32)])
            counts += np.rint(np.asarray(block(fc, fl, w))).astype(np.int64)
        self._compose_counts = counts.reshape(q, q, q)
        self._compose_stride = stride
        return self._compose_counts

    @property
    def compose(self) -> np.ndarray:
        """[Q, Q, Q] bool: ``compose[p, q, r]`` ⇔ DE:F = p and EF:G = q allow DE:G = r."""
        return self.compose_counts() > 0

    @property
    def compose_prob(self) -> np.ndarray:
        """[Q, Q, Q] P(DE:G = r | DE:F = p, EF:G = q), uniform over the (F, G) cell pairs."""
        c = self.compose_counts().astype(np.float64)
        tot = c.sum(axis=2, keepdims=True)
        return np.divide(c, tot, out=np.zeros_like(c), where=tot > 0)

    def register(self, overwrite: bool = False):
        """Make this calculus available as ``calculi.get(self.name)`` (only on request)."""
        from .. import calculi

        return calculi.register(self, overwrite=overwrite)
