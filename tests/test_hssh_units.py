"""Issue 26 item 7: the HSSH does not change with units or origin, and bad input raises.

Each test here failed on the code before issue 26: the small-scale star used absolute
constants (1.0, 1e-9, 1e-12), poses were rounded to float32 before differences, and NaN /
zero / absurd arguments gave NaN maps, silent ``enclosed`` places or ZeroDivisionError.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax.hssh import decompose, local_topology, lpm_init, lpm_update
from pqrm_jax.hssh.lpm import LPMParams
from pqrm_jax.hssh.star import build_star, path_continuity
from pqrm_jax.hssh_global import explore, grid_world, office_world, scale_trajectory
from pqrm_jax.sim.corridors import plus_image
from pqrm_jax.sim.lidar import LidarScan

SCALES = st.sampled_from([1e-30, 1e-12, 1e-6, 1e-3, 0.05, 1.0, 7.0, 1e3, 1e6, 1e12, 1e30])


def _place(rng, g):
    """A random place: ``g`` gateways at random bearings and distances around (0, 0)."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, g))
    dist = rng.uniform(0.0, 10.0, g)
    half = rng.uniform(0.5, 6.0, g)
    tilt = rng.normal(0.0, 0.3, g)
    ends, outs = [], []
    for a, d, h, t in zip(ang, dist, half, tilt, strict=True):
        out = np.array([-np.cos(a + t), np.sin(a + t)])        # (row, col)
        mid = d * np.array([-np.cos(a), np.sin(a)])
        side = np.array([-out[1], out[0]])
        ends.append([mid + h * side, mid - h * side])
        outs.append(out)
    return np.array(ends), np.array(outs)


def _key(star):
    return [(e.path, e.direction, e.traversable, e.gateway) for e in star]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), g=st.integers(1, 6), scale=SCALES,
       offset=st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)))
def test_star_is_scale_and_origin_free(seed, g, scale, offset):
    """The star of a place is the same in every unit and at every origin offset (up to 10^6
    place sizes away): 51 of 200 random places changed at x1e-3 before."""
    rng = np.random.default_rng(seed)
    ends, outs = _place(rng, g)
    centre = rng.normal(0.0, 1.0, 2)
    ref = _key(build_star(ends, outs, centre))
    off = np.asarray(offset) * scale
    got = _key(build_star(ends * scale + off, outs, centre * scale + off))
    assert got == ref


def test_star_scale_examples_that_failed():
    """The counted example of the issue: 200 random places at x1e-3 (51 changed before)."""
    rng = np.random.default_rng(26)
    changed = 0
    for _ in range(200):
        ends, outs = _place(rng, int(rng.integers(1, 6)))
        c = rng.normal(0.0, 1.0, 2)
        changed += _key(build_star(ends, outs, c)) != _key(build_star(ends * 1e-3, outs,
                                                                        c * 1e-3))
    assert changed == 0


@settings(max_examples=40, deadline=None)
@given(scale=SCALES, x=st.floats(-4.2e6, 4.2e6), y=st.floats(-4.2e6, 4.2e6),
       th=st.floats(-3.1, 3.1), step=st.floats(0.01, 10.0), head=st.floats(-3.1, 3.1))
def test_decompose_differences_first(scale, x, y, th, step, head):
    """A step of length ``step`` reads ``step`` at any origin (UTM-sized) and in any unit."""
    prev = np.array([x * scale, y * scale, th])
    pose = prev + np.array([step * scale * math.cos(head), step * scale * math.sin(head), 0.1])
    a, rho, b = (float(v) for v in decompose(prev, pose))
    assert abs(abs(rho) - step * scale) <= 1e-5 * step * scale


def test_decompose_utm_step():
    """At (5e5, 4.2e6) m a 0.1 m step read 0.0 m when poses were cast to float32 first."""
    prev = np.array([5e5, 4.2e6, 0.0])
    rho = float(decompose(prev, prev + np.array([0.0, 0.1, 0.0]))[1])
    assert rho == pytest.approx(0.1, abs=1e-6)


def _scans(n=3):
    ang = jnp.linspace(-np.pi, np.pi, 90, endpoint=False)
    rng = np.random.default_rng(0)
    return [LidarScan(ang, jnp.asarray(rng.uniform(0.3, 0.9, 90), jnp.float32),
                      jnp.ones(90, bool)) for _ in range(n)]


@pytest.mark.parametrize("offset_cells", [(0, 0), (10_000_000, 84_000_000),
                                          (-3_000_001, 7)])
