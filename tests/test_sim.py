"""Tests for the ``sim`` rover simulator: kinematics, worlds, sensors, trajectories.

Decisions tested: docs/decisions.md §9.
"""

import doctest
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import sim
from pqrm_jax.sim import lidar, rover, sensors, trajectories, world

KEY = jax.random.key(0)


# ---------------------------------------------------------------- rover kinematics


def closed_form(pose, v, w, dt):
    x, y, th = (float(a) for a in pose)
    if w == 0.0:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), th])
    return np.array([x + v / w * (math.sin(th + w * dt) - math.sin(th)),
                     y - v / w * (math.cos(th + w * dt) - math.cos(th)),
                     th + w * dt])


def wrapped_diff(a, b):
    d = np.asarray(a, float) - np.asarray(b, float)
    d[..., 2] = (d[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return d


def test_step_matches_closed_form_including_straight_line():
    params = sim.RoverParams(dt=0.7, max_speed=3.0, max_turn_rate=2.0)
    rng = np.random.default_rng(1)
    cases = [(1.5, 0.0), (-2.0, 0.0), (0.0, 1.0), (3.0, -2.0)]
    cases += [(rng.uniform(-3, 3), rng.uniform(-2, 2)) for _ in range(6)]
    for v, w in cases:
        pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)])
        s = sim.reset(KEY, params, pose=pose)
        out = sim.step(s, jnp.array([v, w]), params)
        np.testing.assert_allclose(wrapped_diff(out.pose, closed_form(pose, v, w, 0.7)), 0,
                                   atol=2e-5)
        assert float(out.t) == pytest.approx(0.7)
        assert -np.pi <= float(out.pose[2]) < np.pi


def test_step_tiny_turn_rate_is_finite_and_straight():
    s = sim.reset(KEY, pose=jnp.array([0.0, 0.0, 0.3]))
    for w in (1e-9, -1e-7, 1e-5):
        out = sim.step(s, jnp.array([1.0, w]), sim.RoverParams(dt=1.0))
        assert np.all(np.isfinite(np.asarray(out.pose)))
        np.testing.assert_allclose(out.pose[:2], [math.cos(0.3), math.sin(0.3)], atol=1e-5)
    # The gradient through the omega -> 0 branch is finite too.
    g = jax.grad(
        lambda w: rover.step_kernel(s, jnp.array([1.0, w]), sim.RoverParams(dt=1.0)).pose[1])
    assert np.isfinite(float(g(0.0)))
    assert float(g(0.0)) == pytest.approx(0.5 * math.cos(0.3), rel=1e-4)  # d y / d omega


def test_step_float64_precision():
    with jax.enable_x64(True):
        pose = np.array([1.0, -2.0, 0.4])
        s = sim.reset(KEY, pose=jnp.asarray(pose, jnp.float64))
        out = sim.step(s, jnp.array([1.3, 0.9], jnp.float64), sim.RoverParams(dt=0.5))
        assert out.pose.dtype == jnp.float64
        np.testing.assert_allclose(out.pose, closed_form(pose, 1.3, 0.9, 0.5), atol=1e-12)


def test_controls_are_clipped():
    params = sim.RoverParams(dt=1.0, max_speed=1.0, max_turn_rate=0.5)
    s = sim.reset(KEY, pose=jnp.zeros(3))
    cases = [((10.0, 10.0), (1.0, 0.5)), ((-10.0, -3.0), (-1.0, -0.5)), ((0.5, 0.1), (0.5, 0.1))]
    for u, lim in cases:
        np.testing.assert_allclose(sim.step(s, jnp.array(u), params).pose,
                                   sim.step(s, jnp.array(lim), params).pose, atol=1e-6)
        np.testing.assert_allclose(sim.clip_control(jnp.array(u), params), lim, atol=1e-7)


