"""pqrm_jax.plot draws each kind of map; the figures carry what they claim to show."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from pqrm_jax import calculi, hssh, io, plot, pqrm, qlink, qrm, sim  # noqa: E402
from pqrm_jax import hssh_global as hg  # noqa: E402

DATA = Path(__file__).parent / "data"
# set PQRM_JAX_PLOT_DIR to keep the PNGs (to look at them)
OUT = os.environ.get("PQRM_JAX_PLOT_DIR")


def _save(ax, tmp_path, name):
    p = Path(OUT or tmp_path) / f"{name}.png"
    p.parent.mkdir(parents=True, exist_ok=True)
    ax.figure.savefig(p, dpi=90)
    plt.close(ax.figure)
    assert p.stat().st_size > 5000
    return p


def _lines(ax, color):
    return [ln for ln in ax.lines if matplotlib.colors.same_color(ln.get_color(), color)]


def _marks(ax, label):
    """Number of triple marks of one kind drawn by ``draw_relational_map``."""
    return sum(len(c.get_offsets()) for c in ax.collections if c.get_label() == label)


def test_pqrm_and_qrm_maps(tmp_path):
    lm = io.load_landmarks(DATA / "landmarks.csv")
    n = lm.shape[0]
    pq = pqrm.mapper(("edc",), num_landmarks=n, num_samples=64)
    s = pq.init()
    for t in range(3):
        noisy = lm + np.random.default_rng(t).normal(0, 0.5, lm.shape).astype(np.float32)
        s, _ = pq.update(s, jax.random.key(t), jnp.asarray(noisy), jnp.ones(n, bool), 0.5)
    ax = plot.draw_relational_map(lm, s, calculus="edc", max_triangles=56)
    assert "PQRM map (edc): 56 triples mapped" in ax.get_title()
    assert ax.get_xlabel() == "x" and ax.figure.axes[-1].get_ylabel().startswith("uncertainty")
    _save(ax, tmp_path, "pqrm_map")
    # the true QRM map: every relation certain and correct -> no red triangle, 0 bits
    ax = plot.draw_relational_map(lm, qrm.true_map(jnp.asarray(lm), "edc"), calculus="edc")
    assert "ML state correct 100%" in ax.get_title()
    # (one triple of the example layout lies on an EDC boundary: it has no true state)
    assert _marks(ax, plot.CORRECT) == 55 and _marks(ax, plot.NO_STATE) == 1
    assert _marks(ax, plot.WRONG) == 0
    _save(ax, tmp_path, "qrm_true_map")
    # an empty QRM map: every relation open -> every triple a wrong (not unique) mark
    ax = plot.draw_relational_map(lm, qrm.empty_map(n, "edc"), calculus="edc", max_triangles=10)
    assert _marks(ax, plot.WRONG) == 10 and _marks(ax, plot.CORRECT) == 0
    assert "correct 0%" in ax.get_title()
    plt.close(ax.figure)


def test_relational_map_marks_every_triple_once_at_its_centroid():
    """Each drawn triple is one mark at its triangle's centroid, whatever the overlap of
    triangles (edges are shared by n - 2 triangles in a dense map); half-wrong map -> the
    marks split exactly as the correctness of the rows."""
    lm = io.load_landmarks(DATA / "landmarks.csv")
    n = lm.shape[0]
    m = qrm.true_map(jnp.asarray(lm), "edc")
    rel = np.asarray(m.rel).copy()
    edc = calculi.get("edc")
    tri = [(i, j, k) for i in range(n) for j in range(i + 1, n) for k in range(j + 1, n)
           if int(edc.classify(*lm[[i, j, k]])) >= 0]   # layouts with a true state
    assert len(tri) == 55
    wrong = tri[::2]
    for i, j, k in wrong:          # open every state of ij:k: not unique -> wrong mark
        rel[i, j, k] = (1 << 20) - 1
    ax = plot.draw_relational_map(lm, m._replace(rel=jnp.asarray(rel)), calculus="edc",
                                  max_triangles=56)
    assert _marks(ax, plot.WRONG) == len(wrong)
    assert _marks(ax, plot.CORRECT) == len(tri) - len(wrong)
    got = {tuple(np.round(p, 6)) for c in ax.collections if c.get_label() == plot.WRONG
           for p in c.get_offsets()}
    assert got == {tuple(np.round(np.asarray(lm, float)[list(t)].mean(0), 6)) for t in wrong}
    plt.close(ax.figure)


def test_link_graph_with_planned_and_driven_path(tmp_path):
    lm = io.load_landmarks(DATA / "landmarks.csv")
    poses = io.load_poses(DATA / "poses.csv")
    el, _ = qlink.from_mapping_run(jax.random.key(0), jnp.asarray(lm), jnp.asarray(poses),
                                   sim.SensorParams(max_range=6.0, sigma=0.05))
    g = qlink.link_graph(el, 2)
    plan = qlink.plan_pairs(g, el, np.array([0]), np.array([7]))
    assert bool(plan.reachable[0])
    path = np.asarray(plan.path[0])
    ids = np.asarray(el.ids)[path[path >= 0]]
    driven = np.vstack([lm[0] + [0.3, 0.3], lm[ids].mean(1), lm[7] - [0.3, 0.3]])
    ax = plot.draw_link_graph(lm, el, g, planned=plan.path[0], driven=driven)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(lbl.startswith("planned path") for lbl in labels) and "driven path" in labels
    _save(ax, tmp_path, "link_graph")


def test_local_topology_over_the_ros_map(tmp_path):
    g = io.load_ros_map(DATA / "t_junction.yaml")
    lt = hssh.local_topology(g.occupied, (9, 22), unknown=g.unknown)
    ax = plot.draw_local_topology(g.occupied, lt, unknown=g.unknown, robot_cell=(9, 22))
    assert len(_lines(ax, "tab:red")) == 3  # three gateways
    assert "place, 2 paths" in ax.get_title() and ax.get_xlabel() == "column (cells)"
    _save(ax, tmp_path, "local_topology")


def test_topological_map_with_and_without_layout(tmp_path):
    w = hg.grid_world(2, 3, loop_prob=0.5, seed=1)
    e = hg.explore(w, 10, seed=2)
    log = hg.build_tree(e)
    h = next(x for x in log.leaves if hg.is_true_map(x, e))
    lay = hg.true_layout(w, e)
    ax = plot.draw_topological_map(h, lay)
    assert f"{h.n_places} places" in ax.get_title() and ax.get_xlabel() == "x"
    np.testing.assert_allclose(ax.collections[1].get_offsets(), lay[:, :2])
    _save(ax, tmp_path, "topological_map")
    ax = plot.draw_topological_map(h)
    assert ax.get_xlabel().startswith("layout x")
    _save(ax, tmp_path, "topological_map_spring")


def test_bad_calculus_name_is_refused():
    lm = io.load_landmarks(DATA / "landmarks.csv")
    with pytest.raises((ValueError, KeyError)):
        plot.draw_relational_map(lm, qrm.true_map(jnp.asarray(lm), "edc"), calculus="nope")
