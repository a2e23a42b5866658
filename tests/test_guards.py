"""Every entry point guarded (issue 13 item 4): each reproduction of the reliability review
(D10, D14, D16, D17, D22–D25, SparQ S3) fails loudly or returns its documented result."""

from __future__ import annotations

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pqrm_jax import calculi, cli, pqrm, qrm, sim
from pqrm_jax.compositions import propagation as prop
from pqrm_jax.pqrm import metrics


# ------------------------------------------------------------------ D10: fusion weights
@pytest.fixture(scope="module")
def small_map():
    pq = pqrm.mapper(("edc",), 5, 128)
    lm = sim.uniform_landmarks(jax.random.key(3), 5)
    st, _ = pq.update(pq.init(), jax.random.key(0), lm, np.ones(5, bool), 1.0)
    p, o = prop.from_pqrm(st, 5, "edc")
    o = np.array(o)
    o[0, 1, 4] = o[1, 0, 4] = False
    return p, o, calculi.get("edc").tables.prob_compose


@pytest.mark.parametrize("kw", [{"path_weight": float("nan")}, {"path_weight": float("inf")},
                                {"measurement_weight": float("nan"), "mode": "fuse"},
                                {"measurement_weight": float("inf")}])
def test_d10_propagate_refuses_nan_inf_weights(small_map, kw):
    p, o, t = small_map
    with pytest.raises(ValueError, match="weight must be finite"):
        prop.propagate(p, o, t, **kw)


def test_d10_finite_weight_still_gives_a_distribution(small_map):
    p, o, t = small_map
    out = np.asarray(prop.propagate(p, o, t, path_weight=0.5).probs)
    assert np.isfinite(out).all()


# ------------------------------------------------------------------ D14: nothing seen
def test_d14_update_observed_with_no_landmark_seen():
    pq = pqrm.mapper(("edc",), 4, 64)
    s0 = pq.init()
    s1, _ = pqrm.update_observed(pq, s0, jax.random.key(0), [], np.zeros((0, 2)), 0.5)
    assert int(s1.step) == int(s0.step) + 1
    same = jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(a, b)),
                                  s0._replace(step=0), s1._replace(step=0))
    assert all(jax.tree_util.tree_leaves(same))


# ------------------------------------------------------------------ D16/D17: CLI
def _cli(argv, capsys) -> tuple[int, str]:
    try:
        rc = cli.main(argv)
    except SystemExit as exc:  # argparse: usage line + "error: ..." line, code 2
        rc = exc.code
    err = capsys.readouterr().err
    return rc, err


def _cases(tmp_path: Path) -> list[list[str]]:
    f = tmp_path / "f"
    f.write_text("x")
    bad = str(f / "sub")  # a path below a regular file: cannot be created
    return [
        ["study", "padgett-mc", "--runs", "2", "--levels", "2", "--out", str(f)],
        ["study", "padgett-mc", "--runs", "2", "--levels", "2", "--out", bad],
        ["tables", "nope"],
        ["tables", "edc", "--json", str(f / "t.json")],
        ["tables", "--plot", bad],
        ["tables", "--rebuild", "nope"],
        ["study", "padgett-mc", "--report-only", "--out", str(tmp_path / "missing")],
        ["study", "serge", "--trials", "-5", "--out", str(tmp_path / "s")],
        ["study", "padgett-mc", "--levels", "1", "--out", str(tmp_path / "l1")],
    ]


def test_d16_cli_user_errors_are_one_line_exit_2(tmp_path, capsys):
    for argv in _cases(tmp_path):
        rc, err = _cli(argv, capsys)
        assert rc == 2, (argv, rc, err)
        assert "Traceback" not in err and err.strip(), argv
        last = err.strip().splitlines()[-1]
        assert "error:" in last, (argv, err)
    assert not (tmp_path / "l1" / "levels.jsonl").exists()  # D11: refused up front


@pytest.mark.parametrize("argv,flag", [(["--samples", "0"], "--samples"),
                                       (["--landmarks", "2"], "--landmarks"),
                                       (["--runs", "0"], "--runs"),
                                       (["--levels", "1"], "--levels")])