def test_rollout_matches_steps_and_closes_circle():
    params = sim.RoverParams(dt=0.1, max_speed=2.0, max_turn_rate=1.0)
    s = sim.reset(KEY, params, pose=jnp.array([3.0, 4.0, 1.0]))
    controls = jax.random.uniform(KEY, (20, 2), minval=-1.0, maxval=1.0)
    final, poses = sim.rollout(s, controls, params)
    assert poses.shape == (21, 3)
    np.testing.assert_allclose(poses[0], s.pose)
    manual = s
    for u in controls:
        manual = sim.step(manual, u, params)
    np.testing.assert_allclose(wrapped_diff(final.pose, manual.pose), 0, atol=1e-4)
    assert float(final.t) == pytest.approx(2.0, rel=1e-5)
    # Constant (v, omega) for one full turn returns to the start (exact integration).
    n = 20
    w = 2 * math.pi / (n * 0.1)
    p2 = sim.RoverParams(dt=0.1, max_speed=2.0, max_turn_rate=4.0)
    final, poses = sim.rollout(s, jnp.tile(jnp.array([1.5, w]), (n, 1)), p2)
    np.testing.assert_allclose(wrapped_diff(final.pose, s.pose), 0, atol=1e-4)
    radius = np.linalg.norm(poses[:-1, :2] - poses[:-1, :2].mean(0), axis=1)
    np.testing.assert_allclose(radius, 1.5 / w, rtol=1e-4)


def test_reset_random_pose_deterministic_and_in_box():
    a, b = sim.reset(jax.random.key(3)), sim.reset(jax.random.key(3))
    c = sim.reset(jax.random.key(4))
    np.testing.assert_array_equal(a.pose, b.pose)
    assert not np.allclose(a.pose, c.pose)
    assert 0 <= float(a.pose[0]) <= 100 and 0 <= float(a.pose[1]) <= 100
    assert float(a.t) == 0.0


def test_vmap_over_runs():
    params = sim.RoverParams()
    keys = jax.random.split(KEY, 8)
    states = jax.vmap(lambda k: sim.reset(k, params))(keys)
    controls = jax.random.uniform(KEY, (8, 20, 2), minval=-1, maxval=1)
    finals, poses = jax.vmap(sim.rollout, (0, 0, None))(states, controls, params)
    assert poses.shape == (8, 21, 3)
    for i in (0, 5):
        s_i = sim.RoverState(states.pose[i], states.t[i])
        f_i, p_i = sim.rollout(s_i, controls[i], params)
        np.testing.assert_allclose(p_i, poses[i], atol=1e-5)
    # vmap over parameters as well.
    dts = sim.RoverParams(dt=jnp.array([0.1, 0.2]), max_speed=2.0, max_turn_rate=1.0)
    st = sim.reset(KEY, pose=jnp.zeros(3))
    out = jax.vmap(sim.step, (None, None, sim.RoverParams(0, None, None)))(
        st, jnp.array([1.0, 0.0]), dts)
    np.testing.assert_allclose(out.pose[:, 0], [0.1, 0.2], atol=1e-6)


# ---------------------------------------------------------------- worlds


