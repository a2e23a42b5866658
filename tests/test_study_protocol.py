"""The study protocol (issue 29 item 1) on the studies converted to it: a kill keeps finished
units (compositions-heldout wrote only at the end), two identical runs give byte-identical
results files, presets, claims and ``--sweep`` through the same code."""

from __future__ import annotations

import dataclasses
import math
import re

import pytest

from pqrm_jax.cli import main
from pqrm_jax.compositions import simulation
from pqrm_jax.studies import (
    compositions,
    fdc_design,
    mars_yard,
    mcclelland_mc,
    padgett_mc,
    protocol,
    qbsp,
    serge,
)

CONVERTED = (compositions, fdc_design, serge, padgett_mc, mcclelland_mc, mars_yard, qbsp)


def _tiny2():
    cfg, _ = compositions.configure(["--tiny"])
    return dataclasses.replace(cfg, fractions=(0.25, 0.5))


def _files(out):
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())
            if p.is_file() and not p.name.startswith(".") and p.suffix in
            (".json", ".jsonl", ".csv", ".md")}


def test_compositions_heldout_keeps_finished_cells_after_a_kill(tmp_path, monkeypatch):
    cfg = _tiny2()
    ref = tmp_path / "ref"
    compositions.run_study(cfg, ref, quiet=True)
    compositions.report(ref)
    real, calls = simulation.heldout_study, []

    def dying(*a, **k):
        calls.append(k["fraction"])
        if len(calls) == 2:
            raise KeyboardInterrupt("killed in the second cell")
        return real(*a, **k)

    monkeypatch.setattr(simulation, "heldout_study", dying)
    out = tmp_path / "killed"
    with pytest.raises(KeyboardInterrupt):
        compositions.run_study(cfg, out, quiet=True)
    assert len((out / "cells.jsonl").read_text().splitlines()) == 1  # the first cell kept
    calls.clear()
    monkeypatch.setattr(simulation, "heldout_study",
                        lambda *a, **k: (calls.append(k["fraction"]), real(*a, **k))[1])
    compositions.run_study(cfg, out, quiet=True)
    compositions.report(out)
    assert calls == [0.5]  # only the unfinished cell is computed
    assert _files(out) == _files(ref)  # and the files equal an uninterrupted run's


def test_two_identical_runs_are_byte_identical(tmp_path):
    for d in ("a", "b"):
        assert main(["study", "fdc-design", "--tiny", "--no-progress", "--out",
                     str(tmp_path / d)]) == 0
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert a == b and {"design.json", "searches.jsonl", "results.csv", "report.md"} <= set(a)


@pytest.mark.parametrize("mod", CONVERTED, ids=lambda m: m.NAME)
def test_presets_and_flags_build_the_config(mod):
    assert set(mod.PRESETS) == {"tiny", "reduced", "full"}
    full, args = mod.configure([])
    assert full == dataclasses.replace(mod.Config(), seed=args.seed)
    for name in ("tiny", "reduced"):
        cfg, args = mod.configure([f"--{name}", "--seed", "7"])
        assert cfg == dataclasses.replace(mod.Config(**mod.PRESETS[name]), seed=7)
        assert args.preset == name
    # a sweep cell overrides the preset and the flags
    field = dataclasses.fields(mod.Config)[0].name
    value = getattr(mod.Config(), field)
    cfg, _ = mod.configure(["--tiny"], overrides={field: value})
    assert getattr(cfg, field) == value
    # the stored config is JSON and holds every field (prose apart); padgett-mc and qbsp
    # store their own expanded form (every parameter and decision, as earlier versions did)
    if isinstance(mod.Config(), protocol.StudyConfig):
        assert set(mod.Config().to_json()) == {f.name for f in dataclasses.fields(mod.Config)}
    else:
        assert isinstance(mod.Config().to_json(), dict)


# mcclelland-mc goes through the same checks in tests/test_qrm_studies.py (one run there)
@pytest.mark.parametrize("name", ["mars-yard"])
def test_tiny_run_report_only_and_claims_through_the_protocol(name, tmp_path, capsys):
    """A converted study's ``--tiny`` through the one driver (``protocol.main_for``): the
    report holds the protocol's claims table and captioned figures; ``--report-only``
    rewrites it from the store alone; ``claims`` reads the store; a resume computes nothing
    new; every number measured is a claim row or a headline of ``sweep_summary``."""
    from pqrm_jax.studies import discover

    mod, out = discover()[name], tmp_path / "o"
    assert main(["study", name, "--tiny", "--no-progress", "--out", str(out)]) == 0
    text = (out / "report.md").read_text()
    assert "| claim | published | measured | interval | verdict |" in text
    # an undefined figure is written as such ("n/a"), never as a bare "nan"
    assert not re.search(r"\bnan\b", text, re.IGNORECASE), name
    figs = [ln for ln in text.splitlines() if ln.startswith("![")]
    assert figs and all(not ln.startswith("![fig") for ln in figs)  # real captions
    cs = mod.claims(out)
    assert cs and all(isinstance(c, protocol.Claim) for c in cs)
    assert cs[0].name == "true state never removed" and cs[0].verdict == protocol.MATCH
    (out / "report.md").unlink()
    assert main(["study", name, "--report-only", "--out", str(out)]) == 0
    assert (out / "report.md").read_text() == text  # the same report from the store alone
    summary = mod.sweep_summary(out)
    assert set(summary["claims"]) == {c.name for c in cs}
    def units():  # the stored units (mars-yard recomputes traverse 0 for its figures)
        return {p.name: p.stat().st_mtime_ns for p in [*out.rglob("*.npz"),
                                                       *out.glob("traverse_*.json")]
                if not p.name.startswith("traverse_0.")}

    before = units()
    assert main(["study", name, "--tiny", "--no-progress", "--out", str(out)]) == 0
    assert units() == before  # resumed: nothing recomputed


def test_claims_render_the_same_in_every_report(tmp_path):
    c = [protocol.Claim("x < 3 %", "< 3 %", 0.01, (0.0, 0.03), protocol.verdict_in(0.01, 0, .03)),
         protocol.Claim("y", "text", "a text", None, protocol.NOT_CHECKED)]
    lines = protocol.claims_table(c)
    assert lines[2] == "| x < 3 % | < 3 % | 0.01 | [0, 0.03] | match |"
    assert lines[3].endswith("| a text | – | not checked |")
    assert protocol.verdict_in(math.nan, 0, 1) == protocol.NOT_CHECKED
    assert protocol.verdict_in(2.0, 0, 1) == protocol.MISMATCH
    assert protocol.claims_summary(c) == {"x < 3 %": "match", "y": "not checked"}


def test_sweep_through_the_protocol(tmp_path, capsys):
    out = tmp_path / "sw"
    assert main(["study", "compositions-heldout", "--tiny", "--no-progress",
                 "--sweep", "runs=1,2", "--out", str(out)]) == 0
    text = (out / "sweep_report.md").read_text()
    assert "2 of 2 cells finished" in text and "propagated held-out error < uniform" in text
    assert (out / "runs=2" / "report.md").exists()
    # the report of one cell alone, from its store
    assert main(["study", "compositions-heldout", "--report-only", "--out",
                 str(out / "runs=1")]) == 0
