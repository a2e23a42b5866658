"""Random study environments and initial beliefs (Z §4.3; docs/bsp.md §generator).

* Landmarks: ``n`` uniform in ``[0, S]²`` (units of R) with minimum spacing ``r_min``.
* Composable initial belief ``M_1`` by *nearest-landmark growth*: start with a random landmark
  and its two nearest neighbours, then repeatedly add the excluded landmark nearest to the
  included set together with the included pair (p, q) of smallest ``|pℓ| + |qℓ|`` whose triplet
  is observable (minimum enclosing circle radius ≤ R). ``|M_1| = n − 2``, every landmark is
  covered and each addition is a 2-common cut, so ``M_1`` is composable (Z Thm 3.1) while its
  Link-Graph is often disconnected — the structure of Fig. 4.6a.
* Initial frame ``F_1``: a random ordered pair of a random ``M_1`` triplet; the robot starts at
  a random point within R of both frame landmarks; target τ*: uniform over the ``M_1``
  triplets that do not contain ``F_1`` (a target outside ``M_1`` could never be observed
  without compositions, docs/bsp.md §target).
* Initial belief: every ``M_1`` triplet measured once by PQRM (all orderings), the robot's
  state from the same inverse-sensor sampling, the reference scale (the known frame of
  Z §4.2.5) is F_1's true length bin (docs/bsp.md §Z-10), and — with compositions — every
  other triplet composed (:func:`~pqrm_jax.bsp.compose.augment`). Under the default
  ``"composed"`` scale model the composed rows also serve the frame scales without
  compositions (marked ``SCALE_ONLY``: never candidates).

Bad input raises ``ValueError`` naming it: fewer than 3 landmarks, NaN or coincident positions,
landmark ids that are not integers or are repeated or unknown (target, frame, triplets), a
non-composable initial belief; ``generate`` refuses a non-integer ``n`` and a non-positive or
non-finite ``size`` / ``R`` (negative ``r_min``).
"""

from __future__ import annotations

from functools import partial
from itertools import combinations
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import calculi
from ..compositions import is_composable
from ..compositions.simulation import measured_rows, place_rows
from ..pqrm import state_probabilities
from .belief import COMPOSED, SCALE_ONLY, QBelief, belief_scales, check_scale_model
from .compose import augment
from .models import Models

FAR = 1.0e3  # position of padding landmarks: never visible, never NaN


class Environment(NamedTuple):
    """One test: positions (n, 2) in units of R, ``M_1``, ``F_1``, goal, robot start."""

    pos: np.ndarray
    triplets: tuple
    frame: tuple
    goal: tuple
    start: np.ndarray


def mec_radius(p: np.ndarray) -> float:
    """Radius of the minimum enclosing circle of three points."""
    a, b, c = (float(np.linalg.norm(p[i] - p[j])) for i, j in ((1, 2), (0, 2), (0, 1)))
    s = sorted([a, b, c])
    if s[2] ** 2 >= s[0] ** 2 + s[1] ** 2:  # right or obtuse: the longest side is a diameter
        return s[2] / 2
    u, v = p[1] - p[0], p[2] - p[0]
    area = abs(u[0] * v[1] - u[1] * v[0]) / 2
    return a * b * c / (4 * area)


def grow_triplets(pos: np.ndarray, rng: np.random.Generator, R: float = 1.0):
    """Nearest-landmark growth (module docstring); ``None`` when it gets stuck."""
    n = len(pos)
    D = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    s = int(rng.integers(n))
    nn = [int(x) for x in np.argsort(D[s])[1:3]]
    first = (s, *nn)
    if mec_radius(pos[list(first)]) > R:
        return None
    inc = set(first)
    out = [tuple(sorted(first))]
    while len(inc) < n:
        exc = [x for x in range(n) if x not in inc]
        l = min(exc, key=lambda x: min(D[x, y] for y in inc))
        best = None
        for p, q in combinations(sorted(inc), 2):
            if mec_radius(pos[[p, q, l]]) <= R:
                c = D[p, l] + D[q, l]
                if best is None or c < best[0]:
                    best = (c, p, q)
        if best is None:
            return None
        inc.add(l)
        out.append(tuple(sorted((best[1], best[2], l))))
    return out


