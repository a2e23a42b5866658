"""The hssh-maps study in its reduced setting: files, truth never discarded, resume, guard."""

import csv
import json

import pytest

from pqrm_jax.studies import discover
from pqrm_jax.studies.store import StoreError


def test_reduced_study(tmp_path):
    mod = discover()["hssh-maps"]
    out = tmp_path / "h"
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0
    worlds = [json.loads(x) for x in (out / "worlds.jsonl").read_text().splitlines()]
    assert len(worlds) == 4
    for r in worlds:
        if not r["too_large"]:
            assert r["true_in_leaves"] == 1
            assert r["bound_branching_ok"] == 1 and r["bound_events_ok"] == 1
            assert r["layout_err_relaxed"] < r["layout_err_odometry"]
            assert r["star_leaves_prefix"] <= r["basic_leaves_prefix"] or \
                r["basic_leaves_prefix"] == -1
    office = [json.loads(x) for x in (out / "office.jsonl").read_text().splitlines()]
    assert all(r["true_in_leaves"] == 1 and len(r["leaves"]) == 15 for r in office)
    sim = [json.loads(x) for x in (out / "sim.jsonl").read_text().splitlines()]
    assert len(sim) == 1 and sim[0]["lost"] == 0
    assert sim[0]["views_true"] == sim[0]["views"] and sim[0]["true_in_leaves"] == 1
    # the map from dead reckoning agrees with the walls (a frame shifted by w/2: about 0.04);
    # relaxed poses may do worse here: revisit jitter exceeds the odometry error (docs)
    # dead reckoning alone: 0.77 since issue 26 — measured: the 45° side-obstacle cone moves
    # this world's gateways (B's 90° cone: 0.94; the dead-end drive: ±0.01; noise-free: 0.98;
    # docs/hssh_global.md, "Results")
    assert sim[0]["map_agree_odometry"] > 0.7 and sim[0]["map_agree_relaxed"] > 0.3
    # re-localisation at revisits shrinks the place-frame jitter the loop springs carry
    assert sim[0]["reloc_used"] > 0.5
    assert sim[0]["reloc_err_theta"] < 0.6 * sim[0]["revisit_jitter_theta"]
    assert sim[0]["reloc_err_xy"] <= sim[0]["revisit_jitter_xy"]
    # 0.76 on this one world since issue 26, from the 45° side cone (90°: 0.93; noise-free:
    # 1.00); over the full run's 8 worlds the cone raises the mean from 0.80 to 0.92
    assert sim[0]["map_agree_reloc"] > 0.7 and sim[0]["layout_err_reloc"] < 0.1
    assert sim[0]["nav_success"] > 0.4 and isinstance(sim[0]["nav_lost_reasons"], list)
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {"study", "unit", "metric", "value"} == set(rows[0])
    rep = (out / "report.md").read_text()
    assert "83" in rep and "not published" in rep
    assert "Simulator-driven worlds" in rep and "re-localisation" in rep
    for f in ("tree_size.png", "layout.png", "navigation.png", "sim_map.png"):
        assert (out / f).stat().st_size > 1000
    cs = mod.claims(out)                  # the study protocol: claims from the stored records
    assert [c.verdict for c in cs[:2]] == ["match", "match"]   # truth kept, bounds hold
    assert "| the true map is never discarded (random worlds) |" in rep
    for f in ("tree_size.png", "layout.png", "navigation.png", "sim_map.png"):
        assert f"]({f})" in rep                                 # embedded with a caption
    before = (out / "worlds.jsonl").read_text()
    assert mod.main(["--reduced", "--out", str(out), "--no-progress"]) == 0  # resume: no rerun
    assert (out / "worlds.jsonl").read_text() == before
    with pytest.raises(StoreError):
        mod.main(["--reduced", "--out", str(out), "--no-progress", "--seed", "3"])
