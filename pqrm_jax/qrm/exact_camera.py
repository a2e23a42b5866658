"""Exact camera measurement from the boundary of the range cone (M§IV–V, Table III).

With the camera at the origin, unit bearings ``w_s`` and ranges ``d = (d_near, d_mid,
d_far)``, the landmarks are ``P_s = d_s w_s``. Every constraint of a cyclic relation XY:Z is
``c_n n + c_u u + c_v v + c_m m`` with ``n = |D|², u = E×D, v = E·D, m = |E|²``
(``D = P_Y − P_X``, ``E = P_Z − P_X``), a quadratic form in ``d``; a state is the open set
where its strict sign pattern holds. The measurement must return exactly the states whose
set meets the range-order cone ``0 < d_near < d_mid < d_far``.

**The decision** (docs/qrm.md §camera gives the argument in full). Map a range assignment to
the normalised position ``c = E / D`` of Z in the frame X = 0, Y = 1 (complex numbers). The
constraints only depend on ``c``, and in the ``c`` plane every state is a fixed *connected*
region ``R_s`` bounded by lines and circles (for EDC: 20 regions). The map from the cone to
``c`` is one-to-one, and it sends the cone to a region ``F`` bounded by the images of the
three cone edges (``d_near = 0``, ``d_mid = d_far``, ``d_near = d_mid``); the fourth
vertex ``d_near = d_mid = 0`` goes to ``c ∈ {0, 1, ∞}``, which lies in no open state. Since
``R_s`` is connected and open, ``R_s`` meets ``F`` iff

1. an edge of the cone has a point with the strict pattern of ``s`` (``∂F`` crosses
   ``R_s``), or
2. ``R_s ⊂ F``, which holds iff a fixed interior point ``c_s`` of ``R_s`` has its range
   preimage ``d(c_s)`` (the kernel of a 2 × 3 real system) inside the cone.

On an edge ``d(t) = (1 − t) V_i + t V_j`` each constraint is a quadratic in ``t``; the
sample points are the midpoints between its sorted roots in (0, 1) (plus each quadratic's
vertex, which catches near-tangencies), so every pattern realised on an edge is sampled.
That is 3 edges × 19 samples plus the ``c_s`` per relation — no search, no depth limit.

**Rounding.** Forms are evaluated from the points (``D``, ``E``), not from matrix
coefficients, with a worst-case rounding bound ``e(d)`` built from the machine epsilon of
the dtype (:func:`form_values`). A sample whose every ``|f| > 2e`` is a *witness*: that
float range assignment has the pattern exactly (tested against the rational oracle
:mod:`pqrm_jax.qrm.camera_oracle`). For the exclusion, a sample's sign counts as uncertain
when ``|f|`` is within ``BAND`` times the largest bound on its edge (a root misplaced by
rounding moves a sample by at most that much in value). States compatible with an
uncertain sample but never witnessed are returned as *undecided*: kept (sound) and counted;
the exact path of :func:`pqrm_jax.qrm.camera.measure_triples` settles them with z3. Where a
constraint vanishes identically at a vertex (e.g. ``|XY| = |XZ|`` when X is at the camera and
Y, Z equidistant) the edge quadratic is factored exactly, so no root sits a rounding error
away from the vertex. Only near-degenerate input (a sample within the band of a root of
another constraint: nearly coincident constraint curves on an edge, two equal bearings)
leaves states undecided; random input almost never does (benchmarks/bench_camera_exact.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from .spec import CYCLIC, QRMSpec

__all__ = ["CameraStructure", "camera_structure", "form_values", "exact_sets", "CYCLIC",
           "VERTICES", "EDGES", "BAND", "SCREEN_SHARE", "SCREEN_MIN", "screen_buffer",
           "tolerant_flags"]

#: vertices of the range-order cone on d_far = 1: (0,0,1) both nearer landmarks at the camera,
#: (0,1,1) near at the camera and mid = far, (1,1,1) all ranges equal
VERTICES = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
#: the cone edges as vertex pairs: d_near = 0, d_mid = d_far, d_near = d_mid
EDGES = ((0, 1), (1, 2), (0, 2))
#: uncertainty band on an edge, in units of the edge's largest rounding bound: the edge
#: quadratic is interpolated from three evaluations (|Δq(t)| ≤ 17 × their bound), so a root
#: is misplaced only where |f| ≤ 17 e; 24 adds the root formula's own rounding
BAND = 24.0
_CERTAIN = 2.0  # a sign is certain when |f| exceeds twice its worst-case rounding bound
_CONE_BAND = 64.0  # rounding of the 2×3 kernel (units of eps × |d|): preimage near the cone


@dataclass(frozen=True, eq=False)
class CameraStructure:
    """Static structure of a calculus for the exact camera measurement.

    Attributes:
        vanish: [3, K, 3] bool, constraint k of relation o vanishes identically at vertex v.
        edge_ok: [3, 3] bool, no constraint of relation o vanishes identically on edge e (an
            edge where one does holds no point of any open state).
        reps: [R, 2] float64 points ``c = (α, β)``, one inside every connected component of
            every open state's region of the normalised plane.
        rep_atoms: (R,) int32 atom of each point.
    """

    vanish: np.ndarray
    edge_ok: np.ndarray
    reps: np.ndarray
    rep_atoms: np.ndarray


def _exact_value(Q, d) -> Fraction:
    return sum(Q[s][r] * d[s] * d[r] for s in range(3) for r in range(3))


def _region_points(spec: QRMSpec, half: float = 4.0, step: float = 0.01):
    """One deep interior point per connected component of every open state's region.

    The regions of the normalised plane (X = 0, Y = 1, Z = c) are bounded by the calculus's
    lines and circles; a grid over ``[−half, half + 1] × [−half, half]`` (which holds every
    intersection of the shipped calculi's curves) is labelled per atom (grid points on a
    curve belong to none), and each component contributes its point farthest from the
    component's border.
    """
    a = np.arange(-half, half + 1 + step / 2, step)
    b = np.arange(-half, half + step / 2, step)
    A, B = np.meshgrid(a, b, indexing="ij")
    g = np.stack([np.ones_like(A), -B, A, A * A + B * B], -1)  # (n, u, v, m) at D = 1, E = c
    f = g @ np.asarray(spec.lin).T  # (..., K)
    strict = np.all(np.abs(f) > 1e-9, -1)
    idx = np.sum((np.sign(f).astype(np.int64) + 1) * 3 ** np.arange(spec.k), -1)
    atom = np.where(strict, np.asarray(spec.pattern_atom)[idx], -1)
    reps, rep_atoms = [], []
    for at in range(spec.num_atoms):
        if not np.any(spec.atom_signs[at] == 0):
            lab, n = ndimage.label(atom == at)
            for comp in range(1, n + 1):
                depth = ndimage.distance_transform_edt(np.pad(lab == comp, 1))[1:-1, 1:-1]
                i, j = np.unravel_index(np.argmax(depth), depth.shape)
                reps.append((A[i, j], B[i, j]))
                rep_atoms.append(at)
    return np.asarray(reps, np.float64).reshape(-1, 2), np.asarray(rep_atoms, np.int32)


@cache
def camera_structure(spec: QRMSpec) -> CameraStructure:
    """The (cached) :class:`CameraStructure` of a calculus.

    Identical vanishing is decided in exact rational arithmetic on three generic bearing
    triples (a quadratic vanishing at three points of an edge vanishes on it).

    >>> from pqrm_jax.qrm.spec import qrm_spec
    >>> s = camera_structure(qrm_spec("edc"))
    >>> s.reps.shape, int(s.vanish.sum()), bool(s.edge_ok.all())
    ((20, 2), 13, True)
    """
    from .camera_oracle import exact_forms

    rng = np.random.default_rng(7)
    pts = [[Fraction(x) for x in v] for v in VERTICES]
    mids = [[(pts[i][s] + pts[j][s]) / 2 for s in range(3)] for i, j in EDGES]
    vanish = np.ones((3, spec.k, 3), bool)
    mid_zero = np.ones((3, spec.k, 3), bool)
    for _ in range(3):
        F = exact_forms(spec, rng.uniform(-np.pi, np.pi, 3))
        for o in range(3):
            for k in range(spec.k):
                for v in range(3):
                    vanish[o, k, v] &= _exact_value(F[o][k], pts[v]) == 0
                    mid_zero[o, k, v] &= _exact_value(F[o][k], mids[v]) == 0
    edge_ok = np.ones((3, 3), bool)
    for e, (i, j) in enumerate(EDGES):
        edge_ok[:, e] = ~np.any(vanish[:, :, i] & vanish[:, :, j] & mid_zero[:, :, e], -1)
    reps, rep_atoms = _region_points(spec)
    open_atoms = np.flatnonzero(~np.any(spec.atom_signs == 0, -1))
    missing = set(open_atoms.tolist()) - set(rep_atoms.tolist())
    if missing:
        raise ValueError(f"calculus {spec.calc.name!r}: no grid point inside the regions of "
                         f"atoms {sorted(missing)}; the exact camera measurement needs one")
    return CameraStructure(vanish, edge_ok, reps, rep_atoms)


def form_values(spec: QRMSpec, w, d):
    """Values and rounding bounds of the constraints of the relation XY:Z at ranges ``d``.

    Args:
        spec: the calculus.
        w: ``(cos, sin)`` of the bearings of X, Y, Z, each [3, ...] (broadcastable against
            ``d``'s entries on the trailing axes).
        d: the ranges ``(d_X, d_Y, d_Z)``, each broadcastable to [..., T].

    Returns:
        ``(f, e)`` [K, ..., T]: the constraint values and a worst-case bound on their rounding
        error (cos/sin and every product and sum; machine epsilon of the dtype). A cyclic
        relation of a slot triple is XY:Z with its slots permuted to ``CYCLIC[o]``
        (:func:`exact_sets`).
    """
    cw, sw = w
    eps = jnp.finfo(cw.dtype).eps
    dX, dY, dZ = d
    PXx, PXy = dX * cw[0], dX * sw[0]
    Dx, Dy = dY * cw[1] - PXx, dY * sw[1] - PXy
    Ex, Ey = dZ * cw[2] - PXx, dZ * sw[2] - PXy
    aX, aY, aZ = jnp.abs(dX), jnp.abs(dY), jnp.abs(dZ)
    nD, nE = jnp.abs(Dx) + jnp.abs(Dy), jnp.abs(Ex) + jnp.abs(Ey)
    eD = 2 * eps * (aX + aY) + eps * nD
    eE = 2 * eps * (aX + aZ) + eps * nE
    n = Dx * Dx + Dy * Dy
    m = Ex * Ex + Ey * Ey
    u = Ex * Dy - Ey * Dx
    v = Ex * Dx + Ey * Dy
    cross = nE * eD + nD * eE + eD * eE + 2 * eps * nD * nE
    g = (n, u, v, m)
    eg = ((2 * nD + eD) * eD + 2 * eps * n, cross, cross, (2 * nE + eE) * eE + 2 * eps * m)
    fs, es = [], []
    for row in np.asarray(spec.lin):
        f = e = r = 0.0
        for c, x, ex in zip(row, g, eg, strict=True):
            if c != 0:
                f = f + (x if c == 1 else -x if c == -1 else float(c) * x)
                e = e + abs(float(c)) * ex
                r = r + abs(float(c)) * jnp.abs(x)
        fs.append(f)
        es.append(e + 3 * eps * r)
    return jnp.stack(jnp.broadcast_arrays(*fs)), jnp.stack(jnp.broadcast_arrays(*es))


def _roots(A, B, C, z0, z1):
    """[2, …] roots of ``A t² + B t + C`` (NaN where none); ``z0``/``z1``: the quadratic
    vanishes identically at t = 0 / t = 1 (factored exactly)."""
    disc = B * B - 4 * A * C
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    q = -0.5 * (B + jnp.where(B >= 0, sq, -sq))
    nan = jnp.full_like(A, jnp.nan)
    safe = lambda x: jnp.where(x == 0, 1.0, x)  # noqa: E731
    r1 = jnp.where((disc >= 0) & (A != 0), q / safe(A), nan)
    r1 = jnp.where((A == 0) & (B != 0), -C / safe(B), r1)
    r2 = jnp.where((disc >= 0) & (q != 0), C / safe(q), nan)
    r2 = jnp.where(A == 0, nan, r2)
    # f(0) = 0 structurally: f = t (A t + B); f(1) = 0: f = (t − 1)(A t − C); both: A t(t − 1)
    one0 = jnp.where(A != 0, -B / safe(A), nan)
    one1 = jnp.where(A != 0, C / safe(A), nan)
    r1 = jnp.where(z0 & z1, nan, jnp.where(z0, one0, jnp.where(z1, one1, r1)))
    r2 = jnp.where(z0 | z1, nan, r2)
    return jnp.stack([r1, r2])


def _sample_params(A, B, C, z0, z1):
    """Edge parameters ``t`` [3K + 1, …] and their validity: the midpoints between
    consecutive roots in (0, 1) and the ends (2K + 1; repeated roots repeat a sample), then
    the vertex of every quadratic (K); and each sample's interval ``(lo, hi)`` between
    consecutive roots with the constraint whose root each end is (−1: an end of the edge;
    a vertex sample's interval is the point itself); last, ``nidx`` [2K + 1, …]: the index
    among the interval starts ``lo[:2K + 1]`` of each interval's upper end."""
    K = A.shape[0]
    r = _roots(A, B, C, z0, z1).reshape((-1,) + A.shape[1:])  # (2K, …)
    inside = jnp.isfinite(r) & (r > 0) & (r < 1)
    r = jnp.where(inside, r, 0.0)
    zero = jnp.zeros((1,) + r.shape[1:], r.dtype)
    pts = jnp.concatenate([zero, r])  # every interval starts at one of these
    # midpoint of each interval [p, next value above p] (no sort: a min over the others)
    # (ties broken by index: a repeated root gives a sample on it, as a sort would)
    idx = np.arange(pts.shape[0]).reshape((-1,) + (1,) * (pts.ndim - 1))
    above = (pts[None] > pts[:, None]) | ((pts[None] == pts[:, None]) & (idx[None] > idx[:, None]))
    cand = jnp.where(above, pts[None], 1.0)
    nxt = jnp.min(cand, axis=1)
    mids = 0.5 * (pts + nxt)
    top = -B / jnp.where(A == 0, 1.0, 2 * A)
    t = jnp.concatenate([mids, jnp.where(A != 0, top, 0.5)])
    valid = (t > 0) & (t < 1)
    t = jnp.where(valid, t, 0.5)
    lo = jnp.concatenate([pts, t[pts.shape[0]:]])
    hi = jnp.concatenate([nxt, t[pts.shape[0]:]])
    # owner constraint of each end: pts[1 + m] is a root of constraint m % K
    owner = np.concatenate([[-1], np.arange(2 * K) % K]).reshape(idx.shape)
    own_lo = jnp.where(pts > 0, jnp.asarray(owner), -1)
    nidx = jnp.argmin(jnp.where(above, pts[None], 2.0), axis=1)
    own_hi = jnp.where(nxt < 1, jnp.asarray(owner.ravel())[nidx], -1)
    minus = jnp.full((K,) + A.shape[1:], -1, jnp.int32)
    own_lo = jnp.concatenate([own_lo.astype(jnp.int32) + 0 * minus[:1], minus])
    own_hi = jnp.concatenate([own_hi.astype(jnp.int32), minus])
    return t, valid, lo, hi, own_lo, own_hi, nidx


def _reduced(A, B, C, z0, z1):
    """Coefficients ``(a2, a1, a0)`` of ``q / h`` for the edge quadratic ``q = A t² + B t + C``
    with its structural roots divided out (``h = t``, ``t − 1`` or ``t (t − 1)`` where ``q``
    vanishes identically at ``t = 0`` / ``t = 1``; ``h`` keeps one sign on (0, 1))."""
    zero = jnp.zeros_like(A)
    a2 = jnp.where(z0 | z1, zero, A)
    a1 = jnp.where(z0 & z1, zero, jnp.where(z0 | z1, A, B))
    a0 = jnp.where(z0 & z1, A, jnp.where(z0, B, jnp.where(z1, -C, C)))
    return a2, a1, a0


def _atoms(spec: QRMSpec, f, cert, band, loose=None):
    """Witness and possible atom masks [...] from values ``f`` [K, ...] with the certain
    threshold ``cert`` and the uncertainty band ``band``; ``loose`` [K, ...] marks more
    signs as uncertain (the bearing tolerance)."""
    K = spec.k
    sure = jnp.where(f > cert, 1, jnp.where(f < -cert, -1, 0))
    wts = jnp.asarray(3 ** np.arange(K), jnp.int32).reshape((K,) + (1,) * (f.ndim - 1))
    atom = jnp.asarray(spec.pattern_atom)[jnp.sum((sure + 1) * wts, 0)]
    ok = jnp.all(sure != 0, 0) & (atom >= 0)
    wit = jnp.where(ok, jnp.uint32(1) << jnp.maximum(atom, 0).astype(jnp.uint32),
                    jnp.uint32(0))
    shape = (K,) + (1,) * (f.ndim - 1)
    pos, neg, amb = (jnp.asarray(x, jnp.uint32).reshape(shape)
                     for x in (spec.pos, spec.neg, spec.amb))
    cm = jnp.where(f > band, pos, jnp.where(f < -band, neg, amb))
    if loose is not None:
        cm = jnp.where(loose, amb, cm)
    poss = jax.lax.reduce(cm, np.uint32(0xFFFFFFFF), jax.lax.bitwise_and, (0,))
    return wit, poss


def _form_derivatives(spec: QRMSpec, w, d):
    """[3, K, ...] derivatives of the constraints of XY:Z with respect to the bearings of X,
    Y and Z at ranges ``d`` (as :func:`form_values`): ``∂P_s/∂θ_s = d_s w_s⊥``."""
    cw, sw = w
    dX, dY, dZ = d
    PX, PY, PZ = ((dd * cw[k], dd * sw[k]) for k, dd in enumerate(d))
    Dx, Dy = PY[0] - PX[0], PY[1] - PX[1]
    Ex, Ey = PZ[0] - PX[0], PZ[1] - PX[1]
    perp = [(-dd * sw[k], dd * cw[k]) for k, dd in enumerate(d)]  # ∂P_s / ∂θ_s
    lin = np.asarray(spec.lin)
    out = []
    for p in range(3):
        zero = jnp.zeros_like(Dx)
        dDx = (perp[1][0] if p == 1 else zero) - (perp[0][0] if p == 0 else zero)
        dDy = (perp[1][1] if p == 1 else zero) - (perp[0][1] if p == 0 else zero)
        dEx = (perp[2][0] if p == 2 else zero) - (perp[0][0] if p == 0 else zero)
        dEy = (perp[2][1] if p == 2 else zero) - (perp[0][1] if p == 0 else zero)
        g = (2 * (Dx * dDx + Dy * dDy),
             dEx * Dy + Ex * dDy - dEy * Dx - Ey * dDx,
             dEx * Dx + Ex * dDx + dEy * Dy + Ey * dDy,
             2 * (Ex * dEx + Ey * dEy))
        out.append(jnp.stack(jnp.broadcast_arrays(
            *[sum(float(c) * x for c, x in zip(row, g, strict=True) if c != 0) + 0 * Dx
              for row in lin])))
    return jnp.stack(out)


def _perturbation(spec: QRMSpec, w, nodes_d, Vi, Vd, van, tol):
    """[K, O, 3, T] bound on how much a change of at most ``tol`` of each bearing moves
    ``q / h`` on each edge (``q`` the constraint on the edge ``d = Vi + t Vd``, ``h`` its
    structural factor, :func:`_reduced`).

    First order: ``tol Σ_s max_t |∂(q/h)/∂θ_s|`` (the derivatives are quadratics in ``t``,
    interpolated from the edge nodes like ``q``, structural roots divided out; the max is
    bounded by the sum of their coefficients' magnitudes). Second order: each form is a
    symmetric bilinear ``β(x, y)`` of the linear maps ``D``, ``E`` of the ranges; rotating
    ``w_s`` by ``δ`` moves it by ``δ w_s⊥`` plus at most ``δ²/2``, which bounds the remainder
    ``ρ(x, y)`` from the norms at the given bearings, summed as ``q(t) = β(a, a) +
    2t β(a, b) + t² β(b, b)`` (vanishing terms dropped; ``a`` the vertex with the structural
    root)."""
    i, j = np.array(EDGES).T
    z0, z1 = van[:, :, i, None], van[:, :, j, None]
    dg = _form_derivatives(spec, w, nodes_d)  # (3, K, O, 6, T)
    dg = jnp.concatenate([jnp.where(van[None, ..., None], 0.0, dg[..., :3, :]),
                          dg[..., 3:, :]], -2)
    g0, gh, g1 = dg[..., i, :], dg[..., 3:, :], dg[..., j, :]
    full = (2 * g0 - 4 * gh + 2 * g1, -3 * g0 + 4 * gh - g1, g0)  # 3 × (3, K, O, 3, T)
    red = _reduced(*full, z0, z1)
    cw, sw = w  # [3 (X, Y, Z), O, 1, T]
    cw, sw = cw[:, :, 0], sw[:, :, 0]  # [3, O, T]

    def maps(x):  # ranges 3 × (1, O, 3, 1), (X, Y, Z) order → |D|, |E|, rD, rE (O, 3, T)
        x = [v[0] for v in x]
        Dx = x[1] * cw[1][:, None] - x[0] * cw[0][:, None]
        Dy = x[1] * sw[1][:, None] - x[0] * sw[0][:, None]
        Ex = x[2] * cw[2][:, None] - x[0] * cw[0][:, None]
        Ey = x[2] * sw[2][:, None] - x[0] * sw[0][:, None]
        return (jnp.hypot(Dx, Dy), jnp.hypot(Ex, Ey), jnp.abs(x[0]) + jnp.abs(x[1]),
                jnp.abs(x[0]) + jnp.abs(x[2]))

    cl = np.abs(np.asarray(spec.lin))
    t2 = tol * tol

    def rho(x, y):  # (K, O, 3, T) second-order remainder of β(x, y)
        Dx_, Ex_, rDx, rEx = x
        Dy_, Ey_, rDy, rEy = y

        def one(A, rA, B, rB):  # A(x)·B(y): ½ τ² (|A| rB + rA |B|) + τ² rA rB
            return t2 * (0.5 * (A * rB + rA * B) + rA * rB)

        nn = one(Dx_, rDx, Dy_, rDy)
        mm = one(Ex_, rEx, Ey_, rEy)
        ed = 0.5 * (one(Ex_, rEx, Dy_, rDy) + one(Ey_, rEy, Dx_, rDx))
        return jnp.stack([2 * c[0] * nn + 2 * (c[1] + c[2]) * ed + 2 * c[3] * mm for c in cl])

    eps = jnp.finfo(cw.dtype).eps
    a, b = maps(Vi), maps(Vd)
    a1_ = maps([Vi[k] + Vd[k] for k in range(3)])
    b1 = maps([-Vd[k] for k in range(3)])
    none = rho(a, a) + 2 * rho(a, b) + rho(b, b)
    d0 = 2 * rho(a, b) + rho(b, b)
    d1 = 2 * rho(a1_, b1) + rho(b1, b1)
    both = rho(b, b)
    second_red = jnp.where(z0 & z1, both, jnp.where(z0, d0, jnp.where(z1, d1, none)))
    return full, red, none * (1 + 64 * eps), second_red * (1 + 64 * eps)


def _interval_max(c, lo, hi):
    """[K, S, …] ``Σ_p max over [lo, hi] of |c2 t² + c1 t + c0|`` for derivative
    coefficients ``c`` = 3 × (3 p, K, …) (``lo``/``hi`` [S, …]), with the rounding of the
    evaluation."""
    tot = 0.0
    for p in range(3):
        c2, c1, c0 = (x[p][:, None] for x in c)
        eps = jnp.finfo(c0.dtype).eps

        def q(x, c2=c2, c1=c1, c0=c0):
            return (c2 * x + c1) * x + c0

        v = -c1 / jnp.where(c2 == 0, 1.0, 2 * c2)
        inside = (c2 != 0) & (v > lo[None]) & (v < hi[None])
        m = jnp.maximum(jnp.abs(q(lo[None])), jnp.abs(q(hi[None])))
        m = jnp.maximum(m, jnp.where(inside, jnp.abs(q(v)), 0.0))
        tot = tot + m + 4 * eps * (jnp.abs(c2) + jnp.abs(c1) + jnp.abs(c0))
    return tot


def _or(x, axes):
    """Bitwise OR of ``x`` over ``axes`` (:func:`_fold`)."""
    return _fold(x, axes, np.uint32(0), jax.lax.bitwise_or)


def _any(x, axes):
    """``jnp.any`` of the bool ``x`` over ``axes`` (:func:`_fold`)."""
    return _fold(x, axes, False, jax.lax.bitwise_or)


#: arrays of at least this many elements are reduced by halving (:func:`_fold`)
_FOLD_MIN = 1 << 10


def _fold(x, axes, init, op):
    """``op`` (an exact, associative and commutative one: OR) over ``axes`` of ``x``.

    XLA:CPU reduces the leading axes of these [..., T] arrays one output element at a time,
    recomputing the fused producers with strided reads: on an image's 816 triples that was
    the largest cost of the measurement (the screen's two reductions took more than the
    exact decision). From :data:`_FOLD_MIN` elements the reduced axes are moved to the front,
    flattened and halved elementwise (each step runs along whole contiguous rows, which a
    CPU vectorises; the tolerant decision's buffers of 17 triples too).
    The flattened axis is first padded with ``init`` to a power of two: with an odd length a
    step concatenated its leftover row to the halved rows, a second consumer of the step
    before, and XLA fused the producers into both and computed them again. Smaller arrays
    keep the one reduce. Same result either way (OR is exact; docs/qrm.md §camera).
    """
    axes = tuple(a % x.ndim for a in axes)
    if x.size < _FOLD_MIN:
        return jax.lax.reduce(x, init, op, axes)
    keep = tuple(a for a in range(x.ndim) if a not in axes)
    x = jnp.transpose(x, axes + keep)
    x = x.reshape((-1,) + x.shape[len(axes):])
    p2 = 1 << (x.shape[0] - 1).bit_length()
    if p2 > x.shape[0]:  # padded with ``init`` to a power of two: every step a plain halving
        x = jnp.concatenate([x, jnp.full((p2 - x.shape[0],) + x.shape[1:], init, x.dtype)])
    while x.shape[0] > 1:
        h = x.shape[0] // 2
        x = op(x[:h], x[h:])
    return x[0]


def _preimage(w, reps):
    """Ranges ``(d_X, d_Y, d_Z)`` [O, R, T] each with ``E = c D`` for the points ``c``
    [R, 2]: the kernel of ``d_X (c − 1) w_X − d_Y c w_Y + d_Z w_Z = 0`` (complex), with
    ``w = (cos, sin)`` [3, O, 1, T] in each relation's (X, Y, Z) order."""
    cw, sw = w
    cr, ci = reps[:, :1], reps[:, 1:]
    re = [(cr - 1) * cw[0] - ci * sw[0], -(cr * cw[1] - ci * sw[1]), None]
    im = [(cr - 1) * sw[0] + ci * cw[0], -(cr * sw[1] + ci * cw[1]), None]
    re[2], im[2] = jnp.broadcast_to(cw[2], re[0].shape), jnp.broadcast_to(sw[2], re[0].shape)
    return [re[1] * im[2] - re[2] * im[1], re[2] * im[0] - re[0] * im[2],
            re[0] * im[1] - re[1] * im[0]]


class _Edges(NamedTuple):
    """The tolerance-free part of the edge decision of T triples (:func:`_edges`); shapes
    with O = 3 relations, 3 edges, S = 3K + 1 samples, P = 2K + 1 interval starts."""

    w: tuple  # (cos, sin) [3 (X, Y, Z), O, 1, T]
    nodes_d: list  # the 3 vertices and 3 edge midpoints, 3 × [O, 6, 1] (X, Y, Z) order
    Vi: list  # edge start, 3 × [1, O, 3, 1]
    Vd: list  # edge direction, 3 × [1, O, 3, 1]
    van: jax.Array  # [K, O, 3 vertices] constraint vanishes identically at the vertex
    A: jax.Array  # [K, O, 3, T] edge quadratic A t² + B t + f0 (value f1 at t = 1)
    B: jax.Array
    f0: jax.Array
    fh: jax.Array  # [K, O, 3, T] value at the edge midpoint
    f1: jax.Array
    emax: jax.Array  # [K, O, 3, T] largest rounding bound of the three edge nodes
    t: jax.Array  # [S, O, 3, T] samples (:func:`_sample_params`)
    valid: jax.Array
    lo: jax.Array
    hi: jax.Array
    own_lo: jax.Array
    own_hi: jax.Array
    nidx: jax.Array  # [P, O, 3, T]
    fe: jax.Array  # [K, S, O, 3, T] values at the samples and their rounding bounds
    ee: jax.Array
    band: jax.Array  # [K, S, O, 3, T] uncertainty band of the exact decision


def _edges(spec: QRMSpec, st: CameraStructure, bearings) -> _Edges:
    """The edge samples of bearings [T, 3] and everything the exact decision needs."""
    dtype = bearings.dtype
    perm = np.array(CYCLIC)  # perm[o] = (X, Y, Z): relation-order position → slot
    cw, sw = jnp.cos(bearings).T[perm], jnp.sin(bearings).T[perm]  # [O, 3, T]
    cw, sw = jnp.swapaxes(cw, 0, 1), jnp.swapaxes(sw, 0, 1)  # [3 (X, Y, Z), O, T]
    w = (cw[:, :, None], sw[:, :, None])  # [3, O, 1, T]: broadcasts against [(S,) O, X, T]
    i, j = np.array(EDGES).T
    verts = jnp.asarray(VERTICES, dtype)
    # the three vertices and the three edge midpoints, for the edge quadratics
    nodes = jnp.concatenate([verts, 0.5 * (verts[i] + verts[j])], 0)  # (6, 3)
    nodes_d = _rel_d(nodes, (3, 6, 1), dtype)
    f, e = form_values(spec, w, nodes_d)  # (K, O, 6, T)
    van = jnp.asarray(np.moveaxis(st.vanish, 1, 0))  # (K, O, 3 vertices)
    vmask = van[..., None]
    f = jnp.concatenate([jnp.where(vmask, 0.0, f[:, :, :3]), f[:, :, 3:]], 2)
    e = jnp.concatenate([jnp.where(vmask, 0.0, e[:, :, :3]), e[:, :, 3:]], 2)
    f0, fh, f1 = f[:, :, i], f[:, :, 3:], f[:, :, j]  # (K, O, 3 edges, T)
    A = 2 * f0 - 4 * fh + 2 * f1
    B = -3 * f0 + 4 * fh - f1
    emax = jnp.maximum(jnp.maximum(e[:, :, i], e[:, :, 3:]), e[:, :, j])
    z0, z1 = van[:, :, i, None], van[:, :, j, None]
    t, valid, lo, hi, own_lo, own_hi, nidx = _sample_params(A, B, f0, z0, z1)  # (S, O, 3, T)
    Vi = _rel_d(verts[i], (1, 3, 3, 1), dtype)
    Vd = _rel_d(verts[j] - verts[i], (1, 3, 3, 1), dtype)
    fe, ee = form_values(spec, w, [Vi[k] + t * Vd[k] for k in range(3)])  # (K,S,O,3,T)
    band = jnp.maximum(_CERTAIN * ee, BAND * emax[:, None])
    return _Edges(w, nodes_d, Vi, Vd, van, A, B, f0, fh, f1, emax, t, valid, lo, hi, own_lo,
                  own_hi, nidx, fe, ee, band)


def _rel_d(vals, shape, dtype):
    """Slot-order values (..., 3) → 3 × [O, ...] in each relation's (X, Y, Z) order."""
    v = jnp.asarray(vals, dtype)[..., np.array(CYCLIC)]  # (..., O, 3)
    v = jnp.moveaxis(v, -2, 0)  # (O, ..., 3)
    return [v[..., k].reshape(shape) for k in range(3)]


def _ends(spec: QRMSpec, g: _Edges):
    """Which end of each sample's interval is tested for constraint k: ``(use_l, use_h,
    str_l, str_h)`` [K, S, O, 3, T] (an end that is not k's own root; an end at a
    structural root, where the reduced polynomial is tested instead)."""
    K = spec.k
    i, j = np.array(EDGES).T
    z0, z1 = g.van[:, :, i, None], g.van[:, :, j, None]
    kk = jnp.arange(K).reshape((K,) + (1,) * g.t.ndim)
    str_l = (g.own_lo[None] == -1) & (g.lo[None] == 0) & z0[:, None]  # structural root at 0
    str_h = (g.own_hi[None] == -1) & (g.hi[None] >= 1) & z1[:, None]
    use_l = (g.own_lo[None] != kk) & ~str_l
    use_h = (g.own_hi[None] != kk) & ~str_h
    return use_l, use_h, str_l, str_h


def _tolerance_unsure(spec: QRMSpec, g: _Edges, tol, loose):
    """[K, S, O, 3, T] signs made uncertain by the bearing tolerance, and the bound ``Δ``.

    A sign is unsure where a change of at most ``tol`` of each bearing can flip it somewhere
    on the sample's interval ``[lo, hi]``: the value at the sample or at an end that is not
    the constraint's own root is within rounding + ``Δ`` of zero, ``Δ`` the first-order
    change (derivatives, max over the interval) plus the second-order bound
    (:func:`_perturbation`); at a structural root the reduced polynomial's value is tested.
    """
    lo, hi, fe, ee, emax = g.lo, g.hi, g.fe, g.ee, g.emax
    K = spec.k
    i, j = np.array(EDGES).T
    z0, z1 = g.van[:, :, i, None], g.van[:, :, j, None]
    full_d, red_d, second, second_red = _perturbation(spec, g.w, g.nodes_d, g.Vi, g.Vd,
                                                      g.van, tol)
    delta = tol * _interval_max(full_d, lo, hi) + second[:, None]  # (K, S, O, 3, T)
    P = 2 * K + 1  # interval samples; then the K vertex samples (lo = hi = t)
    fp, ep = form_values(spec, g.w, [g.Vi[k] + lo[:P] * g.Vd[k] for k in range(3)])
    # the upper end of each interval is the start of another (index nidx), or t = 1
    f_hi = jnp.take_along_axis(fp, jnp.broadcast_to(g.nidx[None], fp.shape), 1)
    e_hi = jnp.take_along_axis(ep, jnp.broadcast_to(g.nidx[None], ep.shape), 1)
    at1 = hi[:P] >= 1
    f_hi = jnp.where(at1[None], g.f1[:, None], f_hi)
    e_hi = jnp.where(at1[None], emax[:, None], e_hi)
    f_lo = jnp.concatenate([fp, fe[:, P:]], 1)
    e_lo = jnp.concatenate([ep, ee[:, P:]], 1)
    f_hi = jnp.concatenate([f_hi, fe[:, P:]], 1)
    e_hi = jnp.concatenate([e_hi, ee[:, P:]], 1)
    use_l, use_h, str_l, str_h = _ends(spec, g)
    bmin = BAND * emax[:, None]

    def near0(f_, e_):
        return jnp.abs(f_) <= jnp.maximum(_CERTAIN * e_, bmin) + delta

    flip = lambda f_: jnp.sign(f_) != jnp.sign(fe)  # noqa: E731
    # at a structural root the reduced polynomial's value there (its sign near the vertex)
    r2, r1, r0 = _reduced(g.A, g.B, g.f0, z0, z1)
    g_0, g_1 = r0, r2 + r1 + r0
    dg_0 = jnp.sum(jnp.abs(red_d[2]), 0)
    dg_1 = jnp.sum(jnp.abs(red_d[0] + red_d[1] + red_d[2]), 0)
    str_band = BAND * emax + second_red
    unsure = loose & (near0(fe, ee)
                      | (use_l & (near0(f_lo, e_lo) | flip(f_lo)))
                      | (use_h & (near0(f_hi, e_hi) | flip(f_hi)))
                      | (str_l & (jnp.abs(g_0) <= str_band + tol * dg_0)[:, None])
                      | (str_h & (jnp.abs(g_1) <= str_band + tol * dg_1)[:, None]))
    return unsure, delta


#: Margins of the screen (:func:`_screen`) over the exact path's own bounds, for ranges on
#: the cone's edges (every range in [0, 1], so ``|D|, |E| ≤ 2``): the first-order term of
#: ``Δ`` (``_SCREEN_D1`` × an exact bound of ``Σ_s max |∂f/∂θ_s|`` on the edge, plus
#: ``_SCREEN_D1E eps Σ|c|`` for its interpolation's rounding), the second-order term (``≤ 64
#: Σ|c| τ²``), a reduced derivative's coefficients (``Σ_s |·| ≤ 51 · 4 Σ|c|``) and a form's
#: rounding bound (``e ≤ 72 Σ|c| eps``); each with a margin (≥ 25 %) so the float evaluation
#: of the exact path's bounds never exceeds them (``Σ|c|``: a constraint's coefficients)
_SCREEN_D1, _SCREEN_D1E, _SCREEN_D2, _SCREEN_DRED, _SCREEN_E = 1.25, 1024.0, 128.0, 256.0, 128.0


def _derivative_bound(spec: QRMSpec, g: _Edges):
    """[K, O, 3, T] exact bound of ``Σ_s max_t |∂f_k/∂θ_s|`` on each edge: ``|∂_X n| ≤ 2 |D|
    d_X`` and so on, with ``|D|``, ``|E|`` (convex on the edge) and the ranges at their
    largest vertex value."""
    cw, sw = (x[:, :, 0] for x in g.w)  # [3, O, T]
    # the vertices' ranges in each relation's (X, Y, Z) order: [3, O, 3 vertices, 1]
    vdn = np.moveaxis(VERTICES[:, np.array(CYCLIC)], (2, 1, 0), (0, 1, 2))[..., None]
    vd = [jnp.asarray(x, cw.dtype) for x in vdn]

    def norm(a, b):
        return jnp.hypot(vd[a] * cw[a][:, None] - vd[b] * cw[b][:, None],
                         vd[a] * sw[a][:, None] - vd[b] * sw[b][:, None])

    i, j = np.array(EDGES).T
    Dv, Ev = norm(1, 0), norm(2, 0)  # [O, 3 vertices, T]
    Dm, Em = jnp.maximum(Dv[:, i], Dv[:, j]), jnp.maximum(Ev[:, i], Ev[:, j])  # [O, 3, T]
    dm = np.maximum(vdn[:, :, i], vdn[:, :, j])  # [3, O, 3 edges, 1]
    dX, dY, dZ = (jnp.asarray(x, cw.dtype) for x in dm)
    bn = 2 * Dm * (dX + dY)
    buv = dX * (Dm + Em) + Em * dY + Dm * dZ
    bm = 2 * Em * (dX + dZ)
    cl = np.abs(np.asarray(spec.lin))
    return jnp.stack([c[0] * bn + (c[1] + c[2]) * buv + c[3] * bm for c in cl])


def _screen(spec: QRMSpec, st: CameraStructure, g: _Edges, tol, loose):
    """[T] bool: triples whose edge sets the tolerance may change (sound: an unflagged
    triple's tolerant edge sets equal its exact ones).

    The tolerant decision (:func:`_tolerance_unsure`) differs from the exact one only where
    it makes a sign uncertain that the exact band leaves certain, on a valid sample, or
    where it validates a quadratic's vertex sample. Both need a value within ``Δ`` (plus
    rounding) of zero; here ``Δ`` is replaced by a bound that needs no derivative of the
    forms (:func:`_derivative_bound`, one per edge), and the values at the interval ends by
    the edge quadratic (three flops a value instead of a form evaluation), with the error of
    that interpolation (the node rounding, ``1.25 emax``; the value's own rounding, ``≤
    _SCREEN_E eps Σ|c|``; the polynomial's evaluation, ``≤ 128 eps`` times the largest node
    value) added to the threshold. A sign at an end that differs from the sample's counts as
    near (``q · sign(f) ≤ threshold`` covers both).
    """
    K = spec.k
    S, P = 3 * K + 1, 2 * K + 1
    fe, band, emax, lo, hi = g.fe, g.band, g.emax, g.lo[:P], g.hi[:P]
    dtype = fe.dtype
    eps = jnp.finfo(dtype).eps
    i, j = np.array(EDGES).T
    z0, z1 = g.van[:, :, i, None], g.van[:, :, j, None]  # (K, O, 3, 1)
    csum = jnp.asarray(np.abs(np.asarray(spec.lin)).sum(1), dtype).reshape(K, 1, 1, 1)
    second = csum * (_SCREEN_D2 * tol * tol)
    dbar = tol * (_SCREEN_D1 * _derivative_bound(spec, g) + _SCREEN_D1E * eps * csum) + second
    ebar = csum * (_SCREEN_E * eps)  # ≥ a form's rounding bound on an edge
    big = jnp.maximum(jnp.maximum(jnp.abs(g.f0), jnp.abs(g.fh)), jnp.abs(g.f1))
    err = 2 * emax + ebar + 128 * eps * big  # |form value − edge quadratic| (K, O, 3, T)
    thr = (jnp.maximum(_CERTAIN * ebar, BAND * emax) + dbar + err)[:, None]
    margin = jnp.abs(fe) - band  # > 0: certain in the exact decision
    ok = jnp.asarray(st.edge_ok)[None, :, :, None] & g.valid  # (S, O, 3, T)
    # a quadratic's vertex sample is valid where its own value is within the band (and,
    # with the tolerance, within the band + Δ: the window flags those)
    own_m = jnp.moveaxis(jnp.diagonal(margin[:, S - K:], axis1=0, axis2=1), -1, 0)
    window = ok[S - K:] & (own_m > 0) & (own_m <= dbar)  # (K, O, 3, T)
    ok = jnp.concatenate([ok[:S - K], ok[S - K:] & (own_m <= 0)])
    base = ok & (margin > 0)
    sgn = jnp.sign(fe[:, :P])
    # the interval ends: a start that is k's own root (static owner, unless the root lies
    # outside (0, 1) and the start is t = 0) or an end whose next root is k's is not tested
    owner = np.concatenate([[-1], np.arange(2 * K) % K])  # pts[1 + m]: a root of m % K
    kk = np.arange(K).reshape(K, 1, 1, 1, 1)
    at0, at1 = lo == 0, hi >= 1  # (P, O, 3, T)
    ne_lo = jnp.asarray(owner.reshape(1, P, 1, 1, 1) != kk)
    use_l = jnp.where(at0[None], ~z0[:, None], ne_lo)
    use_h = jnp.where(at1[None], ~z1[:, None], jnp.asarray(owner)[g.nidx][None] != kk)

    def quad(x):
        return (g.A[:, None] * x + g.B[:, None]) * x + g.f0[:, None]

    q_hi = jnp.where(at1[None], g.f1[:, None], quad(hi))
    r2, r1, r0 = _reduced(g.A, g.B, g.f0, z0, z1)
    sb = BAND * emax + second + tol * (csum * _SCREEN_DRED)
    s0 = (z0 & (jnp.abs(r0) <= sb))[:, None]
    s1 = (z1 & (jnp.abs(r2 + r1 + r0) <= sb))[:, None]
    end = ((use_l & (quad(lo) * sgn <= thr)) | (use_h & (q_hi * sgn <= thr))
           | (at0[None] & s0) | (at1[None] & s1))
    changed = (_any(base[:, :P] & end, (0, 1, 2, 3))
               | _any(base & (margin <= dbar[:, None]), (0, 1, 2, 3)))
    return loose & (changed | _any(window, (0, 1, 2)))


def _edge_atoms(spec: QRMSpec, st: CameraStructure, g: _Edges, loose, unsure, delta):
    """Witness and possible atom masks [O, T] of the edge samples (lemma case 1); ``unsure``
    and ``delta`` the tolerance's uncertain signs and bound (None: the exact decision)."""
    K = spec.k
    S = g.t.shape[0]
    fe, band = g.fe, g.band
    # a quadratic's vertex is only needed where it nears zero there (a tangency that the
    # roots may have missed); elsewhere it could sit on another constraint's root
    own = jnp.moveaxis(jnp.diagonal(fe[:, S - K:], axis1=0, axis2=1), -1, 0)
    own_band = jnp.moveaxis(jnp.diagonal(band[:, S - K:], axis1=0, axis2=1), -1, 0)
    if delta is not None:
        own_d = jnp.moveaxis(jnp.diagonal(delta[:, S - K:], axis1=0, axis2=1), -1, 0)
        own_band = own_band + jnp.where(loose, own_d, 0.0)
    valid = jnp.concatenate([g.valid[:S - K], g.valid[S - K:] & (jnp.abs(own) <= own_band)])
    wit, poss = _atoms(spec, fe, _CERTAIN * g.ee, band, unsure)  # (S, O, 3, T)
    ok = jnp.asarray(st.edge_ok)[None, :, :, None] & valid
    wit = _or(jnp.where(ok, wit, jnp.uint32(0)), (0, 2))  # (O, T)
    poss = _or(jnp.where(ok, poss, jnp.uint32(0)), (0, 2))
    return wit, poss


def _tolerant_edge_atoms(spec: QRMSpec, st: CameraStructure, g: _Edges, tol, loose):
    unsure, delta = _tolerance_unsure(spec, g, tol, loose)
    return _edge_atoms(spec, st, g, loose, unsure, delta)


def _abs_max3(v):
    """``max(|v[0]|, |v[1]|, |v[2]|)`` elementwise ([3, ...] → [...]; exact)."""
    return jnp.maximum(jnp.maximum(jnp.abs(v[0]), jnp.abs(v[1])), jnp.abs(v[2]))


def _region_atoms(spec: QRMSpec, st: CameraStructure, w, tol, loose, inv):
    """Witness and possible atom masks [O, T] of the region points (lemma case 2: ``R_s``
    inside the image of the cone): a point's range preimage inside the cone is a witness,
    within rounding of it (or, with a tolerance, within ``2 tol (|c|, |c − 1|, |c| |c − 1|)``
    of it) keeps the point's atom possible."""
    dtype = w[0].dtype
    eps = jnp.finfo(dtype).eps
    reps = jnp.asarray(st.reps, dtype)
    dr = _preimage(w, reps)  # 3 × (O, R, T), (X, Y, Z) order
    fr, er = form_values(spec, w, dr)  # (K, O, R, T)
    D = jnp.stack(dr)  # slot order for the cone test: slot s is position inv[o][s]
    take = jnp.asarray(inv.T)[:, :, None, None]
    ds = jnp.take_along_axis(D, take, 0)
    # how far any bearing change within tol moves the preimage (|Δd| ≤ 2 tol |·|, per
    # component: |c|, |c − 1|, |c| |c − 1| in (X, Y, Z) order), in slot order
    ca, cb_ = jnp.hypot(reps[:, 0], reps[:, 1]), jnp.hypot(reps[:, 0] - 1, reps[:, 1])
    dd = jnp.stack([ca, cb_, ca * cb_])[:, None, :, None] * (2 * tol * (1 + 16 * eps))
    dd = jnp.take_along_axis(jnp.broadcast_to(dd, D.shape), take, 0)
    # the max over the 3 components as two elementwise maxima: as a reduce over the leading
    # axis XLA:CPU ran it through a library fusion at ≈ 0.5 ms an image (docs/qrm.md §camera)
    rnd = 2 * _CONE_BAND * eps * _abs_max3(ds)
    gl = (ds[0], ds[1] - ds[0], ds[2] - ds[1])
    gb = (dd[0], dd[1] + dd[0], dd[2] + dd[1])
    pairs = list(zip(gl, gb, strict=True))
    near_tol = loose & (jnp.all(jnp.stack([g > -(b + rnd) for g, b in pairs]), 0)
                        | jnp.all(jnp.stack([-g > -(b + rnd) for g, b in pairs]), 0))
    ds = ds * jnp.where(ds[2:3] < 0, -1.0, 1.0)
    ds = ds / jnp.maximum(_abs_max3(ds)[None], jnp.finfo(dtype).tiny)
    g = (ds[0], ds[1] - ds[0], ds[2] - ds[1])
    inside = (g[0] > 0) & (g[1] > 0) & (g[2] > 0)
    cb = -_CONE_BAND * eps
    near = (g[0] > cb) & (g[1] > cb) & (g[2] > cb)
    rw, rp = _atoms(spec, fr, _CERTAIN * er, _CERTAIN * er)  # (O, R, T)
    wit = _or(jnp.where(inside, rw, jnp.uint32(0)), (1,))
    # (the atom of a region point is fixed: the pattern depends on c only)
    rep_bit = (jnp.uint32(1) << jnp.asarray(st.rep_atoms, jnp.uint32))[None, :, None]
    poss = (_or(jnp.where(near, rp, jnp.uint32(0)), (1,))
            | _or(jnp.where(near_tol, rep_bit, jnp.uint32(0)), (1,)))
    return wit, poss


#: triples of a batch that get the full tolerant decision in a buffer (the rest keep the
#: exact sets, :func:`_screen`): ``max(SCREEN_MIN, ⌈T · SCREEN_SHARE⌉)``; more flagged
#: triples than that go through it in chunks, as many as they fill (same sets). The
#: decision's cost is linear in the buffer (traverse, 816 triples: 3.3 CPU-ms for 51, 0.9 for
#: 16), so a small buffer costs the images with many flagged triples little: 17 triples on
#: the traverse's 816 (flagged mean 16–30, max 37–66 an image). One size, so the decision is
#: compiled once (docs/qrm.md §camera): until 2026-12-06 a second, 3× larger buffer took
#: the images that overflowed this one, which made every program holding the measurement
#: compile the decision twice
SCREEN_SHARE = 1 / 48
SCREEN_MIN = 6


def screen_buffer(n_triples: int) -> int:
    """Static size of the buffer of flagged triples for a batch of ``n_triples``."""
    return min(n_triples, max(SCREEN_MIN, math.ceil(n_triples * SCREEN_SHARE)))


def tolerant_flags(spec: QRMSpec, bearings: jax.Array, tol) -> jax.Array:
    """[T] bool: the triples of ``bearings`` [T, 3] whose sets :func:`exact_sets` decides
    with the full tolerant edge decision (the others' tolerant edge sets are proven equal to
    their exact ones; all False at ``tol = 0``)."""
    st = camera_structure(spec)
    tol = jnp.asarray(tol, bearings.dtype)
    return _screen(spec, st, _edges(spec, st, bearings), tol, tol > 0)


def exact_sets(spec: QRMSpec, bearings: jax.Array, tol=0.0, *,
               screen: bool = True) -> tuple[jax.Array, jax.Array]:
    """Feasible atoms of the three cyclic relations of each triple, by the boundary decision.

    Args:
        spec: the calculus.
        bearings: [T, 3] bearings in range order (near, mid, far), float32 or float64.
        tol: bearing tolerance τ (radians, a scalar, may be traced): the sets hold every atom
            feasible for *some* bearings within τ of the given ones (each bearing
            independently) and ranges in the given order (ties allowed). 0: the sets of the
            given bearings exactly.
        screen: run the tolerant edge decision only on the triples a cheap sound test flags
            (:func:`_screen`; the others keep their exact edge sets, which it proves equal);
            False: on every triple (the reference; same sets).

    Returns:
        ``(possible, undecided)`` [T, 3] uint32 *atom* masks: ``possible`` holds every
        feasible atom and, besides the witnessed ones, the ``undecided`` atoms that only a
        near-degenerate sample could not exclude (normally none at ``tol = 0``).

    The three relations run as one program along an axis O = 3: relation o is relation 0
    of the triple with its slots permuted to (X, Y, Z) = ``CYCLIC[o]``.

    With ``tol > 0`` the witnesses are those of the given bearings on the widened cone, and a
    sign counts as uncertain also where the constraint's value on a sample's whole interval
    of the edge (structural roots divided out) comes within ``Δ`` of zero, ``Δ`` a bound on
    how much any bearing change within τ moves it; a region point counts as inside where its
    range preimage is within the same kind of bound of the cone (docs/qrm.md §camera).
    """
    st = camera_structure(spec)
    dtype = bearings.dtype
    tol = jnp.asarray(tol, dtype)
    loose = tol > 0
    T = bearings.shape[0]
    inv = np.argsort(np.array(CYCLIC), 1)  # inv[o][slot] = relation-order position
    g = _edges(spec, st, bearings)
    if not screen:
        wit, poss = _tolerant_edge_atoms(spec, st, g, tol, loose)
    else:
        wit0, poss0 = _edge_atoms(spec, st, g, loose, None, None)
        flag = _screen(spec, st, g, tol, loose)
        n = jnp.sum(flag)
        size = screen_buffer(T)

        def in_chunks():
            # the flagged triples through the full decision, ``size`` at a time, as many
            # chunks as they fill: the cost grows with their count, and the program's
            # temporary memory stays one chunk's (a branch on all T triples, even never
            # taken, made every call allocate — and the OS page in — its ~T-sized
            # temporaries; docs/qrm.md §camera)
            idx_all = jnp.nonzero(flag, size=-(-T // size) * size,
                                  fill_value=T)[0].reshape(-1, size)

            def body(c, ws):
                idx = idx_all[c]  # fill T: dropped when scattered back
                sub = bearings[jnp.minimum(idx, T - 1)]
                w_, p_ = _tolerant_edge_atoms(spec, st, _edges(spec, st, sub), tol, loose)
                return (ws[0].at[:, idx].set(w_, mode="drop"),
                        ws[1].at[:, idx].set(p_, mode="drop"))

            return jax.lax.fori_loop(0, (n + size - 1) // size, body, (wit0, poss0))

        # none flagged (always at tol = 0): the exact sets, without gathering any indices
        wit, poss = jax.lax.cond(n == 0, lambda: (wit0, poss0), in_chunks)
    # region points: R_s inside the image of the cone
    rwit, rposs = _region_atoms(spec, st, g.w, tol, loose, inv)
    wit = wit | rwit
    poss = poss | rposs | wit
    return poss.T, (poss & ~wit).T