def test_lpm_same_map_at_utm_origin(offset_cells):
    """The LPM built at UTM-sized coordinates equals the one built near (0, 0) (a third of
    the cells flipped before), including scrolls."""
    p = LPMParams(size=41, resolution=0.05)
    r64 = float(np.float32(p.resolution))
    local = [np.array([0.013, 0.021, 0.3]), np.array([0.113, 0.021, 0.35]),
             np.array([0.213, 0.171, 0.4])]
    maps = []
    for off in ((0, 0), offset_cells):
        o = np.array([off[0] * r64, off[1] * r64, 0.0])
        s = lpm_init(local[0] + o, p)
        for pose, scan in zip(local, _scans(), strict=True):
            s = lpm_update(s, pose + o, scan, p)
        maps.append(np.asarray(s.logodds))
    assert np.abs(maps[0]).sum() > 0
    np.testing.assert_array_equal(maps[1], maps[0])


def test_lpm_float32_callers_unchanged():
    """Float32 and traced poses take the previous float32 path (origin_lo stays 0)."""
    p = LPMParams(size=21, resolution=0.1)
    s = lpm_init(jnp.array([1.0, 2.0, 0.0]), p)
    s = lpm_update(s, jnp.array([1.3, 2.0, 0.0]), _scans(1)[0], p)
    assert np.all(np.asarray(s.origin_lo) == 0)


# ---------------------------------------------------------------- bad input, clear errors


def test_star_bad_input():
    ends = np.array([[[0.0, 4.0], [0.0, 6.0]], [[9.0, 4.0], [9.0, 6.0]]])
    out = np.array([[-1.0, 0.0], [1.0, 0.0]])
    c = np.array([5.0, 5.0])
    bad = ends.copy()
    bad[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match="ends must be finite"):
        build_star(bad, out, c)
    with pytest.raises(ValueError, match="outward normals must be nonzero"):
        build_star(ends, np.zeros((2, 2)), c)
    with pytest.raises(ValueError, match="outward must be finite"):
        build_star(ends, np.full((2, 2), np.inf), c)
    with pytest.raises(ValueError, match="centre"):
        build_star(ends, out, np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="zero-length"):
        build_star(np.zeros((1, 2, 2)), out[:1], c)
    with pytest.raises(ValueError, match="outward normals"):
        path_continuity(ends[0], np.zeros(2), ends[1], out[1])


@pytest.mark.parametrize("m_cap", [0, -1.0, float("nan"), float("inf")])
def test_m_cap_bad(m_cap):
    with pytest.raises(ValueError, match="m_cap"):
        local_topology(plus_image(39), (19, 19), m_cap=m_cap)


@pytest.mark.parametrize("radius", [19.5, 30, 1e6, float("nan"), -1.0])
def test_robot_radius_bad(radius):
    with pytest.raises(ValueError, match="robot_radius"):
        local_topology(plus_image(39), (19, 19), robot_radius=radius)


@pytest.mark.parametrize("pose", [[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0], [0.0, 0.0, np.nan]])
def test_nan_pose(pose):
    with pytest.raises(ValueError, match="pose must be finite"):
        lpm_init(np.array(pose))
    s = lpm_init(np.zeros(3))
    with pytest.raises(ValueError, match="pose must be finite"):
        lpm_update(s, np.array(pose), _scans(1)[0])
    with pytest.raises(ValueError, match="must be finite"):
        decompose(np.zeros(3), np.array(pose))


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), float("inf")])
def test_world_scale_bad(scale):
    with pytest.raises(ValueError, match="scale"):
        grid_world(3, 3, scale=scale)
    with pytest.raises(ValueError, match="scale"):
        office_world(scale=scale)


def test_zero_length_trajectory():
    with pytest.raises(ValueError, match="zero-length"):
        scale_trajectory(np.zeros(3), np.ones(3), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="increments"):
        scale_trajectory(np.zeros(3), np.ones(3), np.zeros(3))


def test_zero_travel_experience_is_empty_not_an_error():
    """An exploration of 0 travels is one view and no odometry (valid, not NaN)."""
    e = explore(grid_world(3, 3, seed=0), 0)
    assert len(e.views) == 1 and e.odometry.shape == (0, 3)


# ------------------------------------- float64 world coordinates in localization (issue 26)

_UTM = np.array([5e5, 4.2e6, 0.0])


def _room(n=41, res=0.1):
    """A 4 m square room with a pillar (occupancy rows along y) and its distance field."""
    from pqrm_jax.hssh.cellular import squared_distance_transform

    g = np.zeros((n, n), bool)
    g[0, :] = g[-1, :] = g[:, 0] = g[:, -1] = True
    g[12:16, 25:30] = True
    return jnp.asarray(g), squared_distance_transform(jnp.asarray(g)[None], cap=20)[0], res


