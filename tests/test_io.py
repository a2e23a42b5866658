"""pqrm_jax.io: your own data in (CSV / NumPy / ROS maps) and maps out (save/load, GraphML)."""

from __future__ import annotations

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pqrm_jax import hssh, io, pqrm, qlink, qrm, sim
from pqrm_jax import hssh_global as hg
from pqrm_jax.protocols import run

DATA = Path(__file__).parent / "data"


# ----------------------------------------------------------------------------- landmarks
def test_shipped_landmarks_and_poses_load():
    lm = io.load_landmarks(DATA / "landmarks.csv")
    assert lm.shape == (8, 2) and lm.dtype == np.float32
    assert lm[0].tolist() == [0.0, 0.0] and lm[3].tolist() == [6.5, 7.0]  # sorted by id
    poses = io.load_poses(DATA / "poses.csv")
    assert poses.shape == (9, 3) and poses[2, 2] == pytest.approx(1.5708)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(3, 12), scale=st.sampled_from([1e-30, 1e-3, 1.0, 1e6, 1e30]),
       seed=st.integers(0, 2**31 - 1), fmt=st.sampled_from(["csv", "npy", "npz"]))
def test_landmarks_round_trip_any_scale(tmp_path_factory, n, scale, seed, fmt):
    rng = np.random.default_rng(seed)
    lm = (rng.normal(size=(n, 2)) * scale).astype(np.float64)
    p = tmp_path_factory.mktemp("lm") / f"lm.{fmt}"
    perm = rng.permutation(n)
    if fmt == "csv":
        p.write_text("id,x,y\n" + "".join(f"{i},{float(lm[i, 0])!r},{float(lm[i, 1])!r}\n"
                                           for i in perm))
    elif fmt == "npy":
        np.save(p, lm)
    else:
        np.savez(p, landmarks=lm)
    got = io.load_landmarks(p, dtype=np.float64)
    np.testing.assert_array_equal(got, lm)


@pytest.mark.parametrize("text,field", [
    ("x,y\n0,0\n1,0\n", "at least 3"),
    ("x,z\n0,0\n1,0\n2,2\n", "column 'y'"),
    ("x,y\n0,0\n1,nan\n2,2\n", "row 3, column 'y'"),
    ("x,y\n0,0\n1,inf\n2,2\n", "row 3, column 'y'"),
    ("x,y\n0,0\n1,abc\n2,2\n", "'abc' is not a number"),
    ("id,x,y\n0,0,0\n0,1,0\n2,2,2\n", "column 'id' repeats id 0"),
    ("id,x,y\n0,0,0\n1,1,0\n5,2,2\n", "column 'id' must hold the ids 0..2"),
    ("id,x,y\n0,0,0\n1.5,1,0\n2,2,2\n", "column 'id': '1.5' is not an integer"),
    ("", "empty file"),
    ("# comment\nx,y\n0,0\n# another\n1,nan\n2,2\n", "row 5, column 'y'"),
    ("x,y,x\n0,0,0\n", "repeats a column"),
])
def test_bad_landmark_csv_names_file_and_field(tmp_path, text, field):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(io.DataError) as e:
        io.load_landmarks(p)
    assert str(p) in str(e.value) and field in str(e.value)
    assert isinstance(e.value, ValueError)


def test_bad_numpy_landmarks(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((4, 3)))
    with pytest.raises(io.DataError, match=r"a\.npy: 'landmarks' must have shape \(N, 2\)"):
        io.load_landmarks(tmp_path / "a.npy")
    np.save(tmp_path / "b.npy", np.array([[0, 0], [1, np.nan], [2, 2.]]))
    with pytest.raises(io.DataError, match=r"b\.npy: 'landmarks' has NaN or inf .*row 1"):
        io.load_landmarks(tmp_path / "b.npy")
    np.savez(tmp_path / "c.npz", points=np.zeros((4, 2)))
    with pytest.raises(io.DataError, match=r"c\.npz: missing array 'landmarks'"):
        io.load_landmarks(tmp_path / "c.npz")
    (tmp_path / "d.npy").write_bytes(b"not numpy")
    with pytest.raises(io.DataError, match=r"d\.npy: not a readable NumPy file"):
        io.load_landmarks(tmp_path / "d.npy")
    with pytest.raises(io.DataError, match="missing.csv: file not found"):
        io.load_landmarks(tmp_path / "missing.csv")


