"""Exact (rational) classification and realised-atom enumeration.

``exact_atom`` classifies ``XY:Z`` in rational arithmetic, so every witness configuration of a
table entry is re-verified without rounding. ``realised`` enumerates configurations (random
samples for open calculi, integer grids for boundary-inclusive ones) in one batched float64
JAX pass; every hit it reports is then re-verified exactly before it is used as a witness.
"""

from __future__ import annotations

import itertools
import math
from fractions import Fraction
from functools import lru_cache, partial

import jax
import jax.numpy as jnp
import numpy as np

from ..calculi.calculus import Calculus, pattern_index


@lru_cache(maxsize=64)
def _integer_forms(calc: Calculus) -> tuple:
    """Each constraint f as integer terms (c, i, j, k, l).

    The terms are those of L·n^D f(u/n, v/n, m/n) = Σ c·u^i v^j m^k n^l (D its degree, L > 0
    the lcm of its coefficients' denominators).
    """
    out = []
    for poly in calc.constraints:
        top = poly.weighted_degree()
        scale = math.lcm(*(c.denominator for c in poly.terms.values()))
        out.append(tuple((int(c * scale), *e, top - sum(e)) for e, c in poly.terms.items()))
    return tuple(out)


def _ratio(v) -> tuple[int, int]:
    """(numerator, denominator > 0) of a number, exactly: ``as_integer_ratio`` of a float, an
    int, a NumPy scalar or a Fraction (C-level for floats; ``Fraction(v)`` cost a third of
    the table build's witness re-verification), ``Fraction(v)`` for anything else (text)."""
    if isinstance(v, int | np.integer):
        return int(v), 1
    if isinstance(v, float | Fraction | np.floating):
        num, den = v.as_integer_ratio()
        return int(num), int(den)
    f = Fraction(v)
    return f.numerator, f.denominator


