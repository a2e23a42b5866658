"""The study store under faults (issue 13 item 3): SIGKILL at random points and resume bit for
bit, a second writer refused, truncated / empty / garbage / wrong-shape records recomputed
alone, a directory of another study or another precision refused, a failed dependency failing
the study (D4–D9, D11, D15, D20)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from pqrm_jax import cli
from pqrm_jax.studies import padgett_mc
from pqrm_jax.studies.store import (
    CorruptRecordWarning,
    Store,
    StoreError,
    StudyError,
    atomic_write_npz,
    csv_text,
    read_csv,
    read_npz,
)

ROOT = Path(__file__).parent.parent

# A toy study on the store: 12 units, each a ~0.5 MB npz and a JSONL record, deterministic.
TOY = r"""
import sys, time, numpy as np
from pqrm_jax.studies.store import Store, tidy_rows
out = sys.argv[1]
with Store.open(out, "toy", {"units": 12, "seed": 7}) as st:
    log = st.records("units.jsonl", key=lambda r: r["unit"], required=("unit", "mean"))
    for u in range(12):
        if u in log and st.read_npz(f"u{u:02d}.npz", ("x",)) is not None:
            continue
        x = np.random.default_rng([7, u]).standard_normal(65536)
        st.write_npz(f"u{u:02d}.npz", {"x": x})
        time.sleep(0.01)
        log.add({"unit": u, "mean": float(x.mean()), "sd": float(x.std())})
        print("unit", u, flush=True)
    st.write_results_csv(tidy_rows(log.values(), unit=lambda r: r["unit"], skip=("unit",)))