def test_worlds_shapes_bounds_and_determinism():
    size = (40.0, 20.0)
    lm = sim.uniform_landmarks(KEY, 30, size)
    assert lm.shape == (30, 2) and lm.dtype == jnp.float32
    assert np.all((np.asarray(lm) >= 0) & (np.asarray(lm) <= size))
    np.testing.assert_array_equal(lm, sim.uniform_landmarks(KEY, 30, size))
    assert not np.allclose(lm, sim.uniform_landmarks(jax.random.key(1), 30, size))

    cl = sim.clustered_landmarks(KEY, 40, 4, size, spread=1.0)
    assert cl.shape == (40, 2) and np.all((np.asarray(cl) >= 0) & (np.asarray(cl) <= size))
    np.testing.assert_array_equal(cl, sim.clustered_landmarks(KEY, 40, 4, size, spread=1.0))
    # With a small spread the points are far more tightly packed than uniform ones.
    def mean_nn(p):
        d = np.linalg.norm(np.asarray(p)[:, None] - np.asarray(p)[None], axis=-1)
        return np.sort(d, axis=1)[:, 1].mean()

    assert mean_nn(cl) < 0.3 * mean_nn(lm)

    hw = np.asarray(sim.hallway_landmarks(KEY, 200, length=30.0, width=3.0, jitter=0.0,
                                          origin=(5.0, 1.0)))
    assert hw.shape == (200, 2)
    np.testing.assert_allclose(hw[0::2, 1], 2.5)
    np.testing.assert_allclose(hw[1::2, 1], -0.5)
    assert np.all((hw[:, 0] >= 5) & (hw[:, 0] <= 35))
    hj = np.asarray(sim.hallway_landmarks(KEY, 200, jitter=0.2))
    assert 0.1 < np.std(hj[0::2, 1] - 2.0) < 0.3

    cg = np.asarray(sim.corridor_grid_landmarks(KEY, n_x=2, n_y=1, spacing=10.0, width=2.0,
                                                per_side=2, jitter=0.0))
    assert cg.shape == (2 * 2 * (2 * 2 + 1 * 3), 2)
    # Every landmark lies on a corridor wall: one coordinate is (multiple of spacing) +- 1.
    on_wall = np.isclose(np.abs(((cg + 1.0) % 10.0) - 1.0), 1.0, atol=1e-5)
    assert np.all(on_wall.any(axis=1))

    keys = jax.random.split(KEY, 5)
    worlds = jax.vmap(lambda k: sim.uniform_landmarks(k, 30, size))(keys)
    assert worlds.shape == (5, 30, 2)
    np.testing.assert_array_equal(worlds[2], sim.uniform_landmarks(keys[2], 30, size))


# ---------------------------------------------------------------- sensors


