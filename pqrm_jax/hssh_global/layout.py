"""Global metrical layout: SE(2) compounding and spring relaxation of place poses (B ch. 9).

Place ``p``'s frame ``O_p`` is the rover pose at its first visit (B §9.1, Fig. 9.2c). At visit
``i`` the rover stands at the place (the dividing pose is taken at the place centre) heading along
its arrival entry, whose bearing ``δ_i`` in ``O_p`` is known from the star stored at the first visit
and the isomorphism of the hypothesis; so the rover pose is ``X_i = χ_{p_i} ⊕ (0, 0, δ_i)``. Each
travel is a spring (B §9.2, ``G(χ)``): residual ``λ_i ⊖ (⊖X_{i-1} ⊕ X_i)`` whitened by the odometry
sd. The layout ``χ̂`` minimises the sum of squares by Levenberg–Marquardt (fixed iterations;
the Jacobian is block-sparse, each spring touching two places, so the normal equations are
assembled from per-spring ``3×3`` blocks, and the small ``3M×3M`` system is solved densely; the
dense ``jax.jacfwd`` of the whole residual is kept as ``jacobian="dense"``), initialised by
compounding the odometry; ``χ_{p_0}`` is anchored at the origin. All hypotheses are padded to
``[H, M]`` places and ``[H, N]`` travels and relaxed together with ``vmap``; the final cost is
the layout score
(``-log G(χ̂)`` up to a constant) used to rank leaves.

>>> import numpy as np
>>> a = np.array([1.0, 2.0, 0.5])
>>> np.allclose(se2_compose(se2_inverse(a), a), 0, atol=1e-6)
True
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .tree import MapHypothesis


def _wrap(xp, t):
    return xp.mod(t + np.pi, 2 * np.pi) - np.pi


def _compose(xp, a, b):
    """``a ⊕ b`` in array module ``xp`` (one formula for :func:`se2_compose` and
    :func:`se2_compose_host`)."""
    c, s = xp.cos(a[..., 2]), xp.sin(a[..., 2])
    return xp.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     _wrap(xp, a[..., 2] + b[..., 2])], -1)


def _inverse(xp, a):
    c, s = xp.cos(a[..., 2]), xp.sin(a[..., 2])
    return xp.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1],
                     _wrap(xp, -a[..., 2])], -1)


def wrap(t):
    """Angle wrapped to ``[-π, π)``."""
    return _wrap(jnp, jnp.asarray(t))


def se2_compose(a, b):
    """``a ⊕ b`` for SE(2) poses ``[..., 3]`` (Smith, Self & Cheeseman; B §9.1).

    Args:
        a: ``[..., 3]`` poses (x, y, θ).
        b: ``[..., 3]`` poses in the frame of ``a``.

    Returns:
        ``[..., 3]`` the composed poses, θ wrapped to [-π, π).
    """
    return _compose(jnp, jnp.asarray(a), jnp.asarray(b))


def se2_inverse(a):
    """``⊖a`` for SE(2) poses ``[..., 3]``.

    Args:
        a: ``[..., 3]`` poses (x, y, θ).

    Returns:
        ``[..., 3]`` the inverse poses (B §9.1).
    """
    return _inverse(jnp, jnp.asarray(a))


def se2_compose_host(a, b) -> np.ndarray:
    """:func:`se2_compose` in NumPy (float64) for host-side bookkeeping (the same formula).

    Eager JAX ops compile once per input shape and dispatch one small program per operation,
    so point clouds of varying size (LPM snapshots) and per-travel loops cost a compile or a
    dispatch each through :func:`se2_compose`, in float32; this one runs in NumPy, in float64.

    Args:
        a: ``[..., 3]`` poses (x, y, θ).
        b: ``[..., 3]`` poses in the frame of ``a``.

    Returns:
        ``[..., 3]`` float64 composed poses.

    >>> se2_compose_host([1.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0]).round(6).tolist()
    [1.0, 1.0, 1.570796]
    """
    return _compose(np, np.asarray(a, float), np.asarray(b, float))


def se2_inverse_host(a) -> np.ndarray:
    """:func:`se2_inverse` in NumPy (float64), see :func:`se2_compose_host`.

    Args:
        a: ``[..., 3]`` poses (x, y, θ).

    Returns:
        ``[..., 3]`` float64 inverse poses (B §9.1).
    """
    return _inverse(np, np.asarray(a, float))



class LayoutProblem(NamedTuple):
    """Padded layout problems, one row per hypothesis.

    Attributes:
        init: ``[H, M, 3]`` initial place poses (compounded odometry).
        src, dst: ``[H, N]`` place of visit ``i-1`` and ``i`` of each travel.
        d_src, d_dst: ``[H, N]`` arrival bearings ``δ`` in the place frames.
        odometry: ``[H, N, 3]`` λ_i.
        sigma: ``[H, N, 3]`` odometry sd.
        mask: ``[H, N]`` valid travels.
    """

    init: jax.Array
    src: jax.Array
    dst: jax.Array
    d_src: jax.Array
    d_dst: jax.Array
    odometry: jax.Array
    sigma: jax.Array
    mask: jax.Array


def pack(hypotheses: list[MapHypothesis], odometry, sigma_xy: float = 0.02,
         sigma_theta: float = 0.01, m_max: int | None = None) -> LayoutProblem:
    """Packs hypotheses sharing one experience into a padded :class:`LayoutProblem`.

    Args:
        hypotheses: leaves of the tree (same experience).
        odometry: ``[N, 3]`` λ_i shared by all hypotheses, or ``[H, N, 3]`` one row per
            hypothesis (e.g. corrected by re-localisation at revisits,
            :func:`~pqrm_jax.hssh_global.relocalize.visit_offsets`); NaN entries raise
            ``ValueError``. The sd always follows the first row's travel lengths.
        sigma_xy: sd per unit travelled on x, y (relative), ``sigma_theta`` sd of θ per corridor.
            The θ sd is ``sigma_theta · d / median |λ|`` (scale-free); the generator in
            :func:`~pqrm_jax.hssh_global.world.explore` divides by the shortest corridor
            instead, a deliberate small model mismatch.
        m_max: padded number of places (default: the largest hypothesis).

    Returns:
        The padded :class:`LayoutProblem` with a leading ``[H]`` hypothesis axis.

    Raises:
        ValueError: for NaN odometry or odometry of the wrong shape.
    """
    if not hypotheses:
        raise ValueError("no hypothesis to lay out")
    raw = np.asarray(odometry, float)
    if raw.ndim == 3:
        if raw.shape[0] != len(hypotheses) or raw.shape[2] != 3:
            raise ValueError(f"per-hypothesis odometry must be [H={len(hypotheses)}, N, 3], "
                             f"got {list(raw.shape)}")
        per_h = raw
    else:
        per_h = raw.reshape(1, -1, 3)
    if not np.all(np.isfinite(per_h)):
        bad = np.where(~np.isfinite(per_h).all(2).all(0))[0].tolist()
        raise ValueError(f"odometry has non-finite displacements at travels {bad}")
    odo = per_h[0]
    n = odo.shape[0]
    m = m_max or max(h.n_places for h in hypotheses)
    h_n = len(hypotheses)
    init = np.zeros((h_n, m, 3))
    src = np.zeros((h_n, max(n, 1)), np.int32)
    dst = np.zeros_like(src)
    ds, dd = np.zeros((h_n, max(n, 1))), np.zeros((h_n, max(n, 1)))
    dist = np.linalg.norm(odo[:, :2], axis=1) if n else np.zeros(0)
    unit = max(float(np.median(dist)), 1e-12) if n else 1.0
    sig = np.zeros((max(n, 1), 3))
    sig[:n, 0] = sig[:n, 1] = np.maximum(sigma_xy * dist, 1e-6 * unit)
    sig[:n, 2] = np.maximum(sigma_theta * dist / unit, 1e-6)
    sig[n:] = 1.0
    mask = np.zeros((h_n, max(n, 1)), bool)
    mask[:, :n] = True
    for k, h in enumerate(hypotheses):
        if len(h.visits) != n + 1:
            raise ValueError("hypothesis and odometry come from different experiences")
        delta = [h.bearings[p][e] for p, e in h.visits]
        odo_k = per_h[k if len(per_h) > 1 else 0]
        pose = np.zeros(3)
        seen = {h.visits[0][0]}
        for i in range(n):
            (p0, _), (p1, _) = h.visits[i], h.visits[i + 1]
            src[k, i], dst[k, i], ds[k, i], dd[k, i] = p0, p1, delta[i], delta[i + 1]
            pose = se2_compose_host(pose, odo_k[i])
            if p1 not in seen:
                seen.add(p1)
                init[k, p1] = se2_compose_host(pose, np.array([0.0, 0.0, -delta[i + 1]]))
    return LayoutProblem(*(jnp.asarray(x) for x in (init, src, dst, ds, dd)),
                         jnp.asarray(np.broadcast_to(per_h if n else np.zeros((1, 1, 3)),
                                                     (h_n, max(n, 1), 3)).copy()),
                         jnp.asarray(np.broadcast_to(sig, (h_n, max(n, 1), 3)).copy()),
                         jnp.asarray(mask))


def _residuals(chi, src, dst, d_src, d_dst, odo, sigma, mask):
    zeros = jnp.zeros_like(d_src)
    xa = se2_compose(chi[src], jnp.stack([zeros, zeros, d_src], -1))
    xb = se2_compose(chi[dst], jnp.stack([zeros, zeros, d_dst], -1))
    pred = se2_compose(se2_inverse(xa), xb)
    r = pred - odo
    r = r.at[..., 2].set(wrap(r[..., 2]))
    r = (r / sigma) * mask[:, None]
    anchor = chi[0] * 1e3  # χ_{p0} at the origin
    return jnp.concatenate([r.ravel(), anchor])


def _relax_one_dense(init, src, dst, d_src, d_dst, odo, sigma, mask, iters: int,
                     damping: float):
    shape = init.shape

    def f(x):
        return _residuals(x.reshape(shape), src, dst, d_src, d_dst, odo, sigma, mask)

    def step(_, x):
        r = f(x)
        j = jax.jacfwd(f)(x)
        a = j.T @ j
        a = a + damping * (jnp.diag(jnp.diag(a)) + jnp.eye(a.shape[0]))
        return x - jnp.linalg.solve(a, j.T @ r)

    x = jax.lax.fori_loop(0, iters, step, init.ravel())
    r = f(x)
    return x.reshape(shape), 0.5 * jnp.sum(r ** 2)


def _spring(xa, xb, da, db, odo, sigma, m):
    """Whitened residual ``[3]`` of one spring between place poses ``xa`` and ``xb``."""
    zero = jnp.zeros_like(da)
    pa = se2_compose(xa, jnp.stack([zero, zero, da]))
    pb = se2_compose(xb, jnp.stack([zero, zero, db]))
    r = se2_compose(se2_inverse(pa), pb) - odo
    r = r.at[2].set(wrap(r[2]))
    return (r / sigma) * m


_spring_jac = jax.vmap(jax.jacfwd(_spring, argnums=(0, 1)))


def _relax_one(init, src, dst, d_src, d_dst, odo, sigma, mask, iters: int, damping: float):
    """LM with the block-sparse Jacobian: each spring touches two places (B §9.2).

    The normal equations ``JᵀJ δ = −Jᵀr`` are assembled from per-spring ``3×3`` blocks
    (``vmap`` of ``jacfwd`` of one spring, scatter-added into ``[M, M, 3, 3]``), so a step costs
    ``O(N)`` spring evaluations instead of the dense ``jacfwd``'s ``O(N·M)``; the ``3M×3M``
    solve is unchanged. Same iterates as :func:`_relax_one_dense` up to rounding.
    """
    m = init.shape[0]
    springs = jax.vmap(_spring)
    blk = jnp.stack([src, src, dst, dst]), jnp.stack([src, dst, src, dst])

    def step(_, chi):
        r = springs(chi[src], chi[dst], d_src, d_dst, odo, sigma, mask)      # [N, 3]
        ja, jb = _spring_jac(chi[src], chi[dst], d_src, d_dst, odo, sigma, mask)
        t = jnp.swapaxes
        blocks = jnp.stack([t(ja, 1, 2) @ ja, t(ja, 1, 2) @ jb, t(jb, 1, 2) @ ja,
                            t(jb, 1, 2) @ jb])                             # [4, N, 3, 3]
        h = jnp.zeros((m, m, 3, 3), chi.dtype).at[blk[0], blk[1]].add(blocks)
        g = (jnp.zeros((m, 3), chi.dtype)
             .at[src].add(jnp.einsum("nij,ni->nj", ja, r))
             .at[dst].add(jnp.einsum("nij,ni->nj", jb, r)))
        # the anchor residual 1e3 · χ_{p0}
        h = h.at[0, 0].add(1e6 * jnp.eye(3, dtype=chi.dtype))
        g = g.at[0].add(1e6 * chi[0])
        a = jnp.transpose(h, (0, 2, 1, 3)).reshape(3 * m, 3 * m)
        a = a + damping * (jnp.diag(jnp.diag(a)) + jnp.eye(3 * m, dtype=chi.dtype))
        return chi - jnp.linalg.solve(a, g.ravel()).reshape(m, 3)

    chi = jax.lax.fori_loop(0, iters, step, init)
    r = _residuals(chi, src, dst, d_src, d_dst, odo, sigma, mask)
    return chi, 0.5 * jnp.sum(r ** 2)


def relax(problem: LayoutProblem, iters: int = 10, damping: float = 1e-3,
          jacobian: str = "sparse"):
    """Relaxes every hypothesis's layout at once (``vmap``; B §9.2 "springs").

    Args:
        problem: from :func:`pack`.
        iters: Levenberg–Marquardt iterations (fixed, static).
        damping: LM damping (Marquardt scaling plus a small identity for unconstrained padding).
        jacobian: ``"sparse"`` (per-spring ``3×3`` blocks, the default) or ``"dense"``
            (``jacfwd`` of the whole residual vector; the reference).

    Returns:
        ``(chi [H, M, 3], cost [H])``; cost is ``0.5 Σ r²`` of the whitened residuals.
    """
    return _relax_batched(problem, iters, damping, _jacobian(jacobian))


def _jacobian(name: str) -> str:
    if name not in ("sparse", "dense"):
        raise ValueError(f"jacobian must be 'sparse' or 'dense', got {name!r}")
    return name


def _one(name):
    return _relax_one if name == "sparse" else _relax_one_dense


@functools.partial(jax.jit, static_argnames=("iters", "jacobian"))
def _relax_batched(problem, iters, damping, jacobian):
    one = _one(jacobian)
    return jax.vmap(lambda *a: one(*a, iters=iters, damping=damping))(*problem)


@functools.partial(jax.jit, static_argnames=("iters", "jacobian"))
def _relax_single(problem, iters, damping, jacobian):
    return _one(jacobian)(*problem, iters=iters, damping=damping)


def relax_loop(problem: LayoutProblem, iters: int = 10, damping: float = 1e-3,
               jacobian: str = "sparse"):
    """The same relaxation one hypothesis at a time (the benchmark reference).

    Args:
        problem: a packed :class:`LayoutProblem` with a leading ``[H]`` axis.
        iters: Gauss–Newton iterations.
        damping: Levenberg–Marquardt damping.
        jacobian: ``"sparse"`` or ``"dense"``.

    Returns:
        ``(chi [H, M, 3], cost [H])`` as :func:`relax` (B §9.2).
    """
    jac = _jacobian(jacobian)
    outs = [_relax_single(LayoutProblem(*(x[k] for x in problem)), iters, damping, jac)
            for k in range(problem.init.shape[0])]
    return jnp.stack([o[0] for o in outs]), jnp.stack([o[1] for o in outs])


def relax_many(leaves: list[MapHypothesis], odometry, sigma_xy: float = 0.02,
               sigma_theta: float = 0.01, chunk: int = 1024,
               least: int = 64) -> tuple[LayoutProblem, np.ndarray, np.ndarray]:
    """Relaxes many hypotheses of one experience in chunks of bucketed shapes (B §9.2).

    Hypotheses are padded (by repeating the first) to a power of two, at least ``least`` and
    at most ``chunk`` per call, and places to travels + 1, so that experiences of equal length
    share compiled code (a compile costs seconds, 64 padded hypotheses milliseconds); the
    padding is dropped from the results.

    Args:
        leaves: hypotheses sharing one experience (``H >= 1``).
        odometry: ``[N, 3]`` λ_i (see :func:`pack`).
        sigma_xy, sigma_theta: odometry noise model (see :func:`pack`).
        chunk: most hypotheses per relaxation call (``>= 1``).
        least: fewest padded hypotheses per call (``>= 1``).

    Returns:
        ``(problem, chi, cost)``: the packed :class:`LayoutProblem` (NumPy, ``[H, ...]``), the
        relaxed poses ``[H, N + 1, 3]`` and the costs ``[H]``.

    >>> from pqrm_jax.hssh_global import grid_world, explore, build_tree
    >>> e = explore(grid_world(2, 2, seed=0), 4, seed=0)
    >>> leaves = build_tree(e).leaves
    >>> _, chi, cost = relax_many(leaves, e.odometry)
    >>> chi.shape[0] == cost.shape[0] == len(leaves)
    True
    """
    if not leaves:
        raise ValueError("no hypothesis to lay out")
    if int(chunk) < 1 or int(least) < 1:
        raise ValueError(f"chunk and least must be >= 1, got chunk={chunk}, least={least}")
    odometry = np.asarray(odometry, float)
    probs, chis, costs = [], [], []
    for s in range(0, len(leaves), chunk):
        part = list(leaves[s:s + chunk])
        h = len(part)
        padded = part + [part[0]] * (min(max(1 << (h - 1).bit_length(), least), chunk) - h)
        prob = pack(padded, odometry, sigma_xy, sigma_theta, m_max=len(odometry) + 1)
        chi, cost = relax(prob)
        probs.append(LayoutProblem(*(np.asarray(x[:h]) for x in prob)))
        chis.append(np.asarray(chi[:h]))
        costs.append(np.asarray(cost)[:h])
    prob = LayoutProblem(*(np.concatenate(xs) for xs in zip(*probs, strict=True)))
    return prob, np.concatenate(chis), np.concatenate(costs)


def layout_supported(cost, leaves: list[MapHypothesis], n_travels: int,
                     alpha: float = 1e-3) -> np.ndarray:
    """Declared geometric test (beyond B): can the metrical layout support each map?

    Under the odometry noise model of :func:`pack` the whitened residuals of the true map at
    its relaxed layout are approximately standard normal, so ``2 · cost`` is approximately
    χ² with ``dof = 3 N − 3 (M − 1)`` degrees of freedom (``N`` travels, ``M`` places, the
    first place anchored). A map whose ``2 · cost`` exceeds the ``1 − alpha`` quantile is one
    the layout cannot support: an aliased map that folds distinct places into one needs
    springs stretched far beyond the odometry noise (a figure-8 and a 3×3 lattice: cost
    1.4·10⁵ against 4.3 for the true map, issue 26). Maps with ``dof <= 0`` (no loop
    closed) are always supported. B ranks by minimality then layout cost (§8.3, §9.2) and
    has no such test; this one is declared, off in B's ordering, and reported on and off.

    Args:
        cost: ``[H]`` layout costs ``0.5 Σ r²`` (:func:`relax`).
        leaves: the ``H`` hypotheses (for their numbers of places).
        n_travels: ``N``, the travels of the experience.
        alpha: false-rejection probability for a map that fits the noise model (0 < α < 1).

    Returns:
        bool ``[H]``: True where the layout supports the map.

    >>> from pqrm_jax.hssh_global import grid_world, explore, build_tree, is_true_map
    >>> e = explore(grid_world(3, 3, seed=1), 12, seed=0)
    >>> leaves = build_tree(e).leaves
    >>> _, _, cost = relax_many(leaves, e.odometry)
    >>> bool(layout_supported(cost, leaves, 12)[[is_true_map(h, e) for h in leaves].index(True)])
    True
    """
    from scipy.stats import chi2

    a = float(alpha)
    if not 0.0 < a < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    cost = np.asarray(cost, float)
    if cost.shape != (len(leaves),):
        raise ValueError(f"cost must be [H={len(leaves)}], got shape {cost.shape}")
    dof = np.array([3 * int(n_travels) - 3 * (h.n_places - 1) for h in leaves])
    bound = np.where(dof > 0, chi2.ppf(1.0 - a, np.maximum(dof, 1)), np.inf)
    return np.isfinite(cost) & (2.0 * cost <= bound)


def score_hypotheses(hypotheses, odometry, **kw) -> np.ndarray:
    """Layout cost of each hypothesis (lower is more likely), ``[H]``.

    Args:
        hypotheses: leaves of the tree of maps (one experience; B §9.2).
        odometry: ``[N, 3]`` or ``[H, N, 3]`` displacements, as :func:`pack`.
        **kw: passed to :func:`relax_many` (``sigma_xy``, ``sigma_theta``, ...).

    Returns:
        ``[H]`` float costs.
    """
    _, cost = relax(pack(hypotheses, odometry, **kw))
    return np.asarray(cost)


def true_layout(world, experience) -> np.ndarray:
    """Ground-truth place poses ``[m_seen, 3]`` in the frame of the first visit, by first visit.

    Places are numbered by first appearance in the experience (as in every hypothesis).

    Args:
        world: the ground-truth :class:`~pqrm_jax.hssh_global.world.CorridorWorld`.
        experience: the exploration.

    Returns:
        ``[m_seen, 3]`` float64 poses (B §9.2).
    """
    from .tree import canonical_places
    lab = canonical_places(experience.true_places)
    first = {}
    for i, (p, c) in enumerate(zip(experience.true_places, lab, strict=True)):
        if c not in first:
            heading = world.bearings[int(p)][int(experience.true_arrivals[i])]
            first[c] = np.array([*world.positions[int(p)], heading])
    x0 = first[0]
    return np.stack([np.asarray(se2_compose(se2_inverse(x0), first[c])) for c in range(len(first))])


def scale_trajectory(x_start, x_end, increments) -> jax.Array:
    """Trajectory fitting between two relaxed place poses (B §9.3.3).

    The recorded increments ``μ_j`` (global-frame pose differences ``[J, 3]``) leave a
    discrepancy ``δ = x_end − x_start − Σ_j μ_j``; each component ``c`` of each increment absorbs
    a share proportional to its magnitude (``Λ`` diagonal ∝ ``|μ|``):
    ``ξ̂^c_j = μ^c_j + |μ^c_j| / Σ_h |μ^c_h| · δ^c`` (an even split when all ``μ^c`` are 0).

    Args:
        x_start, x_end: ``[3]`` corrected poses at the two places.
        increments: ``[J, 3]`` recorded increments.

    Returns:
        ``[J + 1, 3]`` corrected poses from ``x_start`` to ``x_end``.

    >>> import numpy as np
    >>> p = scale_trajectory(np.zeros(3), np.array([2.2, 0.0, 0.0]), np.array([[1.0, 0, 0]] * 2))
    >>> [round(float(v), 3) for v in p[:, 0]]
    [0.0, 1.1, 2.2]

    Raises ``ValueError`` for a zero-length trajectory (no increment) or shapes other than
    ``[3]``, ``[3]``, ``[J, 3]``.
    """
    shapes = [np.shape(x_start), np.shape(x_end), np.shape(increments)]
    if shapes[0] != (3,) or shapes[1] != (3,) or len(shapes[2]) != 2 or shapes[2][1] != 3:
        raise ValueError(f"x_start, x_end must be [3] and increments [J, 3], got {shapes}")
    if shapes[2][0] == 0:
        raise ValueError("increments must hold at least one step (a zero-length trajectory "
                         "has nothing to scale)")
    return _scale_trajectory(x_start, x_end, increments)


@jax.jit
def _scale_trajectory(x_start, x_end, increments) -> jax.Array:
    mu = jnp.asarray(increments)
    x0, x1 = jnp.asarray(x_start), jnp.asarray(x_end)
    delta = x1 - x0 - mu.sum(0)
    delta = delta.at[2].set(wrap(delta[2]))
    a = jnp.abs(mu)
    tot = a.sum(0)
    share = jnp.where(tot > 0, a / jnp.where(tot > 0, tot, 1.0), 1.0 / mu.shape[0])
    xi = mu + share * delta
    poses = x0 + jnp.concatenate([jnp.zeros((1, 3)), jnp.cumsum(xi, 0)])
    return poses.at[:, 2].set(wrap(poses[:, 2]))