def _is_real(v) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(
        v, bool | np.bool_)


def _integer(name: str, v, low: int) -> int:
    """``v`` as an int (Python or NumPy integer, no bool) >= ``low``; else ``ValueError``."""
    if not isinstance(v, int | np.integer) or isinstance(v, bool | np.bool_) or v < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
    return int(v)


def _ids(what: str, ids, count: int | None, n: int) -> tuple:
    """Landmark ids as ints: integers (Python or NumPy) in ``[0, n)``, ``count`` of them."""
    ids = tuple(ids)
    if count is not None and len(ids) != count:
        raise ValueError(f"{what} must have {count} landmark ids, got {ids}")
    for x in ids:
        if not isinstance(x, int | np.integer) or isinstance(x, bool | np.bool_):
            raise ValueError(f"{what} {ids} must hold integer landmark ids, got {x!r}")
    if not all(0 <= x < n for x in ids):
        raise ValueError(f"{what} {ids} uses unknown landmarks (ids 0..{n - 1})")
    return tuple(int(x) for x in ids)


def generate(rng: np.random.Generator, n: int, size: float, r_min: float = 0.05,
             R: float = 1.0, max_tries: int = 1000) -> Environment:
    """One random environment of Z §4.3 (module docstring).

    Args:
        rng: NumPy generator.
        n: number of landmarks, an integer >= 3.
        size: S, the side of the square ``[0, S]²`` in units of R (positive, finite).
        r_min: minimum landmark spacing (non-negative, finite).
        R: sensing range (positive, finite).
        max_tries: draws before giving up (positive integer).

    Returns:
        The :class:`Environment` (landmark positions [n, 2], goal, initial frame, start,
        initial-belief triplets).

    Raises:
        ValueError: naming the argument for bad values; RuntimeError when no valid
            environment is found in ``max_tries`` draws (e.g. ``size`` too small for ``n``
            landmarks ``r_min`` apart).

    >>> import networkx as nx, numpy as np
    >>> env = generate(np.random.default_rng(0), 6, 2.0)
    >>> len(env.pos), env.goal, env.frame, len(env.triplets)
    (6, (0, 2, 3), (0, 5), 4)
    >>> check_environment(env, L_max=12)          # a composable initial belief: accepted
    >>> from pqrm_jax.bsp import triplet_link_graph
    >>> nx.is_connected(triplet_link_graph(env.triplets))
    True
    """
    if not isinstance(n, int | np.integer) or isinstance(n, bool | np.bool_):
        raise ValueError(f"n must be an integer >= 3, got {n!r}")
    n = int(n)
    if n < 3:
        raise ValueError(f"an environment needs at least 3 landmarks (n), got {n}")
    max_tries = _integer("max_tries", max_tries, 1)
    for nm, v, positive in (("size", size, True), ("r_min", r_min, False), ("R", R, True)):
        if not _is_real(v) or not np.isfinite(v) or v < 0 or (positive and v == 0):
            what = "positive" if positive else "non-negative"
            raise ValueError(f"{nm} must be {what} and finite, got {v!r}")
    for _ in range(max_tries):
        pos = rng.uniform(0, size, (n, 2))
        D = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(n) * 1e9
        if D.min() < r_min:
            continue
        M1 = grow_triplets(pos, rng, R)
        if M1 is None:
            continue
        t = M1[int(rng.integers(len(M1)))]
        a, b = (int(x) for x in rng.permutation(t)[:2])
        goals = [g for g in M1 if not {a, b} <= set(g)]
        if not goals:
            continue
        goal = goals[int(rng.integers(len(goals)))]
        for _ in range(200):
            x = pos[a] + rng.uniform(-R, R, 2)
            if max(np.linalg.norm(pos[a] - x), np.linalg.norm(pos[b] - x)) <= R:
                break
        else:
            continue
        return Environment(pos=pos, triplets=tuple(M1), frame=(a, b), goal=tuple(goal), start=x)
    raise RuntimeError(f"no valid environment after {max_tries} tries (n={n}, size={size})")


