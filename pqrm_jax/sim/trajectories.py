"""Trajectories, imaging points and a closed-loop waypoint controller (docs/decisions.md §9).

* :func:`perimeter_loop` -- Padgett's PQRM Monte Carlo trajectory (P §2.3.1): one loop of a
  circle around the perimeter of the 100 m x 100 m environment, one measurement pose every
  16 degrees, heading tangent to the circle.
* :func:`random_imaging_points` -- McClelland's Monte Carlo imaging locations (M §VIII.B).
* :func:`traverse` -- a random path of imaging points 1-2 m apart, like the Mars-Yard traverse
  of M §VIII.C.
* :func:`waypoint_controller` / :func:`follow_waypoints` -- a proportional unicycle controller
  and a ``lax.scan`` that drives a :mod:`sim.rover` through a list of waypoints.

All functions return poses as ``[T, 3]`` arrays of ``(x, y, theta)``; sizes are static Python
ints, everything else may be traced, and the keyed functions ``vmap`` over keys.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from pqrm_jax.sim._validate import (
    as_float,
    check_count,
    check_finite,
    check_nonneg,
    check_positive,
    check_shape,
    wrap_angle,
)
from pqrm_jax.sim.rover import (
    RoverParams,
    RoverState,
    as_state,
    check_params,
    clip_control,
    step_kernel,
)

__all__ = [
    "perimeter_loop",
    "random_imaging_points",
    "traverse",
    "ControllerGains",
    "FollowResult",
    "waypoint_controller",
    "follow_waypoints",
]


def _float():
    return jnp.result_type(float)


def perimeter_loop(
    center: Sequence[float] | jax.Array = (50.0, 50.0),
    radius: float = 50.0,
    dtheta: float = math.radians(16.0),
    start_angle: float = 0.0,
    clockwise: bool = False,
    max_poses: int = 1_000_000,
) -> jax.Array:
    """Poses ``[T, 3]`` on one loop of a circle, one every ``dtheta`` radians.

    Pose ``i`` sits at polar angle ``start_angle +- i * dtheta`` around ``center`` and faces
    along the direction of travel (tangent to the circle). A ``dtheta`` that would give more
    than ``max_poses`` poses (a million by default: e.g. ``dtheta=1e-9`` asks for 6.3·10⁹)
    raises ``ValueError`` instead of returning a huge lazy array that can only fail later;
    raise ``max_poses`` deliberately if you need more.

    Args:
        center: centre of the circle, ``(x, y)``.
        radius: radius of the circle (positive).
        dtheta: angle between poses in radians; must be a concrete number (it fixes the shape).
        start_angle: polar angle of the first pose.
        clockwise: direction of travel.
        max_poses: the most poses allowed.

    Returns:
        [T, 3] poses ``(x, y, theta)`` with ``T = ceil(2 pi / dtheta)`` (23 for the default
        16 degrees).

    Raises:
        ValueError: for a non-positive or non-finite ``dtheta``, more than ``max_poses``
            poses, a bad ``center`` or a non-positive ``radius``.

    >>> poses = perimeter_loop()            # Padgett: 100 m square, a pose every 16 degrees
    >>> poses.shape, [round(float(v), 3) for v in poses[0]]
    ((23, 3), [100.0, 50.0, 1.571])
    """
    dtheta = float(dtheta)
    if not dtheta > 0 or not math.isfinite(dtheta):
        raise ValueError(f"dtheta must be a positive finite angle in radians, got {dtheta}")
    check_shape("center", as_float(center), 1, 2)
    check_finite("center", center)
    check_positive("radius", radius)
    n = math.ceil(2 * math.pi / dtheta - 1e-9)
    if n > max_poses:
        raise ValueError(f"dtheta={dtheta:g} gives {n} poses per loop, more than "
                         f"max_poses={max_poses}; use dtheta ≥ {2 * math.pi / max_poses:.3g} "
                         "or raise max_poses")
    sign = -1.0 if clockwise else 1.0
    return _circle(jnp.asarray(center, _float()), radius, start_angle, sign * dtheta, n)


@partial(jax.jit, static_argnames="n")
def _circle(center, radius, start_angle, dtheta, n):
    phi = start_angle + dtheta * jnp.arange(n, dtype=center.dtype)
    xy = center + radius * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)
    heading = wrap_angle(phi + jnp.sign(dtheta) * 0.5 * jnp.pi)
    return jnp.concatenate([xy, heading[:, None]], axis=-1)


def random_imaging_points(
    key: jax.Array,
    n: int,
    size: Sequence[float] = (100.0, 100.0),
    heading: str | float = "random",
) -> jax.Array:
    """``n`` imaging poses uniform over the box ``[0, size[0]] x [0, size[1]]``.

    Args:
        key: PRNG key.
        n: number of poses.
        size: box side lengths (positive).
        heading: ``"random"`` draws headings uniform in ``[-pi, pi)``; a number gives every
            pose that heading.

    Returns:
        [n, 3] poses ``(x, y, theta)``.

    Raises:
        ValueError: for a bad ``n`` or ``size``, or a ``heading`` that is neither ``"random"``
            nor a number.

    >>> random_imaging_points(jax.random.key(0), 50).shape
    (50, 3)
    """
    n = check_count("n", n)
    check_positive("size", size)
    random_heading = isinstance(heading, str)
    if random_heading and heading != "random":
        raise ValueError(f'heading must be "random" or a number, got {heading!r}')
    return _imaging(key, n, size, 0.0 if random_heading else heading, random_heading)


@partial(jax.jit, static_argnames=("n", "random_heading"))
def _imaging(key, n, size, heading, random_heading):
    k_p, k_h = jax.random.split(key)
    xy = jax.random.uniform(k_p, (n, 2), dtype=_float()) * jnp.asarray(size, _float())
    if random_heading:
        th = jax.random.uniform(k_h, (n,), dtype=_float(), minval=-jnp.pi, maxval=jnp.pi)
    else:
        th = jnp.full((n,), wrap_angle(jnp.asarray(heading, _float())))
    return jnp.concatenate([xy, th[:, None]], axis=-1)


@partial(jax.jit, static_argnames=("n", "random_start"))
def _traverse(key, n, step_min, step_max, start, size, turn_sigma, random_start):
    k_s, k_h, k_l, k_t = jax.random.split(key, 4)
    size = jnp.asarray(size, _float())
    if random_start:
        start = jax.random.uniform(k_s, (2,), dtype=_float()) * size
    th0 = jax.random.uniform(k_h, (), dtype=_float(), minval=-jnp.pi, maxval=jnp.pi)
    lengths = jax.random.uniform(k_l, (n - 1,), dtype=_float(), minval=step_min, maxval=step_max)
    turns = turn_sigma * jax.random.normal(k_t, (n - 1,), dtype=_float())

    def body(carry, inp):
        p, th = carry
        s, dth = inp
        th = th + dth
        d = s * jnp.stack([jnp.cos(th), jnp.sin(th)])
        # Bounce off the walls: flip a displacement component that would leave the box (keeps
        # the step length while the box is wider than two steps), then clip as a last resort.
        q = p + d
        q = jnp.clip(jnp.where((q < 0) | (q > size), p - d, q), 0.0, size)
        d = q - p
        th = jnp.arctan2(d[1], d[0])
        return (q, th), jnp.concatenate([q, th[None]])

    p0 = start
    _, rest = jax.lax.scan(body, (p0, th0), (lengths, turns))
    first = jnp.concatenate([p0, th0[None]])[None]
    return jnp.concatenate([first, rest], axis=0)


def traverse(
    key: jax.Array,
    n: int,
    step_min: float = 1.0,
    step_max: float = 2.0,
    start: Sequence[float] | jax.Array | None = None,
    size: Sequence[float] = (100.0, 100.0),
    turn_sigma: float = 0.5,
) -> jax.Array:
    """A random path of ``n`` imaging poses with steps uniform in ``[step_min, step_max]``.

    The path starts at ``start`` with a random heading; each step turns by a Gaussian angle of
    std ``turn_sigma`` and is mirrored at the walls of the box ``[0, size[0]] x [0, size[1]]``
    (step lengths are exact while the box is wider than ``2 * step_max``). Each pose's heading
    is the direction of the step that reached it (like M §VIII.C: panoramic images every 1-2 m
    of travel).

    Args:
        key: PRNG key.
        n: number of poses (at least 1).
        step_min: shortest step (positive).
        step_max: longest step (at least ``step_min``).
        start: first position ``(x, y)``; default uniform in the box.
        size: box side lengths (positive).
        turn_sigma: std of the turn between steps (radians, non-negative).

    Returns:
        [n, 3] poses ``(x, y, theta)``.

    Raises:
        ValueError: for a bad count, size, step range, ``turn_sigma`` or ``start``.

    >>> path = traverse(jax.random.key(0), 200, start=(10.0, 10.0))
    >>> d = jnp.linalg.norm(jnp.diff(path[:, :2], axis=0), axis=1)
    >>> path.shape, bool((d >= 1 - 1e-4).all() & (d <= 2 + 1e-4).all())
    ((200, 3), True)
    """
    n = check_count("n", n, minimum=1)
    check_positive("size", size)
    check_positive("step_min", step_min)
    check_nonneg("turn_sigma", turn_sigma)
    check_nonneg("step_max - step_min", jnp.asarray(step_max) - jnp.asarray(step_min))
    random_start = start is None
    if random_start:
        start = jnp.zeros((2,), _float())  # drawn from the key inside _traverse
    else:
        start = as_float(start)
        check_shape("start", start, 1, 2)
        check_finite("start", start)
    return _traverse(key, n, step_min, step_max, start.astype(_float()), size, turn_sigma,
                     random_start)


class ControllerGains(NamedTuple):
    """Gains of :func:`waypoint_controller`: ``v = k_v * distance``, ``omega = k_omega * error``."""

    k_v: float = 1.0
    k_omega: float = 2.0


class FollowResult(NamedTuple):
    """Result of :func:`follow_waypoints`.

    state: final :class:`~sim.rover.RoverState`. poses: (n_steps + 1, 3) including the start.
    targets: (n_steps,) int32 index of the waypoint driven towards at each step (``W`` once
    all are reached). n_reached: scalar int32, waypoints reached by the end (``W`` = all).
    """

    state: RoverState
    poses: jax.Array
    targets: jax.Array
    n_reached: jax.Array


def _controller(pose, waypoint, gains, params):
    d = waypoint - pose[:2]
    dist = jnp.sqrt(jnp.sum(d**2))
    err = wrap_angle(jnp.arctan2(d[1], d[0]) - pose[2])
    v = gains.k_v * dist * jnp.maximum(jnp.cos(err), 0.0)
    return clip_control(jnp.stack([v, gains.k_omega * err]), params)


_controller_jit = jax.jit(_controller)


def waypoint_controller(
    pose: jax.Array,
    waypoint: jax.Array,
    gains: ControllerGains | None = None,
    params: RoverParams | None = None,
) -> jax.Array:
    """Proportional go-to-point control ``(v, omega)`` for a unicycle.

    ``omega = k_omega * e`` with ``e`` the heading error to the waypoint (wrapped to
    ``[-pi, pi)``), ``v = k_v * distance * max(cos e, 0)`` (turn on the spot when the waypoint
    is behind), both clipped to the rover's limits. Converges for ``k_v * dt < 1``.

    Args:
        pose: ``[3]`` ``(x, y, theta)``.
        waypoint: ``[2]``.
        gains: controller gains (default ``ControllerGains()``).
        params: the rover (its limits; default ``RoverParams()``).

    Returns:
        ``[2]`` control ``(v, omega)``.

    >>> waypoint_controller(jnp.zeros(3), jnp.array([1.0, 0.0])).tolist()
    [1.0, 0.0]
    """
    pose, waypoint = as_float(pose), as_float(waypoint)
    check_shape("pose", pose, 1, 3)
    check_shape("waypoint", waypoint, 1, 2)
    check_finite("pose", pose)
    check_finite("waypoint", waypoint)
    params = check_params(params)
    gains = ControllerGains() if gains is None else gains
    return _controller_jit(pose, waypoint.astype(pose.dtype), gains, params)


@partial(jax.jit, static_argnames="n_steps")
def _follow(state, waypoints, params, n_steps, tol, gains):
    w = waypoints.shape[0]

    def advance(pose, idx):
        wp = waypoints[jnp.minimum(idx, w - 1)]
        hit = (jnp.sum((wp - pose[:2]) ** 2) < tol**2) & (idx < w)
        return idx + hit.astype(jnp.int32)

    def body(carry, _):
        s, idx = carry
        idx = advance(s.pose, idx)
        u = _controller(s.pose, waypoints[jnp.minimum(idx, w - 1)], gains, params)
        u = jnp.where(idx < w, u, jnp.zeros_like(u))
        s = step_kernel(s, u, params)
        return (s, idx), (s.pose, idx)

    (final, idx), (poses, targets) = jax.lax.scan(
        body, (state, jnp.zeros((), jnp.int32)), None, length=n_steps)
    n_reached = advance(final.pose, idx)
    return FollowResult(final, jnp.concatenate([state.pose[None], poses]), targets, n_reached)


def follow_waypoints(
    state: RoverState,
    waypoints: jax.Array,
    params: RoverParams | None = None,
    n_steps: int = 1000,
    tol: float = 0.5,
    gains: ControllerGains | None = None,
) -> FollowResult:
    """Drive the rover through ``waypoints`` [W, 2] in order for ``n_steps`` steps.

    A waypoint counts as reached when the rover is within ``tol`` of it; the controller then
    moves on to the next one, and the rover stops (zero control) after the last.

    Args:
        state: the rover's start.
        waypoints: ``[W, 2]``.
        params: the rover (default ``RoverParams()``).
        n_steps: simulation steps (static).
        tol: reach distance.
        gains: controller gains.

    Returns:
        :class:`FollowResult` (poses ``[n_steps + 1, 3]``, targets ``[n_steps]``, waypoints
        reached).

    >>> from pqrm_jax.sim.rover import reset
    >>> s = reset(jax.random.key(0), pose=jnp.zeros(3))
    >>> square = jnp.array([[5.0, 0.0], [5.0, 5.0], [0.0, 5.0], [0.0, 0.0]])
    >>> res = follow_waypoints(s, square, RoverParams(), n_steps=600)
    >>> int(res.n_reached)
    4
    """
    state = as_state(state)
    params = check_params(params)
    gains = ControllerGains() if gains is None else gains
    waypoints = as_float(waypoints)
    check_shape("waypoints", waypoints, 2, 2)
    check_finite("waypoints", waypoints)
    check_positive("tol", tol)
    n_steps = check_count("n_steps", n_steps)
    return _follow(state, waypoints.astype(state.pose.dtype), params, n_steps, tol, gains)
