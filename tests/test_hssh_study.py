"""The hssh-plus study (B §6.3.3) on its reduced corpus: runs, resumes, guards its config."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pqrm_jax.studies import discover
from pqrm_jax.studies import hssh_plus as study
from pqrm_jax.studies.store import CorruptRecordWarning, Store, StoreError, StudyError


def test_registered():
    assert discover()["hssh-plus"] is study


# records of the code before the host-stage speed-up (skeleton pruning by tree walks, k-NN side
# picks by argmin; main 83bb97d): the faster code must give the same records
RECORDS = Path(__file__).parent / "data" / "hssh_plus_records.json"


def _records(side, rot, argv):
    got = study.run_unit(side, rot, study._stored(study.configure(argv)[0]))
    for r in got:
        r.pop("seconds")
    return got


def test_reduced_unit_records_equal_the_stored_ones():
    # side 49 of the reduced corpus (2 images)
    assert _records(49, 30.0, ["--reduced"]) == json.loads(RECORDS.read_text())["reduced"]


@pytest.mark.slow
@pytest.mark.parametrize("side, rot", [(49, 30.0), (59, 25.0), (149, 0.0), (149, 25.0),
                                       (299, 40.0)])
def test_unit_records_equal_the_stored_sample(side, rot):
    stored = [r for r in json.loads(RECORDS.read_text())["records"]
              if r["side"] == side and r["rotation"] == rot]
    assert len(stored) == 20
    assert _records(side, rot, []) == stored


def test_reduced_corpus_runs_resumes_and_reports(tmp_path, capsys):
    from pqrm_jax.studies.chunking import FRACTION

    argv = ["--reduced", "--sizes", "49", "--out", str(tmp_path)]   # one size: one compile
    # the chunk sized from a (fake) device memory with room for 1.5 grids: one grid per chunk
    grid = study.grid_bytes(49, {"robot_radius": 0.0, "evg_cap_fraction": 0.2})
    room = str(int(1.5 * grid / FRACTION))
    assert study.main(argv + ["--memory-bytes", room]) == 0
    assert "--chunk 2401 sized from the memory" in capsys.readouterr().out
    units = sorted((tmp_path / "units").glob("*.json"))
    assert len(units) == 2                                    # 1 size x 2 rotations
    rows = [r for u in units for r in json.loads(u.read_text())["records"]]
    assert len(rows) == 4 and {r["noise"] for r in rows} == {0.0, 0.3}
    # noise-free + at 49 cells (paths 16 cells wide, above B's 13-cell bound) is correct
    assert all(r["success"] for r in rows if r["side"] == 49 and r["noise"] == 0.0)
    assert all(r["reason"] for r in rows if not r["success"])
    cfg = json.loads((tmp_path / "config.json").read_text())
    for knob in ("threshold", "robot_radius", "supersample", "evg_cap_fraction", "side_slack",
                 "seed", "method", "noise_levels"):
        assert knob in cfg
    report = (tmp_path / "report.md").read_text()
    assert "5751/6270" in report and "partial corpus" in report
    assert "## Per rotation" in report and "| 30° | 2 |" in report
    for fig in ("accuracy_size_noise.png", "accuracy_rotation_size_noise.png",
                "accuracy_per_rotation.png"):
        assert (tmp_path / fig).stat().st_size > 0
    assert cfg["layout"] == {"chunk_cells": 49 * 49}
    cs = study.claims(tmp_path)           # a partial corpus: nothing checked, nothing failed
    assert cs and all(c.verdict.startswith("not checked") for c in cs)
    assert "](accuracy_size_noise.png)" in report
    before = {u.name: u.read_text() for u in units}
    assert study.main(argv) == 0                                        # resume: nothing new
    assert {u.name: u.read_text() for u in sorted((tmp_path / "units").glob("*.json"))} == before
    # the resume kept the stored chunk though the real memory holds both noise levels
    assert json.loads((tmp_path / "config.json").read_text())["layout"] == cfg["layout"]
    assert (tmp_path / "results.csv").read_text().startswith("study,unit,metric,value")
    # a torn unit is named, set aside and recomputed alone; the other is not touched
    torn, other = units
    torn.write_text(before[torn.name][: len(before[torn.name]) // 2])
    mtime = other.stat().st_mtime_ns
    with pytest.warns(CorruptRecordWarning, match=torn.name):
        assert study.main(argv) == 0
    assert other.stat().st_mtime_ns == mtime
    def untimed(text):
        return [{k: v for k, v in r.items() if k != "seconds"}
                for r in json.loads(text)["records"]]

    assert untimed(torn.read_text()) == untimed(before[torn.name])
    # a record of the wrong shape is refused too
    torn.write_text(json.dumps({"records": [{"side": 49}]}))
    with pytest.warns(CorruptRecordWarning, match="fails its study's check"):
        assert study.main(argv) == 0
    # a second writer on the same --out is refused while the first holds it
    with Store.open(tmp_path, "hssh-plus", None):
        with pytest.raises(StoreError, match="in use by another process"):
            study.main(argv)
    with pytest.raises(StoreError, match="different config"):
        study.main(argv + ["--supersample", "2"])
    # another chunk width (both noise levels in one chunk): the same records
    wide = tmp_path / "wide"
    assert study.main(["--reduced", "--sizes", "49", "--out", str(wide),
                       "--chunk", str(2 * 49 * 49)]) == 0
    assert [untimed(u.read_text()) for u in sorted((wide / "units").glob("*.json"))] == \
        [untimed(before[u.name]) for u in units]
    # measured times live apart (times/): two runs write byte-identical units
    assert [u.read_text() for u in sorted((wide / "units").glob("*.json"))] == \
        [(tmp_path / "units" / u.name).read_text() for u in units]
    assert all(len(json.loads((wide / "times" / u.name).read_text())["seconds"]) == 2
               for u in units)
    # a device without room for one grid, or for the chunk given: refused, nothing written
    small = ["--reduced", "--sizes", "49", "--out", str(tmp_path / "small")]
    cfg = study._stored(study.configure(small)[0])
    with pytest.raises(StudyError, match="--chunk cannot go below one lane"):
        study.chunk_cells(None, tmp_path / "small", [49], cfg, None, memory_bytes=1000)
    with pytest.raises(SystemExit):     # a budget below 1 MiB is refused by the CLI
        study.main(small + ["--memory-bytes", "1000"])
    with pytest.raises(StudyError, match="a chunk of 2 grids of 49x49 cells .* lower "
                                         "--chunk"):
        study.main(small + ["--chunk", str(2 * 49 * 49), "--memory-bytes", room])
    assert not (tmp_path / "small").exists()


@pytest.mark.slow
def test_two_processes_equal_one(tmp_path):
    """hssh-plus on jax.distributed: 2 local processes store the 1-process records."""
    import os
    import socket
    import subprocess
    import sys

    def launch(argvs):
        env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
        procs = [subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  env=env) for a in argvs]
        out = []
        for p in procs:
            try:
                so, se = p.communicate(timeout=600)
            except subprocess.TimeoutExpired:
                for q in procs:
                    q.kill()
                raise
            out.append((p.returncode, so, se))
        return out

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    py = [sys.executable, "-m", "pqrm_jax.cli", "study", "hssh-plus", "--reduced",
          "--sizes", "29,49"]
    two = [*py, "--out", str(tmp_path / "two"), "--coordinator", f"127.0.0.1:{port}",
           "--processes", "2"]
    runs = launch([[*py, "--out", str(tmp_path / "one")], [*two, "--process-id", "1"],
                   [*two, "--process-id", "0"]])
    for rc, _, err in runs:
        assert rc == 0, err[-2000:]

    def records(d):
        out = {}
        for u in sorted((d / "units").glob("*.json")):
            out[u.name] = [{k: v for k, v in r.items() if k != "seconds"}
                           for r in json.loads(u.read_text())["records"]]
        return out

    one, two_r = records(tmp_path / "one"), records(tmp_path / "two")
    assert len(one) == 4 and one == two_r                  # 2 sizes x 2 rotations
    assert (tmp_path / "two" / "report.md").exists()