def check_environment(env: Environment, L_max: int) -> None:
    """Refuse an environment a test cannot run on (Z §4.3; module docstring).

    Refused: fewer than 3 or more than ``L_max`` landmarks, non-finite or coincident
    landmark positions, a non-finite robot start, landmark ids (target, frame, initial-belief
    triplets) that are not integers, repeated or unknown, a non-composable initial belief.

    Args:
        env: the environment.
        L_max: the padded landmark count of the study.

    Raises:
        ValueError: naming the problem.
    """
    pos = np.asarray(env.pos, float)
    n = len(pos)
    if n < 3:
        raise ValueError(f"an environment needs at least 3 landmarks, got {n}")
    if n > L_max:
        raise ValueError(f"{n} landmarks exceed the padding L_max={L_max}")
    if pos.shape != (n, 2) or not np.all(np.isfinite(pos)):
        raise ValueError("landmark positions must be finite (n, 2)")
    D = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.diag(np.full(n, np.inf))
    if np.any(D == 0):
        a, b = (int(x) for x in np.argwhere(D == 0)[0])
        raise ValueError(f"landmarks {a} and {b} coincide at {pos[a].tolist()}: every frame "
                         "and triplet needs distinct positions")
    start = np.asarray(env.start, float)
    if start.shape != (2,) or not np.all(np.isfinite(start)):
        raise ValueError(f"robot start position must be finite (2,), got {start.tolist()}")
    g = _ids("target triplet", env.goal, 3, n)
    if len(set(g)) != 3:
        raise ValueError(f"target triplet must have 3 distinct landmarks, got {g}")
    f = _ids("initial frame", env.frame, 2, n)
    if f[0] == f[1]:
        raise ValueError(f"initial frame {f} must be two distinct known landmarks")
    for t in env.triplets:
        t = _ids("initial-belief triplet", t, 3, n)
        if len(set(t)) != 3:
            raise ValueError(f"initial-belief triplet {t} has repeated or unknown landmarks")
    if not is_composable(env.triplets, range(n)):
        raise ValueError("the initial belief is not composable under the landmark set "
                         "(Z §4.2.6 assumes a composable M_1)")


MODES = ("without", "with")  # the two tests of an environment: compositions off / on


def initial_belief(key: jax.Array, models: Models, env: Environment, *, compositions: bool,
                   L_max: int = 12, sigma_z: float = 0.05, samples: int = 256,
                   calculus: str = "edc", scale_model: str = "composed") -> QBelief:
    """The initial belief of one test (Z §4.3, module docstring), padded to ``L_max`` landmarks.

    With ``scale_model="composed"`` (docs/bsp.md §Z-10) the composed rows are computed in both
    modes; without compositions they are marked ``SCALE_ONLY`` (frame scales, not
    candidates), so both modes have the same initial frame scales. One environment of
    :func:`initial_beliefs` (the same numbers).

    Args:
        key: PRNG key of the PQRM measurement samples (initial triplets and robot state).
        models: the offline tables.
        env: the environment (checked by :func:`check_environment`).
        compositions: whether composed triplets are candidates (Z eqs. 4.26–4.28).
        L_max: padded landmark count L.
        sigma_z: measurement noise in units of R.
        samples: PQRM samples per measured row (P eq. 2.9).
        calculus: the calculus name (EDC in Z).
        scale_model: ``"composed"`` or ``"belief"`` (docs/bsp.md §Z-10).

    Returns:
        The :class:`QBelief` (frame [2], robot [Q], trip [L, L, L, Q], trip_src and ncomp
        [L, L, L], scale [L, L, nb], lm_mask [L], conflicts []).

    Raises:
        ValueError: for a bad environment or an unknown ``scale_model``.
    """
    mode = MODES[int(bool(compositions))]
    out = initial_beliefs(jnp.asarray(key)[None], models, [env], modes=(mode,), L_max=L_max,
                          sigma_z=sigma_z, samples=samples, calculus=calculus,
                          scale_model=scale_model)[mode]
    return jax.tree.map(lambda x: x[0], out)


