"""The qbsp study (Z §4.3) at test size: outputs, raw rows, resume, chunk independence."""

import csv
import json

import pytest

from pqrm_jax.studies import discover, qbsp


def _run(out, *extra):
    return qbsp.main(["--tiny", "--out", str(out), "--no-progress", "--eps", "0.35",
                      "--envs", "4", *extra])


def test_tiny_study(tmp_path, request):
    assert "qbsp" in discover()
    models = str(request.config.cache.mkdir("bsp-models"))
    out = tmp_path / "s"
    assert _run(out, "--models-dir", models, "--chunk", "4") == 0
    rows = list(csv.DictReader(open(out / "tests.csv")))
    assert len(rows) == 4 * 4
    assert {r["mode"] for r in rows} == {"without", "with"} and {r["cost"] for r in rows} == {
        "1", "2"}
    for r in rows:  # plan exists is cost-independent and monotone
        twin = next(x for x in rows if x["env"] == r["env"] and x["mode"] == r["mode"]
                    and x["cost"] != r["cost"])
        assert r["plan_exists"] == twin["plan_exists"]
    envs = [json.loads(x) for x in open(out / "environments.jsonl")]
    assert len(envs) == 4 and all(len(e["triplets"]) == len(e["pos"]) - 2 for e in envs)
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["calibration"]["knob"] is None and "decisions" in cfg
    rep = (out / "report.md").read_text()
    assert "0.684" in rep and "0.816" in rep and "ratio" in rep
    assert (out / "fig45_plan_exists.png").exists()
    before = (out / "tests.csv").read_text()
    # resume: nothing recomputed, same rows; a different configuration is refused
    (out / "report.md").unlink()
    assert _run(out, "--models-dir", models, "--chunk", "4") == 0
    assert (out / "tests.csv").read_text() == before
    with pytest.raises(SystemExit, match="different config"):
        _run(out, "--models-dir", models, "--depth", "2")


@pytest.mark.slow
def test_results_independent_of_chunking(tmp_path, request):
    models = str(request.config.cache.mkdir("bsp-models"))
    _run(tmp_path / "a", "--models-dir", models, "--chunk", "4")
    _run(tmp_path / "b", "--models-dir", models, "--chunk", "3")
    ra = list(csv.DictReader(open(tmp_path / "a" / "tests.csv")))
    rb = list(csv.DictReader(open(tmp_path / "b" / "tests.csv")))
    assert len(ra) == len(rb) == 16
    floats = ("executed_cost", "cost1", "cost2", "root_value")
    for x, y in zip(ra, rb, strict=True):  # discrete outcomes exact, floats to rounding
        assert {k: v for k, v in x.items() if k not in floats} == \
            {k: v for k, v in y.items() if k not in floats}
        for k in floats:
            assert abs(float(x[k]) - float(y[k])) <= 1e-4 * max(1.0, abs(float(x[k])))


@pytest.mark.slow
def test_results_independent_of_device_count(tmp_path, request):
    """The tiny study on 4 forced host devices (lanes sharded) gives the 1-device rows."""
    import os
    import subprocess
    import sys

    models = str(request.config.cache.mkdir("bsp-models"))
    _run(tmp_path / "one", "--models-dir", models, "--chunk", "4")
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    code = ("import sys; from pqrm_jax.studies import qbsp; sys.exit(qbsp.main(sys.argv[1:]))")
    subprocess.run([sys.executable, "-c", code, "--tiny", "--out", str(tmp_path / "four"),
                    "--no-progress", "--eps", "0.35", "--envs", "4", "--chunk", "4",
                    "--models-dir", models], check=True, env=env)
    res = json.loads((tmp_path / "four" / "results.json").read_text())
    assert res["timing"]["devices"] == 4
    ra = list(csv.DictReader(open(tmp_path / "one" / "tests.csv")))
    rb = list(csv.DictReader(open(tmp_path / "four" / "tests.csv")))
    floats = ("executed_cost", "cost1", "cost2", "root_value")
    for x, y in zip(ra, rb, strict=True):
        assert {k: v for k, v in x.items() if k not in floats} == \
            {k: v for k, v in y.items() if k not in floats}
        for k in floats:
            assert abs(float(x[k]) - float(y[k])) <= 1e-4 * max(1.0, abs(float(x[k])))