print("done", flush=True)
"""


def _toy(out: Path, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", TOY, str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, **kw)


def _snapshot(out: Path) -> dict:
    snap = {"units.jsonl": (out / "units.jsonl").read_bytes(),
            "results.csv": (out / "results.csv").read_bytes()}
    for p in sorted(out.glob("u*.npz")):
        with np.load(p) as z:
            snap[p.name] = z["x"].tobytes()
    return snap


def test_sigkill_at_random_points_then_resume_is_bit_identical(tmp_path):
    ref = tmp_path / "ref"
    proc = _toy(ref)
    assert proc.wait(60) == 0, proc.stderr.read()
    out, rng, kills = tmp_path / "killed", random.Random(13), 0
    for _ in range(3):
        proc = _toy(out)
        target = rng.randint(1, 3)
        seen = 0
        for line in proc.stdout:
            if line.startswith("unit"):
                seen += 1
            if seen >= target or line.startswith("done"):
                break
        time.sleep(rng.uniform(0.0, 0.02))  # lands inside a write or between units
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait(60)
    proc = _toy(out)
    assert proc.wait(60) == 0, proc.stderr.read()
    assert kills >= 2
    assert _snapshot(out) == _snapshot(ref)
    assert not list(out.glob(".*.tmp-*"))  # temp files of killed writers are cleaned up


def test_second_writer_is_refused(tmp_path):
    out = tmp_path / "s"
    with Store.open(out, "padgett-mc", {"x": 1}):
        with pytest.raises(StoreError, match="in use by another process"):
            Store.open(out, "padgett-mc", {"x": 1})
        proc = subprocess.run([sys.executable, "-m", "pqrm_jax.cli", "study", "padgett-mc",
                               "--runs", "2", "--levels", "2", "--quiet", "--out", str(out)],
                              capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert proc.returncode == 2 and "in use by another process" in proc.stderr
        assert "Traceback" not in proc.stderr
        assert not (out / "levels.jsonl").exists()
    with Store.open(out, "padgett-mc", {"x": 1}):  # released on close
        pass


def _warned(record) -> str:
    return " ".join(str(w.message) for w in record if w.category is CorruptRecordWarning)


def test_records_torn_garbage_and_wrong_shape_lines(tmp_path):
    out = tmp_path / "r"
    with Store.open(out, "toy", {}) as st:
        log = st.records("r.jsonl", key=lambda r: r["unit"], required=("unit", "v"))
        for u in range(4):
            log.add({"unit": u, "v": u * 1.5})
    good = (out / "r.jsonl").read_text().splitlines()
    bad = [good[0], "null", '{"lvl": 2}', "garbage{", good[2], "[1, 2]", good[3][:9]]
    (out / "r.jsonl").write_text("\n".join(bad))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        with Store.open(out, "toy", {}) as st:
            log = st.records("r.jsonl", key=lambda r: r["unit"], required=("unit", "v"))
    msg = _warned(rec)
    for no in (2, 3, 4, 6, 7):
        assert f"r.jsonl:{no}:" in msg
    assert sorted(log.done) == [0, 2]  # lines after a garbage line are still read
    assert [json.loads(x)["unit"] for x in (out / "r.jsonl").read_text().splitlines()] == [0, 2]


@pytest.mark.parametrize("damage", ["truncate", "empty", "garbage", "missing_key"])
def test_corrupt_npz_is_named_and_set_aside(tmp_path, damage):
    p = tmp_path / "a.npz"
    atomic_write_npz(p, {"x": np.arange(10000.0), "y": np.ones(3)})
    data = p.read_bytes()
    if damage == "truncate":
        p.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        p.write_bytes(b"")
    elif damage == "garbage":
        p.write_bytes(os.urandom(len(data)))
    with pytest.warns(CorruptRecordWarning, match="a.npz"):
        got = read_npz(p, ("x", "y", "z") if damage == "missing_key" else ("x", "y"))
    assert got is None and not p.exists() and (tmp_path / "a.npz.corrupt").exists()


def test_wrong_study_and_unknown_files_refused(tmp_path):
    from pqrm_jax.studies import fdc_design, serge

    out = tmp_path / "p"
    with Store.open(out, "padgett-mc", {}):
        pass
    with pytest.raises(StoreError, match="holds a 'padgett-mc' study, not 'fdc-design'"):
        fdc_design.main(["--reduced", "--no-progress", "--out", str(out)])
    with pytest.raises(StoreError, match="not 'serge'"):
        serge.main(["--reduced", "--out", str(out)])
    other = tmp_path / "o"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match="notes.txt"):
        Store.open(other, "padgett-mc", {})


TINY = ["--runs", "4", "--levels", "2", "--samples", "16", "--landmarks", "4", "--quiet"]


def test_padgett_mc_corrupt_levels_recomputed_alone(tmp_path):
    import dataclasses

    out = tmp_path / "mc"
    cfg = padgett_mc.Config(runs=4, levels=2, num_samples=16, num_landmarks=4,
                            representations=("edc", "lr"))  # two representations: fast compile
    padgett_mc.run_study(cfg, out, quiet=True)
    levels = (out / "levels.jsonl").read_text()
    arrays = {p.name: read_npz(p) for p in sorted(out.glob("level_*.npz"))}
    lines = levels.splitlines()
    # level 1: truncated npz; level 2: empty npz; level 3: line replaced by `null`;
    # level 4: line replaced by {"lvl": 2}; a garbage line in the middle
    p1, p2 = out / "level_01.npz", out / "level_02.npz"
    p1.write_bytes(p1.read_bytes()[:300])
    p2.write_bytes(b"")
    lines[3], lines[4] = "null", '{"lvl": 2}'
    lines.insert(2, "#garbage")
    (out / "levels.jsonl").write_text("\n".join(lines) + "\n")
    kept = out / "level_00.npz"
    mtime = kept.stat().st_mtime_ns
    with pytest.warns(CorruptRecordWarning) as rec:
        padgett_mc.run_study(cfg, out, quiet=True)
    msg = _warned(rec)
    assert "level_01.npz" in msg and "level_02.npz" in msg
    assert all(f"levels.jsonl:{no}:" in msg for no in (3, 5, 6))
    assert kept.stat().st_mtime_ns == mtime  # the intact level was not recomputed
    assert (out / "levels.jsonl").read_text() == levels
    for name, a in arrays.items():
        b = read_npz(out / name)
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name}:{k}")
    stored = json.loads((out / "config.json").read_text())
    assert stored["precision"] == "float32" and stored["layout"] == {"chunk": 4, "devices": 1}
    # the tidy results table: one row per level × metric
    import csv

    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {r["unit"] for r in rows} == {f"level_{i:02d}" for i in range(len(arrays))}
    assert rows[0].keys() == {"study", "unit", "metric", "value"}
    edc = {r["metric"]: float(r["value"]) for r in rows
           if r["unit"] == "level_01" and r["metric"].startswith("reps/edc/")}
    assert edc["reps/edc/error_mean"] == json.loads(levels.splitlines()[1])["reps"]["edc"][
        "error_mean"]
    pd = pytest.importorskip("pandas")
    assert pd.read_csv(out / "results.csv")["value"].dtype == np.float64
    # a resume under float64 is refused: x64 draws differ (D7). (The CLI asks for all six
    # representations, so the message lists that difference too.)
    env = dict(os.environ, JAX_ENABLE_X64="1")
    proc = subprocess.run([sys.executable, "-m", "pqrm_jax.cli", "study", "padgett-mc", *TINY,
                           "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
                          env=env, timeout=120)
    assert proc.returncode == 2 and "precision: 'float32' there, 'float64' asked" in proc.stderr
    # another chunk layout changes float bits (D15): refused too
    with pytest.raises(StoreError, match="layout"):
        padgett_mc.run_study(dataclasses.replace(cfg, chunk_runs=3), out, quiet=True)


def test_padgett_mc_failed_table_dependency_fails_the_study(tmp_path, monkeypatch, capsys):
    import pqrm_jax.tables as tables
    from pqrm_jax.calculi import Calculus

    real = Calculus.neighbor_distance

    def broken(calc):  # what a truncated lr.json in the table cache gives
        if calc.name == "lr":
            raise tables.CacheError("table file lr.json is corrupt (truncated)")
        return real.fget(calc)

    monkeypatch.setattr(Calculus, "neighbor_distance", property(broken))
    out = tmp_path / "t"
    argv = ["--runs", "2", "--levels", "2", "--samples", "8", "--landmarks", "4", "--quiet",
            "--out", str(out)]
    with pytest.raises(StudyError, match="neighbour-distance table of 'lr'"):
        padgett_mc.main(argv)
    assert cli.main(["study", "padgett-mc", *argv]) == 2
    assert "lr.json is corrupt" in capsys.readouterr().err
    assert not (out / "levels.jsonl").exists() or not (out / "levels.jsonl").read_text()


@pytest.mark.slow
def test_padgett_mc_sigkill_and_resume_bit_identical(tmp_path):
    """The real study killed twice mid-run, then resumed: same files as one run."""
    argv = [sys.executable, "-m", "pqrm_jax.cli", "study", "padgett-mc", *TINY]
    ref = tmp_path / "ref"
    subprocess.run([*argv, "--out", str(ref)], check=True, cwd=ROOT, capture_output=True)
    out = tmp_path / "k"
    for delay in (8.0, 14.0):
        proc = subprocess.Popen([*argv, "--out", str(out)], cwd=ROOT,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    subprocess.run([*argv, "--out", str(out)], check=True, cwd=ROOT, capture_output=True)
    assert (out / "levels.jsonl").read_bytes() == (ref / "levels.jsonl").read_bytes()
    for p in ref.glob("level_*.npz"):
        a, b = read_npz(p), read_npz(out / p.name)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("text", ['{"traverse": 1, "wall_s": 3.2, "remo', "", "null",
                                  '{"traverse": 1}', "[]"])
def test_torn_or_wrong_json_record_is_recomputed(tmp_path, text):
    """mars-yard's per-traverse JSON (D9): a torn or wrong file reads as 'not done'."""
    from pqrm_jax.studies.store import read_json

    p = tmp_path / "traverse_1.json"
    p.write_text(text)
    with pytest.warns(CorruptRecordWarning, match="traverse_1.json"):
        assert read_json(p, ("traverse", "wall_s", "removed_pct")) is None
    assert not p.exists()