def exact_signs(calc: Calculus, X, Y, Z):
    """Signs of the calculus constraints for ``XY:Z`` (rationals), or 'dou'/'tri' if X=Y.

    Exact in integers: the coordinates are scaled to integers by their common denominator
    (a similarity, so the relation is unchanged) and each constraint is evaluated in its
    homogenised integer form, a positive multiple of n^D f(u/n, v/n, m/n)."""
    q = [_ratio(v) for P in (X, Y, Z) for v in P]
    den = math.lcm(*(d for _, d in q))
    x0, y0, x1, y1, x2, y2 = (num * (den // d) for num, d in q)
    dx, dy = x1 - x0, y1 - y0
    ex, ey = x2 - x0, y2 - y0
    n = dx * dx + dy * dy
    m = ex * ex + ey * ey
    if n == 0:
        return "tri" if m == 0 else "dou"
    u = ex * dy - ey * dx
    v = ex * dx + ey * dy
    signs = []
    for terms in _integer_forms(calc):
        val = sum(c * u**i * v**j * m**k * n**l for c, i, j, k, l in terms)
        signs.append((val > 0) - (val < 0))
    return tuple(signs)


def exact_state(calc: Calculus, X, Y, Z) -> int:
    """State index of ``XY:Z`` computed in rational arithmetic (sentinels as ``classify``)."""
    s = exact_signs(calc, X, Y, Z)
    if s == "dou":
        return calc.dou if calc.boundary_inclusive else -2
    if s == "tri":
        return calc.tri if calc.boundary_inclusive else -2
    return int(calc.sign_table[pattern_index(s)])


def exact_interior_state(calc: Calculus, X, Y, Z) -> int:
    """State index of ``XY:Z`` in rational arithmetic when ``Z`` lies off every boundary of
    the calculus (no constraint vanishes, ``X ≠ Y``), else −1: the ground truth of a relation
    that no rounding of a measurement may lose (the camera-set evidence, issue 27)."""
    s = exact_signs(calc, X, Y, Z)
    return -1 if isinstance(s, str) or 0 in s else int(calc.sign_table[pattern_index(s)])


def atom_lookup(calc: Calculus, atoms: list) -> np.ndarray:
    """Pattern index → atom number (−1 if the pattern is not an atom)."""
    lut = np.full(3**calc.k, -1, np.int32)
    for i, a in enumerate(atoms):
        if isinstance(a, tuple):
            lut[pattern_index(a)] = i
    return lut


def _atoms_of(calc: Calculus, lut, dou, tri, X, Y, Z):
    vals = calc.constraint_values(X, Y, Z)
    idx = jnp.sum((jnp.sign(vals).astype(jnp.int32) + 1) * (3 ** jnp.arange(calc.k)), -1)
    at = jnp.asarray(lut)[idx]
    d = Y - X
    e = Z - X
    n = (d**2).sum(-1)
    m = (e**2).sum(-1)
    return jnp.where(n == 0, jnp.where(m == 0, tri, dou), at)


#: the six relations of a configuration (A, B, C, D) the pre-pass reads: name → point indices
_RELATIONS = {"abc": (0, 1, 2), "bca": (1, 2, 0), "cab": (2, 0, 1), "bac": (1, 0, 2),
              "bcd": (1, 2, 3), "abd": (0, 1, 3)}


def _six_atoms(calc: Calculus, lut, dou: int, tri: int, P) -> jax.Array:
    """[6, M] atom indices of the :data:`_RELATIONS` of float64 configurations P [M, 4, 2]."""
    return jnp.stack([_atoms_of(calc, lut, dou, tri, P[:, x], P[:, y], P[:, z])
                      for x, y, z in _RELATIONS.values()])


def _lookups(calc: Calculus, atoms: list) -> tuple:
    lut = atom_lookup(calc, atoms)
    dou = atoms.index("dou") if "dou" in atoms else -1
    tri = atoms.index("tri") if "tri" in atoms else -1
    return lut, dou, tri


@partial(jax.jit, static_argnums=(0, 2, 3))
def _realised_jit(calc, lut, dou, tri, P):
    return _six_atoms(calc, lut, dou, tri, P)


def realised(calc: Calculus, atoms: list, configs: np.ndarray) -> dict[str, np.ndarray]:
    """Atom indices of the relations of configurations [M, 4, 2] = (A, B, C, D).

    Returns arrays for AB:C, BC:A, CA:B, BA:C, BC:D and AB:D (−1 = not an atom). One jitted
    float64 program for the six relations (eagerly, each of its ~50 operations would compile
    on its own; same atoms on the EDC and DCC pre-passes), compiled once per calculus and
    shape; hits are re-verified exactly.
    """
    lut, dou, tri = _lookups(calc, atoms)
    with jax.enable_x64(True):
        out = np.asarray(_realised_jit(calc, jnp.asarray(lut), dou, tri,
                                       jnp.asarray(configs, jnp.float64)))
    return dict(zip(_RELATIONS, out, strict=True))


def _draws(key, n: int):
    k1, k2, k3 = jax.random.split(key, 3)
    return (jax.random.randint(k1, (n, 2, 1), 0, 4, jnp.int32),
            jax.random.randint(k3, (n, 2), 0, 3, jnp.int32),
            jax.random.uniform(k2, (n, 2, 2), jnp.float32, minval=-1.0, maxval=1.0))


_SCALES = np.asarray([0.6, 1.2, 2.5, 5.0], np.float32)
_CENTRES = np.asarray([[0.0, 0.0], [0.0, 0.5], [0.0, 1.0]], np.float32)
_AB = np.asarray([[0.0, 0.0], [0.0, 1.0]])


def _points(key, n: int):
    """[n, 2, 2] float32 C and D of :func:`sample_configs` (traced with float64 enabled).

    ``centre + scale · u`` with the product and the sum each rounded once to float32, as
    eager float32 arithmetic does: both are formed exactly in float64 and then converted (a
    product of two float32 numbers has at most 48 significant bits; u is a multiple of 2⁻²³
    and the scales of 2⁻²⁴, so the sum is a multiple of 2⁻⁴⁷ below 8 in magnitude: at most
    50 bits). Written as float32 operations, XLA may fuse them into one multiply-add with a
    single rounding (it did: 6 % of the coordinates moved by an ulp).
    """
    scale_i, centre_i, u = _draws(key, n)
    f64 = jnp.float64
    p = (jnp.asarray(_SCALES, f64)[scale_i] * u.astype(f64)).astype(jnp.float32)
    return (jnp.asarray(_CENTRES, f64)[centre_i] + p.astype(f64)).astype(jnp.float32)


_points_jit = jax.jit(_points, static_argnums=1)


def configs_of(points: np.ndarray) -> np.ndarray:
    """Configurations [M, 4, 2] float64 (A = (0, 0), B = (0, 1)) of points C, D [M, 2, 2]."""
    ab = np.broadcast_to(_AB, (len(points), 2, 2))
    return np.concatenate([ab, np.asarray(points, np.float64)], 1)


def sample_configs(key, n: int) -> np.ndarray:
    """Random configurations in the canonical frame at several scales (for open calculi).

    [n, 4, 2] float64; C and D are ``centre + scale · u`` in float32 (u uniform in
    [−1, 1)², the scale one of 0.6, 1.2, 2.5, 5 and the centre one of (0, 0), (0, ½), (0, 1)
    per point), bitwise what eager float32 JAX gives (:func:`_points`)."""
    with jax.enable_x64(True):
        return configs_of(np.asarray(_points_jit(key, n)))


@partial(jax.jit, static_argnums=(0, 2, 3))
def _points_realised_jit(calc, lut, dou, tri, pts):
    ab = jnp.broadcast_to(jnp.asarray(_AB), (pts.shape[0], 2, 2))
    return _six_atoms(calc, lut, dou, tri, jnp.concatenate([ab, pts.astype(jnp.float64)], 1))


def sampled_realised(calc: Calculus, atoms: list, key, n: int) -> tuple[dict, np.ndarray]:
    """:func:`realised` of :func:`sample_configs` ``(key, n)`` without the round trip.

    Returns the six atom arrays and the points C, D [n, 2, 2] float32
    (:func:`configs_of` gives the configurations). The points stay on the device between the
    two programs (drawing, classifying) instead of being written out as float64
    configurations and read back in: 0.24 instead of 0.5 s for the EDC pre-pass's 2²⁰
    samples (one program for both measured 0.35 s; cause not investigated).
    """
    lut, dou, tri = _lookups(calc, atoms)
    with jax.enable_x64(True):
        pts = _points_jit(key, int(n))
        six = _points_realised_jit(calc, jnp.asarray(lut), dou, tri, pts)
        return dict(zip(_RELATIONS, np.asarray(six), strict=True)), np.asarray(pts)


def grid_configs(radius: int = 2) -> np.ndarray:
    """All configurations with A=(0,0), B ∈ {(0,0), (0,2)}, C, D on an integer grid."""
    g = range(-radius, radius + 1)
    pts = np.array(list(itertools.product(g, g)), np.float64)
    out = []
    for B in ((0.0, 0.0), (0.0, 2.0)):
        C = np.repeat(pts, len(pts), 0)
        D = np.tile(pts, (len(pts), 1))
        M = len(C)
        cfg = np.stack([np.zeros((M, 2)), np.broadcast_to(B, (M, 2)), C, D], 1)
        out.append(cfg)
    return np.concatenate(out, 0)