def test_d17_messages_name_real_flags(argv, flag, capsys, tmp_path):
    from pqrm_jax.studies import padgett_mc

    with pytest.raises(SystemExit) as exc:
        padgett_mc.main([*argv, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"{flag} must be" in err or f"argument {flag}: must be" in err
    assert "--num-" not in err
    if flag != "--landmarks":
        assert "landmarks ≥ 3" not in err and "3 landmarks" not in err


# ------------------------------------------------------------------ D22: undefined truth
def test_d22_metrics_exclude_undefined_truths():
    p = jnp.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    truth = jnp.array([0, -1, 1])
    mask = jnp.array([True, True, True])
    assert float(metrics.error_rate(p, truth, mask)) == 0.0
    np.testing.assert_array_equal(np.asarray(metrics.topn_error_rates(p, truth, mask)), [0, 0])
    np.testing.assert_array_equal(np.asarray(metrics.confusion_matrix(p, truth, mask)),
                                  [[1, 0], [0, 1]])
    d = jnp.array([[0, 1], [1, 0]])
    assert float(metrics.neighbor_distance(p, jnp.array([1, -1, 1]), mask, d)) == 0.5


# ------------------------------------------------------------------ D23: clear errors
def test_d23_measure_triples_empty_batch():
    with pytest.raises(ValueError, match="no triple"):
        qrm.camera.measure_triples(np.zeros((0, 3), np.float32))


def test_d23_serge_chunk_and_grid():
    from pqrm_jax.serge import GaussianBeliefs, Grid, initial_cells, serge

    xy = np.stack(np.meshgrid(np.arange(2.0), np.arange(2.0)), -1).reshape(-1, 2) * 10
    p = initial_cells(jax.random.PRNGKey(0),
                      GaussianBeliefs(xy, np.tile(np.eye(2) * 0.2, (4, 1, 1))),
                      Grid((-5.0, -5.0), (15.0, 15.0), (8, 8)))
    with pytest.raises(ValueError, match="chunk must be"):
        serge(jax.random.PRNGKey(0), p, mu=2, sigma=2.0, trials=4, chunk=0)
    with pytest.raises(ValueError, match="cells"):
        Grid((0.0, 0.0), (1.0, 1.0), (100_000, 100_000))


# ------------------------------------------------------------------ D24: NaN / inf
def test_d24_navigate_and_run_sequence_refuse_nan():
    from pqrm_jax.qrm.hypergraph import true_map
    from pqrm_jax.qrm.navigation import navigate
    from pqrm_jax.qrm.pipeline import run_sequence
    from pqrm_jax.qrm.rng import rng_estimate

    lm = jnp.array([[10.0, 10.0], [30.0, 13.0], [52.0, 9.0], [70.0, 12.0]])
    est = rng_estimate(true_map(lm))
    bad = lm.at[1, 0].set(jnp.nan)
    with pytest.raises(ValueError, match="landmarks contains NaN"):
        navigate(bad, est, jnp.array([8.0, 8.0, 0.0]), jnp.array([72.0, 14.0]), n_steps=10)
    poses = sim.random_imaging_points(jax.random.key(1), 3)
    with pytest.raises(ValueError, match="landmarks contain NaN"):
        run_sequence(bad, poses, n=4)
    with pytest.raises(ValueError, match="poses contain NaN"):
        run_sequence(lm, poses.at[0, 0].set(jnp.nan), n=4)


def test_d24_sensor_sigma_inf_refused():
    with pytest.raises(ValueError, match="sigma must be finite"):
        sim.SensorParams(sigma=float("inf"))
    with pytest.raises(ValueError, match="sigma contains NaN or inf"):  # arrays: at observe
        sim.observe(jax.random.key(0), jnp.zeros(3), jnp.ones((3, 2)),
                    sim.SensorParams(sigma=jnp.float32(jnp.inf)))
    assert sim.SensorParams(max_range=float("inf")).max_range == math.inf  # unbounded range


# ------------------------------------------------------------------ D25 (navigation part)
def test_d25_perimeter_loop_pose_bound():
    with pytest.raises(ValueError, match="max_poses"):
        sim.trajectories.perimeter_loop(dtheta=1e-9)
    assert sim.trajectories.perimeter_loop(dtheta=2 * math.pi / 1000).shape == (1000, 3)


# ------------------------------------------------------------------ S3: closure cap
def test_s3_closure_reports_non_convergence():
    from pqrm_jax.qrm.hypergraph import closure, empty_map, true_relations

    lm = sim.uniform_landmarks(jax.random.key(5), 6)
    truth = np.asarray(true_relations(lm))
    rel = np.array(empty_map(6).rel)
    for t in ((0, 1, 2), (1, 2, 3), (2, 3, 4), (3, 4, 5), (0, 2, 4)):  # a chain of triples
        rel[t] = 1 << int(truth[t])
    full = closure(rel)
    assert bool(full.converged) and not bool(full.inconsistent)
    assert int(full.sweeps) >= 2
    cut = closure(rel, max_sweeps=int(full.sweeps) - 1)
    assert not bool(cut.converged) and int(cut.sweeps) == int(full.sweeps) - 1
    with pytest.raises(ValueError, match="max_sweeps"):
        closure(rel, max_sweeps=0)