def test_bad_poses(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("x,y\n0,0\n")
    with pytest.raises(io.DataError, match=r"p\.csv: missing column 'theta'"):
        io.load_poses(p)
    p.write_text("t,x,y,yaw\n0,0,0,0\n0,1,0,0\n")
    with pytest.raises(io.DataError, match=r"p\.csv: row 3, column 't/step'"):
        io.load_poses(p)
    p.write_text("t,x,y,heading\n0,0,0,0\n1,1,0,0.5\n")
    assert io.load_poses(p)[1].tolist() == [1.0, 0.0, 0.5]


# -------------------------------------------------------------------- into the mappers
def _world(n=7, seed=0):
    lm = sim.uniform_landmarks(jax.random.key(seed), n)
    poses = sim.random_imaging_points(jax.random.key(seed + 1), 4)
    return np.asarray(lm), np.asarray(poses)


def test_observations_csv_feeds_pqrm_like_the_arrays(tmp_path):
    lm, poses = _world()
    n = lm.shape[0]
    rows = ["step,landmark,x,y"]
    pos = np.zeros((len(poses), n, 2), np.float32)
    vis = np.zeros((len(poses), n), bool)
    for t, pose in enumerate(poses):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        for m in range(n):
            if (t + m) % 3 == 0:
                continue  # some landmarks unseen
            d = lm[m] - pose[:2]
            x, y = c * d[0] + s * d[1], -s * d[0] + c * d[1]
            rows.append(f"{t},{m},{float(x)!r},{float(y)!r}")
            pos[t, m] = (x, y)
            vis[t, m] = True
    p = tmp_path / "obs.csv"
    p.write_text("\n".join(rows) + "\n")
    obs = io.load_observations(p, n)
    np.testing.assert_array_equal(obs.visible, vis)
    np.testing.assert_array_equal(obs.positions, pos)
    pq = pqrm.mapper(("edc",), num_landmarks=n, num_samples=32)
    a = b = pq.init()
    for t in range(len(poses)):
        a, _ = pq.update(a, jax.random.key(t), obs.positions[t], obs.visible[t], 0.05)
        b, _ = pq.update(b, jax.random.key(t), pos[t], vis[t], 0.05)
    np.testing.assert_array_equal(a.probs["edc"], b.probs["edc"])
    assert int(a.mapped.sum()) > 0


def test_bad_observations(tmp_path):
    p = tmp_path / "o.csv"
    p.write_text("step,landmark,x,y\n0,0,1,1\n0,0,2,2\n")
    with pytest.raises(io.DataError, match=r"o\.csv: step 0 lists landmark 0 twice"):
        io.load_observations(p, 4)
    p.write_text("step,landmark,x,y\n0,9,1,1\n")
    with pytest.raises(io.DataError, match=r"o\.csv: column 'landmark' must lie in 0\.\.3"):
        io.load_observations(p, 4)
    p.write_text("step,landmark,x\n0,1,1\n")
    with pytest.raises(io.DataError, match=r"o\.csv: missing column 'y'"):
        io.load_observations(p, 4)
    with pytest.raises(ValueError, match="num_landmarks"):
        io.load_observations(p, 2)


@pytest.mark.parametrize("order", ["range", "rank"])
def test_bearings_csv_equals_the_simulated_camera_and_maps_the_same(tmp_path, order):
    lm, poses = _world(6, seed=3)
    n = lm.shape[0]
    cams = [sim.camera(jnp.asarray(pz), jnp.asarray(lm), sim.SensorParams(max_range=1e6))
            for pz in poses]
    rows = [f"step,landmark,bearing,{order}"]
    for t, (pz, cam) in enumerate(zip(poses, cams, strict=True)):
        for m in range(n):
            if bool(cam.visible[m]):
                val = (repr(float(np.hypot(*(lm[m] - pz[:2])))) if order == "range"
                       else str(int(cam.range_rank[m])))
                rows.append(f"{t},{m},{float(cam.bearings[m]) + (2 * math.pi if m % 2 else 0)!r},"
                            f"{val}")
    p = tmp_path / "bear.csv"
    p.write_text("\n".join(rows) + "\n")
    b = io.load_bearings(p, n)
    vis = np.stack([np.asarray(c.visible) for c in cams])
    np.testing.assert_array_equal(b.visible, vis)
    np.testing.assert_array_equal(b.range_rank, np.stack([np.asarray(c.range_rank) for c in cams]))
    np.testing.assert_allclose(np.where(vis, b.bearings, 0),
                               np.where(vis, np.stack([np.asarray(c.bearings) for c in cams]), 0),
                               atol=1e-5)
    qm = qrm.mapper("edc", n, n=n)
    images = sim.CameraObservation(*(jnp.asarray(a) for a in b))
    m1, _ = run(qm, jax.random.key(0), qm.init(), images)
    m2, _ = run(qm, jax.random.key(0), qm.init(), jax.tree.map(lambda *x: jnp.stack(x), *cams))
    np.testing.assert_array_equal(m1.rel, m2.rel)


def test_bad_bearing_rank(tmp_path):
    p = tmp_path / "b.csv"
    p.write_text("step,landmark,bearing,rank\n0,0,0.1,0\n0,1,0.2,2\n")
    with pytest.raises(io.DataError, match=r"b\.csv: step 0: column 'rank' must hold 0\.\.1"):
        io.load_bearings(p, 4)
    p.write_text("step,landmark,bearing\n0,0,0.1\n")
    with pytest.raises(io.DataError, match=r"b\.csv: missing column 'rank'"):
        io.load_bearings(p, 4)


def test_landmarks_and_poses_feed_qlink():
    lm = io.load_landmarks(DATA / "landmarks.csv")
    poses = io.load_poses(DATA / "poses.csv")
    el, vis = qlink.from_mapping_run(jax.random.key(0), jnp.asarray(lm), jnp.asarray(poses),
                                     sim.SensorParams(max_range=6.0, sigma=0.05))
    assert vis.shape == (9, 8) and el.ids.shape[0] > 0
    g = qlink.link_graph(el, 2)
    assert g.cost.shape == (el.ids.shape[0],) * 2


# ------------------------------------------------------------------------------ ROS maps
def test_shipped_ros_map_gives_a_t_junction_place():
    g = io.load_ros_map(DATA / "t_junction.yaml")
    assert g.occupied.shape == (34, 40) and g.resolution == 0.05
    assert g.origin == (-1.0, -0.5, 0.0)
    assert g.unknown[0].all() and g.occupied[1].all() and not g.occupied[5, 5]
    assert np.isnan(g.probability[g.unknown]).all()
    lt = hssh.local_topology(g.occupied, g.cell_of((0.35, 0.55)), unknown=g.unknown)
    assert lt.kind == "place" and lt.num_paths == 2 and lt.gateways.shape[0] == 3


def _write(tmp_path, yaml: str, img: bytes | None = None, name="m"):
    y = tmp_path / f"{name}.yaml"
    y.write_text(yaml)
    if img is not None:
        (tmp_path / f"{name}.pgm").write_bytes(img)
    return y


_PGM = b"P5\n3 2\n255\n" + bytes([0, 254, 205, 100, 30, 255])
_YAML = ("image: m.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: {neg}\n"
         "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: {mode}\n")


def test_ros_thresholds_negate_and_modes(tmp_path):
    g = io.load_ros_map(_write(tmp_path, _YAML.format(neg=0, mode="trinary"), _PGM))
    # p = (255 - v) / 255: 0 -> 1 occupied, 254 -> free, 205 -> 0.196 unknown, 100 -> 0.61
    # unknown, 30 -> 0.88 occupied, 255 -> free
    assert g.occupied.tolist() == [[True, False, False], [False, True, False]]
    assert g.unknown.tolist() == [[False, False, True], [True, False, False]]
    n = io.load_ros_map(_write(tmp_path, _YAML.format(neg=1, mode="trinary"), _PGM))
    assert n.occupied.tolist() == [[False, True, True], [False, False, True]]
    s = io.load_ros_map(_write(tmp_path, _YAML.format(neg=0, mode="scale"), _PGM))
    assert not s.unknown.any() and s.occupied.tolist() == g.occupied.tolist()
    r = io.load_ros_map(_write(tmp_path, _YAML.format(neg=0, mode="raw"), _PGM))
    # raw: v in 0..100 is the occupancy percentage, else unknown
    assert r.unknown.tolist() == [[False, True, True], [False, False, True]]
    assert r.occupied.tolist() == [[False, False, False], [True, False, False]]


def test_ascii_and_16_bit_pgm(tmp_path):
    (tmp_path / "a.pgm").write_bytes(b"P2\n# c\n2 1\n65535\n0 65535\n")
    assert io.read_pgm(tmp_path / "a.pgm").tolist() == [[0, 65535]]
    (tmp_path / "b.pgm").write_bytes(b"P5\n2 1\n65535\n" + bytes([0, 0, 255, 255]))
    img = io.read_pgm(tmp_path / "b.pgm")
    assert img.dtype == np.uint16 and img.tolist() == [[0, 65535]]


@pytest.mark.parametrize("yaml,img,field", [
    ("resolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n", _PGM,
     "missing key 'image'"),
    ("image: m.pgm\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n", _PGM,
     "missing key 'resolution'"),
    ("image: m.pgm\nresolution: nan\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n",
     _PGM, "key 'resolution' must be a finite number"),
    ("image: m.pgm\nresolution: -1\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n",
     _PGM, "key 'resolution' must be > 0"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n",
     _PGM, "key 'origin' must be [x, y, yaw]"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nfree_thresh: 0.2\n", _PGM,
     "missing key 'occupied_thresh'"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 0.1\nfree_thresh: 0.2\n",
     _PGM, "'free_thresh' (0.2) exceeds 'occupied_thresh'"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 1.5\nfree_thresh: 0.2\n",
     _PGM, "key 'occupied_thresh' = 1.5 outside"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n"
     "mode: fancy\n", _PGM, "key 'mode' must be one of"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 0.6\nfree_thresh: 0.2\n"
     "negate: 2\n", _PGM, "key 'negate' must be 0 or 1"),
    ("this is not yaml\n", _PGM, "line 1: expected 'key: value'"),
])
def test_bad_ros_yaml_names_file_and_key(tmp_path, yaml, img, field):
    y = _write(tmp_path, yaml, img)
    with pytest.raises(io.DataError) as e:
        io.load_ros_map(y)
    assert str(y) in str(e.value) and field in str(e.value)


@pytest.mark.parametrize("img,field", [
    (b"P6\n3 2\n255\n" + bytes(18), "magic 'P6' is not a PGM"),
    (b"P5\n3 2\n255\n" + bytes(4), "pixel data: 4 bytes, header promises 6"),
    (b"P5\n3 x\n255\n" + bytes(6), "width/height/maxval must be integers"),
    (b"P2\n2 1\n10\n3 11\n", "exceeds maxval 10"),
    (b"P5\n3", "truncated PGM header"),
])
def test_bad_pgm_names_the_image_and_field(tmp_path, img, field):
    y = _write(tmp_path, _YAML.format(neg=0, mode="trinary"), img)
    with pytest.raises(io.DataError) as e:
        io.load_ros_map(y)
    assert "m.pgm" in str(e.value) and field in str(e.value)
    (tmp_path / "m.pgm").unlink()
    with pytest.raises(io.DataError, match=r"m\.pgm: image file not found"):
        io.load_ros_map(y)


@settings(max_examples=30, deadline=None)
@given(res=st.sampled_from([1e-3, 0.05, 1.0, 250.0]), ox=st.floats(-1e3, 1e3),
       oy=st.floats(-1e3, 1e3), yaw=st.floats(-3.1, 3.1), seed=st.integers(0, 10**6))
def test_write_read_ros_map_and_cell_conversions(tmp_path_factory, res, ox, oy, yaw, seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((12, 15)) < 0.3
    unk = ~occ & (rng.random((12, 15)) < 0.2)
    y = io.write_ros_map(tmp_path_factory.mktemp("w") / "map.yaml", occ, unk, resolution=res,
                         origin=(ox, oy, yaw))
    g = io.load_ros_map(y)
    np.testing.assert_array_equal(g.occupied, occ)
    np.testing.assert_array_equal(g.unknown, unk)
    for cell in [(0, 0), (11, 14), (int(rng.integers(12)), int(rng.integers(15)))]:
        assert g.cell_of(g.xy_of(cell)) == cell
    # row 0 is the top: moving up in y (in the map frame) decreases the row
    r0, c0 = 6, 7
    x, yy = g.xy_of((r0, c0))
    up = (x - math.sin(yaw) * res, yy + math.cos(yaw) * res)
    assert g.cell_of(up) == (r0 - 1, c0)
    with pytest.raises(ValueError, match="outside the map"):
        g.cell_of(g.xy_of((-3, 0)))


# ---------------------------------------------------------------------------- maps out
def _maps():
    lm, poses = _world(6, seed=5)
    pq = pqrm.mapper(("edc", "lr"), num_landmarks=6, num_samples=16)
    ps, _ = pq.update(pq.init(), jax.random.key(0), jnp.asarray(lm) - 1.0, jnp.ones(6, bool),
                      0.05)
    qm = qrm.mapper("edc", 6, n=6)
    cams = jax.tree.map(lambda *x: jnp.stack(x), *[
        sim.camera(jnp.asarray(p), jnp.asarray(lm), sim.SensorParams(max_range=1e6))
        for p in poses])
    qmap, _ = run(qm, jax.random.key(1), qm.init(), cams)
    el = qlink.exact_elements(jnp.asarray(lm), np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]]))
    lg = qlink.link_graph(el, 2)
    grid = io.load_ros_map(DATA / "t_junction.yaml")
    lt = hssh.local_topology(grid.occupied, (9, 22), unknown=grid.unknown)
    w = hg.grid_world(2, 3, loop_prob=0.5, seed=1)
    leaves = hg.build_tree(hg.explore(w, 8, seed=2)).leaves
    return {"pqrm": ps, "qrm": qmap, "elements": el, "linkgraph": lg, "local": lt,
            "hypothesis": leaves[0], "leaves": list(leaves)}


