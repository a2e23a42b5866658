"""The qbsp study (Z §4.3) at test size: outputs, raw rows, resume, chunk independence, and
the study store (a torn record recomputed alone, a second writer refused, a corrupt model
cache failing the study)."""

import csv
import json
import shutil
import warnings

import pytest

from pqrm_jax.studies import discover, qbsp
from pqrm_jax.studies.store import CorruptRecordWarning, Store, StoreError, StudyError


def _run(out, *extra):
    return qbsp.main(["--tiny", "--out", str(out), "--no-progress", "--eps", "0.35",
                      "--envs", "4", *extra])


def test_tiny_study(tmp_path, request, capsys):
    assert "qbsp" in discover()
    models = str(request.config.cache.mkdir("bsp-models"))
    out = tmp_path / "s"
    # no --chunk: sized from the device memory (capped at the 4 environments), then stored
    assert _run(out, "--models-dir", models) == 0
    assert "--chunk 4 environments per call, sized from the memory" in capsys.readouterr().out
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
    assert cfg["eps_fixed"] == 0.35 and "decisions" in cfg and cfg["precision"] == "float32"
    assert cfg["layout"]["chunk"] == 4
    # measured times live apart: timing.json, not results.json
    assert set(json.loads((out / "results.json").read_text())) == {"results"}
    timing = json.loads((out / "timing.json").read_text())
    assert timing["total_s"] >= 0 and timing["lane_seconds_mean"] > 0
    rec = json.loads((out / "chunks" / "env00000.json").read_text())
    assert len(rec["rows"]) == 4 and not any("lane_seconds" in r for r in rec["rows"])
    assert json.loads((out / "study.json").read_text())["study"] == "qbsp"
    tidy = list(csv.DictReader(open(out / "results.csv")))
    assert tidy[0].keys() == {"study", "unit", "metric", "value"}
    assert {r["unit"] for r in tidy} >= {"env00000/with/cost1", "table4.1"}
    rep = (out / "report.md").read_text()
    assert "0.684" in rep and "0.816" in rep and "ratio" in rep
    assert (out / "fig45_plan_exists.png").exists()
    assert "![Z Fig. 4.5: share of environments" in rep  # figures embedded with captions
    # --report-only: the same report and claims again from the store alone
    assert qbsp.main(["--report-only", "--out", str(out)]) == 0
    assert (out / "report.md").read_text() == rep
    cs = qbsp.claims(out)
    assert [c.name for c in cs][:2] == ["plan exists, without compositions",
                                        "plan exists, with compositions"]
    assert all(c.verdict.split(":")[0] in ("match", "mismatch", "not checked") for c in cs)
    before = (out / "tests.csv").read_text()
    # resume: nothing recomputed, same rows, the stored chunk kept (a 1000-byte device could
    # not size one: no probe runs); a different configuration is refused
    (out / "report.md").unlink()
    assert _run(out, "--models-dir", models, "--memory-bytes", "1000") == 0
    assert (out / "tests.csv").read_text() == before
    with pytest.raises(StoreError, match="different config"):
        _run(out, "--models-dir", models, "--depth", "2")
    # a torn and a wrong-shape record: named, set aside, recomputed alone, same rows
    dmg = tmp_path / "damaged"
    shutil.copytree(out, dmg)
    p1, p2 = dmg / "chunks" / "env00001.json", dmg / "chunks" / "env00002.json"
    p1.write_text(p1.read_text()[:40])
    p2.write_text('{"env": 2, "rows": []}')
    kept = {i: (dmg / "chunks" / f"env{i:05d}.json").stat().st_mtime_ns for i in (0, 3)}
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        assert _run(dmg, "--models-dir", models, "--chunk", "4") == 0
    msg = " ".join(str(w.message) for w in rec if w.category is CorruptRecordWarning)
    assert "env00001.json" in msg and "env00002.json" in msg
    assert all((dmg / "chunks" / f"env{i:05d}.json").stat().st_mtime_ns == t
               for i, t in kept.items())
    assert (dmg / "tests.csv").read_text() == before
    # a second writer on the same --out is refused while the first holds it
    with Store.open(out, "qbsp", None):
        with pytest.raises(StoreError, match="in use by another process"):
            _run(out, "--models-dir", models, "--chunk", "4")
    # a device too small for one environment (the cached probe), or for the given chunk:
    # refused naming --chunk before any environment is written
    with pytest.raises(StudyError, match="--chunk cannot go below one lane"):
        _run(tmp_path / "small", "--models-dir", models, "--memory-bytes", "1000")
    assert not (tmp_path / "small").exists()
    with pytest.raises(StudyError, match="a chunk of 4 environments .* lower --chunk"):
        _run(tmp_path / "small", "--models-dir", models, "--chunk", "4",
             "--memory-bytes", "1000")
    assert not list((tmp_path / "small").glob("chunks/*.json"))


