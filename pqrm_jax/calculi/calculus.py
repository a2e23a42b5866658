"""Ternary point calculi as polynomial sign constraints (docs/decisions.md §2, P2.2.1, MT App. C).

Offers :class:`Calculus`: a calculus defined by k polynomial constraints in the canonical
frame and a map from sign patterns to states, or by merging the states of another calculus;
a division-free, jit-able ``classify`` with documented sentinels; and the definition hash
that keys its tables.

The canonical frame, division-free classification and the sentinels:
docs/calculi.md §calculus and docs/decisions.md §2.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from fractions import Fraction
from functools import cached_property, partial

import jax
import jax.numpy as jnp
import numpy as np

from .poly import Poly, as_constraint
from .protocol import BOUNDARY, DEGENERATE, INVALID

SENTINEL_NAMES = {BOUNDARY: "BOUNDARY", DEGENERATE: "DEGENERATE", INVALID: "INVALID"}

SignRule = Callable[[tuple[int, ...]], "str | None"]


def pattern_index(signs: Sequence[int]) -> int:
    return sum((s + 1) * 3**a for a, s in enumerate(signs))


def _fill_open_boundaries(full: dict[tuple[int, ...], int], k: int) -> np.ndarray:
    """Sign table for an open calculus: full patterns from ``full``.

    A pattern with zeros gets a state only when every realisable completion of its zeros is that
    same state.
    """
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
    """A ternary qualitative calculus; see docs/calculi.md §calculus.

    Frozen once built (setting or deleting an attribute raises ``AttributeError``; its
    ``sign_table`` and ``parent_map`` are read-only arrays).

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
        if not self.states:
            raise ValueError(f"calculus {name!r} has no states")
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
        # the same with integer coefficients (times L > 0, the lcm of the denominators)
        self._int_homog = []
        for c in self.constraints:
            top = c.weighted_degree()
            self._homog.append(
                [(float(coef), e[0], e[1], e[2], top - sum(e)) for e, coef in c.terms.items()]
            )
            scale = math.lcm(*(q.denominator for q in c.terms.values())) if c.terms else 1
            self._int_homog.append(
                [(int(coef * scale), e[0], e[1], e[2], top - sum(e))
                 for e, coef in c.terms.items()])
        # exact constraint signs at the coincidences C = B (α, β, ρ = 0, 1, 1) and C = A (0)
        self._signs_c_eq_b = np.array([_sign(c.evaluate([0, 1, 1])) for c in self.constraints],
                                      np.int32)
        self._signs_c_eq_a = np.array([_sign(c.evaluate([0, 0, 0])) for c in self.constraints],
                                      np.int32)
        self._jit_classify = jax.jit(self._classify)
        self.sign_table.setflags(write=False)
        if self.parent_map is not None:
            self.parent_map.setflags(write=False)
        object.__setattr__(self, "_frozen", True)

    def __setattr__(self, name: str, value) -> None:
        """A calculus is frozen once built: it is a registry singleton and a static jit
        argument, so changing it in place would change every user's calculus silently."""
        if getattr(self, "_frozen", False):
            raise AttributeError(f"calculus {self.name!r} is frozen: cannot set {name!r} "
                                 "(build a new Calculus, or merge this one, instead)")
        object.__setattr__(self, name, value)

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"calculus {self.name!r} is frozen: cannot delete {name!r}")

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
        if not assign:
            raise ValueError(f"calculus {name!r}: the rule returned no state for any sign "
                             "pattern (every pattern was None)")
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
        """State labels of state indices; a sentinel gets its name.

        ``BOUNDARY``, ``DEGENERATE`` and ``INVALID`` (−1, −2, −3) give ``"BOUNDARY"``,
        ``"DEGENERATE"`` and ``"INVALID"``, so ``labels(classify(...))`` never turns a
        sentinel into a state; any other index outside ``[0, num_states)`` raises
        ``ValueError``.

        >>> from pqrm_jax import calculi
        >>> edc = calculi.get("edc")
        >>> edc.labels([6, edc.classify([0., 0.], [0., 1.], [0., 0.5])])
        ['7', 'BOUNDARY']
        """
        out = []
        for i in np.asarray(indices).reshape(-1).tolist():
            i = int(i)
            if 0 <= i < len(self.states):
                out.append(self.states[i])
            elif i in SENTINEL_NAMES:
                out.append(SENTINEL_NAMES[i])
            else:
                raise ValueError(f"{i} is not a state index of {self.name!r} "
                                 f"(0..{len(self.states) - 1}) nor a sentinel (-1, -2, -3)")
        return out

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

    def exact_integer_bound(self, dtype=jnp.float32) -> int:
        """Largest B such that integer-valued ``dtype`` coordinates with every coordinate
        difference |Δ| ≤ B are classified exactly by the float path.

        Every monomial of u, v, m, n (each ≤ 2B²) and every partial sum of a constraint's
        positive or negative part then stays below 2^p (p the mantissa bits), so no product
        or sum is rounded. Integer dtypes given eagerly are always exact (integer arithmetic).

        >>> from pqrm_jax import calculi
        >>> calculi.get("edc").exact_integer_bound("float32")
        2048
        """
        p = jnp.finfo(dtype).nmant + 1
        best = 1 << p
        for terms in self._int_homog:
            deg = max((iu + iv + im + pn for _, iu, iv, im, pn in terms), default=1) or 1
            coef = max(sum(c for c, *_ in terms if c > 0), -sum(c for c, *_ in terms if c < 0),
                       1)
            lo, hi = 0, best
            while lo < hi:  # largest b with coef · (2 b²)^deg ≤ 2^p
                mid = (lo + hi + 1) // 2
                if coef * (2 * mid * mid) ** deg <= 1 << p:
                    lo = mid
                else:
                    hi = mid - 1
            best = min(best, lo)
        return best

    def _signs_and_flags(self, a, b, c):
        """Sign-pattern index (...,) and an ``invalid`` mask by the scale-free float path."""
        dtype = a.dtype
        finfo = jnp.finfo(dtype)
        d = b - a
        e = c - a
        c_eq_b = jnp.all(c == b, axis=-1)
        c_eq_a = jnp.all(c == a, axis=-1)
        finite = jnp.all(jnp.isfinite(d) & jnp.isfinite(e), axis=-1)
        d = jnp.where(finite[..., None], d, 0)
        e = jnp.where(finite[..., None], e, 0)
        # rescale d and e by the power of two nearest max |component| (exact, keeps signs)
        big = jnp.maximum(jnp.max(jnp.abs(d), axis=-1), jnp.max(jnp.abs(e), axis=-1))
        d, e = rescale_pow2(big[..., None], d, e)
        dx, dy, ex_, ey = d[..., 0], d[..., 1], e[..., 0], e[..., 1]
        prods = (ex_ * dy, ey * dx, ex_ * dx, ey * dy, ex_ * ex_, ey * ey, dx * dx, dy * dy)
        # after rescaling every component is ≤ 1, so a product can only underflow when one of
        # its factors is a non-zero component below 2^(emin/2)
        small = float(2.0 ** (finfo.minexp // 2))
        underflow = jnp.zeros(big.shape, bool)
        for x in (dx, dy, ex_, ey):
            underflow = underflow | ((x != 0) & (jnp.abs(x) < small))
        u_pos, u_neg, v_a, v_b, m_a, m_b, n_a, n_b = prods
        u = u_pos - u_neg
        v = v_a + v_b
        m = m_a + m_b
        n = n_a + n_b
        base = (u, v, m, n)
        idx = jnp.zeros(big.shape, jnp.int32)
        ambiguous = jnp.zeros(big.shape, bool)
        nonfinite = jnp.zeros(big.shape, bool)
        for a_i, terms in enumerate(self._int_homog):
            pos = jnp.zeros_like(n)
            neg = jnp.zeros_like(n)
            for coef, iu, iv, im, pn in terms:
                deg = iu + iv + im + pn
                mag = abs(coef)
                if deg == 1 and iu == 1:
                    # a linear u term: its two products go to opposite sides (no subtraction)
                    hi_side, lo_side = (u_pos, u_neg) if coef > 0 else (u_neg, u_pos)
                    pos = pos + mag * hi_side
                    neg = neg + mag * lo_side
                    continue
                t = jnp.full_like(n, float(mag))
                for bv, pw in zip(base, (iu, iv, im, pn), strict=True):
                    if pw:
                        t = t * bv**pw
                if coef > 0:
                    pos = pos + t
                else:
                    neg = neg + t
            # (sign + 1) · 3^a: 0 below, 3^a equal, 2·3^a above
            idx = idx + jnp.where(pos > neg, 2 * 3**a_i, jnp.where(pos < neg, 0, 3**a_i))
            nonfinite = nonfinite | ~jnp.isfinite(pos) | ~jnp.isfinite(neg)
            ambiguous = ambiguous | (jnp.abs(pos - neg) < jnp.sqrt(finfo.tiny))
        idx = jnp.where(c_eq_b, pattern_index(self._signs_c_eq_b.tolist()), idx)
        idx = jnp.where(c_eq_a, pattern_index(self._signs_c_eq_a.tolist()), idx)
        coincident = c_eq_a | c_eq_b
        invalid = ~finite | (~coincident & (nonfinite | (underflow & ambiguous)))
        return idx, invalid

    @cached_property
    def _extended_table(self) -> np.ndarray:
        """``sign_table`` + [INVALID, A=B≠C, A=B=C]: one gather gives every result."""
        if self.boundary_inclusive:
            degen = [self.dou, self.tri]
        else:
            degen = [DEGENERATE, DEGENERATE]
        return np.concatenate([self.sign_table, [INVALID, *degen]]).astype(np.int32)

    def _classify(self, a, b, c):
        """Traced classification (see :meth:`classify`); floats or integers of one shape."""
        return jnp.asarray(self._extended_table)[self._pattern(a, b, c)]

    def _pattern(self, a, b, c):
        """Index into :attr:`_extended_table` of ``AB:C`` (traced; see :meth:`classify`).

        A function of the constraints alone (their sign pattern, the degenerate and invalid
        cases), so a calculus and its merges give the same index (:func:`classify_all`).
        """
        a, b, c = (jnp.asarray(x) for x in (a, b, c))
        int_input = all(jnp.issubdtype(x.dtype, jnp.integer) or jnp.issubdtype(x.dtype, jnp.bool_)
                        for x in (a, b, c))
        if int_input:
            dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
        else:
            dtype = jnp.result_type(a, b, c, jnp.float32)
        af, bf, cf = (x.astype(dtype) for x in (a, b, c))
        idx, invalid = self._signs_and_flags(af, bf, cf)
        a_eq_b = jnp.all(af == bf, axis=-1)
        c_eq_a = jnp.all(cf == af, axis=-1)
        full = 3**self.k
        idx = jnp.where(a_eq_b, jnp.where(c_eq_a, full + 2, full + 1), idx)
        finite = jnp.all(jnp.isfinite(af) & jnp.isfinite(bf) & jnp.isfinite(cf), axis=-1)
        invalid = invalid | ~finite
        if int_input:
            bound = self.exact_integer_bound(dtype)
            lim = float(2 ** (jnp.finfo(dtype).nmant + 1))
            big = jnp.maximum(jnp.max(jnp.abs(bf - af), -1), jnp.max(jnp.abs(cf - af), -1))
            huge = jnp.max(jnp.abs(jnp.stack([af, bf, cf])), axis=(0, -1))
            invalid = invalid | (big > bound) | (huge > lim)
        return jnp.where(invalid, full, idx)

    def _classify_integers(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Exact classification of integer coordinates (NumPy int64, or Python ints)."""
        a, b, c = np.broadcast_arrays(a, b, c)
        batch = a.shape[:-1]
        a, b, c = (x.reshape(-1, 2) for x in (a, b, c))
        top = max((abs(int(x.max(initial=0))) for x in (a, b, c)), default=0)
        bot = max((abs(int(x.min(initial=0))) for x in (a, b, c)), default=0)
        big = max(top, bot)
        worst = max((sum(abs(t[0]) for t in terms) * (8 * big * big + 1)
                     ** max((sum(t[1:]) for t in terms), default=1)
                     for terms in self._int_homog), default=1)
        kind = np.int64 if worst < 2**62 and big < 2**30 else object
        a, b, c = (x.astype(kind) for x in (a, b, c))
        d = b - a
        e = c - a
        dx, dy, ex, ey = d[..., 0], d[..., 1], e[..., 0], e[..., 1]
        u = ex * dy - ey * dx
        v = ex * dx + ey * dy
        m = ex * ex + ey * ey
        n = dx * dx + dy * dy
        signs = []
        for terms in self._int_homog:
            acc = np.zeros(n.shape, kind)
            for coef, iu, iv, im, pn in terms:
                t = np.full(n.shape, coef, kind)
                for bv, pw in zip((u, v, m, n), (iu, iv, im, pn), strict=True):
                    if pw:
                        t = t * bv**pw
                acc = acc + t
            signs.append(np.sign(acc).astype(np.int32))
        signs = np.stack(signs, axis=-1) if signs else np.zeros((*n.shape, 0), np.int32)
        idx = np.sum((signs + 1) * (3 ** np.arange(self.k)), axis=-1)
        state = self.sign_table[idx]
        a_eq_b = np.all(d == 0, axis=-1)
        c_eq_a = np.all(e == 0, axis=-1)
        if self.boundary_inclusive:
            degen = np.where(c_eq_a, self.tri, self.dou)
        else:
            degen = np.full(state.shape, DEGENERATE)
        return np.where(a_eq_b, degen, state).astype(np.int32).reshape(batch)

    def classify(self, a, b, c) -> jax.Array:
        """State index of ``AB:C`` for points of shape [..., 2] (broadcast); jit-able.

        Returns an int32 array of the broadcast batch shape; sentinels as in docs/decisions.md §2.
        Integer dtypes are classified exactly (eagerly); complex input raises ``TypeError``.

        >>> from pqrm_jax import calculi
        >>> lr = calculi.get("lr_full")
        >>> b = [0.1, 0.7]
        >>> lr.states[int(lr.classify([0.3, -0.2], b, b))]      # C = B: the relation 'e'
        'e'
        >>> int(lr.classify([0, 0], [0, 3_000_000_000], [-3, 1_000_000_000]))  # exact int64
        0
        """
        raw, shape = _points(a, b, c)
        if _exact_integers(raw):
            out = self._classify_integers(*(np.asarray(x) for x in raw))
            return jnp.asarray(out.reshape(shape[:-1]), jnp.int32)
        a, b, c = jnp.broadcast_arrays(*(jnp.asarray(x) for x in raw))
        return self._jit_classify(a, b, c)

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
        """[Q, Q] bool conceptual neighbourhood computed from geometry (P§2.3.1).

        Read from :attr:`tables`, so the first access may build them.
        """
        return self.tables.adjacency

    @property
    def neighbor_distance(self) -> np.ndarray:
        """[Q, Q] int shortest-path length in the conceptual neighbourhood graph.

        Read from :attr:`tables`, so the first access may build them.
        """
        return self.tables.neighbor_distance


def classify_all(calcs: Sequence, a: jax.typing.ArrayLike, b: jax.typing.ArrayLike,
                 c: jax.typing.ArrayLike) -> tuple[jax.Array, ...]:
    """``tuple(calc.classify(a, b, c) for calc in calcs)``, one sign evaluation per family.

    Calculi with the same constraints (a calculus and its merges, e.g. Padgett's six
    representations of the EDC, P §2.2.1) classify by the same sign pattern of those
    constraints and differ only in the table that names its state
    (:meth:`Calculus.merge`). The pattern is evaluated once per such family and looked up
    in each calculus' own table, so every result equals ``calc.classify(a, b, c)`` bit for
    bit (sentinels included: a boundary of the fine calculus can be a state of a merge) at
    the cost of one classification and a table lookup per calculus. As in ``classify``, the
    pattern is compiled together with its lookup: compiled apart, LLVM may contract its
    products and sums into FMAs differently, and a float point at a boundary can then change
    state (the property test in tests/test_calculi.py found such a point). Integer coordinates
    outside a trace are classified exactly by each calculus, as :meth:`Calculus.classify`
    does; a calculus of another kind (a :class:`~pqrm_jax.calculi.TernaryCalculus` such as a
    SERGE calculus) is classified by its own ``classify``.

    Args:
        calcs: calculi (:class:`Calculus` or any ``TernaryCalculus``).
        a, b, c: points ``[..., 2]`` (broadcast), as for :meth:`Calculus.classify`.

    Returns:
        One int32 array of the broadcast batch shape per calculus, in the order of ``calcs``.

    >>> from pqrm_jax import calculi
    >>> lr, edc = calculi.get("lr"), calculi.get("edc")
    >>> states = classify_all([edc, lr], [0., 0.], [0., 1.], [2., 5.])
    >>> [int(x) for x in states] == [int(edc.classify([0., 0.], [0., 1.], [2., 5.])), 1]
    True
    """
    calcs = tuple(calcs)
    raw, _ = _points(a, b, c)
    if _exact_integers(raw):
        return tuple(calc.classify(*raw) for calc in calcs)
    pts = jnp.broadcast_arrays(*(jnp.asarray(x) for x in raw))
    families: dict[tuple, list[int]] = {}
    out: list = [None] * len(calcs)
    for i, calc in enumerate(calcs):
        if isinstance(calc, Calculus):
            families.setdefault(calc.constraints, []).append(i)
        else:
            out[i] = calc.classify(*pts)
    for members in families.values():
        for i, state in zip(members, _jit_family(tuple(calcs[i] for i in members), *pts),
                            strict=True):
            out[i] = state
    return tuple(out)


@partial(jax.jit, static_argnums=0)
def _jit_family(family: tuple[Calculus, ...], a, b, c) -> tuple[jax.Array, ...]:
    """The states in each calculus of ``family`` (same constraints), in one program: the
    pattern and its lookup compiled together, as in :meth:`Calculus.classify` (compiled
    apart, LLVM may contract the pattern's products and sums into FMAs differently, which
    can move a sign at a boundary)."""
    if len(family) == 1:
        return (family[0]._classify(a, b, c),)
    # the tables side by side, looked up by one gather of whole rows: one lookup per
    # calculus would each re-evaluate the pattern (XLA fuses it into every lookup)
    table = np.stack([calc._extended_table for calc in family], axis=-1)
    states = jnp.asarray(table)[family[0]._pattern(a, b, c)]
    return tuple(states[..., j] for j in range(len(family)))


def _points(a, b, c) -> tuple[list, tuple[int, ...]]:
    """The checked coordinate arrays of ``classify(a, b, c)`` and their broadcast shape."""
    raw = []
    for nm, x in (("a", a), ("b", b), ("c", c)):
        if not isinstance(x, jax.Array | np.ndarray):
            try:
                x = np.asarray(x)
            except (TypeError, ValueError) as err:
                raise TypeError(f"classify: {nm} is not an array of coordinates") from err
        dt = x.dtype
        if jnp.issubdtype(dt, jnp.complexfloating):
            raise TypeError(f"classify: {nm} is complex ({dt}); coordinates must be real")
        if jnp.issubdtype(dt, jnp.bool_) or not (jnp.issubdtype(dt, jnp.integer)
                                                  or jnp.issubdtype(dt, jnp.floating)):
            raise TypeError(f"classify: {nm} has dtype {dt}; coordinates must be real "
                            "numbers (integer or float)")
        if x.ndim < 1 or x.shape[-1] != 2:
            raise ValueError(f"classify: {nm} must have shape (..., 2), got {x.shape}")
        raw.append(x)
    try:
        shape = np.broadcast_shapes(*(x.shape for x in raw))
    except ValueError as err:
        raise ValueError(f"classify: shapes {[x.shape for x in raw]} do not "
                         "broadcast") from err
    return raw, shape


def _exact_integers(raw) -> bool:
    """Integer coordinates outside a trace: classified exactly, in NumPy int64."""
    return (not any(isinstance(x, jax.core.Tracer) for x in raw)
            and all(jnp.issubdtype(x.dtype, jnp.integer) for x in raw))


def _sign(x: Fraction) -> int:
    return (x > 0) - (x < 0)


def rescale_pow2(big: jax.Array, *xs: jax.Array) -> tuple[jax.Array, ...]:
    """``xs`` times the power of two 2^-k that brings ``big`` (≥ 0) into [½, 1) (exactly).

    A power of two changes no bit of a mantissa, so products formed afterwards round exactly
    as they would at scale one, without overflow or underflow at any scale (used by
    ``classify`` and the fused PQRM kernel). ``big`` = 0 or non-finite leaves ``xs`` as is.
    ``big`` broadcasts against each of ``xs``.

    >>> import jax.numpy as jnp
    >>> rescale_pow2(jnp.float32(3e30), jnp.float32(3e30))[0].item()
    0.5916456580162048
    """
    dtype = jnp.result_type(*xs)
    ok = (big > 0) & jnp.isfinite(big)
    _, k = jnp.frexp(jnp.where(ok, big, 1).astype(dtype))
    s1 = _pow2(-(k // 2), dtype)
    s2 = _pow2(-k + k // 2, dtype)
    return tuple(x * s1 * s2 for x in xs)


def _pow2(k: jax.Array, dtype) -> jax.Array:
    """2**k exactly, for integer k in the normal exponent range of ``dtype``."""
    finfo = jnp.finfo(dtype)
    itype = jnp.int64 if finfo.bits == 64 else jnp.int32
    bits = (k.astype(itype) + (finfo.maxexp - 1)) << finfo.nmant
    return jax.lax.bitcast_convert_type(bits, dtype)


def _natural_key(s: str):
    return (0, int(s), "") if s.isdigit() else (1, 0, s)
