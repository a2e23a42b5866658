"""Unicycle rover with explicit state and parameters, gymnax style (docs/decisions.md §9).

``state = reset(key, params)``; ``state = step(state, control, params)``;
``final, poses = rollout(state, controls, params)`` (a ``lax.scan``). Everything is a pure
function of pytrees (:class:`RoverParams`, :class:`RoverState`) and can be ``vmap``-ed over
Monte Carlo runs.

The exact chord-form dynamics and the control limits: docs/sim.md §rover.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from pqrm_jax.sim._validate import (
    as_float,
    check_finite,
    check_nonneg,
    check_positive,
    check_shape,
    wrap_angle,
)

__all__ = ["RoverParams", "RoverState", "reset", "step", "rollout", "clip_control"]


class RoverParams(NamedTuple):
    """Rover parameters (a pytree; fields may be traced or batched).

    dt: integration step in seconds. max_speed: bound on ``|v|`` (m/s). max_turn_rate: bound
    on ``|omega|`` (rad/s).
    """

    dt: float = 0.1
    max_speed: float = 2.0
    max_turn_rate: float = 1.0


class RoverState(NamedTuple):
    """Rover state: ``pose`` (3,) = (x, y, theta) and time ``t`` (scalar, seconds)."""

    pose: jax.Array
    t: jax.Array


def check_params(params: RoverParams | None) -> RoverParams:
    if params is None:
        return RoverParams()
    if not isinstance(params, RoverParams):
        raise ValueError(f"params must be a RoverParams, got {type(params).__name__}")
    check_positive("RoverParams.dt", params.dt)
    check_nonneg("RoverParams.max_speed", params.max_speed)
    check_nonneg("RoverParams.max_turn_rate", params.max_turn_rate)
    return params


def _check_state(state: RoverState) -> None:
    if not isinstance(state, RoverState):
        raise ValueError(f"state must be a RoverState, got {type(state).__name__}")
    check_shape("state.pose", state.pose, 1, 3)
    check_finite("state.pose", state.pose)
    check_finite("state.t", state.t)


def _sinc(u):
    small = jnp.abs(u) < 1e-4
    u_safe = jnp.where(small, 1.0, u)
    return jnp.where(small, 1.0 - u * u / 6.0, jnp.sin(u_safe) / u_safe)


def clip_control(control: jax.Array, params: RoverParams) -> jax.Array:
    """Clip ``(v, omega)`` to ``[-max_speed, max_speed] x [-max_turn_rate, max_turn_rate]``.

    Args:
        control: ``[2]`` ``(v, omega)`` (or ``[..., 2]``).
        params: the rover's limits.

    Returns:
        The clipped control, same shape.
    """
    control = as_float(control)
    lim = jnp.stack([jnp.asarray(params.max_speed, control.dtype),
                     jnp.asarray(params.max_turn_rate, control.dtype)])
    return jnp.clip(control, -lim, lim)


def step_kernel(state: RoverState, control, params: RoverParams) -> RoverState:
    x, y, th = state.pose[0], state.pose[1], state.pose[2]
    v, w = clip_control(control, params)
    dt = jnp.asarray(params.dt, state.pose.dtype)
    half = 0.5 * w * dt
    d = v * dt * _sinc(half)
    pose = jnp.stack([x + d * jnp.cos(th + half), y + d * jnp.sin(th + half),
                      wrap_angle(th + w * dt)])
    return RoverState(pose.astype(state.pose.dtype), state.t + dt)


_step_jit = jax.jit(step_kernel)


@jax.jit
def _rollout(state, controls, params):
    def body(s, u):
        s = step_kernel(s, u, params)
        return s, s.pose

    final, poses = jax.lax.scan(body, state, controls)
    return final, jnp.concatenate([state.pose[None], poses], axis=0)


def as_state(state: RoverState) -> RoverState:
    _check_state(state)
    pose = as_float(state.pose)
    return RoverState(pose, jnp.asarray(state.t, pose.dtype))


def reset(
    key: jax.Array,
    params: RoverParams | None = None,
    pose: jax.Array | None = None,
    size: tuple[float, float] = (100.0, 100.0),
) -> RoverState:
    """Initial state at ``pose``, or (``pose=None``) at a pose drawn from ``key``; ``t = 0``.

    Args:
        key: PRNG key (used only when ``pose`` is None).
        params: rover parameters (checked; defaults to ``RoverParams()``).
        pose: ``[3]`` initial pose ``(x, y, theta)``.
        size: box of a drawn pose: position uniform over ``[0, size[0]] x [0, size[1]]``,
            heading uniform in ``[-pi, pi)``.

    Returns:
        The initial :class:`RoverState`.

    Raises:
        ValueError: for bad parameters or a ``pose`` of the wrong shape or with NaN/inf.

    >>> s = reset(jax.random.key(0), RoverParams(), pose=jnp.array([1.0, 2.0, 0.0]))
    >>> s.pose.tolist(), float(s.t)
    ([1.0, 2.0, 0.0], 0.0)
    """
    check_params(params)
    if pose is None:
        return _random_reset(key, jnp.asarray(size, jnp.result_type(float)))
    pose = as_float(pose)
    check_shape("pose", pose, 1, 3)
    check_finite("pose", pose)
    return _given_reset(pose)


@jax.jit
def _random_reset(key, size):
    k_p, k_h = jax.random.split(key)
    xy = jax.random.uniform(k_p, (2,), dtype=size.dtype) * size
    th = jax.random.uniform(k_h, (), dtype=size.dtype, minval=-jnp.pi, maxval=jnp.pi)
    return RoverState(jnp.concatenate([xy, th[None]]), jnp.zeros((), size.dtype))


@jax.jit
def _given_reset(pose):
    return RoverState(pose.at[2].set(wrap_angle(pose[2])), jnp.zeros((), pose.dtype))


def step(
    state: RoverState, control: jax.Array, params: RoverParams | None = None
) -> RoverState:
    """Advance one ``params.dt`` under the (clipped) constant control ``(v, omega)``.

    Args:
        state: current :class:`RoverState`.
        control: ``[2]`` control ``(v, omega)``, clipped to the parameters' limits.
        params: rover parameters (defaults to ``RoverParams()``).

    Returns:
        The next :class:`RoverState` (exact unicycle motion, docs/sim.md §rover).

    Raises:
        ValueError: for bad parameters or a ``control`` of the wrong shape or with NaN/inf.

    >>> s = reset(jax.random.key(0), pose=jnp.zeros(3))
    >>> step(s, jnp.array([1.0, 0.0]), RoverParams(dt=2.0)).pose.tolist()
    [2.0, 0.0, 0.0]
    """
    state = as_state(state)
    params = check_params(params)
    control = as_float(control)
    check_shape("control", control, 1, 2)
    check_finite("control", control)
    return _step_jit(state, control, params)


def rollout(
    state: RoverState, controls: jax.Array, params: RoverParams | None = None
) -> tuple[RoverState, jax.Array]:
    """Apply ``controls`` [T, 2] in sequence (a ``lax.scan`` over :func:`step`).

    Args:
        state: initial :class:`RoverState`.
        controls: [T, 2] controls ``(v, omega)``.
        params: rover parameters (defaults to ``RoverParams()``).

    Returns:
        ``(final_state, poses)`` with ``poses`` [T + 1, 3] and ``poses[0] = state.pose``.

    Raises:
        ValueError: for bad parameters or ``controls`` of the wrong shape or with NaN/inf.

    >>> s = reset(jax.random.key(0), pose=jnp.zeros(3))
    >>> final, poses = rollout(s, jnp.tile(jnp.array([1.0, 0.0]), (20, 1)), RoverParams(dt=0.25))
    >>> poses.shape, final.pose.tolist()
    ((21, 3), [5.0, 0.0, 0.0])
    """
    state = as_state(state)
    params = check_params(params)
    controls = as_float(controls)
    check_shape("controls", controls, 2, 2)
    check_finite("controls", controls)
    return _rollout(state, controls, params)
