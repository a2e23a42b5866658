"""Ternary point calculi as polynomial sign constraints (SPEC §2, P2.2.1, MT App. C).

A relation ``AB:C`` places C in the frame of the ordered pair (A, B). In the canonical frame
A=(0,0), B=(0,1), C=(α, β) (right of AB is α > 0), a calculus is k polynomial constraints
``f_a(α, β, ρ)`` (ρ = α² + β²) and a map from their sign patterns in {−,0,+}^k to states.

``classify`` never divides: with d = B − A, e = C − A, u = e×d, v = e·d, m = |e|², n = |d|²
we have α = u/n, β = v/n, ρ = m/n, and every constraint is multiplied by n^D (D its weighted
degree), which keeps its sign. Integer coordinates are therefore classified exactly (in float64
up to |x| ≲ 2^12 for degree-one constraints), so collinear, perpendicular and coincident
configurations get their boundary relations.

Sentinel results (documented, never a silent wrong state):

* ``BOUNDARY`` (−1): C lies on a boundary of an *open* calculus (measure zero).
* ``DEGENERATE`` (−2): A = B in an open calculus (the frame does not exist).
* ``INVALID`` (−3): a NaN or infinite coordinate.

Boundary-inclusive calculi (``dcc``, ``lr_full``) give a state for every configuration,
including A = B ≠ C (``dou``) and A = B = C (``tri``).
"""

from __future__ import annotations

import hashlib
import itertools
import json
from collections.abc import Callable, Mapping, Sequence
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .poly import Poly, as_constraint
from .protocol import BOUNDARY, DEGENERATE, INVALID

SignRule = Callable[[tuple[int, ...]], "str | None"]


def pattern_index(signs: Sequence[int]) -> int:
    return sum((s + 1) * 3**a for a, s in enumerate(signs))


def _fill_open_boundaries(full: dict[tuple[int, ...], int], k: int) -> np.ndarray:
    """Sign table for an open calculus: full patterns from ``full``; a pattern with zeros gets
    a state only when every realisable completion of its zeros is that same state."""
    table = np.full(3**k, BOUNDARY, dtype=np.int32)
    for signs in itertools.product((-1, 0, 1), repeat=k):
        zeros = [a for a, s in enumerate(signs) if s == 0]
        if not zeros:
            table[pattern_index(signs)] = full.get(signs, BOUNDARY)
            continue
        seen = set()
        for fill in itertools.product((-1, 1), repeat=len(zeros)):
            comp = list(signs)
            for a, s in zip(zeros, fill, strict=True):
                comp[a] = s
            st = full.get(tuple(comp), BOUNDARY)
            if st >= 0:
                seen.add(st)
        if len(seen) == 1:
            table[pattern_index(signs)] = seen.pop()
    return table


