"""The SERGE study (P§3.4) runs, writes its report and resumes."""

import json

import pytest

from pqrm_jax.studies import discover
from pqrm_jax.studies import serge as study
from pqrm_jax.studies.store import StoreError


def test_study_is_discovered():
    assert discover()["serge"] is study


def test_reduced_study_runs_and_resumes(tmp_path):
    argv = ["--reduced", "--datasets", "hallway", "--trials", "8", "--grid", "40",
            "--out", str(tmp_path)]
    assert study.main(argv) == 0
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    rows = [json.loads(x) for x in lines]
    assert len(rows) == 2 * 9                              # 2 folds × (5 μ + 4 σ)
    assert all(0.0 <= r["error_rate"] <= 1.0 and r["n_regions"] >= 1 for r in rows)
    by_mu = {r["mu"]: r["n_regions"] for r in rows if r["sweep"] == "mu" and r["fold"] == 0}
    assert by_mu[1] == 1 and by_mu[22] > by_mu[5]
    report = (tmp_path / "report.md").read_text()
    assert "Measured vs published" in report and "hallway" in report
    assert (tmp_path / "fig_3_7_cv.png").exists() and (tmp_path / "fig_3_8_maps.png").exists()
    # a rerun finds everything done and adds nothing
    assert study.main(argv) == 0
    assert len((tmp_path / "results.jsonl").read_text().splitlines()) == len(lines)
    # resuming with settings that change results is refused, nothing is appended
    with pytest.raises(StoreError, match="trials"):
        study.main(argv[:4] + ["9"] + argv[5:])
    assert len((tmp_path / "results.jsonl").read_text().splitlines()) == len(lines)


@pytest.mark.slow
def test_reduced_study_all_datasets_matches_published(tmp_path):
    assert study.main(["--reduced", "--out", str(tmp_path)]) == 0
    assert "All checked claims hold: **True**" in (tmp_path / "report.md").read_text()