def initial_beliefs(keys: jax.Array, models: Models, envs: list[Environment], *,
                    modes: tuple[str, ...] = MODES, L_max: int = 12, sigma_z: float = 0.05,
                    samples: int = 256, calculus: str = "edc",
                    scale_model: str = "composed") -> dict[str, QBelief]:
    """The initial beliefs of many environments in both modes, batched (Z §4.3).

    Environment ``e`` with key ``keys[e]`` gets the belief of :func:`initial_belief` with that
    key in each mode of ``modes``. The measurements (P eq. 2.9) and the robot's state are
    one compiled call over all environments, the frame scales one per mode; the minimal
    composition trees (:func:`~pqrm_jax.bsp.compose.augment`, host) are built once per
    environment and shared by both modes (the modes differ only in the source codes under
    the ``"composed"`` scale model, docs/bsp.md §Z-10).

    Args:
        keys: [E] PRNG keys, one per environment.
        models: the offline tables.
        envs: the E environments (each checked by :func:`check_environment`).
        modes: which beliefs: ``"without"`` and/or ``"with"`` compositions (:data:`MODES`).
        L_max: padded landmark count L.
        sigma_z: measurement noise in units of R.
        samples: PQRM samples per measured row (P eq. 2.9).
        calculus: the calculus name (EDC in Z).
        scale_model: ``"composed"`` or ``"belief"`` (docs/bsp.md §Z-10).

    Returns:
        ``{mode: QBelief}``, every field with a leading ``[E]`` axis.

    Raises:
        ValueError: for a bad environment (naming it and its index), an unknown mode or
            ``scale_model``, or a key count that is not the environment count.

    >>> import jax, numpy as np
    >>> from pqrm_jax.bsp import Environment, initial_beliefs, load_models, ModelParams
    >>> env = Environment(pos=np.array([[0., 0.], [1., 0.], [.5, .8], [1.4, .9]]),
    ...                   triplets=((0, 1, 2), (1, 2, 3)), frame=(0, 1), goal=(1, 2, 3),
    ...                   start=np.array([.5, .3]))
    >>> models = load_models(ModelParams(samples=600, pool=1 << 18, seed=3))
    >>> b = initial_beliefs(jax.random.split(jax.random.key(0), 2), models, [env, env])
    >>> w, wo = b["with"], b["without"]   # ABD: composed (2); without: for scales only (3)
    >>> w.trip.shape, int(w.trip_src[1, 0, 1, 3]), int(wo.trip_src[1, 0, 1, 3])
    ((2, 12, 12, 12, 20), 2, 3)
    """
    check_scale_model(scale_model)
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise ValueError(f"modes must be a non-empty subset of {MODES}, got {modes!r}")
    envs = list(envs)
    if len(envs) == 0:
        raise ValueError("envs is empty: initial_beliefs needs at least one environment")
    keys = jnp.asarray(keys)
    if keys.shape != (len(envs),):
        raise ValueError(f"keys must be {len(envs)} PRNG keys (one per environment), got "
                         f"shape {keys.shape}")
    for e, env in enumerate(envs):
        try:
            check_environment(env, L_max)
        except ValueError as exc:
            raise ValueError(f"environment {e}: {exc}") from None
    calc = calculi.get(calculus)
    E = len(envs)
    trips = [np.asarray(sorted(tuple(sorted(int(x) for x in t)) for t in env.triplets),
                        np.int32).reshape(-1, 3) for env in envs]
    width = 1 << max(3, (max(len(t) for t in trips) - 1).bit_length())  # few compiled shapes
    tri = np.zeros((E, width, 3), np.int32)
    tri[:, :, 1], tri[:, :, 2] = 1, 2  # padding rows: a valid triplet, never placed
    for e, t in enumerate(trips):
        tri[e, :len(t)] = t
    pos = np.stack([padded_positions(env, L_max) for env in envs])
    start = np.stack([np.asarray(env.start, np.float32) for env in envs])
    frame = np.asarray([env.frame for env in envs], np.int32)
    rows, robot = _measurements(keys, jnp.asarray(pos), jnp.asarray(tri), jnp.asarray(start),
                                jnp.asarray(frame), jnp.float32(sigma_z), calculus, samples)
    rows = np.asarray(rows)
    parts = _mode_rows(models, envs, trips, rows, modes, L_max, calc, scale_model)
    ref_scale = jnp.asarray(np.stack([reference_scale(models, env) for env in envs]))
    lm = jnp.asarray(np.stack([np.arange(L_max) < len(env.pos) for env in envs]))
    frame = jnp.asarray(frame)
    out = {}
    for m in modes:
        trip, src, ncomp = (jnp.asarray(np.stack(x)) for x in zip(*parts[m], strict=True))
        src = src.astype(jnp.int8)
        scale = _batched_scales(models, trip, src, frame, ref_scale, lm, scale_model)
        out[m] = QBelief(frame=frame, robot=robot, trip=trip, trip_src=src,
                         ncomp=ncomp.astype(jnp.int8), scale=scale, lm_mask=lm,
                         conflicts=jnp.zeros((E,), jnp.int32))
    return out


