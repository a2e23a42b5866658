"""The Q-Link trajectory level: arcs, circle searches and straight drives (P §4.3.2, §4.4.1).

"The low level controller drives an arc of radius R in the qualitative state specified by U_i
and searches for reference landmarks in a circle of radius R when necessary" (P §4.4.1).
Geometry used here (decisions, see the study config): the quadrants of the reference pair
(A, B) are 90° wedges with apex at the midpoint M = (A + B)/2 (P Fig. 4.5), so the arc "of
radius R in the qualitative state" is the quarter circle of radius R (the mapping range) about M
inside the commanded wedge (πR/2 long; the four together are the 2πR of P §4.4.1's bound). The
circle search is the circle of radius R′ (the navigating robot's range) about the link landmark.

A :class:`Motion` is "drive straight to ``entry``, then sweep ``sweep`` radians about
``centre`` at ``radius``". :func:`motion_control` turns it into unicycle controls for
:func:`pqrm_jax.sim.step`: turn in place until the heading is right, then drive (straight, or
with ``ω = ±v/r`` on the arc, which the rover integrates exactly), one step of at most
``v_max·dt`` metres. Everything is traceable (``jit``/``vmap``/``while_loop``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["Motion", "QUADRANT_OFFSETS", "quadrant_wedge", "arc_motion", "circle_motion",
           "drive_motion", "motion_control", "advance", "arc_min_distance"]

# wedge start angle relative to the direction A→B, for front-left, front-right, back-left,
# back-right (the ``quadrant`` calculus's state order); each wedge spans +π/2
QUADRANT_OFFSETS = (0.0, -jnp.pi / 2, jnp.pi / 2, -jnp.pi)

_TOL = 1e-4


class Motion(NamedTuple):
    """A trajectory-level command: approach ``entry`` then sweep about ``centre``.

    entry: ``[2]`` point to reach first. centre: ``[2]``. radius: arc radius (0 = no arc).
    sweep: signed angle to sweep (counter-clockwise positive). stage: 0 approaching, 1 on the
    arc. progress: arc length done so far.
    """

    entry: jax.Array
    centre: jax.Array
    radius: jax.Array
    sweep: jax.Array
    stage: jax.Array
    progress: jax.Array


def _wrap(a):
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def quadrant_wedge(a: jax.Array, b: jax.Array, q) -> tuple[jax.Array, jax.Array]:
    """``(centre [2], start angle)`` of quadrant ``q``'s wedge for references ``a``, ``b``.

    >>> c, lo = quadrant_wedge(jnp.array([0., 0.]), jnp.array([2., 0.]), 2)   # back-left
    >>> c.tolist(), round(float(lo), 4)
    ([1.0, 0.0], 1.5708)
    """
    u = b - a
    base = jnp.arctan2(u[1], u[0])
    return 0.5 * (a + b), base + jnp.asarray(QUADRANT_OFFSETS)[q]


def arc_motion(pos, centre, radius, lo) -> Motion:
    """The quarter arc ``[lo, lo + π/2]`` about ``centre``, entered at the end nearer ``pos``.

    >>> m = arc_motion(jnp.array([0., -5.]), jnp.zeros(2), 10.0, -jnp.pi / 2)
    >>> [round(x, 3) + 0.0 for x in m.entry.tolist()], round(float(m.sweep), 4)
    ([0.0, -10.0], 1.5708)
    """
    hi = lo + jnp.pi / 2
    e_lo = centre + radius * jnp.stack([jnp.cos(lo), jnp.sin(lo)])
    e_hi = centre + radius * jnp.stack([jnp.cos(hi), jnp.sin(hi)])
    near_lo = jnp.linalg.norm(e_lo - pos) <= jnp.linalg.norm(e_hi - pos)
    entry = jnp.where(near_lo, e_lo, e_hi)
    sweep = jnp.where(near_lo, jnp.pi / 2, -jnp.pi / 2)
    z = jnp.zeros((), pos.dtype)
    return Motion(entry, centre, jnp.asarray(radius, pos.dtype), sweep.astype(pos.dtype),
                  jnp.int32(0), z)


def circle_motion(pos, centre, radius) -> Motion:
    """One full counter-clockwise turn of radius ``radius`` about ``centre``, entered at the
    point of the circle nearest ``pos``.

    >>> m = circle_motion(jnp.array([0., 3.]), jnp.zeros(2), 1.0)
    >>> [round(x, 3) + 0.0 for x in m.entry.tolist()], round(float(m.sweep), 4)
    ([0.0, 1.0], 6.2832)
    """
    d = pos - centre
    phi = jnp.where(jnp.linalg.norm(d) > 0, jnp.arctan2(d[1], d[0]), 0.0)
    entry = centre + radius * jnp.stack([jnp.cos(phi), jnp.sin(phi)])
    return Motion(entry, centre, jnp.asarray(radius, pos.dtype),
                  jnp.asarray(2 * jnp.pi, pos.dtype), jnp.int32(0), jnp.zeros((), pos.dtype))


def drive_motion(point) -> Motion:
    """Drive straight to ``point`` (e.g. a segment centre or an element centroid, P §4.4.2)."""
    point = jnp.asarray(point)
    z = jnp.zeros((), point.dtype)
    return Motion(point, point, z, z, jnp.int32(0), z)


def motion_control(pose, motion: Motion, v_max, w_max, dt) -> tuple[jax.Array, Motion]:
    """Control ``(v, ω)`` for this step and the motion with its stage updated.

    >>> m = drive_motion(jnp.array([3., 0.]))
    >>> u, _ = motion_control(jnp.zeros(3), m, 1.0, 1.0, 1.0)
    >>> u.tolist()
    [1.0, 0.0]
    """
    pos, th = pose[:2], pose[2]
    to = motion.entry - pos
    dist = jnp.linalg.norm(to)
    stage = jnp.where((motion.stage == 0) & (dist <= 1e-5 * (1 + motion.radius)), 1,
                      motion.stage)
    # approach
    err0 = _wrap(jnp.arctan2(to[1], to[0]) - th)
    # on the arc: heading tangent in the sweep direction
    sgn = jnp.sign(motion.sweep)
    rel = pos - motion.centre
    phi = jnp.arctan2(rel[1], rel[0])
    err1 = _wrap(phi + sgn * jnp.pi / 2 - th)
    remaining = jnp.abs(motion.sweep) * motion.radius - motion.progress
    err = jnp.where(stage == 0, err0, err1)
    turning = jnp.abs(err) > _TOL
    v_go = jnp.where(stage == 0, jnp.minimum(v_max, dist / dt),
                     jnp.minimum(v_max, jnp.maximum(remaining, 0.0) / dt))
    w_go = jnp.where(stage == 0, err / dt,
                     sgn * v_go / jnp.maximum(motion.radius, 1e-30))
    v = jnp.where(turning, 0.0, v_go)
    w = jnp.where(turning, jnp.clip(err / dt, -w_max, w_max), w_go)
    return jnp.stack([v, w]), motion._replace(stage=jnp.asarray(stage, jnp.int32))


def advance(motion: Motion, control, dt) -> tuple[Motion, jax.Array]:
    """Book the step's arc progress; returns ``(motion, done)``."""
    on_arc = motion.stage == 1
    prog = motion.progress + jnp.where(on_arc, control[0] * dt, 0.0)
    total = jnp.abs(motion.sweep) * motion.radius
    done = on_arc & (prog >= total - 1e-5 * (1 + motion.radius))
    return motion._replace(progress=prog), done


def arc_min_distance(point, centre, radius, lo) -> jax.Array:
    """Least distance from ``point`` to the quarter arc ``[lo, lo + π/2]`` (analytic).

    >>> float(arc_min_distance(jnp.array([0., 5.]), jnp.zeros(2), 10.0, 0.0))
    5.0
    """
    rel = point - centre
    ang = _wrap(jnp.arctan2(rel[..., 1], rel[..., 0]) - lo)
    inside = (ang >= 0) & (ang <= jnp.pi / 2)
    on = jnp.abs(jnp.linalg.norm(rel, axis=-1) - radius)
    ends = [centre + radius * jnp.stack([jnp.cos(t), jnp.sin(t)], -1)
            for t in (lo, lo + jnp.pi / 2)]
    d_end = jnp.minimum(jnp.linalg.norm(point - ends[0], axis=-1),
                        jnp.linalg.norm(point - ends[1], axis=-1))
    return jnp.where(inside, on, d_end)