def brute_force(pose, lm, max_range, fov, radius):
    """Plain NumPy (float64) reference: robot-frame positions, visibility, bearings, ranks."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    rel = np.array([[c * (a - x) + s * (b - y), -s * (a - x) + c * (b - y)] for a, b in lm])
    n = len(lm)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    vis = np.zeros(n, bool)
    for j in range(n):
        ok = dist[j] <= max_range and (fov >= 2 * np.pi or abs(bearing[j]) <= fov / 2)
        for k in range(n):
            if k == j or not dist[k] < dist[j]:
                continue
            t = np.clip(rel[k] @ rel[j] / (rel[j] @ rel[j]), 0, 1)
            if np.linalg.norm(rel[k] - t * rel[j]) < radius:
                ok = False
        vis[j] = ok
    order = [j for j in np.argsort(dist, kind="stable") if vis[j]]
    rank = -np.ones(n, int)
    rank[order] = np.arange(len(order))
    return rel, vis, bearing, rank


def test_visibility_and_camera_match_brute_force():
    rng = np.random.default_rng(7)
    n_hidden = n_fov = 0
    for trial in range(6):
        lm = rng.uniform(0, 50, (30, 2))
        pose = np.array([*rng.uniform(0, 50, 2), rng.uniform(-np.pi, np.pi)])
        fov = [2 * np.pi, np.pi, 2.0][trial % 3]
        params = sim.SensorParams(max_range=30.0, fov=fov, landmark_radius=1.5, sigma=0.0)
        rel, vis, bearing, rank = brute_force(pose, lm, 30.0, fov, 1.5)
        obs = sim.observe(KEY, jnp.asarray(pose), jnp.asarray(lm), params)
        np.testing.assert_allclose(obs.true_rel, rel, atol=1e-4)
        np.testing.assert_allclose(obs.rel, rel, atol=1e-4)  # sigma = 0
        np.testing.assert_array_equal(obs.visible, vis)
        cam = sim.camera(jnp.asarray(pose), jnp.asarray(lm), params)
        np.testing.assert_array_equal(cam.visible, vis)
        np.testing.assert_array_equal(cam.range_rank, rank)
        d = (np.asarray(cam.bearings) - bearing + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(d, 0, atol=1e-5)
        assert cam.range_rank.dtype == jnp.int32
        no_occ = brute_force(pose, lm, 30.0, fov, 0.0)[1]
        n_hidden += int(np.sum(no_occ & ~vis))
        n_fov += int(np.sum(brute_force(pose, lm, 30.0, 2 * np.pi, 0.0)[1] & ~no_occ))
    assert n_hidden > 0 and n_fov > 0  # the random worlds exercise occlusion and the fov


def padded(points, n=30):
    """Pad with far-away landmarks to the shape used elsewhere (saves a recompile)."""
    return jnp.concatenate([jnp.asarray(points), jnp.full((n - len(points), 2), 1e4)])


def test_occlusion_fov_and_range_hand_cases():
    lm = padded([[5.0, 0.0], [10.0, 0.5], [10.0, 3.0], [-3.0, 0.0], [70.0, 0.0]])
    p = sim.SensorParams(max_range=60.0, fov=2 * np.pi, landmark_radius=1.0)
    vis = sim.observe(KEY, jnp.zeros(3), lm, p).visible.tolist()
    assert vis[:5] == [True, False, True, True, False] and not any(vis[5:])
    p_fov = p._replace(fov=np.pi, landmark_radius=0.0)
    assert sim.visibility(jnp.zeros(3), lm, p_fov).tolist()[:5] == [True, True, True, False, False]
    # Facing the other way (theta = pi) the landmark behind becomes the only visible one.
    assert sim.visibility(jnp.array([0.0, 0.0, np.pi]), lm, p_fov).tolist()[:5] == [
        False, False, False, True, False]
    cam = sim.camera(jnp.zeros(3), lm, p)
    assert cam.range_rank.tolist()[:5] == [1, -1, 2, 0, -1]


def test_noise_statistics_and_determinism():
    lm = padded(np.random.default_rng(3).uniform(0, 100, (30, 2)))
    pose = jnp.array([50.0, 50.0, 0.7])
    params = sim.SensorParams(max_range=200.0, sigma=2.0)
    keys = jax.random.split(jax.random.key(11), 100)
    obs = [sim.observe(k, pose, lm, params) for k in keys]  # 3000 samples, no new compile
    err = np.concatenate([np.asarray(o.rel - o.true_rel) for o in obs])
    assert np.all(np.abs(err.mean(0)) < 4 * 2.0 / math.sqrt(len(err)))
    np.testing.assert_allclose(err.std(0), 2.0, rtol=0.05)
    assert abs(np.corrcoef(err.T)[0, 1]) < 0.06
    same = sim.observe(keys[0], pose, lm, params)
    np.testing.assert_array_equal(same.rel, obs[0].rel)
    assert not np.allclose(obs[1].rel, obs[0].rel)
    np.testing.assert_array_equal(obs[1].true_rel, obs[0].true_rel)


def test_sensors_vmap_and_jit_over_runs():
    lm = sim.uniform_landmarks(KEY, 30)
    poses = sim.perimeter_loop()
    keys = jax.random.split(KEY, poses.shape[0])
    params = sim.SensorParams(max_range=60.0, sigma=1.0, landmark_radius=0.5)
    batch = jax.vmap(sim.observe, (0, 0, None, None))(keys, poses, lm, params)
    assert batch.rel.shape == (23, 30, 2) and batch.visible.shape == (23, 30)
    one = sim.observe(keys[4], poses[4], lm, params)
    np.testing.assert_allclose(batch.rel[4], one.rel, atol=1e-5)
    np.testing.assert_array_equal(batch.visible[4], one.visible)
    cams = jax.jit(jax.vmap(sim.camera, (0, None, None)))(poses, lm, params)
    np.testing.assert_array_equal(cams.range_rank[7], sim.camera(poses[7], lm, params).range_rank)
    # Padgett's setup: a 60 m range does not see every landmark from the perimeter.
    assert not bool(batch.visible.all())
    # vmap over noise levels (P §2.3.1 sweeps 21 values of sigma).
    sig = jnp.linspace(0.0, 100.0, 5)
    sweep = jax.vmap(sim.observe, (None, None, None, sim.SensorParams(None, None, None, 0)))(
        KEY, poses[0], lm, params._replace(sigma=sig))
    std = np.asarray(jnp.std(sweep.rel - sweep.true_rel, axis=(1, 2)))
    assert std[0] == 0.0 and np.all(np.diff(std) > 0)


# ---------------------------------------------------------------- lidar


def exit_distance(p, ang, lo, hi):
    """Distance from p (inside the box [lo, hi]^2) along direction ang to the box boundary."""
    d = np.array([math.cos(ang), math.sin(ang)])
    ts = [((hi if d[k] > 0 else lo) - p[k]) / d[k] for k in range(2) if abs(d[k]) > 1e-12]
    return min(ts)


def test_lidar_scan_in_a_walled_room():
    grid = np.zeros((20, 20), bool)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = True  # free interior [1, 19]^2
    pose = np.array([10.3, 7.2, 0.4])
    params = sim.LidarParams(n_beams=36, max_range=40.0)
    scan = sim.lidar_scan(KEY, jnp.asarray(pose), jnp.asarray(grid), 1.0, (0.0, 0.0), params)
    assert bool(scan.hit.all())
    step = 1.0 / 4
    for a, r in zip(np.asarray(scan.angles), np.asarray(scan.ranges), strict=True):
        exact = exit_distance(pose[:2], pose[2] + a, 1.0, 19.0)
        assert exact - 1e-4 <= r <= exact + step + 1e-4
    np.testing.assert_allclose(np.diff(np.asarray(scan.angles)), 2 * np.pi / 36, atol=1e-5)
    # Short range: nothing hit, ranges report max_range; partial fov centred on the heading.
    short = sim.lidar_scan(KEY, jnp.asarray(pose), jnp.asarray(grid), 1.0, (0.0, 0.0),
                           params._replace(max_range=2.0, fov=np.pi / 2, n_beams=5))
    assert not bool(short.hit.any())
    np.testing.assert_allclose(short.ranges, 2.0)
    np.testing.assert_allclose(short.angles, np.linspace(-np.pi / 4, np.pi / 4, 5), atol=1e-6)
    noisy = sim.lidar_scan(KEY, jnp.asarray(pose), jnp.asarray(grid), 1.0, (0.0, 0.0),
                           params._replace(sigma=0.5))
    assert 0.2 < float(jnp.std(noisy.ranges - scan.ranges)) < 0.9
    # Landmark discs rasterised into a grid are seen by the lidar.
    g = sim.rasterize_discs(jnp.array([[15.0, 7.2]]), 1.0, (20, 20), 1.0)
    hit = sim.lidar_scan(KEY, jnp.asarray([10.3, 7.2, 0.0]), g, 1.0, (0.0, 0.0),
                         params._replace(n_beams=1, fov=0.0))
    assert bool(hit.hit[0]) and abs(float(hit.ranges[0]) - 3.7) <= 0.5
    centres = (np.stack(np.meshgrid(np.arange(20), np.arange(20)), -1) + 0.5)
    ref = np.linalg.norm(centres - np.array([15.0, 7.2]), axis=-1) <= 1.0
    np.testing.assert_array_equal(g, ref)
    with pytest.raises(ValueError, match="grid"):
        sim.lidar_scan(KEY, jnp.zeros(3), jnp.zeros(5, bool), 1.0)
    with pytest.raises(ValueError, match="resolution"):
        sim.lidar_scan(KEY, jnp.zeros(3), jnp.zeros((5, 5), bool), -1.0)


# ---------------------------------------------------------------- trajectories


def test_perimeter_loop():
    poses = np.asarray(sim.perimeter_loop())
    assert poses.shape == (23, 3)  # one loop, a measurement every 16 degrees
    np.testing.assert_allclose(np.linalg.norm(poses[:, :2] - 50.0, axis=1), 50.0, rtol=1e-5)
    ang = np.unwrap(np.arctan2(poses[:, 1] - 50, poses[:, 0] - 50))
    np.testing.assert_allclose(np.diff(ang), np.radians(16.0), atol=1e-5)
    # Heading is tangent (direction of travel, counter-clockwise).
    fwd = np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], -1)
    np.testing.assert_allclose(np.sum(fwd * (poses[:, :2] - 50.0), axis=1), 0, atol=1e-3)
    r = poses[:, :2] - 50.0
    assert np.all(r[:, 0] * fwd[:, 1] - r[:, 1] * fwd[:, 0] > 0)
    cw = np.asarray(sim.perimeter_loop((0.0, 0.0), 2.0, np.pi / 2, clockwise=True))
    np.testing.assert_allclose(cw[:, :2], [[2, 0], [0, -2], [-2, 0], [0, 2]], atol=1e-6)


def test_random_imaging_points_and_traverse():
    pts = sim.random_imaging_points(KEY, 50, (30.0, 10.0))
    assert pts.shape == (50, 3)
    assert np.all((np.asarray(pts[:, :2]) >= 0) & (np.asarray(pts[:, :2]) <= (30, 10)))
    np.testing.assert_array_equal(pts, sim.random_imaging_points(KEY, 50, (30.0, 10.0)))
    fixed = sim.random_imaging_points(KEY, 5, heading=0.5)
    np.testing.assert_allclose(fixed[:, 2], 0.5)

    path = np.asarray(sim.traverse(KEY, 200, 1.0, 2.0, start=(5.0, 5.0), size=(20.0, 20.0)))
    assert path.shape == (200, 3)
    np.testing.assert_allclose(path[0, :2], (5.0, 5.0))
    steps = np.diff(path[:, :2], axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    assert np.all((lengths > 1 - 1e-4) & (lengths < 2 + 1e-4))
    assert np.all((path[:, :2] >= 0) & (path[:, :2] <= 20))
    np.testing.assert_allclose(np.arctan2(steps[:, 1], steps[:, 0]), path[1:, 2], atol=1e-4)
    assert not np.allclose(path, sim.traverse(jax.random.key(9), 200, start=(5.0, 5.0),
                                              size=(20.0, 20.0)))
    many = jax.vmap(lambda k: sim.traverse(k, 10, start=jnp.array([1.0, 1.0])))(
        jax.random.split(KEY, 4))
    assert many.shape == (4, 10, 3)


def test_waypoint_following_reaches_waypoints():
    params = sim.RoverParams(dt=0.1, max_speed=2.0, max_turn_rate=1.5)
    wps = jnp.array([[10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.0]])
    s = sim.reset(KEY, params, pose=jnp.array([0.0, 0.0, np.pi]))  # starts facing away
    res = sim.follow_waypoints(s, wps, params, n_steps=600, tol=0.3)
    assert int(res.n_reached) == 4
    assert res.poses.shape == (601, 3) and res.targets.shape == (600,)
    assert np.all(np.diff(np.asarray(res.targets)) >= 0)
    for wp in np.asarray(wps):
        assert np.min(np.linalg.norm(np.asarray(res.poses[:, :2]) - wp, axis=1)) < 0.3
    # After the last waypoint the rover stops.
    np.testing.assert_allclose(res.poses[-1], res.poses[-10], atol=1e-6)
    # vmap over random starts; each one gets through the waypoints.
    starts = jax.vmap(lambda k: sim.reset(k, params, size=(10.0, 10.0)))(jax.random.split(KEY, 6))
    out = jax.vmap(sim.follow_waypoints, (0, None, None, None, None))(starts, wps, params, 600, 0.3)
    assert np.all(np.asarray(out.n_reached) == 4)
    u = sim.waypoint_controller(jnp.array([0.0, 0.0, 0.0]), jnp.array([0.0, 5.0]),
                                params=params)
    np.testing.assert_allclose(u, [0.0, 1.5], atol=1e-6)  # turn left on the spot, clipped


# ---------------------------------------------------------------- bad input


def test_bad_input_raises_clear_errors():
    lm = jnp.ones((4, 2))
    ok = sim.SensorParams()
    with pytest.raises(ValueError, match="pose"):
        sim.observe(KEY, jnp.array([np.nan, 0.0, 0.0]), lm, ok)
    with pytest.raises(ValueError, match="landmarks"):
        sim.observe(KEY, jnp.zeros(3), lm.at[1, 0].set(np.inf), ok)
    with pytest.raises(ValueError, match="sigma"):
        sim.observe(KEY, jnp.zeros(3), lm, ok._replace(sigma=-1.0))
    with pytest.raises(ValueError, match="max_range"):
        sim.camera(jnp.zeros(3), lm, ok._replace(max_range=-5.0))
    with pytest.raises(ValueError, match="landmark_radius"):
        sim.camera(jnp.zeros(3), lm, ok._replace(landmark_radius=float("nan")))
    with pytest.raises(ValueError, match=r"pose must have shape \(3,\)"):
        sim.camera(jnp.zeros(2), lm, ok)
    with pytest.raises(ValueError, match=r"landmarks must have shape \(N, 2\)"):
        sim.observe(KEY, jnp.zeros(3), jnp.ones((4, 3)), ok)
    s = sim.reset(KEY, pose=jnp.zeros(3))
    with pytest.raises(ValueError, match="control"):
        sim.step(s, jnp.zeros(3))
    with pytest.raises(ValueError, match="controls"):
        sim.rollout(s, jnp.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="dt"):
        sim.step(s, jnp.zeros(2), sim.RoverParams(dt=0.0))
    with pytest.raises(ValueError, match="max_speed"):
        sim.step(s, jnp.zeros(2), sim.RoverParams(max_speed=-1.0))
    with pytest.raises(ValueError, match="pose"):
        sim.reset(KEY, pose=jnp.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="n must be"):
        sim.uniform_landmarks(KEY, 3.5)
    with pytest.raises(ValueError, match="size"):
        sim.uniform_landmarks(KEY, 3, size=(10.0, -1.0))
    with pytest.raises(ValueError, match="dtheta"):
        sim.perimeter_loop(dtheta=0.0)
    with pytest.raises(ValueError, match="waypoints"):
        sim.follow_waypoints(s, jnp.ones((3, 3)), n_steps=5)
    with pytest.raises(ValueError, match="heading"):
        sim.random_imaging_points(KEY, 3, heading="north")


def test_inside_jit_values_are_not_checked():
    # Under jit the values are tracers: no exception, NaN propagates (documented behaviour).
    obs = jax.jit(sim.observe)(KEY, jnp.array([np.nan, 0.0, 0.0]), jnp.ones((4, 2)),
                               sim.SensorParams())
    assert np.all(np.isnan(np.asarray(obs.true_rel[:, 0])))
    assert not bool(obs.visible.any())
    # Shapes are static and still checked under jit.
    with pytest.raises(ValueError, match="pose"):
        jax.jit(sim.camera)(jnp.zeros(4), jnp.ones((4, 2)), sim.SensorParams())


def test_float64_sensor_when_x64_enabled():
    with jax.enable_x64(True):
        lm = jnp.asarray(np.random.default_rng(0).uniform(0, 10, (6, 2)))
        obs = sim.observe(jax.random.key(0), jnp.array([1.0, 2.0, 0.3]), lm,
                          sim.SensorParams(sigma=0.0))
        assert obs.true_rel.dtype == jnp.float64
        rel = brute_force(np.array([1.0, 2.0, 0.3]), np.asarray(lm), 60.0, 2 * np.pi, 0.0)[0]
        np.testing.assert_allclose(obs.true_rel, rel, atol=1e-12)


def test_docstring_examples():
    for mod in (world, rover, sensors, trajectories, lidar):
        result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
        assert result.failed == 0, mod.__name__


def test_top_level_sim_shim_aliases_the_package():
    import importlib
    import warnings

    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        shim = importlib.import_module("sim")
        shim_world = importlib.import_module("sim.world")
    assert shim_world is world
    assert shim.uniform_landmarks is sim.uniform_landmarks