@pytest.fixture(scope="module")
def maps():
    return _maps()


def _same(a, b):
    assert type(a) is type(b), (type(a), type(b))
    if isinstance(a, tuple) and hasattr(a, "_fields"):
        for f in a._fields:
            _same(getattr(a, f), getattr(b, f))
    elif isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            _same(a[k], b[k])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    elif isinstance(a, nx.Graph):
        assert nx.utils.nodes_equal(a.nodes(data=True), b.nodes(data=True))
        assert sorted(a.edges(data=True), key=repr) == sorted(b.edges(data=True), key=repr)
    elif isinstance(a, np.ndarray | jax.Array):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b)
    else:
        assert a == b


@pytest.mark.parametrize("name,kind", [
    ("pqrm", "MapState"), ("qrm", "QRMMap"), ("elements", "MapElements"),
    ("linkgraph", "LinkGraph"), ("local", "LocalTopology"), ("hypothesis", "MapHypothesis"),
    ("leaves", None)])
def test_every_map_round_trips(maps, tmp_path, name, kind):
    obj = maps[name]
    p = io.save_map(tmp_path / f"{name}.npz", obj)
    back = io.load_map(p, kind=kind)
    _same(obj, back)
    if kind:
        assert io.map_kind(p).endswith("." + kind)


