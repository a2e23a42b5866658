"""The Q-Link study (P §4.4.1) in its reduced setting: files, resume, config guard, baseline."""

import csv
import json

import numpy as np
import pytest

from pqrm_jax.studies import discover


def test_reduced_study(tmp_path):
    mod = discover()["qlink"]
    out = tmp_path / "q"
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert set(rows[0]) == set(mod.FIELDS)
    cfg = json.loads((out / "config.json").read_text())
    assert set(mod.REASONS) <= set(cfg["reasons"])          # every knob has a reason
    w = np.load(out / "world_00.npz")
    assert w["positions"].shape == (50, 2) and w["element_ids"].shape[1] == 3
    base = [r for r in rows if r["beta"] == "2" and r["setting"] == "R" and r["reachable"] == "1"]
    assert base and all(r["success"] == "1" for r in base)   # 0 % failure at R' = R
    n = np.array([int(r["n_elements"]) for r in base])
    ln = np.array([float(r["length_m"]) for r in base])
    assert (ln <= (2 * np.pi + 1) * 20.0 * (n + 1)).all()
    fails = [r for r in rows if r["success"] == "0" and r["reachable"] == "1"]
    assert all(r["reason"] in ("link_not_found", "refs_not_found", "goal_not_found",
                               "start_not_localized", "no_plan_from_view") for r in fails)
    report = (out / "report.md").read_text()
    assert "Table 4.1" in report and "Fig. 4.6" in report and "β = 1" in report
    assert (out / "fig4_7_length_vs_elements.png").exists()
    # resume: nothing is recomputed, the rows are identical
    before = (out / "trials.csv").read_text()
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    assert (out / "trials.csv").read_text() == before
    # a different configuration is refused
    with pytest.raises(SystemExit, match="different config"):
        mod.main(["--reduced", "--out", str(out), "--max-pairs", "10", "--no-progress"])
