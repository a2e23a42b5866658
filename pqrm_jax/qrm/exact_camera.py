"""Witnesses of the camera measurement from an exact 2-D arrangement sweep (M§IV–V).

With the camera at the origin and ranges ``d = (d_near, d_mid, d_far)`` along known unit
bearings, every EDC constraint of a cyclic relation is a quadratic form ``dᵀQd`` (M Table III;
:mod:`pqrm_jax.qrm.camera`). The forms are homogeneous of degree 2, so the range-ordering
cone is decided on its slice ``d_far = 1``: the triangle ``0 ≤ d_near ≤ d_mid ≤ 1`` cut by
six conics per relation. A state is feasible iff its strict sign pattern holds in some open
cell of that arrangement (ties and the limit ``d_near = 0`` add nothing: a state is open,
and an open set meets the closed cone iff it meets its interior).

**Sweep** (a cylindrical decomposition of the triangle, batched). Two line families are
swept: rays from the corner ``d_near = d_mid = 0`` (``d = (a·b, b, 1)``, fixed ``a``; each
conic is a quadratic in ``b``) and horizontal lines ``d_mid = y`` (quadratic in ``d_near``).
On every line the cells are the intervals between consecutive roots of the six conics and
the triangle's edges; their midpoints are the sample points. The lines are placed between
consecutive *critical values* of the family (where the number of roots on a line changes:
discriminant zeros, conic–edge intersections, roots escaping through the corner) and on a
uniform grid; all critical values are roots of quadratics in closed form. (Conic–conic
crossings are not among the critical values — a cell that lives only between two such
crossings and no line can be missed; the branch-and-bound of the kernel then keeps the
state undecided and the exact stage settles it, so nothing is lost.)

Every sample point is a *witness* only if all its signs are certain: ``|f(d)|`` above a
margin that bounds float32 rounding of the evaluation and of the coefficients
(``margin``: relative ``2e-5`` of ``Σ|Q||d||d|`` plus ``4e-6 Σ|d||d|``), and it lies strictly
inside the cone. Witnesses are exact: the sign pattern holds at that range assignment of the
exact system (tested in rational arithmetic against :mod:`pqrm_jax.qrm.camera_oracle`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .spec import QRMSpec

__all__ = ["range_forms", "sweep_witnesses", "corner_vanishing", "corner_rule", "REL_MARGIN",
           "ABS_MARGIN", "GRID_LINES"]

#: the three cyclic relations of a slot triple (near, mid, far) = (0, 1, 2): XY:Z
CYCLIC = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
#: certain-sign margin: relative to Σ|Q_sr| d_s d_r (evaluation rounding, float32 ~1e-7 per
#: operation, a dozen operations) and absolute Σ d_s d_r (coefficient rounding: the float32
#: forms differ from the exact ones by a few ulps of entries of magnitude ≤ 12)
REL_MARGIN = 2e-5
ABS_MARGIN = 4e-6
#: uniform lines added to each sweep family besides the critical-value midpoints
GRID_LINES = 8


def range_forms(spec: QRMSpec, bearings: jax.Array) -> jax.Array:
    """(…, O=3, K, 3, 3) symmetric matrices of every constraint of the cyclic relations over d.

    ``bearings`` (…, 3) in range order (near, mid, far). ``Q[..., o, k]`` is constraint k of
    relation ``CYCLIC[o]`` as the quadratic form ``dᵀQd`` (M Table III).
    """
    w = jnp.stack([jnp.cos(bearings), jnp.sin(bearings)], -1)  # (..., 3, 2)
    eye = jnp.eye(3, dtype=w.dtype)
    lin = jnp.asarray(spec.lin, w.dtype)
    out = []
    for X, Y, Z in CYCLIC:
        ld = w[..., Y, :, None] * eye[Y] - w[..., X, :, None] * eye[X]  # (..., 2, 3)
        le = w[..., Z, :, None] * eye[Z] - w[..., X, :, None] * eye[X]
        n = jnp.einsum("...is,...ir->...sr", ld, ld)
        m = jnp.einsum("...is,...ir->...sr", le, le)
        v = jnp.einsum("...is,...ir->...sr", le, ld)
        u = le[..., 0, :, None] * ld[..., 1, None, :] - le[..., 1, :, None] * ld[..., 0, None, :]
        forms = jnp.stack([n, u, v, m], -3)
        forms = 0.5 * (forms + jnp.swapaxes(forms, -1, -2))
        out.append(jnp.einsum("kc,...csr->...ksr", lin, forms))
    return jnp.stack(out, -4)


def _roots(A, B, C):
    """(…, 2) real roots of ``A t² + B t + C`` (NaN where none; degree drops handled)."""
    scale = jnp.maximum(jnp.maximum(jnp.abs(A), jnp.abs(B)), jnp.abs(C))
    lin = jnp.abs(A) <= 1e-7 * scale
    disc = B * B - 4 * A * C
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    qv = -0.5 * (B + jnp.where(B >= 0, sq, -sq))
    r1 = jnp.where(lin, -C / jnp.where(B == 0, 1.0, B), qv / jnp.where(A == 0, 1.0, A))
    r2 = jnp.where(lin, jnp.nan, C / jnp.where(qv == 0, 1.0, qv))
    bad = (~lin & (disc < 0)) | (scale == 0)
    r1 = jnp.where(bad | (lin & (B == 0)), jnp.nan, r1)
    r2 = jnp.where(bad | (qv == 0), jnp.nan, r2)
    return jnp.stack([r1, r2], -1)


def _cells(lo, hi, roots):
    """Midpoints (…, R+1) of the intervals between sorted roots (…, R) clipped to [lo, hi]."""
    r = jnp.where(jnp.isfinite(roots), jnp.clip(roots, lo[..., None], hi[..., None]),
                  lo[..., None])
    pts = jnp.sort(jnp.concatenate([lo[..., None], r, hi[..., None]], -1), -1)
    return 0.5 * (pts[..., 1:] + pts[..., :-1])


def _lines(crit):
    """Line positions in (0, 1): midpoints between sorted critical values and a grid."""
    lo = jnp.zeros(crit.shape[:-1], crit.dtype)
    mids = _cells(lo, lo + 1, crit)
    grid = jnp.broadcast_to((jnp.arange(GRID_LINES, dtype=crit.dtype) + 0.5) / GRID_LINES,
                            crit.shape[:-1] + (GRID_LINES,))
    return jnp.concatenate([mids, grid], -1)


def _witness_atoms(spec: QRMSpec, Q, d):
    """Atom masks (…,) certified at points d (…, P, 3) for forms Q (…, K, 3, 3)."""
    # dᵀQd as a product of the six monomials with the form coefficients (one matmul)
    d0, d1, d2 = d[..., 0], d[..., 1], d[..., 2]
    mono = jnp.stack([d0 * d0, d0 * d1, d1 * d1, d0 * d2, d1 * d2, d2 * d2], -1)
    coef = jnp.stack([Q[..., 0, 0], 2 * Q[..., 0, 1], Q[..., 1, 1], 2 * Q[..., 0, 2],
                      2 * Q[..., 1, 2], Q[..., 2, 2]], -1)  # (…, K, 6)
    val = jnp.einsum("...pm,...km->...pk", mono, coef)
    mag = jnp.einsum("...pm,...km->...pk", jnp.abs(mono), jnp.abs(coef))
    dd = jnp.sum(jnp.abs(d), -1) ** 2
    tol = REL_MARGIN * mag + ABS_MARGIN * dd[..., None]
    sgn = jnp.where(val > tol, 1, jnp.where(val < -tol, -1, 0))
    inside = (d[..., 0] > 0) & (d[..., 0] < d[..., 1]) & (d[..., 1] < d[..., 2])
    ok = jnp.all(sgn != 0, -1) & inside
    weights = jnp.asarray(3 ** np.arange(spec.k), jnp.int32)
    atom = jnp.asarray(spec.pattern_atom)[jnp.sum((sgn + 1) * weights, -1)]
    ok = ok & (atom >= 0)
    bits = jnp.where(ok, jnp.uint32(1) << jnp.maximum(atom, 0).astype(jnp.uint32),
                     jnp.uint32(0))
    return jax.lax.reduce(bits, np.uint32(0), jax.lax.bitwise_or, (bits.ndim - 1,))


def sweep_witnesses(spec: QRMSpec, Q: jax.Array) -> jax.Array:
    """(…,) uint32 atom masks of one relation's states with a certified witness.

    ``Q`` (…, K, 3, 3): the relation's forms (:func:`range_forms`). Both sweep families are
    run; the union of their witnesses is returned.
    """
    q00, q01, q02 = Q[..., 0, 0], Q[..., 0, 1], Q[..., 0, 2]
    q11, q12, q22 = Q[..., 1, 1], Q[..., 1, 2], Q[..., 2, 2]
    flat = lambda x: x.reshape(*x.shape[:-2], -1)  # noqa: E731  (…, K, 2) -> (…, 2K)
    # family A: rays d = (a b, b, 1); f = q(a) b² + 2 l(a) b + c
    crit_a = jnp.concatenate([
        flat(_roots(q02 * q02 - q22 * q00, 2 * (q02 * q12 - q22 * q01), q12 * q12 - q22 * q11)),
        flat(_roots(q00, 2 * q01, q11)),
        flat(_roots(q00, 2 * (q01 + q02), q11 + 2 * q12 + q22)),
        -q12 / jnp.where(q02 == 0, 1.0, q02)], -1)
    a = _lines(crit_a)  # (…, La)
    A_ = q00[..., None, :] * a[..., :, None] ** 2 + 2 * q01[..., None, :] * a[..., :, None] \
        + q11[..., None, :]  # (…, La, K)
    B_ = 2 * (q02[..., None, :] * a[..., :, None] + q12[..., None, :])
    C_ = jnp.broadcast_to(q22[..., None, :], A_.shape)
    rb = flat(_roots(A_, B_, C_))  # (…, La, 2K)
    zero = jnp.zeros(a.shape, a.dtype)
    b = _cells(zero, zero + 1, rb)  # (…, La, 2K+1)
    ab = jnp.broadcast_to(a[..., None], b.shape)
    da = jnp.stack([ab * b, b, jnp.ones_like(b)], -1).reshape(*b.shape[:-2], -1, 3)
    # family B: lines d = (x, y, 1); f = q00 x² + 2 (q01 y + q02) x + (q11 y² + 2 q12 y + q22)
    crit_b = jnp.concatenate([
        flat(_roots(q01 * q01 - q00 * q11, 2 * (q01 * q02 - q00 * q12), q02 * q02 - q00 * q22)),
        flat(_roots(q11, 2 * q12, q22)),
        flat(_roots(q00 + 2 * q01 + q11, 2 * (q02 + q12), q22))], -1)
    y = _lines(crit_b)  # (…, Lb)
    yy = y[..., :, None]
    A_ = jnp.broadcast_to(q00[..., None, :], yy.shape[:-1] + q00.shape[-1:])
    B_ = 2 * (q01[..., None, :] * yy + q02[..., None, :])
    C_ = q11[..., None, :] * yy ** 2 + 2 * q12[..., None, :] * yy + q22[..., None, :]
    rx = flat(_roots(A_, B_, C_))
    x = _cells(jnp.zeros(y.shape, y.dtype), y, rx)  # (…, Lb, 2K+1)
    ybr = jnp.broadcast_to(y[..., None], x.shape)
    db = jnp.stack([x, ybr, jnp.ones_like(x)], -1).reshape(*x.shape[:-2], -1, 3)
    d = jnp.concatenate([da, db], -2)
    return _witness_atoms(spec, Q, d)


def corner_vanishing(spec: QRMSpec) -> np.ndarray:
    """(O, K) bool: constraints that vanish identically at the cone corner ``d = (0, 1, 1)``.

    There the near landmark is at the camera and the other two are equidistant from it, so
    e.g. ``|AB| = |AC|`` in ``01:2``. Found structurally: zero (to 1e-12) at that corner for
    several random bearing triples in float64.
    """
    rng = np.random.default_rng(0)
    d = np.array([0.0, 1.0, 1.0])
    out = np.ones((3, spec.k), bool)
    for _ in range(4):
        b = rng.uniform(-np.pi, np.pi, 3)
        w = np.stack([np.cos(b), np.sin(b)], -1)
        P = d[:, None] * w
        for o, (X, Y, Z) in enumerate(CYCLIC):
            D, E = P[Y] - P[X], P[Z] - P[X]
            q = np.array([D @ D, E[0] * D[1] - E[1] * D[0], E @ D, E @ E])
            out[o] &= np.abs(spec.lin @ q) < 1e-12
    return out


def corner_rule(spec: QRMSpec, coef: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Sign of each corner-vanishing constraint near the corner ``(a, b) = (0, 1)``.

    ``coef`` (T, O·K, 3, 3): monomial coefficients over the box parametrisation ``d = (a·b,
    b, 1)`` (:func:`pqrm_jax.qrm.camera.cone_forms`). With ``b = 1 − s`` a constraint that
    vanishes at the corner is ``f = α a + β s + R(a, s)``, every term of ``R`` of total degree
    ≥ 2 with ``|R| ≤ G·h·(a + s)`` on ``[0, h]²`` (``G`` = sum of their |coefficients|). If
    ``α`` and ``β`` share the sign σ, then ``σ f ≥ (a + s)(min(|α|, |β|) − G h) > 0`` on the
    box minus the corner for ``h ≤ h* = min(|α|, |β|) / (2G)``; the corner itself is in no
    open state (``f = 0`` there). This is what lets the boxes exclude the states whose
    closure only touches the corner, which no interval bound can. Returns ``(σ, h*)`` (T,
    O·K): σ = 0 where the rule does not apply (constraint not vanishing there, opposite
    gradient signs, or a gradient below ``1e-4`` of the coefficient scale).
    """
    van = jnp.asarray(corner_vanishing(spec).reshape(-1))  # (OK,)
    j = np.arange(3)
    # E[i, l] = Σ_j C[i, j] binom(j, l) (−1)^l   (b^j = (1 − s)^j)
    binom = np.array([[1, 0, 0], [1, 1, 0], [1, 2, 1]], np.float64)  # [j, l]
    M = jnp.asarray(binom * (-1.0) ** j[None, :], coef.dtype)
    E = jnp.einsum("tkij,jl->tkil", coef, M)  # (T, OK, i, l)
    alpha, beta = E[..., 1, 0], E[..., 0, 1]
    deg = j[:, None] + j[None, :]
    G = jnp.sum(jnp.where(jnp.asarray(deg >= 2), jnp.abs(E), 0.0), (-1, -2))
    scale = jnp.max(jnp.abs(coef), (-1, -2))
    m = jnp.minimum(jnp.abs(alpha), jnp.abs(beta))
    ok = van[None, :] & (jnp.sign(alpha) == jnp.sign(beta)) & (m > 1e-4 * scale)
    sig = jnp.where(ok, jnp.sign(alpha), 0).astype(jnp.int32)
    hst = jnp.where(ok, m / (2 * G + 1e-30), 0.0)
    return sig, hst
