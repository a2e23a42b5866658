"""The hssh-plus study (B §6.3.3) on its reduced corpus: runs, resumes, guards its config."""

from __future__ import annotations

import json

import pytest

from pqrm_jax.studies import discover
from pqrm_jax.studies import hssh_plus as study
from pqrm_jax.studies.store import CorruptRecordWarning, Store, StoreError


def test_registered():
    assert discover()["hssh-plus"] is study


def test_reduced_corpus_runs_resumes_and_reports(tmp_path):
    argv = ["--reduced", "--sizes", "49", "--out", str(tmp_path)]   # one size: one compile
    assert study.main(argv) == 0
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
    before = {u.name: u.read_text() for u in units}
    assert study.main(argv) == 0                                        # resume: nothing new
    assert {u.name: u.read_text() for u in sorted((tmp_path / "units").glob("*.json"))} == before
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
