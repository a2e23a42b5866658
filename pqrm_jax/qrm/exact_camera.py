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

from dataclasses import dataclass
from fractions import Fraction
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from .spec import QRMSpec

__all__ = ["CameraStructure", "camera_structure", "form_values", "exact_sets", "CYCLIC",
           "VERTICES", "EDGES", "BAND"]

#: the three cyclic relations of a slot triple (near, mid, far) = (0, 1, 2): XY:Z
CYCLIC = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
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
    the vertex of every quadratic (K)."""
    r = _roots(A, B, C, z0, z1).reshape((-1,) + A.shape[1:])  # (2K, …)
    inside = jnp.isfinite(r) & (r > 0) & (r < 1)
    r = jnp.where(inside, r, 0.0)
    zero = jnp.zeros((1,) + r.shape[1:], r.dtype)
    pts = jnp.concatenate([zero, r])  # every interval starts at one of these
    # midpoint of each interval [p, next value above p] (no sort: a min over the others)
    # (ties broken by index: a repeated root gives a sample on it, as a sort would)
    idx = np.arange(pts.shape[0]).reshape((-1,) + (1,) * (pts.ndim - 1))
    above = (pts[None] > pts[:, None]) | ((pts[None] == pts[:, None]) & (idx[None] > idx[:, None]))
    nxt = jnp.min(jnp.where(above, pts[None], 1.0), axis=1)
    mids = 0.5 * (pts + nxt)
    top = -B / jnp.where(A == 0, 1.0, 2 * A)
    t = jnp.concatenate([mids, jnp.where(A != 0, top, 0.5)])
    valid = (t > 0) & (t < 1)
    return jnp.where(valid, t, 0.5), valid


def _atoms(spec: QRMSpec, f, cert, band):
    """Witness and possible atom masks [...] from values ``f`` [K, ...] with the certain
    threshold ``cert`` and the uncertainty band ``band``."""
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
    poss = jax.lax.reduce(cm, np.uint32(0xFFFFFFFF), jax.lax.bitwise_and, (0,))
    return wit, poss


def _or(x, axes):
    return jax.lax.reduce(x, np.uint32(0), jax.lax.bitwise_or, axes)


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


def exact_sets(spec: QRMSpec, bearings: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Feasible atoms of the three cyclic relations of each triple, by the boundary decision.

    Args:
        spec: the calculus.
        bearings: [T, 3] bearings in range order (near, mid, far), float32 or float64.

    Returns:
        ``(possible, undecided)`` [T, 3] uint32 *atom* masks: ``possible`` holds every
        feasible atom and, besides the witnessed ones, the ``undecided`` atoms that only a
        near-degenerate sample could not exclude (normally none).

    The three relations run as one program along an axis O = 3: relation o is relation 0
    of the triple with its slots permuted to (X, Y, Z) = ``CYCLIC[o]``.
    """
    st = camera_structure(spec)
    dtype = bearings.dtype
    eps = jnp.finfo(dtype).eps
    K = spec.k
    perm = np.array(CYCLIC)  # perm[o] = (X, Y, Z): relation-order position → slot
    inv = np.argsort(perm, 1)  # inv[o][slot] = relation-order position
    cw, sw = jnp.cos(bearings).T[perm], jnp.sin(bearings).T[perm]  # [O, 3, T]
    cw, sw = jnp.swapaxes(cw, 0, 1), jnp.swapaxes(sw, 0, 1)  # [3 (X, Y, Z), O, T]

    w = (cw[:, :, None], sw[:, :, None])  # [3, O, 1, T]: broadcasts against [(S,) O, X, T]

    def rel_d(vals, shape):  # slot-order constants (..., 3) → 3 × [O, ...] in (X, Y, Z) order
        v = np.asarray(vals)[..., perm]  # (..., O, 3)
        v = np.moveaxis(v, -2, 0)  # (O, ..., 3)
        return [jnp.asarray(v[..., k].reshape(shape), dtype) for k in range(3)]

    i, j = np.array(EDGES).T
    # the three vertices and the three edge midpoints, for the edge quadratics
    nodes = np.concatenate([VERTICES, 0.5 * (VERTICES[i] + VERTICES[j])], 0)  # (6, 3)
    f, e = form_values(spec, w, rel_d(nodes, (3, 6, 1)))  # (K, O, 6, T)
    van = np.moveaxis(st.vanish, 1, 0)  # (K, O, 3 vertices)
    vmask = jnp.asarray(van)[..., None]
    f = jnp.concatenate([jnp.where(vmask, 0.0, f[:, :, :3]), f[:, :, 3:]], 2)
    e = jnp.concatenate([jnp.where(vmask, 0.0, e[:, :, :3]), e[:, :, 3:]], 2)
    f0, fh, f1 = f[:, :, i], f[:, :, 3:], f[:, :, j]  # (K, O, 3 edges, T)
    A = 2 * f0 - 4 * fh + 2 * f1
    B = -3 * f0 + 4 * fh - f1
    emax = jnp.maximum(jnp.maximum(e[:, :, i], e[:, :, 3:]), e[:, :, j])
    t, valid = _sample_params(A, B, f0, jnp.asarray(van[:, :, i, None]),
                              jnp.asarray(van[:, :, j, None]))  # (S, O, 3, T)
    S = t.shape[0]
    Vi = rel_d(VERTICES[i], (1, 3, 3, 1))
    Vd = rel_d(VERTICES[j] - VERTICES[i], (1, 3, 3, 1))
    fe, ee = form_values(spec, w, [Vi[k] + t * Vd[k] for k in range(3)])  # (K,S,O,3,T)
    band = jnp.maximum(_CERTAIN * ee, BAND * emax[:, None])
    # a quadratic's vertex is only needed where it nears zero there (a tangency that the
    # roots may have missed); elsewhere it could sit on another constraint's root
    own = jnp.moveaxis(jnp.diagonal(fe[:, S - K:], axis1=0, axis2=1), -1, 0)
    own_band = jnp.moveaxis(jnp.diagonal(band[:, S - K:], axis1=0, axis2=1), -1, 0)
    valid = jnp.concatenate([valid[:S - K], valid[S - K:] & (jnp.abs(own) <= own_band)])
    wit, poss = _atoms(spec, fe, _CERTAIN * ee, band)  # (S, O, 3, T)
    ok = jnp.asarray(st.edge_ok)[None, :, :, None] & valid
    wit = _or(jnp.where(ok, wit, jnp.uint32(0)), (0, 2))  # (O, T)
    poss = _or(jnp.where(ok, poss, jnp.uint32(0)), (0, 2))
    # region points: R_s inside the image of the cone
    reps = jnp.asarray(st.reps, dtype)
    dr = _preimage(w, reps)  # 3 × (O, R, T), (X, Y, Z) order
    fr, er = form_values(spec, w, dr)  # (K, O, R, T)
    D = jnp.stack(dr)  # slot order for the cone test: slot s is position inv[o][s]
    ds = jnp.take_along_axis(D, jnp.asarray(inv.T)[:, :, None, None], 0)
    ds = ds * jnp.where(ds[2:3] < 0, -1.0, 1.0)
    ds = ds / jnp.maximum(jnp.max(jnp.abs(ds), 0, keepdims=True), jnp.finfo(dtype).tiny)
    g = (ds[0], ds[1] - ds[0], ds[2] - ds[1])
    inside = (g[0] > 0) & (g[1] > 0) & (g[2] > 0)
    cb = -_CONE_BAND * eps
    near = (g[0] > cb) & (g[1] > cb) & (g[2] > cb)
    rw, rp = _atoms(spec, fr, _CERTAIN * er, _CERTAIN * er)  # (O, R, T)
    wit = wit | _or(jnp.where(inside, rw, jnp.uint32(0)), (1,))
    poss = poss | _or(jnp.where(near, rp, jnp.uint32(0)), (1,)) | wit
    return poss.T, (poss & ~wit).T