def test_scan_likelihood_at_utm_equals_origin():
    """Poses and map origin shifted by (5e5, 4.2e6) m give the likelihoods at the origin;
    before, the float32 cast put beam ends up to 0.25 m off (other cells)."""
    from pqrm_jax.hssh.localization import scan_likelihood
    from pqrm_jax.sim.lidar import LidarParams, lidar_scan

    g, d2, res = _room()
    pose = np.array([1.93, 2.07, 0.4])
    z = lidar_scan(jax.random.key(0), jnp.asarray(pose, jnp.float32), g, res,
                   params=LidarParams(n_beams=60, max_range=6.0, sigma=0.0))
    poses = pose + np.array([[0.0, 0.0, 0.0], [0.03, -0.02, 0.01], [0.11, 0.07, -0.02]])
    at0 = np.asarray(scan_likelihood(poses, z, d2, np.zeros(2), res, 0.1))
    at_utm = np.asarray(scan_likelihood(poses + _UTM, z, d2, _UTM[:2], res, 0.1))
    assert at0[0] > 0.9
    np.testing.assert_allclose(at_utm, at0, atol=1e-6)


def _log():
    from pqrm_jax.sim.lidar import LidarParams, lidar_scan

    g, d2, res = _room()
    lp = LidarParams(n_beams=36, max_range=6.0, sigma=0.005)
    true = np.array([[1.03, 1.51, 0.0], [1.13, 1.52, 0.02], [1.23, 1.55, 0.04]])
    odom = true + np.array([[0.0, 0.0, 0.0], [-0.01, 0.0, 0.0], [-0.02, 0.01, 0.01]])
    scans = [lidar_scan(jax.random.key(k), jnp.asarray(p, jnp.float32), g, res, params=lp)
             for k, p in enumerate(true)]
    return d2, res, true, odom, scans


def test_localize_at_utm_equals_origin():
    """One localization step at (5e5, 4.2e6) m equals the one at the origin, shifted (float64
    NumPy input). Before, poses were float32 world coordinates: the prior moved by up to
    0.25 m and a 0.1 m odometry step read 0 or 0.5 m."""
    from pqrm_jax.hssh.localization import LocalizeParams, localize_with_count
    from pqrm_jax.hssh.motion import ACTION_MODELS

    d2, res, true, odom, scans = _log()
    c = jnp.asarray(ACTION_MODELS["large"])
    params = LocalizeParams(blocks=2, block=32)
    out = []
    for off in (np.zeros(3), _UTM):
        pose, lik, _ = localize_with_count(jax.random.key(9), odom[0] + off, odom[0] + off,
                                           odom[1] + off, scans[1], d2, off[:2], res, c,
                                           params=params)
        out.append((np.asarray(pose, np.float64) - off, float(lik)))
    np.testing.assert_allclose(out[1][0], out[0][0], atol=1e-5)
    assert abs(out[1][1] - out[0][1]) < 1e-6 and out[0][1] > 0.5


@pytest.mark.slow
def test_track_run_at_utm_equals_origin():
    """A short tracked run (localize, then map) at (5e5, 4.2e6) m equals the one at the
    origin, shifted: poses, likelihoods and the LPM (~15 s: the compile of the run)."""
    from pqrm_jax.hssh.localization import LocalizeParams
    from pqrm_jax.hssh.lpm import LPMParams
    from pqrm_jax.hssh.motion import ACTION_MODELS
    from pqrm_jax.hssh.tracking import lpm_tracker, track_run

    _, _, true, odom, scans = _log()
    c = jnp.asarray(ACTION_MODELS["large"])
    params = LocalizeParams(blocks=2, block=32)
    tracker = lpm_tracker(c, lpm_params=LPMParams(size=48, resolution=0.1), loc_params=params)
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *scans)
    runs = []
    for off in (np.zeros(3), _UTM):
        final, steps = track_run(tracker, jax.random.key(3), true[0] + off, odom + off, stacked)
        runs.append((np.asarray(steps.pose) - off, np.asarray(steps.likelihood),
                     np.asarray(final.lpm.logodds)))
    np.testing.assert_allclose(runs[1][0], runs[0][0], atol=1e-5)
    np.testing.assert_allclose(runs[1][1], runs[0][1], atol=1e-6)
    np.testing.assert_array_equal(runs[1][2], runs[0][2])
