"""Exact sparse polynomials with rational coefficients.

A qualitative calculus is a set of sign constraints ``f_a(α, β)`` in the canonical frame
A=(0,0), B=(0,1), C=(α, β) (docs/decisions.md §2, P2.2.1). We write them over three
symbols ``alpha``, ``beta`` and ``rho = α² + β²`` so that a line or circle constraint has
weighted degree one.
The same class represents the feasibility problems' polynomials over the free coordinates
(M§III.B Table II), exactly, so witnesses can be re-verified in rational arithmetic.

>>> from pqrm_jax.calculi.poly import alpha, beta, rho
>>> str(2 * beta - rho)
'2*b - r'
>>> (1 - 2 * beta).evaluate([0, 0.5, 0])
Fraction(0, 1)
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from fractions import Fraction

Number = int | float | Fraction


def _frac(x: Number) -> Fraction:
    if isinstance(x, Fraction):
        return x
    if isinstance(x, bool):
        raise TypeError("booleans are not polynomial coefficients")
    return Fraction(x)


class Poly:
    """Sparse polynomial ``{exponent tuple: Fraction}`` over ``nvars`` variables."""

    __slots__ = ("nvars", "terms", "names", "_norm", "_hash")

    def __init__(self, nvars: int, terms: dict | None = None, names: Sequence[str] | None = None):
        self.nvars = nvars
        self.names = tuple(names) if names else tuple(f"x{i}" for i in range(nvars))
        self.terms: dict[tuple[int, ...], Fraction] = {}
        for mono, c in (terms or {}).items():
            c = _frac(c)
            if c != 0:
                self.terms[tuple(mono)] = self.terms.get(tuple(mono), Fraction(0)) + c
        self.terms = {m: c for m, c in self.terms.items() if c != 0}
        # memos of normalized() and hash (polys are never mutated after construction)
        self._norm = None
        self._hash = None

    # construction -------------------------------------------------------------------
    @classmethod
    def const(cls, nvars: int, c: Number, names=None) -> Poly:
        return cls(nvars, {(0,) * nvars: c}, names)

    @classmethod
    def var(cls, nvars: int, i: int, names=None) -> Poly:
        mono = [0] * nvars
        mono[i] = 1
        return cls(nvars, {tuple(mono): 1}, names)

    def _coerce(self, other) -> Poly:
        if isinstance(other, Poly):
            if other.nvars != self.nvars:
                raise ValueError("polynomials over different variables")
            return other
        return Poly.const(self.nvars, other, self.names)

    # arithmetic ---------------------------------------------------------------------
    def __add__(self, other) -> Poly:
        other = self._coerce(other)
        t = dict(self.terms)
        for m, c in other.terms.items():
            t[m] = t.get(m, Fraction(0)) + c
        return Poly(self.nvars, t, self.names)

    __radd__ = __add__

    def __neg__(self) -> Poly:
        return Poly(self.nvars, {m: -c for m, c in self.terms.items()}, self.names)

    def __sub__(self, other) -> Poly:
        return self + (-self._coerce(other))

    def __rsub__(self, other) -> Poly:
        return self._coerce(other) - self

    def __mul__(self, other) -> Poly:
        other = self._coerce(other)
        t: dict = {}
        for m1, c1 in self.terms.items():
            for m2, c2 in other.terms.items():
                m = tuple(a + b for a, b in zip(m1, m2, strict=True))
                t[m] = t.get(m, Fraction(0)) + c1 * c2
        return Poly(self.nvars, t, self.names)

    __rmul__ = __mul__

    def __pow__(self, k: int) -> Poly:
        if not isinstance(k, int) or k < 0:
            raise ValueError("only non-negative integer powers")
        out = Poly.const(self.nvars, 1, self.names)
        for _ in range(k):
            out = out * self
        return out

    def __eq__(self, other) -> bool:
        other = self._coerce(other)
        return self.terms == other.terms

    def __hash__(self) -> int:
        if self._hash is None:
            self._hash = hash(tuple(sorted(self.terms.items())))
        return self._hash

    # inspection ---------------------------------------------------------------------
    @property
    def degree(self) -> int:
        return max((sum(m) for m in self.terms), default=0)

    def is_zero(self) -> bool:
        return not self.terms

    def is_constant(self) -> bool:
        return all(sum(m) == 0 for m in self.terms)

    def constant(self) -> Fraction:
        return self.terms.get((0,) * self.nvars, Fraction(0))

    def variables(self) -> set[int]:
        return {i for m in self.terms for i, e in enumerate(m) if e}

    def normalized(self) -> tuple[Poly, int]:
        """(p / leading coefficient, sign of the leading coefficient); zero stays zero.

        ``sign(p(x)) == s * sign(q(x))`` for ``q, s = p.normalized()``.
        """
        if not self.terms:
            return self, 0
        if self._norm is None:
            lead = self.terms[max(self.terms)]
            s = 1 if lead > 0 else -1
            self._norm = (self, 1) if lead == 1 else (
                Poly(self.nvars, {m: c / lead for m, c in self.terms.items()}, self.names), s)
        return self._norm

    def evaluate(self, x: Sequence[Number]) -> Fraction:
        """Exact value at rational (or float, converted exactly) coordinates."""
        xs = [_frac(v) for v in x]
        total = Fraction(0)
        for m, c in self.terms.items():
            term = c
            for v, e in zip(xs, m, strict=True):
                if e:
                    term *= v**e
            total += term
        return total

    def substitute(self, args: Sequence[Poly], weights: Sequence[int] | None = None,
                   homogenize_with: Poly | None = None) -> Poly:
        """Compose: replace variable i by ``args[i]``.

        With ``homogenize_with=n`` every monomial of weighted degree d is multiplied by
        ``n**(D - d)`` where D is the weighted degree of self (weights default to 1); used to
        clear the denominators of α = u/n, β = v/n, ρ = m/n.
        """
        if len(args) != self.nvars:
            raise ValueError("need one argument per variable")
        weights = weights or [1] * self.nvars
        wdeg = {m: sum(w * e for w, e in zip(weights, m, strict=True)) for m in self.terms}
        top = max(wdeg.values(), default=0)
        out = Poly.const(args[0].nvars, 0, args[0].names)
        for m, c in self.terms.items():
            term = Poly.const(args[0].nvars, c, args[0].names)
            for a, e in zip(args, m, strict=True):
                if e:
                    term = term * a**e
            if homogenize_with is not None and top > wdeg[m]:
                term = term * homogenize_with ** (top - wdeg[m])
            out = out + term
        return out

    def weighted_degree(self, weights: Sequence[int] | None = None) -> int:
        weights = weights or [1] * self.nvars
        return max((sum(w * e for w, e in zip(weights, m, strict=True)) for m in self.terms),
                   default=0)

    def quadratic_form(self) -> tuple[float, list[float], list[list[float]]]:
        """(c, b, A) with p(x) = c + b·x + xᵀAx (A symmetric); raises if degree > 2."""
        if self.degree > 2:
            raise ValueError(f"polynomial {self} has degree {self.degree} > 2")
        n = self.nvars
        c = 0.0
        b = [0.0] * n
        A = [[0.0] * n for _ in range(n)]
        for m, coef in self.terms.items():
            idx = [i for i, e in enumerate(m) for _ in range(e)]
            if not idx:
                c += float(coef)
            elif len(idx) == 1:
                b[idx[0]] += float(coef)
            else:
                i, j = idx
                if i == j:
                    A[i][i] += float(coef)
                else:
                    A[i][j] += float(coef) / 2
                    A[j][i] += float(coef) / 2
        return c, b, A

    def __repr__(self) -> str:
        return f"Poly({self})"

    def __str__(self) -> str:
        if not self.terms:
            return "0"
        parts = []
        for m in sorted(self.terms, key=lambda m: (-sum(m), [-e for e in m])):
            c = self.terms[m]
            mono = "*".join(
                n if e == 1 else f"{n}^{e}" for n, e in zip(self.names, m, strict=True) if e
            )
            mag = abs(c)
            if mono:
                body = mono if mag == 1 else f"{mag}*{mono}"
            else:
                body = str(mag)
            parts.append(("-" if c < 0 else "+", body))
        s = ("-" if parts[0][0] == "-" else "") + parts[0][1]
        for sign, body in parts[1:]:
            s += f" {sign} {body}"
        return s


SYMBOLS = ("a", "b", "r")
alpha = Poly.var(3, 0, SYMBOLS)
beta = Poly.var(3, 1, SYMBOLS)
rho = Poly.var(3, 2, SYMBOLS)


def as_constraint(p: Poly | Number) -> Poly:
    """Coerce a number or polynomial over (α, β, ρ) into a constraint polynomial."""
    if isinstance(p, Poly):
        if p.nvars != 3:
            raise ValueError("calculus constraints are polynomials in (alpha, beta, rho)")
        return p
    return Poly.const(3, p, SYMBOLS)


def line(a: Number, b: Number, c: Number) -> Poly:
    """The linear constraint ``a·α + b·β + c`` in the canonical frame (docs/calculi.md).

    Args:
        a, b, c: rational (or int/float) coefficients.

    Returns:
        A :class:`Poly` in ``(α, β, ρ)``; its sign says on which side of the line C lies.

    >>> str(line(1, 0, -1))
    'a - 1'
    """
    return a * alpha + b * beta + c


def circle(cx: Number, cy: Number, r: Number) -> Poly:
    """The circle constraint ``r² − |C − (cx, cy)|²`` in the canonical frame (docs/calculi.md).

    Args:
        cx, cy: the centre (canonical coordinates: A at the origin, B at (0, 1)).
        r: the radius.

    Returns:
        A :class:`Poly` in ``(α, β, ρ)``: negative outside the circle, positive inside.
    """
    return -(rho - 2 * cx * alpha - 2 * cy * beta) - (cx * cx + cy * cy) + r * r


def all_terms(polys: Iterable[Poly]) -> set:
    return {m for p in polys for m in p.terms}