def test_directory_of_an_older_version_is_adopted_with_its_config(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.json").write_text(json.dumps({"runs": 4}))
    (old / "levels.jsonl").write_text("")
    legacy = ("config.json", "levels.jsonl")
    with pytest.raises(StoreError, match="runs: 4 there, 5 asked"):
        Store.open(old, "p", {"runs": 5, "layout": 1}, legacy=legacy, legacy_assume=("layout",))
    with pytest.warns(UserWarning, match="before studies recorded 'layout'"):
        Store.open(old, "p", {"runs": 4, "layout": 1}, legacy=legacy,
                   legacy_assume=("layout",)).close()
    assert json.loads((old / "study.json").read_text())["study"] == "p"
    serge_dir = tmp_path / "serge"  # serge kept its config in meta.json
    serge_dir.mkdir()
    (serge_dir / "meta.json").write_text(json.dumps({"trials": 8}))
    with pytest.raises(StoreError, match="trials: 8 there, 9 asked"):
        Store.open(serge_dir, "serge", {"trials": 9}, legacy=("meta.json",),
                   legacy_config="meta.json")


@pytest.mark.parametrize("damage", ["torn_row", "cut_at_row", "empty", "garbage", "header",
                                    "extra_cell"])
def test_corrupt_csv_record_is_named_and_set_aside(tmp_path, damage):
    """A checked CSV record (qlink's per-setting trials): any damage makes the file 'not done'."""
    fields = ["unit", "x"]
    p = tmp_path / "t.csv"
    good = csv_text(fields, [{"unit": i, "x": i / 4} for i in range(6)])
    p.write_text(good)
    assert read_csv(p, fields, check=lambda rows: len(rows) == 6)[5] == {"unit": "5",
                                                                        "x": "1.25"}
    lines = good.splitlines(keepends=True)
    bad = {"torn_row": "".join(lines[:-1]) + lines[-1][:2], "cut_at_row": "".join(lines[:-2]),
           "empty": "", "garbage": "\x00\x01garbage\n", "header": good.replace("x", "y", 1),
           "extra_cell": good.replace("1.25", "1.25,9")}[damage]
    p.write_text(bad)
    with pytest.warns(CorruptRecordWarning, match="t.csv"):
        assert read_csv(p, fields, check=lambda rows: len(rows) == 6) is None
    assert not p.exists() and (tmp_path / "t.csv.corrupt").exists()
