"""The store never blocks or loses work (issue 29 item 3): a NaN setting resumes, a kill
between the study marker and ``config.json`` never blocks, prose is not guarded and a refusal
is short and names the keys, records are appended (not rewritten), measured times live apart
from results."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst

from pqrm_jax.studies import store as store_mod
from pqrm_jax.studies.store import (
    Store,
    StoreError,
    canonical,
    config_diff,
    read_jsonl,
    tidy_rows,
)

_leaf = hst.one_of(hst.floats(allow_nan=True, allow_infinity=True), hst.integers(-10**6, 10**6),
                   hst.booleans(), hst.text(max_size=5), hst.none())
_cfg = hst.dictionaries(hst.text(min_size=1, max_size=6),
                        hst.recursive(_leaf, lambda c: hst.lists(c, max_size=3)
                                      | hst.dictionaries(hst.text(max_size=3), c, max_size=3),
                                      max_leaves=8), max_size=5)


@settings(max_examples=60, deadline=None)
@given(_cfg)
def test_a_config_equals_itself_after_a_json_round_trip(cfg):
    """NaN, inf, 1e-30..1e30, nested lists: the stored config is never 'different' from the
    one that wrote it (today NaN != NaN refuses every resume)."""
    back = json.loads(json.dumps(cfg))
    assert config_diff(back, cfg) == []
    assert canonical(back) == canonical(cfg)


def test_a_directory_whose_config_holds_nan_resumes(tmp_path):
    out = tmp_path / "s"
    cfg = {"eps": math.nan, "x": [1.0, math.inf, -math.inf], "n": 3}
    Store.open(out, "demo", cfg).close()
    Store.open(out, "demo", cfg).close()  # the same config again: resumed, not refused
    with pytest.raises(StoreError, match=r"different config \(n: 3 there, 4 asked\)"):
        Store.open(out, "demo", dict(cfg, n=4))


@pytest.mark.parametrize("fresh", [False, True])
def test_a_kill_between_marker_and_config_never_blocks(tmp_path, monkeypatch, fresh):
    """The second of the two writes of a first open is killed (an exception there): the
    directory is still resumable, and --fresh works on it."""
    out = tmp_path / "s"
    real, calls = store_mod.atomic_write_json, []

    def dying(path, obj, indent=1):
        calls.append(path.name)
        if len(calls) == 2:
            raise KeyboardInterrupt("killed")
        return real(path, obj, indent)

    monkeypatch.setattr(store_mod, "atomic_write_json", dying)
    with pytest.raises(KeyboardInterrupt):
        Store.open(out, "demo", {"n": 1})
    monkeypatch.setattr(store_mod, "atomic_write_json", real)
    assert calls[0] == "study.json"  # the marker is written first
    Store.open(out, "demo", {"n": 1}, fresh=fresh).close()
    assert json.loads((out / "study.json").read_text())["study"] == "demo"
    # an older version's order (config.json, then killed before the marker) is adopted too
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.json").write_text(json.dumps({"n": 1, "precision": "float32"}))
    Store.open(old, "demo", {"n": 1}, fresh=fresh).close()


def test_prose_is_not_guarded_and_a_refusal_is_short(tmp_path):
    out = tmp_path / "s"
    reasons = {f"knob{i}": "a long reason " * 20 for i in range(12)}
    Store.open(out, "demo", {"n": 1, "reasons": reasons}).close()
    reworded = {k: v.upper() for k, v in reasons.items()}
    with Store.open(out, "demo", {"n": 1, "reasons": reworded}) as st:  # rewording: resumes
        assert st.config["reasons"] == reworded  # the current prose is stored for the reader
    big = {f"k{i}": list(range(200)) for i in range(10)}
    Store.open(tmp_path / "t", "demo", big).close()
    with pytest.raises(StoreError) as exc:
        Store.open(tmp_path / "t", "demo", {k: v[::-1] for k, v in big.items()})
    msg = str(exc.value)
    assert len(msg) < 600, len(msg)
    assert all(f"k{i}" in msg for i in range(10))  # every differing key is named


def test_records_are_appended_not_rewritten(tmp_path, monkeypatch):
    writes = []
    real = store_mod.atomic_write_text
    monkeypatch.setattr(store_mod, "atomic_write_text",
                        lambda p, t: (writes.append(p.name), real(p, t))[1])
    with Store.open(tmp_path / "s", "demo", {"n": 1}) as st:
        log = st.records("r.jsonl", key=lambda r: r["u"], required=("u", "x"))
        written = [w for w in writes]
        for u in (3, 1, 2, 0, *range(4, 300)):
            log.add({"u": u, "x": u / 7})
        assert writes == written  # no whole-file rewrite per record
        assert len((tmp_path / "s" / "r.jsonl").read_text().splitlines()) == 300
    # closed: the file is put in key order once, equal to an uninterrupted sorted run
    lines = (tmp_path / "s" / "r.jsonl").read_text().splitlines()
    assert [json.loads(x)["u"] for x in lines] == list(range(300))
    # a torn last line (a kill inside a write) is named, dropped and repaired before appending
    p = tmp_path / "s" / "r.jsonl"
    p.write_text(p.read_text() + '{"u": 300, "x"')
    with Store.open(tmp_path / "s", "demo", {"n": 1}) as st:
        with pytest.warns(store_mod.CorruptRecordWarning, match="torn"):
            log = st.records("r.jsonl", key=lambda r: r["u"], required=("u", "x"))
        log.add({"u": 300, "x": 1.0})
    good, bad = read_jsonl(p, key=lambda r: r["u"], required=("u", "x"))
    assert len(good) == 301 and not bad


def test_measured_times_live_apart_from_results(tmp_path):
    """Two identical runs with different wall times: every results file is byte-identical;
    the times are kept in a sidecar and merged back for the study's report."""
    def run(out, speed):
        with Store.open(out, "demo", {"n": 3}) as st:
            log = st.records("w.jsonl", key=lambda r: r["world"], required=("world", "explore_s"))
            for w in range(3):
                log.add({"world": w, "score": w * 0.25, "explore_s": speed * (w + 1.5),
                         "seconds": speed})
            assert log.get(1)["explore_s"] == speed * 2.5
            st.write_results_csv(tidy_rows(log.values(), unit=lambda r: r["world"],
                                           skip=("world",)))
        with Store.open(out, "demo", {"n": 3}) as st:  # resumed: the times are merged back
            log = st.records("w.jsonl", key=lambda r: r["world"], required=("world", "explore_s"))
            assert len(log) == 3 and log.get(2)["explore_s"] == speed * 3.5

    run(tmp_path / "a", 1.0)
    run(tmp_path / "b", 7.3)
    for name in ("w.jsonl", "results.csv", "config.json", "study.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert "explore_s" not in (tmp_path / "a" / "results.csv").read_text()
    assert "7.3" in (tmp_path / "b" / "w.times.jsonl").read_text()


def test_fresh_wipes_only_its_own_study(tmp_path):
    """``--fresh`` in a study that opens its store later (protocol.fresh_start): process 0
    wipes its own study's directory; another study's directory is refused; other processes
    touch nothing."""
    import argparse

    from pqrm_jax.studies import protocol
    from pqrm_jax.studies.distributed import Cluster

    out = tmp_path / "s"
    with Store.open(out, "demo", {"n": 1}) as st:
        st.write_json("unit.json", {"x": 1})
    args = argparse.Namespace(fresh=True)
    protocol.fresh_start(args, out, "demo", Cluster(1, 2, "h:1"))  # not process 0: kept
    assert (out / "unit.json").exists()
    with pytest.raises(StoreError, match="holds a 'demo' study, not 'other'"):
        protocol.fresh_start(args, out, "other", Cluster(0, 2, "h:1"))
    assert (out / "unit.json").exists()
    protocol.fresh_start(args, out, "demo", Cluster(0, 2, "h:1"))
    assert not (out / "unit.json").exists() and not (out / "config.json").exists()
    Store.open(out, "demo", {"n": 2}).close()  # a new configuration is accepted after --fresh
    protocol.fresh_start(argparse.Namespace(fresh=False), out, "demo")
    assert (out / "config.json").exists()