def _mode_rows(models: Models, envs: list, trips: list, rows: np.ndarray, modes, L_max: int,
               calc, scale_model: str) -> dict[str, list]:
    """Host part of :func:`initial_beliefs`: per environment and mode the dense (trip, src,
    ncomp) of the measured rows ``rows`` [E, T, 6, Q] of ``trips``, the composition trees
    built once per environment and shared by the modes (docs/bsp.md §Z-10)."""
    Q = calc.num_states
    need_aug = "with" in modes or scale_model == "composed"
    tensor = np.asarray(calc.tables.prob_compose, np.float32) if need_aug else None
    U = np.asarray(models.U)
    parts: dict[str, list] = {m: [] for m in modes}
    for e, env in enumerate(envs):
        trip = np.full((L_max, L_max, L_max, Q), 1.0 / Q, np.float32)
        measured = np.zeros((L_max, L_max, L_max), bool)
        place_rows(trip, measured, trips[e], rows[e, :len(trips[e])])
        if need_aug:
            aug, src_c, ncomp_c = augment(trip, measured, len(env.pos), tensor, U)
        for m in modes:
            if m == "with":
                parts[m].append((aug, src_c, ncomp_c))
            elif scale_model == "composed":  # composed rows serve the frame scales only (§Z-10)
                parts[m].append((aug, np.where(src_c == COMPOSED, SCALE_ONLY,
                                               src_c).astype(np.int8), ncomp_c))
            else:
                parts[m].append((trip, measured.astype(np.int8),
                                 np.zeros(measured.shape, np.int8)))
    return parts


@partial(jax.jit, static_argnames=("calculus", "samples"))
def _measurements(keys, pos, tri, start, frame, sigma_z, calculus: str, samples: int):
    """[E, T, 6, Q] rows of the measured triplets and [E, Q] robot states (one program)."""
    calc = calculi.get(calculus)

    def one(key, pos, tri, x, fr):
        k1, k2 = jax.random.split(key)
        rows = measured_rows(calc, k1, pos, tri, sigma_z, samples)
        means = jnp.stack([pos[fr[0]] - x, pos[fr[1]] - x, jnp.zeros(2, jnp.float32)])[None]
        sig = jnp.stack([sigma_z, sigma_z, jnp.float32(0.0)])[None]
        return rows, state_probabilities(k2, calc, means, sig, samples)[0]

    return jax.vmap(one)(keys, pos, tri, start, frame)


@partial(jax.jit, static_argnames=("scale_model",))
def _batched_scales(models, trip, src, frame, ref_scale, lm, scale_model: str):
    """:func:`~pqrm_jax.bsp.belief.belief_scales` over a leading environment axis: a
    ``lax.map``, so that each environment's scales are the single-environment program's bit
    for bit (a ``vmap`` batches the contractions and rounds some entries 1 ulp apart)."""
    return jax.lax.map(lambda a: belief_scales(models, *a, scale_model),
                       (trip, src, frame, ref_scale, lm))


def reference_scale(models: Models, env: Environment) -> np.ndarray:
    """(nb,) one-hot scale bin of the initial frame F_1 (the known scale, docs/bsp.md §Z-10)."""
    nb = models.num_bins
    a, b = env.frame
    d = float(np.linalg.norm(np.asarray(env.pos[a]) - np.asarray(env.pos[b])))
    return np.eye(nb, dtype=np.float32)[min(int(d * (nb - 1) / 2.0), nb - 1)]


def padded_positions(env: Environment, L_max: int) -> np.ndarray:
    """(L_max, 2) positions with padding landmarks far away."""
    pos = np.full((L_max, 2), FAR, np.float32)
    pos[: len(env.pos)] = env.pos
    return pos
