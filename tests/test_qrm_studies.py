"""The McClelland studies (M§VIII, MT ch. 1) run end to end from the CLI in reduced form:
reports and figures written, soundness held, resume of mcclelland-mc (its multi-process run:
tests/test_distributed.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pqrm_jax.studies import fdc_design, mars_yard, mcclelland_mc
from pqrm_jax.studies.store import StoreError

MCC = ["--reduced", "--runs", "2", "--images", "6", "--ns", "6", "8", "--no-progress",
       "--exact-sample", "2"]


def _runs(out):
    return {p.name: dict(np.load(p)) for p in sorted((out / "runs").glob("n*_r*.npz"))}


def test_mcclelland_mc_report_and_resume(tmp_path):
    a = tmp_path / "a"
    assert mcclelland_mc.main(MCC + ["--out", str(a)]) == 0
    assert (a / "report.md").exists() and (a / "fig7.png").exists()
    summary = json.loads((a / "summary.json").read_text())["per_n"]
    assert set(summary) == {"6", "8"}
    assert all(s["truth_kept"] and s["runs"] == 2 for s in summary.values())
    # kernel vs exact (z3) sets on first-image triples: sound, and the report shows both
    assert all(s["exact_first_image"]["sound"] and s["exact_first_image"]["triples"] == 2
               for s in summary.values())
    assert "Exact sets (z3 oracle" in (a / "report.md").read_text()
    assert summary["8"]["removed_pct_final"] > summary["6"]["removed_pct_final"]
    # the study protocol (as test_study_protocol checks for mars-yard): the claims table and
    # captioned figures; --report-only rewrites the same report from the store alone
    text = (a / "report.md").read_text()
    assert "| claim | published | measured | interval | verdict |" in text
    figs = [ln for ln in text.splitlines() if ln.startswith("![")]
    assert figs and all(not ln.startswith("![fig") for ln in figs)
    cs = mcclelland_mc.claims(a)
    assert cs[0].name == "true state never removed" and cs[0].verdict == "match"
    assert set(mcclelland_mc.sweep_summary(a)["claims"]) == {c.name for c in cs}
    (a / "report.md").unlink()
    assert mcclelland_mc.main(["--report-only", "--out", str(a)]) == 0
    assert (a / "report.md").read_text() == text
    # measured times live apart: timing.json, never summary.json or results.csv
    timing = json.loads((a / "timing.json").read_text())["per_n"]
    assert timing["6"]["run_wall_s_mean"] > 0 and "peak_slope" in json.loads(
        (a / "timing.json").read_text())
    assert not any("wall" in k or "time" in k for s in summary.values() for k in s)
    assert "wall" not in (a / "results.csv").read_text()
    full = _runs(a)
    assert set(full) == {f"n{n}_r{r}.npz" for n in (6, 8) for r in (0, 1)}
    assert not any("wall" in r or "update_time" in r for r in full.values())
    assert {p.name for p in (a / "times").glob("*.npz")} == set(full)  # the times apart
    # resume: only the missing run is recomputed
    kept = a / "runs" / "n6_r0.npz"
    mtime = kept.stat().st_mtime_ns
    (a / "runs" / "n8_r1.npz").unlink()
    assert mcclelland_mc.main(MCC + ["--out", str(a)]) == 0
    assert kept.stat().st_mtime_ns == mtime and (a / "runs" / "n8_r1.npz").exists()
    # the removed --shard is an unknown option now (multi-process: --coordinator/--processes)
    with pytest.raises(SystemExit):
        mcclelland_mc.main(MCC + ["--out", str(a), "--shard", "0/2"])
    # another configuration is refused rather than mixed into the stored runs
    with pytest.raises(StoreError, match="images"):
        mcclelland_mc.main(MCC[:4] + ["7"] + MCC[5:] + ["--out", str(a)])


def test_mars_yard_reduced(tmp_path):
    assert mars_yard.main(["--reduced", "--runs", "1", "--out", str(tmp_path),
                           "--no-progress"]) == 0
    for f in ("report.md", "fig10.png", "fig11.png", "navigation.png"):
        assert (tmp_path / f).exists(), f
    tr = json.loads((tmp_path / "traverse_0.json").read_text())
    assert tr["truth_kept"] is True
    # the measured wall time lives apart from the stored row (identical runs: identical rows)
    assert "wall_s" not in tr
    assert json.loads((tmp_path / "traverse_0.times.json").read_text())["wall_s"] > 0
    removed = np.asarray(tr["removed_pct"])
    assert np.all(np.diff(removed) >= -1e-6) and removed[-1] > removed[0]
    with pytest.raises(StoreError, match="different config"):  # the full preset
        mars_yard.main(["--runs", "1", "--out", str(tmp_path), "--no-progress"])


def test_fdc_design_reduced(tmp_path):
    assert fdc_design.main(["--reduced", "--out", str(tmp_path), "--no-progress"]) == 0
    design = json.loads((tmp_path / "design.json").read_text())
    assert design and all(d["fully_constrained_end"] and d["none_before_fourth"]
                          for d in design)