class Calculus:
    """A ternary qualitative calculus; see the module docstring.

    >>> from pqrm_jax import calculi
    >>> edc = calculi.get("edc")
    >>> int(edc.classify([0., 0.], [0., 1.], [-0.3, 0.9]))   # left, inside both circles
    6
    >>> edc.states[6]
    '7'
    """

    def __init__(
        self,
        name: str,
        states: Sequence[str],
        constraints: Sequence[Poly],
        sign_table: np.ndarray,
        *,
        boundary_inclusive: bool = False,
        degenerate: tuple[str, str] | None = None,
        parent: Calculus | None = None,
        parent_map: Sequence[int] | None = None,
        description: str = "",
    ):
        self.name = name
        self.states = tuple(states)
        if len(set(self.states)) != len(self.states):
            raise ValueError(f"calculus {name!r}: duplicate state labels")
        self.constraints = tuple(as_constraint(c) for c in constraints)
        self.k = len(self.constraints)
        self.sign_table = np.asarray(sign_table, dtype=np.int32)
        if self.sign_table.shape != (3**self.k,):
            raise ValueError(f"calculus {name!r}: sign table must have 3**k entries")
        self.boundary_inclusive = boundary_inclusive
        self.degenerate = degenerate
        if degenerate is not None:
            self.dou, self.tri = (self.states.index(s) for s in degenerate)
        elif boundary_inclusive:
            raise ValueError(f"calculus {name!r}: a boundary-inclusive calculus needs the "
                             "labels of its A=B≠C and A=B=C relations")
        self.parent = parent
        self.parent_map = None if parent_map is None else np.asarray(parent_map, np.int32)
        self.description = description
        # homogenised monomials: coefficient, exponents of (u, v, m) and the power of n
        self._homog = []
        for c in self.constraints:
            top = c.weighted_degree()
            self._homog.append(
                [(float(coef), e[0], e[1], e[2], top - sum(e)) for e, coef in c.terms.items()]
            )
        self._jit_classify = jax.jit(self._classify)

    # construction -------------------------------------------------------------------------
    @classmethod
    def from_rule(
        cls,
        name: str,
        constraints: Sequence[Poly],
        rule: SignRule,
        states: Sequence[str] | None = None,
        *,
        boundary_inclusive: bool = False,
        degenerate: tuple[str, str] | None = None,
        description: str = "",
    ) -> Calculus:
        """Build a calculus from constraints and ``rule(signs) -> label | None``.

        ``signs`` is a tuple of −1/0/+1, the sign of each constraint. For an open calculus the
        rule is asked about zero-free patterns only; ``None`` marks an unrealisable pattern.

        >>> from pqrm_jax.calculi import Calculus
        >>> from pqrm_jax.calculi.poly import alpha
        >>> lr = Calculus.from_rule("my_lr", [-alpha], lambda s: "r" if s[0] < 0 else "l")
        >>> lr.states
        ('l', 'r')
        """
        constraints = [as_constraint(c) for c in constraints]
        k = len(constraints)
        labels: list[str] = list(states) if states is not None else []
        assign: dict[tuple[int, ...], str] = {}
        sign_set = (-1, 0, 1) if boundary_inclusive else (-1, 1)
        for signs in itertools.product(sign_set, repeat=k):
            lab = rule(signs)
            if lab is None:
                continue
            lab = str(lab)
            if states is None and lab not in labels:
                labels.append(lab)
            elif lab not in labels:
                raise ValueError(f"calculus {name!r}: rule returned unknown state {lab!r}")
            assign[signs] = lab
        if degenerate is not None:
            for lab in degenerate:
                if lab not in labels:
                    labels.append(lab)
        if states is None and not boundary_inclusive:
            labels = sorted(labels, key=_natural_key)
        index = {lab: i for i, lab in enumerate(labels)}
        if boundary_inclusive:
            table = np.full(3**k, BOUNDARY, dtype=np.int32)
            for signs, lab in assign.items():
                table[pattern_index(signs)] = index[lab]
        else:
            table = _fill_open_boundaries({s: index[lab] for s, lab in assign.items()}, k)
        return cls(name, labels, constraints, table, boundary_inclusive=boundary_inclusive,
                   degenerate=degenerate, description=description)

    def merge(self, name: str, groups: Mapping[str, Sequence[str]],
              description: str = "") -> Calculus:
        """Coarsen: ``groups`` maps each new label to the fine labels it merges.

        Every fine state must be in exactly one group. Operator tables of the merged calculus
        are the exact unions of the fine tables.

        >>> from pqrm_jax import calculi
        >>> lr = calculi.get("edc").merge("lr2", {"l": "1 3 5 6 7 11 12 13 17 19".split(),
        ...                                       "r": "2 4 8 9 10 14 15 16 18 20".split()})
        >>> int(lr.classify([0., 0.], [0., 1.], [2., 5.]))
        1
        """
        fine_to_coarse = np.full(len(self.states), -1, dtype=np.int32)
        labels = list(groups)
        for ci, lab in enumerate(labels):
            for f in groups[lab]:
                if f not in self.states:
                    raise ValueError(f"merge {name!r}: {f!r} is not a state of {self.name!r}; "
                                     f"states are {self.states}")
                if fine_to_coarse[self.states.index(f)] >= 0:
                    raise ValueError(f"merge {name!r}: state {f!r} is in two groups")
                fine_to_coarse[self.states.index(f)] = ci
        missing = [self.states[i] for i in np.flatnonzero(fine_to_coarse < 0)]
        if missing:
            raise ValueError(f"merge {name!r}: states {missing} are in no group")
        degenerate = None
        if self.degenerate is not None:
            degenerate = tuple(labels[fine_to_coarse[self.states.index(s)]]
                               for s in self.degenerate)
        if self.boundary_inclusive:
            table = np.where(self.sign_table >= 0, fine_to_coarse[self.sign_table], BOUNDARY)
        else:
            full = {}
            for signs in itertools.product((-1, 1), repeat=self.k):
                st = self.sign_table[pattern_index(signs)]
                if st >= 0:
                    full[signs] = int(fine_to_coarse[st])
            table = _fill_open_boundaries(full, self.k)
        return Calculus(name, labels, self.constraints, table,
                        boundary_inclusive=self.boundary_inclusive, degenerate=degenerate,
                        parent=self, parent_map=fine_to_coarse, description=description)

    # identity ------------------------------------------------------------------------------
    @cached_property
    def definition_hash(self) -> str:
        """Hash of everything that determines the operator tables (the cache key)."""
        spec = {
            "states": self.states,
            "constraints": [sorted((list(m), str(c)) for m, c in p.terms.items())
                            for p in self.constraints],
            "table": self.sign_table.tolist(),
            "boundary_inclusive": self.boundary_inclusive,
            "degenerate": self.degenerate,
            "parent": None if self.parent is None else self.parent.definition_hash,
            "parent_map": None if self.parent_map is None else self.parent_map.tolist(),
        }
        return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]

    @property
    def num_states(self) -> int:
        return len(self.states)

    def index(self, label: str | int) -> int:
        """State index of a label (ints are taken as labels, e.g. EDC state 7 → index 6)."""
        lab = str(label)
        if lab not in self.states:
            raise ValueError(f"{lab!r} is not a state of {self.name!r}; states are {self.states}")
        return self.states.index(lab)

    def indices(self, labels) -> list[int]:
        return [self.index(x) for x in labels]

    def labels(self, indices) -> list[str]:
        return [self.states[int(i)] for i in indices]

    def __repr__(self) -> str:
        kind = "boundary-inclusive" if self.boundary_inclusive else "open"
        return f"Calculus({self.name!r}, {self.num_states} states, {self.k} constraints, {kind})"

    # classification ------------------------------------------------------------------------
    def constraint_values(self, a, b, c) -> jax.Array:
        """Homogenised constraint values (..., k); same signs as ``f_a(α, β, ρ)``."""
        a, b, c = jnp.asarray(a), jnp.asarray(b), jnp.asarray(c)
        d = b - a
        e = c - a
        n = d[..., 0] ** 2 + d[..., 1] ** 2
        u = e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]
        v = e[..., 0] * d[..., 0] + e[..., 1] * d[..., 1]
        m = e[..., 0] ** 2 + e[..., 1] ** 2
        vals = []
        for terms in self._homog:
            acc = jnp.zeros_like(n)
            for coef, iu, iv, im, pn in terms:
                t = coef * jnp.ones_like(n)
                for base, p in ((u, iu), (v, iv), (m, im), (n, pn)):
                    if p:
                        t = t * base**p
                acc = acc + t
            vals.append(acc)
        return jnp.stack(vals, axis=-1)

    def _classify(self, a, b, c):
        vals = self.constraint_values(a, b, c)
        signs = jnp.sign(vals).astype(jnp.int32)
        weights = jnp.asarray(3 ** np.arange(self.k), dtype=jnp.int32)
        idx = jnp.sum((signs + 1) * weights, axis=-1)
        state = jnp.asarray(self.sign_table)[idx]
        d = b - a
        e = c - a
        n = d[..., 0] ** 2 + d[..., 1] ** 2
        m = e[..., 0] ** 2 + e[..., 1] ** 2
        if self.boundary_inclusive:
            degen = jnp.where(m == 0, self.tri, self.dou)
        else:
            degen = jnp.full_like(state, DEGENERATE)
        state = jnp.where(n == 0, degen, state)
        finite = jnp.all(jnp.isfinite(a) & jnp.isfinite(b) & jnp.isfinite(c), axis=-1)
        return jnp.where(finite, state, INVALID)

    def classify(self, a, b, c) -> jax.Array:
        """State index of ``AB:C`` for points of shape (..., 2) (broadcast); jit-able.

        Returns an int32 array of the broadcast batch shape; sentinels as in the module doc.
        """
        a, b, c = (jnp.asarray(x) for x in (a, b, c))
        for nm, x in (("a", a), ("b", b), ("c", c)):
            if x.ndim < 1 or x.shape[-1] != 2:
                raise ValueError(f"classify: {nm} must have shape (..., 2), got {x.shape}")
        dtype = jnp.result_type(a, b, c, jnp.float32)
        a, b, c = (jnp.broadcast_arrays(a, b, c))
        return self._jit_classify(a.astype(dtype), b.astype(dtype), c.astype(dtype))

    # operators (computed lazily by pqrm_jax.tables) ----------------------------------------
    @property
    def tables(self):
        """Exact operator tables (unary, compose, adjacency), loaded from cache or built.

        A lazy accessor into :func:`pqrm_jax.tables.store.load_tables`: the first access of a
        user calculus without a cached file runs the exact build (seconds to minutes).
        """
        from ..tables.store import load_tables

        return load_tables(self)

    @property
    def adjacency(self) -> np.ndarray:
        """(Q, Q) bool conceptual neighbourhood computed from geometry (P§2.3.1).

        Read from :attr:`tables`, so the first access may build them.
        """
        return self.tables.adjacency

    @property
    def neighbor_distance(self) -> np.ndarray:
        """(Q, Q) int shortest-path length in the conceptual neighbourhood graph.

        Read from :attr:`tables`, so the first access may build them.
        """
        return self.tables.neighbor_distance


def _natural_key(s: str):
    return (0, int(s), "") if s.isdigit() else (1, 0, s)
