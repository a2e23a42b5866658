"""Every figure a study report shows is embedded with a caption (issue 30 item 5).

``protocol.figure(path, caption)`` writes ``![caption](path)``, a blank line and ``*caption*``;
each report below must embed every PNG of its directory that way, with a non-empty caption
that says what the axes and marks are. The tiny presets keep this fast.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from pqrm_jax.studies import compositions, fdc_design, serge, sweep

sys.path.insert(0, str(Path(__file__).parent))
from test_sweep import GRID, _tiny_study  # noqa: E402  (the sweep tests' tiny study)

IMAGE = re.compile(r"^!\[(.*)\]\(([^)]+\.png)\)$")


def captions(report: Path) -> dict[str, str]:
    """figure file → caption, checking the ``protocol.figure`` layout of every image line."""
    lines = report.read_text().splitlines()
    found = {}
    for i, line in enumerate(lines):
        if line.startswith("!["):
            m = IMAGE.match(line)
            assert m, f"{report.name}: malformed image line {line!r}"
            alt, path = m.groups()
            assert len(alt.split()) >= 8, f"{report.name}: {path} has no real caption: {alt!r}"
            assert lines[i + 1] == "" and lines[i + 2] == f"*{alt}*", (
                f"{report.name}: {path} is not followed by its caption")
            found[path] = alt
    return found


def every_png_is_captioned(out: Path, report: Path) -> dict[str, str]:
    cap = captions(report)
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs, f"{out} holds no figure"
    assert sorted(cap) == pngs, (sorted(cap), pngs)
    return cap


def test_captions_reject_a_bare_image(tmp_path):
    (tmp_path / "report.md").write_text("# r\n\n![design](fdc_design.png)\n\n| a |\n")
    with pytest.raises(AssertionError, match="no real caption"):
        captions(tmp_path / "report.md")


def test_fdc_design_report_captions_its_figure(tmp_path):
    assert fdc_design.main(["--tiny", "--out", str(tmp_path), "--no-progress"]) == 0
    cap = every_png_is_captioned(tmp_path, tmp_path / "report.md")
    assert "imaging points" in cap["fdc_design.png"] and "MT Fig. 1.6a" in cap["fdc_design.png"]


def test_compositions_report_has_a_captioned_figure(tmp_path):
    assert compositions.main(["--tiny", "--out", str(tmp_path), "--no-progress"]) == 0
    cap = every_png_is_captioned(tmp_path, tmp_path / "report.md")
    assert "fraction of triplets held out" in cap["heldout.png"]


def test_serge_report_captions_both_figures(tmp_path):
    assert serge.main(["--tiny", "--out", str(tmp_path), "--no-progress"]) == 0
    cap = every_png_is_captioned(tmp_path, tmp_path / "report.md")
    assert set(cap) == {"fig_3_7_cv.png", "fig_3_8_maps.png"}
    assert "hallway μ = 18, σ = 2" in cap["fig_3_8_maps.png"]   # the tiny preset: hallway only
    assert "lab" not in cap["fig_3_8_maps.png"]


def test_sweep_report_captions_one_figure_per_metric(tmp_path):
    out = tmp_path / "sw"
    report = sweep.run(_tiny_study([]), [*GRID, "--out", str(out), "--quiet"])
    cap = every_png_is_captioned(out, report)
    assert set(cap) == {"sweep_total.png", "sweep_largest.png"}
    assert cap["sweep_total.png"].startswith("`total` of every finished cell")
    assert cap["sweep_largest.png"].startswith("`largest` of every finished cell")