def test_round_trip_keeps_inf_nan_and_dtypes(tmp_path):
    lg = qlink.LinkGraph(np.array([[np.inf, 1.5], [np.nan, -0.0]]), np.eye(2, dtype=np.int64), 2)
    back = io.load_map(io.save_map(tmp_path / "g.npz", lg))
    _same(lg, back)
    m = qrm.QRMMap(jnp.arange(27, dtype=jnp.uint32).reshape(3, 3, 3), jnp.zeros(3, bool))
    back = io.load_map(io.save_map(tmp_path / "q.npz", m))
    assert isinstance(back.rel, jax.Array) and back.rel.dtype == jnp.uint32


def test_bad_map_files_name_file_and_field(tmp_path, maps):
    p = io.save_map(tmp_path / "q.npz", maps["qrm"])
    with pytest.raises(io.DataError,
                       match=r"q\.npz: field 'kind' is .*QRMMap.*expected 'MapState'"):
        io.load_map(p, kind="MapState")
    import json
    with np.load(p) as z:
        header = json.loads(z["__header__"].tobytes())
        arrays = {k: z[k] for k in z.files if k != "__header__"}
    for field, value, msg in [("format_version", io.MAP_FORMAT_VERSION + 1, "newer than"),
                              ("format_version", "1", "field 'format_version'"),
                              ("format", "other", "field 'format'")]:
        h = dict(header, **{field: value})
        np.savez(tmp_path / "x.npz", __header__=np.frombuffer(json.dumps(h).encode(), np.uint8),
                 **arrays)
        with pytest.raises(io.DataError, match=msg) as e:
            io.load_map(tmp_path / "x.npz")
        assert "x.npz" in str(e.value)
    h = dict(header)
    h["tree"] = dict(h["tree"], cls="os.path.Foo")
    np.savez(tmp_path / "y.npz", __header__=np.frombuffer(json.dumps(h).encode(), np.uint8),
             **arrays)
    with pytest.raises(io.DataError, match=r"y\.npz: refuses class 'os\.path\.Foo'"):
        io.load_map(tmp_path / "y.npz")
    np.savez(tmp_path / "z.npz", a=np.zeros(3))
    with pytest.raises(io.DataError, match=r"z\.npz: not a pqrm-jax map file \(no '__header__'\)"):
        io.load_map(tmp_path / "z.npz")
    (tmp_path / "w.npz").write_bytes(b"garbage")
    with pytest.raises(io.DataError, match=r"w\.npz: not a pqrm-jax map file"):
        io.load_map(tmp_path / "w.npz")
    with pytest.raises(ValueError, match="must end in .npz"):
        io.save_map(tmp_path / "q.bin", maps["qrm"])
    with pytest.raises(TypeError, match="cannot save a value of type"):
        io.save_map(tmp_path / "o.npz", {"f": object()})


@pytest.mark.parametrize("name", ["linkgraph", "hypothesis", "local"])
def test_graphs_to_networkx_and_graphml(maps, tmp_path, name):
    kw = {"elements": maps["elements"]} if name == "linkgraph" else {}
    g = io.networkx_graph(maps[name], **kw)
    assert isinstance(g, nx.Graph) and g.number_of_nodes() > 0
    p = io.write_graphml(maps[name], tmp_path / f"{name}.graphml", **kw)
    h = nx.read_graphml(p)
    assert h.number_of_nodes() == g.number_of_nodes()
    assert h.number_of_edges() == g.number_of_edges()
    if name == "linkgraph":
        lg = maps["linkgraph"]
        assert g.number_of_edges() == int(np.isfinite(lg.cost).sum())
    if name == "hypothesis":
        hyp = maps["hypothesis"]
        assert g.number_of_nodes() == hyp.n_places
    with pytest.raises(TypeError, match="no graph view"):
        io.networkx_graph(maps["qrm"])
