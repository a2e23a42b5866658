"""Exploration and navigation driven by the simulator and the HSSH local levels (B §8.1, §7.1.3).

The abstract :class:`~pqrm_jax.hssh_global.world.CorridorWorld` is rendered into an occupancy
grid (:func:`sim_world`): every place-to-place corridor becomes a free rectangle of width ``w``
(``SimParams.width`` times the shortest corridor), drawn with
:func:`pqrm_jax.sim.corridors.render_free_rectangles`. A unicycle rover
(:mod:`pqrm_jax.sim.rover`) drives in it; each control step is one jitted ``lax.scan`` body:

1. the carrot controller (:func:`pqrm_jax.sim.waypoint_controller`) steers the *odometry* pose
   towards a carrot: a point ``look`` ahead on a line (a gateway midpoint and its outward normal
   while travelling, B §7.1.3's gateway targets) or a fixed point (the place centre);
2. the true pose moves with the commanded ``(v, ω)`` corrupted by scale-free Gaussian noise
   (sd ``sigma_v · |v|`` and ``sigma_w · |v| / w``); the odometry pose integrates the commands,
   so dead-reckoning error accumulates as on a real rover;
3. a lidar scan from the true pose (:func:`pqrm_jax.sim.lidar_scan`) updates the scrolling LPM
   at the odometry pose (:func:`pqrm_jax.hssh.lpm_update`, B §4.1).

Every ``check_every`` steps the host runs the local topology of the LPM
(:func:`pqrm_jax.hssh.local_topology`, unknown cells counted as walls, rows flipped so stars are
world-clockwise) and classifies the view (B §5.3.2): ``"path"`` while in a corridor; once the
rover has left the last place (odometry distance more than half the LPM side), a ``"place"`` or
``"dead_end"`` starts the approach: the carrot becomes the core centre (re-estimated at each
check) and, when the rover stands on it, the view ⟨star, arrival entry⟩ is read with
:func:`~pqrm_jax.hssh_global.star.view_from_local_star`, the arrival gateway being the one whose
outward normal points most nearly back along the travel direction. The *dividing pose* of the
place is the core centre with the heading of the arrival entry (its angle in the star), in the
odometry frame; ``λ_i`` is the SE(2) displacement between consecutive dividing poses.

The exploration policy (:func:`explore_sim`) takes a gateway not traversed yet, else a random
one other than the U-turn, as :func:`~pqrm_jax.hssh_global.world.explore` does; only this
*choice* uses the ground truth (which true gateway an observed entry is). Everything fed to the
tree of maps comes from the LPM and odometry. The ground truth recorded beside it (true place,
arrival entry, displacement) is for evaluation: the true place is the world place nearest to the
true rover position, which must lie within ``w`` of it, else :class:`SimulationError` is raised.

Navigation (:func:`navigate_sim`) executes the turn commands of a route
(:func:`~pqrm_jax.hssh_global.navigation.plan_route`) with the same travel machinery: at each
place the command is applied to the *observed* star. :func:`global_occupancy` projects the LPM
snapshots taken at the places from the relaxed place poses (the global map ``m*`` of B ch. 9).

Everything is measured in corridor widths, so results do not change with units.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pqrm_jax import hssh
from pqrm_jax import sim as _sim

from .layout import se2_compose, se2_compose_host, se2_inverse, se2_inverse_host
from .navigation import apply_command, shortest_distance
from .star import view_from_local_star
from .world import CorridorWorld, Experience

__all__ = ["SimParams", "SimWorld", "SimExperience", "SimulationError", "sim_world",
           "explore_sim", "navigate_sim", "evaluate_navigation_sim", "global_occupancy",
           "map_agreement", "true_layout_sim", "revisit_jitter"]


class SimulationError(RuntimeError):
    """The rover lost its way: no place found in time, or a place the world does not have."""


class SimParams(NamedTuple):
    """Simulation settings, lengths in corridor widths ``w`` (scale-free).

    width: corridor width as a fraction of the shortest corridor.
    cells: LPM cells across a corridor (B §6.3.3 wants at least 13 for reliable gateways).
    lpm_widths: LPM side in corridor widths (an intersection and the start of its arms).
    speed: top speed in ``w`` per second; ``turn_rate`` in rad/s; ``dt`` the control step (s).
    look: carrot look-ahead in ``w``.
    centring: gain of the follow-midline correction (the carrot moves towards the corridor
        midline measured by the lidar, so a tilted gateway normal does not steer into a wall).
    check_every: control steps between two local-topology checks.
    n_beams: lidar beams (full circle); ``range_widths`` lidar range in ``w``.
    sigma_v: relative sd of the executed speed; ``sigma_w`` heading-rate sd per ``w`` travelled.
    arrive_tol: distance to the core centre (in ``w``) at which the view is read.
    dead_end_wall: a dead end's view is read once its end wall is this close ahead (in ``w``;
        the dead end's place, the end of the corridor's centre line, lies ``w / 2`` before the
        wall). A dead end has no skeleton junction, so its core centre is the rover's own
        cell wherever the rover stands; without this rule the place was recorded where the
        end wall first came into view (up to ``lpm_widths / 2`` away, issue 26).
    rereads: nudged re-reads of a place view whose gateways cross.
    max_checks: topology checks per travel before :class:`SimulationError`.
    """

    width: float = 0.2
    cells: int = 14
    lpm_widths: float = 3.2
    speed: float = 1.0
    turn_rate: float = 1.5
    dt: float = 0.1
    look: float = 0.8
    centring: float = 2.0
    check_every: int = 4
    n_beams: int = 180
    range_widths: float = 2.5
    sigma_v: float = 0.02
    sigma_w: float = 0.02
    arrive_tol: float = 0.1
    dead_end_wall: float = 0.5
    rereads: int = 4
    max_checks: int = 60


class SimWorld(NamedTuple):
    """A rendered corridor world.

    occupied: bool ``[R, C]`` (rows along y, the :mod:`pqrm_jax.sim.lidar` convention).
    resolution: world cell size; ``origin``: world (x, y) of cell (0, 0)'s corner.
    world: the abstract ground truth; ``width``: corridor width (world units).
    params: the :class:`SimParams` it was rendered with (the rover uses them too).
    """

    occupied: jax.Array
    resolution: float
    origin: tuple
    world: CorridorWorld
    width: float
    params: SimParams


class SimExperience(NamedTuple):
    """An exploration in the simulator.

    experience: the :class:`~pqrm_jax.hssh_global.world.Experience` fed to the tree of maps.
    snapshots: ``n+1`` LPM log-odds ``[N, N]`` at each place (rows along y).
    snap_poses: ``[n+1, 3]`` odometry dividing pose of each view.
    snap_origins: ``[n+1, 2]`` odometry-frame origin of each snapshot.
    true_poses: ``[n+1, 3]`` true rover pose when each view was read.
    true_dividing: ``[n+1, 3]`` true dividing pose of each view (the odometry dividing pose
        relative to the rover, moved to the true rover pose): ``experience.true_odometry`` is
        between these, so odometry error is dead-reckoning error only.
    distance: true distance driven (world units).
    checks: local-topology runs.
    rejected: place views refused because their gateways crossed (then re-read).
    """

    experience: Experience
    snapshots: np.ndarray
    snap_poses: np.ndarray
    snap_origins: np.ndarray
    true_poses: np.ndarray
    true_dividing: np.ndarray
    distance: float
    checks: int
    rejected: int


def sim_world(world: CorridorWorld, params: SimParams | None = None,
              supersample: int = 2) -> SimWorld:
    """Renders an abstract corridor world into an occupancy grid for the simulator.

    The lidar grid has twice the LPM resolution (``2 · cells`` cells per corridor width). Each
    corridor is a rectangle of width ``w`` from place to place, extended by ``w / 2`` beyond both
    places so junctions and corners are filled and dead ends close ``w / 2`` past the place.

    Args:
        world: the abstract corridor world.
        params: the simulation parameters (default :class:`SimParams`).
        supersample: lidar cells per LPM cell.

    Returns:
        The :class:`SimWorld` (occupancy grid, geometry, the world).

    >>> from pqrm_jax.hssh_global.world import office_world
    >>> sw = sim_world(office_world())
    >>> sw.occupied.dtype, round(sw.width, 3)
    (dtype('bool'), 0.2)
    """
    params = SimParams() if params is None else params
    if not 0 < params.width < 0.6:
        raise ValueError(f"width must be in (0, 0.6) of the shortest corridor, got {params.width}")
    unit = min(d for (_, _, d) in world.edges.values())
    w = params.width * unit
    res = w / (2 * params.cells)
    lo = world.positions.min(0) - 1.5 * params.lpm_widths * w
    hi = world.positions.max(0) + 1.5 * params.lpm_widths * w
    side = int(math.ceil(float((hi - lo).max()) / res))
    ext = side * res
    rects, seen = [], set()
    for (p, _), (q, _, _) in world.edges.items():
        a, b = world.positions[p], world.positions[q]
        key = (min(p, q), max(p, q), tuple(np.round((a + b) / 2, 9)))
        if key in seen:
            continue
        seen.add(key)
        d = b - a
        length = float(np.hypot(*d))
        mid = (a + b) / 2 - lo
        rects.append((mid[0] / ext, mid[1] / ext, (length + w) / ext, w / ext,
                      math.atan2(d[1], d[0])))
    img = np.asarray(_sim.corridors.render_free_rectangles(side, rects, supersample))
    occupied = jnp.asarray((img < 128)[::-1])
    return SimWorld(occupied, float(res), (float(lo[0]), float(lo[1])), world, float(w),
                    params)


class _Drive(NamedTuple):
    true_pose: jax.Array
    odom_pose: jax.Array
    lpm: hssh.LPMState
    key: jax.Array
    travelled: jax.Array


def _consts(sw: SimWorld, p: SimParams):
    w = sw.width
    n = int(round(p.lpm_widths * p.cells)) | 1
    lpm = hssh.LPMParams(size=n, resolution=float(w / p.cells))
    rover = _sim.RoverParams(dt=float(p.dt), max_speed=float(p.speed * w),
                             max_turn_rate=float(p.turn_rate))
    lidar = _sim.LidarParams(n_beams=int(p.n_beams), max_range=float(p.range_widths * w))
    return lpm, rover, lidar


@partial(jax.jit, static_argnames=("n_steps", "lpm_p", "rover_p", "lidar_p", "grid_res",
                                   "grid_origin", "noise"))
def _drive(state, grid, target, direction, look, n_steps, lpm_p, rover_p, lidar_p, grid_res,
           grid_origin, noise):
    sigma_v, sigma_w_per_len, centring = noise

    def body(s, _):
        k0, k1, k2 = jax.random.split(s.key, 3)
        t = jnp.zeros((), s.true_pose.dtype)
        scan = _sim.lidar_scan(k1, s.true_pose, grid, grid_res, grid_origin, lidar_p)
        lpm = hssh.lpm_update(s.lpm, s.odom_pose, scan, lpm_p)
        # follow-midline: lateral offset of the corridor midline from the scan, measured
        # perpendicular to the travel direction (beams within 30 degrees of either normal)
        rel_ang = scan.angles + s.odom_pose[2] - jnp.arctan2(direction[1], direction[0])
        side = jnp.sin(rel_ang) * scan.ranges
        lateral = jnp.abs(jnp.cos(rel_ang)) < 0.5
        inf = jnp.asarray(1e9, side.dtype)
        left = jnp.min(jnp.where(lateral & scan.hit & (side > 0), side, inf))
        right = jnp.min(jnp.where(lateral & scan.hit & (side < 0), -side, inf))
        seen = (left < inf) & (right < inf) & (jnp.sum(direction ** 2) > 0)
        offset = jnp.where(seen, 0.5 * (left - right), 0.0)
        normal = jnp.stack([-direction[1], direction[0]])
        rel = s.odom_pose[:2] - target
        carrot = (target + direction * (jnp.dot(rel, direction) + look)
                  + jnp.where(seen, jnp.dot(rel, normal) + centring * offset, 0.0) * normal)
        u = _sim.waypoint_controller(s.odom_pose, carrot, None, rover_p)
        eps = jax.random.normal(k0, (2,))
        v_true = u[0] * (1.0 + sigma_v * eps[0])
        w_true = u[1] + sigma_w_per_len * jnp.abs(u[0]) * eps[1]
        true = _sim.rover.step_kernel(_sim.RoverState(s.true_pose, t),
                                      jnp.stack([v_true, w_true]), rover_p).pose
        odom = _sim.rover.step_kernel(_sim.RoverState(s.odom_pose, t), u, rover_p).pose
        moved = jnp.hypot(*(true[:2] - s.true_pose[:2]))
        return _Drive(true, odom, lpm, k2, s.travelled + moved), None

    out, _ = jax.lax.scan(body, state, None, length=n_steps)
    return out


class _Rover:
    """Host side of one simulated rover: drive, read the local topology, convert frames."""

    def __init__(self, sw: SimWorld, p: SimParams, pose, key):
        self.sw, self.p = sw, p
        self.lpm_p, self.rover_p, self.lidar_p = _consts(sw, p)
        pose = jnp.asarray(pose, jnp.float32)
        self.s = _Drive(pose, pose, hssh.lpm_init(pose, self.lpm_p), key,
                        jnp.zeros((), jnp.float32))
        self.checks = 0
        self.rejected = 0          # place views refused because their gateways cross
        self.trace: list = []      # (true pose, kind or None) of every topology check
        noise = (float(p.sigma_v), float(p.sigma_w / sw.width), float(p.centring))
        self._kw = dict(lpm_p=self.lpm_p, rover_p=self.rover_p, lidar_p=self.lidar_p,
                        grid_res=sw.resolution, grid_origin=sw.origin, noise=noise)

    def drive(self, target, direction, look, n_steps):
        self.s = _drive(self.s, self.sw.occupied, jnp.asarray(target, jnp.float32),
                        jnp.asarray(direction, jnp.float32), jnp.float32(look),
                        n_steps=int(n_steps), **self._kw)

    # frames: LPM image (flipped rows, (row, col) cell indices) <-> odometry (x, y)
    def to_odom(self, rc):
        n, r = self.lpm_p.size, self.lpm_p.resolution
        o = np.asarray(self.s.lpm.origin, float)
        rc = np.asarray(rc, float)
        return np.array([o[0] + (rc[1] + 0.5) * r, o[1] + (n - 1 - rc[0] + 0.5) * r])

    @staticmethod
    def vec_to_odom(drc):
        return np.array([float(drc[1]), -float(drc[0])])

    def topology(self):
        """Local topology of the LPM at the rover (None when the pipeline refuses the grid)."""
        self.checks += 1
        occ, unk = hssh.lpm_classify(self.s.lpm, self.lpm_p)
        blocked = np.asarray(occ | unk)[::-1]
        n = self.lpm_p.size
        try:
            lt = hssh.local_topology(blocked, (n - 1 - n // 2, n // 2))
        except ValueError:
            lt = None
        self.trace.append((self.true(), None if lt is None else lt.kind))
        return lt

    def odom(self):
        return np.asarray(self.s.odom_pose, float)

    def wall_ahead(self, direction) -> float:
        """Distance (world units) from the rover along ``direction`` (odometry frame, unit) to
        the first occupied or unknown LPM cell (the LPM border when none)."""
        occ, unk = hssh.lpm_classify(self.s.lpm, self.lpm_p)
        blocked = np.asarray(occ | unk)
        n, r = self.lpm_p.size, float(self.lpm_p.resolution)
        o = np.asarray(self.s.lpm.origin, float) + np.asarray(self.s.lpm.origin_lo, float)
        t = np.arange(1, 2 * n) * (0.5 * r)
        pts = self.odom()[:2][None, :] + t[:, None] * np.asarray(direction, float)[None, :]
        j = np.floor((pts[:, 0] - o[0]) / r).astype(int)
        i = np.floor((pts[:, 1] - o[1]) / r).astype(int)
        inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        stop = ~inside
        stop[inside] = blocked[i[inside], j[inside]]
        k = int(np.argmax(stop)) if stop.any() else len(t) - 1
        return float(t[k])

    def true(self):
        return np.asarray(self.s.true_pose, float)


def _heading_of(angle_deg: float) -> float:
    """World heading (ccw from +x) of a star angle (clockwise degrees from "up")."""
    return float((np.pi / 2 - np.radians(angle_deg) + np.pi) % (2 * np.pi) - np.pi)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


class _Arrival(NamedTuple):
    view: tuple
    bearings: tuple
    entries: tuple
    gateway_lines: dict       # observed entry -> (midpoint odom, outward odom)
    pose: np.ndarray          # odometry dividing pose
    true_pose: np.ndarray     # true rover pose at the reading
    odom_pose: np.ndarray     # odometry rover pose at the reading


def _gateway_axes(lt) -> np.ndarray:
    """Corridor axis ``[G, 2]`` (row, col unit vectors) leaving through each gateway.

    The pruned skeleton runs along the midline of the corridor beyond a gateway to an exit at
    the LPM border; the axis is the direction from the gateway's skeleton point to the exit
    best aligned with its outward normal (cosine at least 0.7), else the normal itself. Anchor
    gateways at L corners are sometimes diagonal (B Fig. 6.36), their normals then point up to
    45° off the corridor, while the skeleton does not.
    """
    out = np.asarray(lt.outward, float).reshape(-1, 2).copy()
    exits = np.asarray(lt.skeleton.exits, float).reshape(-1, 2)
    for g, rec in enumerate(lt.details):
        if len(exits) == 0:
            break
        d = exits - np.asarray(rec.centre, float)[None, :]
        n = np.hypot(d[:, 0], d[:, 1])
        ok = n > 1.0
        if not ok.any():
            continue
        cos = np.where(ok, (d @ out[g]) / np.where(ok, n, 1.0), -1.0)
        k = int(np.argmax(cos))
        if cos[k] >= 0.7:
            out[g] = d[k] / n[k]
    return out


def _star_entries(lt) -> list:
    """The star of a local topology with every entry placed by its gateway normal.

    The pairing of gateways into local paths is the local levels' (path continuity, B §5.2.2);
    each traversable entry sits at the angle of its corridor axis (:func:`_gateway_axes`) and
    the non-traversable opposite of an unpaired gateway at the opposite angle (the direction of
    B's inward ray). :func:`pqrm_jax.hssh.build_star` places the latter where a
    short ray from the gateway midpoint ends, which is unstable when the midpoint lies near the
    core centre (seen at L corners with a tilted gateway: the two non-traversable entries swap).
    """
    axes = _gateway_axes(lt)
    groups: dict = {}
    for e in lt.entries:
        if e.traversable:
            groups.setdefault(e.path, []).append(e.gateway)
    raw = []
    for grp, gws in groups.items():
        for g in gws:
            raw.append((hssh.star.clockwise_angle(axes[g]), True, g, grp))
        if len(gws) == 1:
            raw.append((hssh.star.clockwise_angle(-axes[gws[0]]), False, -1, grp))
    raw.sort(key=lambda t: (round(t[0], 9), not t[1]))
    ids: dict = {}
    seen: set = set()
    out = []
    for ang, trav, gw, grp in raw:
        ids.setdefault(grp, len(ids))
        if len(groups[grp]) == 2:
            direction = -1 if grp in seen else 1
        else:
            direction = 1 if trav else -1
        seen.add(grp)
        out.append(hssh.StarEntry(ids[grp], direction, trav, gw, ang))
    return out


def _read_view(rv: _Rover, lt, travel_dir) -> _Arrival:
    """The view, entry bearings, exit lines and dividing pose of the place in view.

    The arrival gateway is the one whose outward normal points most nearly back along the
    travel direction. The dividing pose heading is the travel direction (the corridor axis from
    the odometry track); entry bearings are the corridor axes of the gateways
    (:func:`_gateway_axes`) relative to it (a non-traversable entry: its opposite's bearing plus
    π). Exit lines run from a gateway's skeleton point along its axis.
    """
    outs = np.array([rv.vec_to_odom(o) for o in lt.outward]).reshape(-1, 2)
    travel_dir = np.asarray(travel_dir, float) / np.linalg.norm(travel_dir)
    back = outs @ (-travel_dir)
    g = int(np.argmax(back))
    if back[g] < 0.7:
        raise SimulationError(f"no gateway behind the rover (best cosine {back[g]:.2f})")
    entries = _star_entries(lt)
    axes = np.array([rv.vec_to_odom(o) for o in _gateway_axes(lt)]).reshape(-1, 2)
    view, _ = view_from_local_star(entries, g)
    star, arr = view
    heading = float(np.arctan2(travel_dir[1], travel_dir[0]))
    head = [None] * len(star)
    for i, e in enumerate(entries):
        if e.traversable:
            head[i] = float(np.arctan2(axes[e.gateway][1], axes[e.gateway][0]))
    for i in range(len(star)):
        if head[i] is None:
            head[i] = head[star.opp[i]] + np.pi
    bear = tuple(float(_wrap(b - heading)) for b in head)
    centre = rv.to_odom(lt.core.centre)
    pose = np.array([*centre, heading])
    lines = {}
    for i, e in enumerate(entries):
        if e.traversable:
            mid = rv.to_odom(lt.details[e.gateway].centre)
            lines[i] = (mid, axes[e.gateway])
    return _Arrival(view, bear, tuple(entries), lines, pose, rv.true(), rv.odom())


def _segments_cross(a, b) -> bool:
    """Do the open segments ``a`` and ``b`` (``[2, 2]``) properly intersect?"""
    def orient(p, q, r):
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))
    return bool(orient(a[0], a[1], b[0]) * orient(a[0], a[1], b[1]) < 0
                and orient(b[0], b[1], a[0]) * orient(b[0], b[1], a[1]) < 0)


def _sane(lt) -> bool:
    """A place view whose gateways do not cross one another (two crossing gateways cannot
    both bound the place: a known failure of anchor gateways at corners, B Fig. 6.36)."""
    g = lt.gateways
    return not any(_segments_cross(g[i], g[j]) for i in range(len(g))
                   for j in range(i + 1, len(g)))


def _settled_view(rv: _Rover, centre) -> object | None:
    """Read the place view at ``centre`` after two more control steps of scans.

    A view with crossing gateways is not read: the rover nudges by a quarter width (a different
    whole-cell scroll of the LPM) in turn along four directions and reads again, up to
    ``SimParams.rereads`` times; ``None`` when no sane place view comes.
    """
    w = rv.sw.width
    zero = np.zeros(2)
    target = np.asarray(centre, float)
    for k in range(rv.p.rereads + 1):
        rv.drive(target, zero, 0.0, 2 if k == 0 else rv.p.check_every)
        lt = rv.topology()
        if lt is None or lt.kind not in ("place", "dead_end") or lt.core is None:
            return None
        if _sane(lt):
            return lt
        rv.rejected += 1
        ang = 0.5 * np.pi * k + np.pi / 4
        target = np.asarray(centre, float) + 0.25 * w * np.array([np.cos(ang), np.sin(ang)])
    return None


def _corridor_axis(track, out, w) -> np.ndarray:
    """Travel direction at arrival: the odometry track along the corridor (the follow-midline
    behaviour keeps it parallel to the walls) when it spans at least ``w / 2``, else ``out``."""
    if len(track) >= 2:
        d = np.asarray(track[-1]) - np.asarray(track[0])
        if np.hypot(*d) >= 0.5 * w:
            return d / np.hypot(*d)
    return np.asarray(out, float)


def _approach(rv: _Rover, line, travel_dir, leave_from=None) -> _Arrival:
    """Drive along ``line`` until a place is in view, then settle on its core centre.

    While the rover is within half an LPM side of ``leave_from`` (the place it is leaving) the
    views are not read. Afterwards each check either steers to the core centre of the place or
    dead end in view, or (a ``"path"`` view, or a grid the local levels refuse) keeps following
    the line. The view is read once the rover stands within ``arrive_tol`` of the core centre,
    after two more control steps of scans at that spot.
    """
    p, w = rv.p, rv.sw.width
    mid, out = (np.asarray(x, float) for x in line)
    zero = np.zeros(2)
    leave = 0.5 * p.lpm_widths * w
    track: list = []   # odometry positions while following the corridor
    rejected0, settled = rv.rejected, 0
    for _ in range(p.max_checks):
        away = leave_from is None or np.hypot(*(rv.odom()[:2] - leave_from)) > leave
        lt = rv.topology()
        if (away and lt is not None and lt.kind == "dead_end" and lt.core is not None
                and len(lt.outward) == 1):
            # a dead end: its core centre is the rover's own cell, so drive on towards the
            # end wall (away from the one gateway) until it is dead_end_wall widths ahead
            ahead = -rv.vec_to_odom(lt.outward[0])
            ahead = ahead / np.hypot(*ahead)
            gap = rv.wall_ahead(ahead) - p.dead_end_wall * w
            if gap > p.arrive_tol * w:
                rv.drive(rv.odom()[:2] + gap * ahead, zero, 0.0, p.check_every)
                continue
        if (away and lt is not None and lt.kind in ("place", "dead_end")
                and lt.core is not None):
            c = rv.to_odom(lt.core.centre)
            if np.hypot(*(c - rv.odom()[:2])) <= p.arrive_tol * w:
                settled += 1
                lt2 = _settled_view(rv, c)
                if lt2 is not None:
                    return _read_view(rv, lt2, _corridor_axis(track, out, w))
            rv.drive(c, zero, 0.0, p.check_every)
            continue
        if away:
            track.append(rv.odom()[:2])
        if lt is not None and lt.kind == "path":
            # path following: the carrot line is the gateway ahead (B §7.1.3)
            outs = np.array([rv.vec_to_odom(o) for o in lt.outward]).reshape(-1, 2)
            ahead = outs @ out
            g = int(np.argmax(ahead))
            if ahead[g] > 0.9:
                mid, out = rv.to_odom(np.mean(lt.gateways[g], axis=0)), outs[g]
        rv.drive(mid, out, p.look * w, p.check_every)
    kinds = [k for _, k in rv.trace[-p.max_checks:]]
    why = ""
    if rv.rejected > rejected0:
        # the rover stood on a core centre but every read had crossing gateways: a local-level
        # gateway failure (an anchor gateway across the junction, B Fig. 6.36), not a drive error
        why = (f"; {settled} settles on a core centre, {rv.rejected - rejected0} place views "
               "refused because their gateways cross (local-level gateway defect)")
    raise SimulationError(f"no place reached within {p.max_checks} checks (true pose "
                          f"{np.round(rv.true(), 3).tolist()}; last views {kinds[-6:]}{why})")


def _travel(rv: _Rover, here: _Arrival, exit_entry: int) -> _Arrival:
    """Leave through the gateway of ``exit_entry``, follow the corridor, settle at the next
    place."""
    line = here.gateway_lines[exit_entry]
    return _approach(rv, line, line[1], leave_from=here.pose[:2])


def _params(sw: SimWorld, params: SimParams | None) -> SimParams:
    if params is None:
        return sw.params
    if (params.width, params.cells, params.lpm_widths) != (sw.params.width, sw.params.cells,
                                                           sw.params.lpm_widths):
        raise ValueError("params.width, cells and lpm_widths must be the ones the world was "
                         "rendered with (sim_world)")
    return params


def _true_place(sw: SimWorld, xy) -> int:
    d = np.hypot(*(sw.world.positions - np.asarray(xy)[None, :]).T)
    q = int(np.argmin(d))
    if d[q] > sw.width:
        raise SimulationError(f"the rover read a place {d[q] / sw.width:.2f} corridor widths "
                              "from any world place")
    return q


def _true_entry(world: CorridorWorld, q: int, heading: float) -> int:
    b = np.asarray(world.bearings[q])
    return int(np.argmin(np.abs(_wrap(b - heading))))


def _start(sw: SimWorld, params: SimParams, place: int, arrival: int, key):
    """A rover at ``place`` heading along its entry ``arrival``; reads the first view."""
    world = sw.world
    heading = world.bearings[place][arrival]
    pose = np.array([*world.positions[place], heading])
    rv = _Rover(sw, params, pose, key)
    rv.drive(pose[:2], np.zeros(2), 0.0, 2)
    d = np.array([np.cos(heading), np.sin(heading)])
    return rv, _approach(rv, (pose[:2], d), d)


def _true_dividing(a: _Arrival, odom_pose) -> np.ndarray:
    """The dividing pose moved from the odometry frame to the true frame via the rover pose."""
    rel = se2_compose(se2_inverse(np.asarray(odom_pose, float)), a.pose)
    return np.asarray(se2_compose(a.true_pose, rel))


def explore_sim(sw: SimWorld, n_travels: int, seed: int = 0, params: SimParams | None = None,
                start: int | None = None) -> SimExperience:
    """Explores a rendered world with the simulated rover and the local levels (B §8.1, §8.4).

    Args:
        sw: from :func:`sim_world`.
        n_travels: travel actions (``≥ 0``).
        seed: seed of the policy, the start and the noise.
        params: :class:`SimParams` (default ``sw.params``; ``width``, ``cells`` and
            ``lpm_widths`` must be those ``sw`` was rendered with).
        start: start place (random when ``None``).

    Returns:
        :class:`SimExperience`; ``.experience`` feeds :func:`~pqrm_jax.hssh_global.build_tree`.

    Raises:
        SimulationError: the rover did not find a place, or read one the world does not have.
    """
    if n_travels < 0:
        raise ValueError(f"n_travels must be >= 0, got {n_travels}")
    params = _params(sw, params)
    world = sw.world
    rng = np.random.default_rng(seed)
    p = int(rng.integers(world.n_places)) if start is None else int(start)
    if not 0 <= p < world.n_places:
        raise ValueError(f"start place {start} not in the world")
    gates = [e for e in range(len(world.stars[p])) if world.stars[p].alpha[e]]
    arr_t = world.stars[p].opp[int(rng.choice(gates))]
    rv, here = _start(sw, params, p, arr_t, jax.random.key(seed))
    views, bears, turns, odo, todo = [here.view], [here.bearings], [], [], []
    places, arrivals = [p], [arr_t]
    snaps, poses, origins, trues, tdiv = [], [], [], [], []

    def snap(a: _Arrival):
        snaps.append(np.asarray(rv.s.lpm.logodds))
        origins.append(np.asarray(rv.s.lpm.origin, float))
        poses.append(a.pose)
        trues.append(a.true_pose)
        tdiv.append(_true_dividing(a, a.odom_pose))

    snap(here)
    visited: set = set()
    for _ in range(n_travels):
        star, arr = here.view
        cands = sorted(here.gateway_lines)
        back = star.opp[arr]
        tru = {e: _true_entry(world, p, float(np.arctan2(*here.gateway_lines[e][1][::-1])))
               for e in cands}
        fresh = [e for e in cands if (p, tru[e]) not in visited]
        if fresh:
            ex = int(rng.choice(fresh))
        else:
            ch = [e for e in cands if e != back] or cands
            ex = int(rng.choice(ch))
        nxt = _travel(rv, here, ex)
        q = _true_place(sw, nxt.true_pose[:2])
        d = world.positions[q] - world.positions[p]
        heading = float(np.arctan2(d[1], d[0])) if q != p else _wrap(
            world.bearings[p][tru[ex]] + np.pi)
        a_t = _true_entry(world, q, heading)
        visited.update({(p, tru[ex]), (q, world.stars[q].opp[a_t])})
        todo.append(np.asarray(se2_compose(se2_inverse(tdiv[-1]),
                                           _true_dividing(nxt, nxt.odom_pose))))
        odo.append(np.asarray(se2_compose(se2_inverse(here.pose), nxt.pose)))
        turns.append((ex - arr) % len(star))
        views.append(nxt.view)
        bears.append(nxt.bearings)
        places.append(q)
        arrivals.append(a_t)
        snap(nxt)
        here, p = nxt, q
    exp = Experience(tuple(views), tuple(bears), np.array(turns, np.int32),
                     np.array(odo, float).reshape(-1, 3), np.array(places, np.int32),
                     np.array(todo, float).reshape(-1, 3), np.array(arrivals, np.int32))
    return SimExperience(exp, np.stack(snaps), np.stack(poses), np.stack(origins),
                         np.stack(trues), np.stack(tdiv), float(rv.s.travelled), rv.checks,
                         rv.rejected)


def true_layout_sim(se: SimExperience) -> np.ndarray:
    """True dividing poses ``[m_seen, 3]`` of the places by first visit, in the first visit's frame.

    The simulator's counterpart of :func:`~pqrm_jax.hssh_global.layout.true_layout`: a place's
    frame is the dividing pose the rover measured at its first visit, so its truth is that pose
    in the true frame (:attr:`SimExperience.true_dividing`), not the lattice node.

    Args:
        se: the simulated exploration.

    Returns:
        ``[m_seen, 3]`` float64 poses (B §9.2).
    """
    from .tree import canonical_places
    lab = canonical_places(se.experience.true_places)
    first: dict = {}
    for i, c in enumerate(lab):
        first.setdefault(c, se.true_dividing[i])
    x0 = first[0]
    return np.stack([se2_compose_host(se2_inverse_host(x0), first[c]) for c in range(len(first))])


def navigate_sim(sw: SimWorld, start: tuple[int, int], commands, seed: int = 0,
                 params: SimParams | None = None) -> tuple[list, float, bool]:
    """Executes turn commands with the simulated rover and the local levels (B §7.1.3).

    The rover starts at the true dstate ``start = (place, arrival entry)``, reads the view there
    and, at each place, applies the next command to the *observed* star
    (:func:`~pqrm_jax.hssh_global.navigation.apply_command`) and travels through that gateway.

    Returns:
        ``(true places reached, true distance driven, all commands executable)``.

    Raises:
        SimulationError: the rover lost its way (see :func:`explore_sim`).

    Args:
        sw: the simulated world.
        start: the true dstate ``(place, arrival entry)``.
        commands: turn commands, one per travel.
        seed: NumPy seed of the rover's noise.
        params: the simulation parameters.
    """
    params = _params(sw, params)
    rv, here = _start(sw, params, int(start[0]), int(start[1]), jax.random.key(seed))
    places = [_true_place(sw, here.true_pose[:2])]
    d0 = float(rv.s.travelled)
    for cmd in commands:
        star, arr = here.view
        e = apply_command(star, arr, tuple(cmd))
        if e is None or e not in here.gateway_lines:
            return places, float(rv.s.travelled) - d0, False
        here = _travel(rv, here, e)
        places.append(_true_place(sw, here.true_pose[:2]))
    return places, float(rv.s.travelled) - d0, True


def evaluate_navigation_sim(sw: SimWorld, se: SimExperience, h, n_pairs: int = 5,
                            seed: int = 0, params: SimParams | None = None) -> dict:
    """Success rate and path length over random start/goal pairs, executed in the simulator.

    As :func:`~pqrm_jax.hssh_global.navigation.evaluate_navigation`, but the commands of the
    route planned on map ``h`` are driven by the rover (:func:`navigate_sim`). The length ratio
    is the true distance driven (manoeuvres at places included) over the shortest corridor
    route of the world. A :class:`SimulationError` during a run counts as a failure
    (``lost`` counts them; ``lost_reasons`` keeps each one's pair and message).

    Args:
        sw: the simulated world.
        se: the simulated exploration ``h`` was built from.
        h: the map hypothesis navigated with.
        n_pairs: random start/goal pairs.
        seed: NumPy seed of the pairs and the runs.
        params: the simulation parameters.

    Returns:
        ``{"success", "length_ratio", "pairs", "lost", "lost_reasons"}``.
    """
    from .navigation import plan_route
    ex = se.experience
    rng = np.random.default_rng(seed)
    first: dict = {}
    for i, (p, _) in enumerate(h.visits):
        first.setdefault(p, int(ex.true_places[i]))
    if h.n_places < 2:
        return {"success": float("nan"), "length_ratio": float("nan"), "pairs": 0, "lost": 0,
                "lost_reasons": []}
    ok, lost, ratios, reasons = 0, 0, [], []
    for k in range(n_pairs):
        i = int(rng.integers(len(h.visits)))
        goal = int(rng.choice([p for p in range(h.n_places) if p != h.visits[i][0]]))
        _, cmds = plan_route(h, ex.odometry, h.visits[i], goal)
        ts = (int(ex.true_places[i]), int(ex.true_arrivals[i]))
        try:
            places, dist, done = navigate_sim(sw, ts, cmds, seed=seed + 7919 * (k + 1),
                                              params=params)
        except SimulationError as exc:
            lost += 1
            reasons.append(f"pair {k} {ts}->{first[goal]}: {exc}")
            continue
        if done and places[-1] == first[goal]:
            ok += 1
            sd = shortest_distance(sw.world, ts[0], first[goal])
            if sd > 0:
                ratios.append(dist / sd)
    return {"success": ok / n_pairs, "length_ratio": float(np.mean(ratios)) if ratios
            else float("nan"), "pairs": n_pairs, "lost": lost, "lost_reasons": reasons}


def global_occupancy(sw: SimWorld, se: SimExperience, h, chi,
                     offsets=None) -> tuple[np.ndarray, np.ndarray, float]:
    """The global occupancy map ``m*`` projected from corrected place poses (B ch. 9).

    Each LPM snapshot (taken at a view) is placed by its view's dividing pose in hypothesis ``h``:
    ``χ_p ⊕ (0, 0, δ)`` with ``δ`` the bearing of the arrival entry in place ``p``'s frame (as in
    :mod:`~pqrm_jax.hssh_global.layout`); its cell centres, relative to the odometry dividing
    pose, are moved there and their log-odds summed into a global grid of the LPM resolution.

    Args:
        sw: the rendered world the exploration ran in (for the LPM resolution).
        se: the exploration.
        h: a map hypothesis of ``se.experience`` (e.g. the preferred or the true leaf).
        chi: ``[M, 3]`` its place poses (relaxed, or ``pack(...).init`` for raw odometry).
        offsets: optional ``[n+1, 3]`` offsets ``r_i`` of each view's real dividing pose from
            ``χ_p ⊕ (0, 0, δ)`` (re-localisation at revisits,
            :attr:`~pqrm_jax.hssh_global.relocalize.Relocalization.offsets` of this ``h``).

    Returns:
        ``(logodds [R, C] rows along y, origin [2], resolution)`` in the frame of place 0.
    """
    chi = np.asarray(chi, float)
    n = se.snapshots.shape[-1]
    r = sw.width / sw.params.cells
    ij = (np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1) + 0.5) * r
    pts, vals = [], []
    for i, (p, e) in enumerate(h.visits):
        lo = se.snapshots[i]
        keep = lo != 0
        xy = se.snap_origins[i][None, :] + ij[keep][:, ::-1]          # (x, y) in odometry
        rel = se2_compose_host(se2_inverse_host(se.snap_poses[i]),
                           np.concatenate([xy, np.zeros((len(xy), 1))], 1))
        d = se2_compose_host(chi[p], np.array([0.0, 0.0, h.bearings[p][e]]))
        if offsets is not None:
            d = se2_compose_host(d, offsets[i])
        pts.append(se2_compose_host(d, rel)[:, :2])
        vals.append(lo[keep])
    pts, vals = np.concatenate(pts), np.concatenate(vals)
    origin = pts.min(0) - r
    cells = np.floor((pts - origin) / r).astype(int)
    shape = tuple(cells.max(0)[::-1] + 2)
    grid = np.zeros(shape)
    np.add.at(grid, (cells[:, 1], cells[:, 0]), vals)
    return grid, origin, r


def map_agreement(sw: SimWorld, grid: np.ndarray, origin, resolution: float, frame,
                  threshold: float = 0.4, tol_cells: float = 2.0) -> float:
    """Fraction of the global map's occupied cells that lie on a true wall surface.

    Args:
        sw: the rendered world (the truth).
        grid, origin, resolution: from :func:`global_occupancy`.
        frame: ``[3]`` true pose of the map frame (``SimExperience.true_dividing[0]``).
        threshold: log-odds above which a map cell is occupied.
        tol_cells: distance to the wall surface, in map cells, that still agrees (an LPM hit
            cell's centre lies up to about one cell from the surface, plus one for the
            whole-cell scrolling and the lidar's march step).

    Returns:
        The share of occupied map cells whose centre is within ``tol_cells`` map cells of the
        true wall surface, on either side (NaN when the map has no occupied cell).
    """
    from scipy.ndimage import distance_transform_edt
    rows, cols = np.nonzero(np.asarray(grid) > threshold)
    if len(rows) == 0:
        return float("nan")
    xy = np.asarray(origin)[None, :] + (np.stack([cols, rows], 1) + 0.5) * resolution
    pts = se2_compose_host(frame, np.concatenate([xy, np.zeros((len(xy), 1))], 1))[:, :2]
    occ = np.asarray(sw.occupied)
    # distance to the wall surface (the boundary between free and occupied), either side
    dist = np.where(occ, distance_transform_edt(occ), distance_transform_edt(~occ)) \
        * sw.resolution
    j = np.floor((pts[:, 0] - sw.origin[0]) / sw.resolution).astype(int)
    i = np.floor((pts[:, 1] - sw.origin[1]) / sw.resolution).astype(int)
    inside = (i >= 0) & (i < occ.shape[0]) & (j >= 0) & (j < occ.shape[1])
    near = np.zeros(len(pts), bool)
    near[inside] = dist[i[inside], j[inside]] <= tol_cells * resolution
    return float(near.mean())


def revisit_jitter(se: SimExperience, h, offsets=None) -> tuple[float, float]:
    """How far the dividing poses of revisits stray from what the place frame predicts.

    At a revisit of place ``p`` on entry ``e`` the layout assumes the rover stands at
    ``χ_p ⊕ (0, 0, δ_e)`` (:mod:`~pqrm_jax.hssh_global.layout`), ``χ_p`` being the first visit's
    dividing pose. With the true dividing poses this returns the mean position discrepancy
    (world units) and mean absolute heading discrepancy (rad) over all revisits: the noise the
    loop-closing springs carry, beside the odometry's (NaN, NaN without a revisit).

    With ``offsets`` (``[n+1, 3]``, re-localisation at revisits,
    :attr:`~pqrm_jax.hssh_global.relocalize.Relocalization.offsets` of this ``h``) the
    prediction is ``χ_p ⊕ (0, 0, δ_e − δ_first) ⊕ r_i``: what remains is the re-localisation
    error.

    Args:
        se: the simulated exploration.
        h: the map hypothesis (places of the visits).
        offsets: optional ``[n+1, 3]`` re-localisation offsets.

    Returns:
        ``(mean position discrepancy, mean heading discrepancy)``.
    """
    first: dict = {}
    dxy, dth = [], []
    for i, (p, e) in enumerate(h.visits):
        if p not in first:
            first[p] = (se.true_dividing[i], h.bearings[p][e])
            continue
        x0, d0 = first[p]
        pred = se2_compose_host(x0, np.array([0.0, 0.0, h.bearings[p][e] - d0]))
        if offsets is not None:
            pred = se2_compose_host(pred, offsets[i])
        dxy.append(float(np.hypot(*(se.true_dividing[i][:2] - pred[:2]))))
        dth.append(abs(float(_wrap(se.true_dividing[i][2] - pred[2]))))
    if not dxy:
        return float("nan"), float("nan")
    return float(np.mean(dxy)), float(np.mean(dth))