def test_corrupt_model_cache_fails_the_study(tmp_path):
    from pqrm_jax.bsp import models as M

    key = M.ModelParams(**qbsp.config_for(qbsp.configure(["--tiny"])[0])["models"]).key()
    cache = tmp_path / "models"
    cache.mkdir()
    (cache / f"bsp-edc-{key}.npz").write_bytes(b"PK\x03\x04 torn")
    with pytest.raises(StudyError, match="BSP models are not available"):
        _run(tmp_path / "s", "--models-dir", str(cache))
    assert not list((tmp_path / "s" / "chunks").glob("*.json"))


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
    timing = json.loads((tmp_path / "four" / "timing.json").read_text())
    assert timing["devices"] == 4
    ra = list(csv.DictReader(open(tmp_path / "one" / "tests.csv")))
    rb = list(csv.DictReader(open(tmp_path / "four" / "tests.csv")))
    floats = ("executed_cost", "cost1", "cost2", "root_value")
    for x, y in zip(ra, rb, strict=True):
        assert {k: v for k, v in x.items() if k not in floats} == \
            {k: v for k, v in y.items() if k not in floats}
        for k in floats:
            assert abs(float(x[k]) - float(y[k])) <= 1e-4 * max(1.0, abs(float(x[k])))


@pytest.mark.slow
def test_two_processes_equal_one(tmp_path, request):
    """The tiny study as 2 processes on jax.distributed (calibration, lanes and their gather
    split over the processes; process 0 alone writes) gives the 1-process files bit for bit."""
    import os
    import socket
    import subprocess
    import sys

    models = str(request.config.cache.mkdir("bsp-models"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = "import sys; from pqrm_jax.studies import qbsp; sys.exit(qbsp.main(sys.argv[1:]))"
    args = ["--tiny", "--no-progress", "--envs", "4", "--chunk", "2", "--models-dir", models]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    runs = [[sys.executable, "-c", code, "--out", str(tmp_path / "one"), *args]] + [
        [sys.executable, "-c", code, "--out", str(tmp_path / "two"), *args,
         "--coordinator", f"127.0.0.1:{port}", "--processes", "2", "--process-id", str(i)]
        for i in (1, 0)]
    procs = [subprocess.Popen(r, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env) for r in runs]
    for p in procs:
        _, err = p.communicate(timeout=900)
        assert p.returncode == 0, err[-2000:]
    one, two = tmp_path / "one", tmp_path / "two"
    for f in ("tests.csv", "calibration.json", "sweep.json", "environments.jsonl"):
        assert (one / f).read_text() == (two / f).read_text(), f
    assert sorted(p.name for p in one.iterdir()) == sorted(p.name for p in two.iterdir())
    timing = json.loads((two / "timing.json").read_text())
    assert timing["processes"] == 2 and timing["devices_per_process"] == 1


@pytest.mark.slow
def test_nondetection_extension_is_declared_and_off_by_default(tmp_path, request):
    """The EXTENSION (docs/bsp.md §non-detection): off by default (no key in config.json),
    declared with its reason when on, named in the report; plan existence is unchanged (it is
    decided before any observation); the two configurations never mix."""
    models = str(request.config.cache.mkdir("bsp-models"))
    off, on = tmp_path / "off", tmp_path / "on"
    assert _run(off, "--models-dir", models, "--chunk", "4") == 0
    assert _run(on, "--models-dir", models, "--chunk", "4", "--nondetection") == 0
    c_off = json.loads((off / "config.json").read_text())
    c_on = json.loads((on / "config.json").read_text())
    assert "extensions" not in c_off and "EXTENSION" not in (off / "report.md").read_text()
    assert "Reason" in c_on["extensions"]["nondetection"]
    assert "EXTENSIONS beyond the thesis's model are ON" in (on / "report.md").read_text()
    r_off = list(csv.DictReader(open(off / "tests.csv")))
    r_on = list(csv.DictReader(open(on / "tests.csv")))
    assert [r["plan_exists"] for r in r_off] == [r["plan_exists"] for r in r_on]
    with pytest.raises(StoreError, match="different config"):
        _run(on, "--models-dir", models, "--chunk", "4")
