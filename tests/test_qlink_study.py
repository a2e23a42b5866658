"""The Q-Link study (P §4.4.1) in its reduced setting: files, resume, config guard, baseline,
and the study store (torn/garbage trial files recomputed alone, a second writer refused)."""

import csv
import json
import warnings

import numpy as np
import pytest

from pqrm_jax.studies import discover
from pqrm_jax.studies.store import CorruptRecordWarning, Store, StoreError


def test_reduced_study(tmp_path):
    mod = discover()["qlink"]
    out = tmp_path / "q"
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert set(rows[0]) == set(mod.FIELDS)
    cfg = json.loads((out / "config.json").read_text())
    assert set(mod.REASONS) <= set(cfg["reasons"])          # every knob has a reason
    info = json.loads((out / "world_00.json").read_text())     # measured times live apart
    assert "map_s" not in info and "setting_s" not in info
    assert {"map_s", "setting_s"} <= set(json.loads((out / "world_00.times.json").read_text()))
    assert json.loads((out / "times.json").read_text())["wall_s"] >= 0
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
    # every figure is embedded with its caption (protocol.figure): alt text = caption below it
    for png in ("fig4_6_path_elements.png", "fig4_7_length_vs_elements.png"):
        cap = next(ln for ln in report.splitlines() if ln.endswith(f"]({png})"))[2:-len(png) - 3]
        assert len(cap) > 40 and f"*{cap}*" in report, png
    cs = mod.claims(out)          # Table 4.1 at the primary beta, one claim per setting
    assert [c.name for c in cs] == ["Table 4.1 failure rate, R (β = 2)",
                                    "Table 4.1 failure rate, 0.8R (β = 2)",
                                    "Table 4.1 failure rate, occ 0.5 m (β = 2)"]
    assert cs[0].verdict == "match" and cs[0].measured == 0.0
    assert "## Claims" in report and "| Table 4.1 failure rate, R (β = 2) |" in report
    # resume: nothing is recomputed, the rows are identical
    before = (out / "trials.csv").read_text()
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    assert (out / "trials.csv").read_text() == before
    # a different configuration is refused
    with pytest.raises(StoreError, match="different config"):
        mod.main(["--reduced", "--out", str(out), "--max-pairs", "10", "--no-progress"])
    assert cfg["precision"] == "float32"
    assert json.loads((out / "study.json").read_text())["study"] == "qlink"
    tidy = list(csv.DictReader((out / "results.csv").open()))
    assert tidy[0].keys() == {"study", "unit", "metric", "value"}
    assert {"w00/b2/R", "mean/b2/R"} <= {r["unit"] for r in tidy}
    # a torn trials file and a garbage one: named, set aside, recomputed alone, same rows
    torn, junk = out / "trials" / "w00_b2_0.8R.csv", out / "trials" / "w00_b1_R.csv"
    text = torn.read_text()
    torn.write_text(text[: len(text) // 2])
    junk.write_bytes(b"\x00\xffgarbage")
    kept = [p for p in (out / "trials").glob("*.csv") if p not in (torn, junk)]
    kept.append(out / "world_00.npz")
    mtimes = {p: p.stat().st_mtime_ns for p in kept}
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    msg = " ".join(str(w.message) for w in rec if w.category is CorruptRecordWarning)
    assert "w00_b2_0.8R.csv" in msg and "w00_b1_R.csv" in msg
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items())
    assert (out / "trials.csv").read_text() == before
    # a second writer on the same --out is refused while the first holds it
    with Store.open(out, "qlink", None):
        with pytest.raises(StoreError, match="in use by another process"):
            mod.main(["--reduced", "--out", str(out), "--no-progress"])


def test_failed_table_dependency_fails_the_study(tmp_path, monkeypatch, capsys):
    """A table cache that cannot be read while the map is built fails the study (exit 2 from
    the CLI, one line naming the table) and stores no trials."""
    from pqrm_jax import cli
    from pqrm_jax.studies import qlink
    from pqrm_jax.studies.store import StudyError
    from pqrm_jax.tables import CacheError

    def broken(cfg, w):
        raise CacheError("table file quadrant.json is corrupt (truncated)")

    monkeypatch.setattr(qlink, "build_world", broken)
    out = tmp_path / "q"
    with pytest.raises(StudyError, match="table the map of world 0 needs"):
        qlink.main(["--reduced", "--out", str(out), "--no-progress"])
    assert cli.main(["study", "qlink", "--reduced", "--out", str(out), "--no-progress"]) == 2
    assert "quadrant.json is corrupt" in capsys.readouterr().err
    assert not list(out.rglob("*.csv"))
