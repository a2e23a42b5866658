"""Graph-based navigation between Voronoi cells along RNG paths (M§VII.B), closed loop.

Strategy (M§VII.B steps 1–6): find the landmarks nearest to START and END (their Voronoi
cells), plan the cheapest sequence of landmarks along RNG edges (hop count plus ``lam`` times
the Alg. 2 edge cost — the qualitative map has no metric lengths), then drive towards the
next landmark of the sequence using only its camera bearing until the rover is inside its
Voronoi cell, which the camera detects as that landmark being the nearest (range rank 0);
repeat until the goal landmark's cell is reached. Step 7 (a local planner to END) is
executed as a straight drive to END. Everything runs in one jitted ``lax.scan`` per run and
``vmap``s over start/goal pairs.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import sim
from pqrm_jax.sim.rover import RoverParams, RoverState, step_kernel

from .rng import RNGEstimate

__all__ = ["RNGNavResult", "plan_next_hop", "navigate", "navigate_many"]


class RNGNavResult(NamedTuple):
    """Outcome of one navigation run.

    ``success`` (goal cell reached and END within ``tol``), ``reached_cell``, ``length``
    (metres driven), ``straight`` (|END − START|), ``poses`` [n_steps + 1, 3], ``path``
    [N] planned landmark sequence (−1 padded), ``hops``.
    """

    success: jax.Array
    reached_cell: jax.Array
    length: jax.Array
    straight: jax.Array
    poses: jax.Array
    path: jax.Array
    hops: jax.Array


@jax.jit
def plan_next_hop(edges: jax.Array, cost: jax.Array, lam: float = 1.0):
    """All-pairs shortest paths on the RNG estimate (Floyd–Warshall, ``lax.fori_loop``).

    Returns ``(dist [N, N], nxt [N, N])``: ``nxt[i, j]`` is the landmark after i on a
    cheapest path to j (−1 if unreachable); edge weight = 1 + lam · w_ij.
    """
    n = edges.shape[0]
    w = jnp.where(edges, 1.0 + lam * cost, jnp.inf)
    w = jnp.where(jnp.eye(n, dtype=bool), 0.0, w)
    nxt = jnp.where(jnp.isfinite(w), jnp.arange(n)[None, :], -1)

    def body(k, st):
        d, nx = st
        via = d[:, k][:, None] + d[k][None, :]
        better = via < d
        return jnp.where(better, via, d), jnp.where(better, nx[:, k][:, None], nx)

    return jax.lax.fori_loop(0, n, body, (w, nxt))


def _path(nxt, s, g, n):
    def body(i, st):
        path, cur = st
        cur = jnp.where(cur >= 0, nxt[jnp.maximum(cur, 0), g], -1)
        cur = jnp.where(path[i - 1] == g, -1, cur)
        return path.at[i].set(cur), cur

    path0 = jnp.full((n,), -1, jnp.int32).at[0].set(s)
    path, _ = jax.lax.fori_loop(1, n, body, (path0, s))
    return path


@partial(jax.jit, static_argnames=("n_steps",))
def _navigate(landmarks, nxt, start, goal, params, sensor, *, n_steps, k_turn, tol):
    n = landmarks.shape[0]
    d_s = jnp.sum((landmarks - start[:2]) ** 2, -1)
    d_g = jnp.sum((landmarks - goal) ** 2, -1)
    s, g = jnp.argmin(d_s), jnp.argmin(d_g)
    path = _path(nxt, s, g, n)
    hops = jnp.sum(path >= 0) - 1
    reachable = jnp.any(path == g)

    def body(carry, _):
        state, k, dist = carry
        cam = sim.sensors.camera_kernel(state.pose, landmarks, sensor)
        nearest = jnp.argmin(jnp.where(cam.visible, cam.range_rank, n + 1))
        target = path[jnp.clip(k, 0, n - 1)]
        in_cell = (nearest == target) & cam.visible[jnp.maximum(target, 0)]
        k = jnp.where(in_cell & (target != g) & (target >= 0), k + 1, k)
        target = path[jnp.clip(k, 0, n - 1)]
        at_goal_cell = (target == g) & (nearest == g)
        # bearing-only drive to the next landmark; last leg: drive to END (local planner)
        rel = jnp.where(at_goal_cell, goal, landmarks[jnp.maximum(target, 0)]) - state.pose[:2]
        err = sim.wrap_angle(jnp.arctan2(rel[1], rel[0]) - state.pose[2])
        dist_goal = jnp.sqrt(jnp.sum((goal - state.pose[:2]) ** 2))
        done = at_goal_cell & (dist_goal < tol)
        visible_target = cam.visible[jnp.maximum(target, 0)] | at_goal_cell
        v = jnp.where(done | ~visible_target | ~reachable, 0.0,
                      params.max_speed * jnp.maximum(jnp.cos(err), 0.0) ** 2)
        v = jnp.where(at_goal_cell, jnp.minimum(v, dist_goal / params.dt), v)
        u = jnp.stack([v, jnp.where(done, 0.0, k_turn * err)])
        new = step_kernel(state, u, params)
        dist = dist + jnp.sqrt(jnp.sum((new.pose[:2] - state.pose[:2]) ** 2))
        return (new, k, dist), (new.pose, at_goal_cell, done)

    st0 = RoverState(start, jnp.zeros((), start.dtype))
    (final, _, length), (poses, cell, done) = jax.lax.scan(
        body, (st0, jnp.zeros((), jnp.int32), jnp.zeros((), start.dtype)), None, length=n_steps)
    straight = jnp.sqrt(jnp.sum((goal - start[:2]) ** 2))
    return RNGNavResult(done.any(), cell.any(), length, straight,
                     jnp.concatenate([start[None], poses]), path, hops)


def navigate(
    landmarks: jax.Array,
    rng: RNGEstimate,
    start: jax.Array,
    goal: jax.Array,
    params: RoverParams | None = None,
    sensor: sim.SensorParams | None = None,
    *,
    n_steps: int = 3000,
    lam: float = 1.0,
    k_turn: float = 2.0,
    tol: float = 0.5,
) -> RNGNavResult:
    """Drive the simulated rover from ``start`` (x, y, θ) to ``goal`` (x, y) (M§VII.B).

    The strategy is described in docs/qrm.md §navigation.

    Args:
        landmarks: [N, 2] true landmark positions (the simulator's world; the controller sees
            them only through :func:`pqrm_jax.sim.camera` bearings and range ranks).
        rng: the RNG estimate to plan on (:func:`pqrm_jax.qrm.rng_estimate`).
        start: ``[3]`` start pose.
        goal: ``[2]`` goal position.
        params: rover parameters.
        sensor: camera parameters.
        n_steps: the most simulation steps.
        lam: weight of the Alg. 2 edge cost against the hop count in the plan.
        k_turn: heading gain of the bearing controller.
        tol: distance to ``goal`` that counts as arrived.

    Returns:
        The :class:`RNGNavResult` of the run.

    Raises:
        ValueError: for inputs of the wrong shape or with NaN/inf.

    >>> import jax, jax.numpy as jnp
    >>> from pqrm_jax.qrm.hypergraph import true_map
    >>> from pqrm_jax.qrm.rng import rng_estimate
    >>> lm = jnp.array([[10., 10.], [30., 13.], [52., 9.], [70., 12.]])
    >>> res = navigate(lm, rng_estimate(true_map(lm)), jnp.array([8., 8., 0.]),
    ...                jnp.array([72., 14.]))
    >>> bool(res.success), res.path.tolist()
    (True, [0, 1, 2, 3])
    """
    params = RoverParams() if params is None else params
    sensor = sim.SensorParams(max_range=1e6) if sensor is None else sensor
    landmarks = jnp.asarray(landmarks, jnp.float32)
    start = jnp.asarray(start, jnp.float32)
    goal = jnp.asarray(goal, jnp.float32)
    check_nav_inputs(landmarks, start, goal)
    _, nxt = plan_next_hop(rng.edges, rng.cost, lam)
    sensor = sim.SensorParams(*(jnp.asarray(v, jnp.float32) for v in sensor))
    return _navigate(landmarks, nxt, start, goal, params, sensor, n_steps=n_steps,
                     k_turn=k_turn, tol=tol)


def navigate_many(landmarks, rng: RNGEstimate, starts, goals, params=None, sensor=None, *,
                  n_steps: int = 3000, lam: float = 1.0) -> RNGNavResult:
    """:func:`navigate` ``vmap``-ed over start/goal pairs [S, 3] / [S, 2].

    Args:
        landmarks: [N, 2] true landmark positions.
        rng: the RNG estimate to plan on.
        starts: [S, 3] start poses.
        goals: [S, 2] goal positions.
        params: rover parameters.
        sensor: camera parameters.
        n_steps: the most simulation steps.
        lam: weight of the Alg. 2 edge cost against the hop count (M§VII.B).

    Returns:
        The :class:`RNGNavResult` with a leading ``[S]`` axis.
    """
    params = RoverParams() if params is None else params
    sensor = sim.SensorParams(max_range=1e6) if sensor is None else sensor
    sensor = sim.SensorParams(*(jnp.asarray(v, jnp.float32) for v in sensor))
    _, nxt = plan_next_hop(rng.edges, rng.cost, lam)
    landmarks = jnp.asarray(landmarks, jnp.float32)
    starts, goals = jnp.asarray(starts, jnp.float32), jnp.asarray(goals, jnp.float32)
    check_nav_inputs(landmarks, starts, goals, batched=True)
    f = jax.vmap(lambda s, g: _navigate(landmarks, nxt, s, g,
                                        params, sensor, n_steps=n_steps, k_turn=2.0,
                                        tol=0.5))
    return f(starts, goals)


def check_nav_inputs(landmarks, start, goal, batched: bool = False) -> None:
    """Raise ``ValueError`` unless landmarks (N, 2), start (…, 3), goal (…, 2) are finite.

    A NaN landmark would otherwise make every bearing comparison false and the run end
    quietly with ``success=False`` (checked only outside ``jit``: tracers pass).
    """
    lead = (start.shape[:1] if batched and start.ndim else ())
    for nm, x, shp in (("landmarks", landmarks, (landmarks.shape[0], 2) if landmarks.ndim
                        else (None, 2)), ("start", start, (*lead, 3)), ("goal", goal, (*lead, 2))):
        if x.shape != shp:
            want = "(N, 2)" if nm == "landmarks" else str(shp)
            raise ValueError(f"{nm} must have shape {want}, got {x.shape}")
        if not isinstance(x, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(x))):
            raise ValueError(f"{nm} contains NaN or inf")


def summarize(res: RNGNavResult) -> dict:
    """Success rate and path length / straight-line ratio over a batch of runs."""
    ok = np.asarray(res.success)
    ratio = np.asarray(res.length) / np.maximum(np.asarray(res.straight), 1e-9)
    return {"runs": int(ok.size), "success_rate": float(ok.mean()),
            "length_ratio_mean": float(ratio[ok].mean()) if ok.any() else float("nan"),
            "length_ratio_median": float(np.median(ratio[ok])) if ok.any() else float("nan")}
